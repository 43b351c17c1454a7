"""The identities command as a user runs it: the README's line, the dvc it runs (this venv's
``python`` first on PATH), a failed repro that keeps the entries, removal that leaves nothing of
the identity and touches nothing else, and the dataset page that lists only real assets."""

from __future__ import annotations

import hashlib
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.errors import ScanError
from pipeline.synthetic_head import identity_files as idf
from stages import identities as ids

ROOT = Path(__file__).resolve().parents[1]


def _copy_params(folder) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "params.yaml"
    shutil.copyfile(ROOT / "params.yaml", p)
    return p


def _one_error_line(err: str, path) -> None:
    assert err.startswith(f"error: {path}: ") and err.count("\n") == 1, err


# ----------------------------------------------------------------------------- adding

def test_the_readme_command_adds_twenty(tmp_path):
    line = next(ln for ln in (ROOT / "README.md").read_text().splitlines()
                if ln.startswith(".venv/bin/python -m stages.identities"))
    words = shlex.split(line.split("#")[0])
    assert words[:3] == [".venv/bin/python", "-m", "stages.identities"]
    p = _copy_params(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, *words[1:], "--no-repro"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    names = [f"ident_s0_{i:03d}" for i in range(20)]
    assert done.stdout.splitlines()[-1] == "dvc repro " + " ".join(f"usd@{n}" for n in names)
    data = yaml.safe_load(p.read_text())
    assert list(data["identities"]) == ["synthetic_head", *names] and data["scans"] == ["synthetic_head", *names]


def test_dvc_runs_with_this_pythons_bin_first_on_path(tmp_path):
    venv = tmp_path / "venv" / "bin"
    venv.mkdir(parents=True)
    (venv / "python").symlink_to(sys.executable)        # as in a venv: a link to the base interpreter
    (venv / "dvc").write_text("#!/bin/sh\n")
    (venv / "dvc").chmod(0o755)
    env = idf.repro_env(venv / "python", {"PATH": "/usr/local/bin:/usr/bin", "HOME": "/h"})
    assert env == {"PATH": f"{venv}{os.pathsep}/usr/local/bin{os.pathsep}/usr/bin", "HOME": "/h"}
    argv, env = idf.repro_invocation(["a", "b"], venv / "python", {"PATH": "/usr/bin"})
    assert argv == [str(venv / "dvc"), "repro", "usd@a", "usd@b"]
    assert shutil.which("python", path=env["PATH"]) == str(venv / "python")
    assert idf.repro_env()["PATH"].split(os.pathsep)[0] == str(Path(sys.executable).parent)
    with pytest.raises(ScanError, match="has no dvc"):
        idf.repro_invocation(["a"], tmp_path / "bare" / "python", {"PATH": str(tmp_path / "nothing")})


def test_no_dvc_anywhere_leaves_params_unchanged(tmp_path, capsys, monkeypatch):
    p = _copy_params(tmp_path)
    before = p.read_bytes()
    monkeypatch.setattr(sys, "executable", str(tmp_path / "bare" / "python"))
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))
    assert ids.main(["--n", "2", "--params", str(p)]) == 2
    _one_error_line(capsys.readouterr().err, tmp_path / "bare")
    assert p.read_bytes() == before


def test_a_failed_repro_keeps_the_entries_and_says_what_to_rerun(tmp_path, capsys, monkeypatch):
    p = _copy_params(tmp_path)
    calls = []

    def call(argv, cwd, env):
        calls.append((argv, cwd, env))
        return 1

    monkeypatch.setattr(ids.subprocess, "call", call)
    assert ids.main(["--n", "2", "--params", str(p)]) == 1
    (argv, cwd, env), = calls
    assert Path(argv[0]).name == "dvc" and argv[1:] == ["repro", "usd@ident_s0_000", "usd@ident_s0_001"]
    assert cwd == tmp_path and env["PATH"].split(os.pathsep)[0] == str(Path(sys.executable).parent)
    assert list(yaml.safe_load(p.read_text())["identities"])[1:] == ["ident_s0_000", "ident_s0_001"]
    err = capsys.readouterr().err
    _one_error_line(err, p)
    assert "stay listed" in err and f"-m stages.identities --n 2 --params {p}`" in err and "--remove" in err


# ----------------------------------------------------------------------------- removing

NAMES = ("ident_s0_000", "ident_s0_001")


def _lock_block(stage, name):
    return (f"  {stage}@{name}:\n"
            f"    cmd: python -m stages.{stage} 'raw_scans/{name}' 'build/{name}/{stage}' --metrics \n"
            f"      'build/{name}/{stage}.metrics.json'\n"
            f"    deps:\n    - path: raw_scans/{name}\n      hash: md5\n"
            f"      md5: {hashlib.md5(f'{stage}@{name}'.encode()).hexdigest()}.dir\n      size: 10\n      nfiles: 2\n"
            f"    outs:\n    - path: build/{name}/{stage}\n      hash: md5\n      md5: 0f\n      size: 3\n")


def _project(tmp_path) -> tuple[Path, dict]:
    """A project: params.yaml with two identities and the scan ``home``, their folders, a dvc.lock."""
    p = _copy_params(tmp_path / "proj")
    assert ids.main(["--n", "2", "--params", str(p), "--no-repro"]) == 0
    p.write_text(p.read_text().replace("  - synthetic_head\n", "  - synthetic_head\n  - home\n", 1))
    root = p.parent
    blocks = {n: [_lock_block(s, n) for s in ("synthetic_head", "ingest", "usd")] for n in NAMES}
    blocks["home"] = [_lock_block(s, "home") for s in ("ingest", "usd")]
    head = "schema: '2.0'\nstages:\n  check_params:\n    cmd: python -m stages.check_params\n"
    order = [blocks[NAMES[0]][0], blocks["home"][0], blocks[NAMES[1]][0], blocks[NAMES[0]][1],
             blocks[NAMES[1]][1], blocks["home"][1], blocks[NAMES[1]][2], blocks[NAMES[0]][2]]
    (root / "dvc.lock").write_text(head + "".join(order))
    for n in (*NAMES, "home"):
        for rel in (f"raw_scans/{n}/scan.obj", f"build/{n}/ingest/mesh.npz", f"build/{n}/usd.metrics.json",
                    f"rigged_assets/{n}/{n}.usda", f"rigged_assets/{n}.preview.png", f"renders/{n}/000000.png"):
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(f"{n} {rel}".encode())
    return p, {"head": head, "order": order, "blocks": blocks}


def _tree(root) -> dict:
    return {f.relative_to(root).as_posix(): f.read_bytes() for f in sorted(Path(root).rglob("*")) if f.is_file()}


def test_remove_leaves_nothing_of_it_and_the_rest_byte_identical(tmp_path, capsys):
    p, lock = _project(tmp_path)
    root = p.parent
    before, params_before = _tree(root), p.read_text()
    capsys.readouterr()
    assert ids.main(["--remove", NAMES[0], "--params", str(p)]) == 0
    assert capsys.readouterr().out.count("\n") == 1
    gone = [k for k in before if NAMES[0] in k]
    assert len(gone) == 6
    after = _tree(root)
    assert set(after) == set(before) - set(gone)              # nothing left behind, no temp sibling
    assert {k: v for k, v in after.items() if k not in ("params.yaml", "dvc.lock")} == \
        {k: v for k, v in before.items() if k not in ("params.yaml", "dvc.lock", *gone)}
    assert not any((root / d / NAMES[0]).exists() for d in idf.OUTPUT_FOLDERS)
    assert not (root / "rigged_assets" / f"{NAMES[0]}.preview.png").exists()
    kept = [b for b in lock["order"] if b not in lock["blocks"][NAMES[0]]]
    assert (root / "dvc.lock").read_text() == lock["head"] + "".join(kept)
    data = yaml.safe_load(p.read_text())
    assert list(data["identities"]) == ["synthetic_head", NAMES[1]]
    assert data["scans"] == ["synthetic_head", "home", NAMES[1]]
    assert [ln for ln in params_before.split("\n") if NAMES[0] not in ln] == p.read_text().split("\n")
    # the other identity goes the same way, and then the marks are as a fresh params.yaml has them
    assert ids.main(["--remove", NAMES[1], "--params", str(p)]) == 0
    assert p.read_text() == (ROOT / "params.yaml").read_text().replace("  - synthetic_head\n",
                                                                       "  - synthetic_head\n  - home\n", 1)
    assert (root / "dvc.lock").read_text() == lock["head"] + "".join(lock["blocks"]["home"])
    assert sorted(_tree(root)) == sorted(k for k in before if "ident_" not in k)


@pytest.mark.parametrize("names", [["nope"], [NAMES[0], "nope"], ["home"], ["synthetic_head"]])
def test_remove_refuses_a_name_that_is_no_identity_in_one_line(tmp_path, capsys, names):
    p, _ = _project(tmp_path)
    before = _tree(p.parent)
    capsys.readouterr()
    assert ids.main(["--remove", *names, "--params", str(p)]) == 2
    err = capsys.readouterr().err
    _one_error_line(err, p)
    assert repr(names[-1]) in err
    assert _tree(p.parent) == before


def test_remove_refuses_a_symlinked_folder_and_changes_nothing(tmp_path, capsys):
    p, _ = _project(tmp_path)
    root = p.resolve().parent
    elsewhere = tmp_path / "elsewhere"
    shutil.move(root / "rigged_assets" / NAMES[0], elsewhere)
    (root / "rigged_assets" / NAMES[0]).symlink_to(elsewhere, target_is_directory=True)
    before, kept = _tree(root), _tree(elsewhere)
    capsys.readouterr()
    assert ids.main(["--remove", NAMES[0], "--params", str(p)]) == 2
    _one_error_line(capsys.readouterr().err, root / "rigged_assets" / NAMES[0])
    assert _tree(root) == before and _tree(elsewhere) == kept
    assert (root / "raw_scans" / NAMES[0]).is_dir()        # refused before the first change


def test_lock_edit_refuses_a_layout_it_cannot_cut(tmp_path):
    from pipeline.synthetic_head.identities import drop_lock_stages

    text = "schema: '2.0'\nstages: {usd@a: {cmd: x}, usd@b: {cmd: y}}\n"
    with pytest.raises(ScanError, match="dvc.lock: "):
        drop_lock_stages(text, ["a"], "dvc.lock")
    assert drop_lock_stages(text, ["c"], "dvc.lock") == (text, [])
    assert drop_lock_stages("", ["a"], "dvc.lock") == ("", [])
    real = (ROOT / "dvc.lock").read_text()                # dvc's own layout: wrapped cmd lines
    out, dropped = drop_lock_stages(real, ["synthetic_head"], "dvc.lock")
    assert len(dropped) == 10 and all(d.endswith("@synthetic_head") for d in dropped)   # synthetic_head .. preview
    kept = yaml.safe_load(out)["stages"]
    assert set(kept) == {k for k in yaml.safe_load(real)["stages"] if "@" not in k}
    assert all(line in real for line in out.split("\n"))


# ----------------------------------------------------------------------------- the dataset page

def test_dataset_page_lists_only_real_assets(tmp_path):
    from tests.fixtures.assets import images_per_asset

    for n in ("home", "ident_s0_000"):
        (tmp_path / "rigged_assets" / n).mkdir(parents=True)
        (tmp_path / "rigged_assets" / n / f"{n}.usda").write_text("#usda 1.0\n")
    (tmp_path / "rigged_assets" / "ident_s0_001").mkdir()            # never became an asset
    assets = sorted(str(d) for d in (tmp_path / "rigged_assets").iterdir())
    lines = images_per_asset({"ident_s0_001": 87, "home": 86, "ident_s0_000": 87, "gone": 3}, assets)
    assert lines == ["Images per asset: home 86, ident_s0_000 87",
                     "Not assets (no rigged_assets/<name>/<name>.usda), images labelled with them: "
                     "gone 3, ident_s0_001 87"]
    assert images_per_asset({"home": 1}, assets) == ["Images per asset: home 1"]
