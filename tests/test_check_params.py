"""Stage ``check_params``: scan names are data, never shell syntax; every block is checked first."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.errors import ScanError
from pipeline.settings import check_scan_name
from stages import check_params as cp
from stages._common import run_stage

from fixtures import defaults_params, params_file

ROOT = Path(__file__).resolve().parents[1]
EVIL = "scan$(touch${IFS}PWNED)"


@pytest.mark.parametrize("name", ["synthetic_head", "ict_neutral", "james-2", "A.b_c", "x"])
def test_safe_names_pass(name):
    assert check_scan_name(name) == name


@pytest.mark.parametrize("name", [EVIL, "../../x", "..", ".", ".hidden", "", "a b", "a/b", "a;b", "a'b",
                                  'a"b', "a`id`", "a\nb", "name\n", "é", "x" * 129, 12, None])
def test_unsafe_names_refused_naming_params_yaml(name):
    with pytest.raises(ScanError) as exc:
        check_scan_name(name)
    assert str(exc.value).startswith("params.yaml: scans: ") and "not a safe scan name" in str(exc.value)


def _params(tmp_path, **changes) -> Path:
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data.update(changes)
    p = tmp_path / "params.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


def test_the_repository_params_pass(tmp_path, capsys):
    out = tmp_path / "check_params.ok"
    assert run_stage(cp.main, [str(ROOT / "params.yaml"), str(out)]) == 0
    assert out.read_text() == cp.OK_TEXT


@pytest.mark.parametrize("scans, message", [
    (["synthetic_head", EVIL], f"params.yaml: scans: {EVIL!r} is not a safe scan name"),
    (["../../x"], "params.yaml: scans: '../../x' is not a safe scan name"),
    (["a", "a"], "params.yaml: scans: 'a' is listed twice"),
    ("synthetic_head", "params.yaml: scans must be a list"),
])
def test_bad_scans_refused_one_line_exit_2(tmp_path, capsys, scans, message):
    p = _params(tmp_path, scans=scans)
    out = tmp_path / "check_params.ok"
    assert run_stage(cp.main, [str(p), str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("block, key, value, message", [
    ("bake", "max_distance_mm", -4, "bake.max_distance_mm must be > 0 (got -4)"),
    ("render", "n_images", "1e9", "render.n_images must be <= 1000000"),
    ("snap", "falloff_mm", float("nan"), "snap.falloff_mm must be a finite number"),
    ("rig", "max_segment", 3, "rig.max_segment is an unknown key"),
    ("ingest", "max_vertex", 3, "max_vertex"),
])
def test_bad_settings_refused_before_any_stage(tmp_path, capsys, block, key, value, message):
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data[block][key] = value
    p = tmp_path / "params.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    assert run_stage(cp.main, [str(p), str(tmp_path / "ok")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith(f"error: {p}: ") and err.count("\n") == 1


def test_unknown_block_refused(tmp_path, capsys):
    p = _params(tmp_path, retopology={"target_polygons": 10})
    assert run_stage(cp.main, [str(p), str(tmp_path / "ok")]) == 2
    assert "'retopology' is not a block of this pipeline" in capsys.readouterr().err


#: the stages that take a scan's name from a folder's own name, and where that folder is
SCAN_FOLDER = {"ingest": (0, 2), "usd": (5, 6), "synthetic_head": (0, 1)}


@pytest.mark.parametrize("stage", sorted(SCAN_FOLDER))
def test_stages_refuse_an_unsafe_scan_folder_name(tmp_path, capsys, monkeypatch, stage):
    """Defence in depth: a stage run by hand (or by DVC without check_params) refuses a scan
    folder whose own name is not a safe scan name, whatever the folders above it are called."""
    import importlib

    mod = importlib.import_module(f"stages.{stage}")
    at, n_pos = SCAN_FOLDER[stage]
    argv = [str(tmp_path / "ok")] * n_pos
    argv[at] = f"My Scans/{EVIL}"
    monkeypatch.chdir(tmp_path)
    assert run_stage(mod.main, argv) == 2
    err = capsys.readouterr().err
    assert err == f"error: My Scans/{EVIL}: {EVIL!r} is not a safe scan name (use 1-128 letters, digits, " \
                  "'.', '_' or '-', not starting with '.')\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [] and not list(tmp_path.rglob("PWNED"))
    for name in ("..", ".hidden", "a b"):
        argv[at] = f"raw_scans/{name}"
        with pytest.raises(ScanError, match=f"raw_scans/{name}: '{name}' is not a safe scan name"):
            mod.main(argv)


ORDINARY = ("My Scans", ".local", "out dir", "données.v2", "..", "x y")


@pytest.mark.parametrize("stage", ["ingest", "remove_eyeballs", "retopo", "bake", "snap", "rig", "usd", "render"])
def test_stages_take_ordinary_parent_paths(tmp_path, capsys, stage):
    """Spaces, dots, leading dots, non-ASCII and '..' in the folders above a scan folder are
    ordinary: the stage goes on to read its (here missing) inputs. A whole run: test_paths.py."""
    import importlib

    mod = importlib.import_module(f"stages.{stage}")
    base = tmp_path.joinpath(*ORDINARY)
    n_pos = {"ingest": 2, "remove_eyeballs": 2, "retopo": 2, "bake": 3, "snap": 4, "rig": 2, "usd": 6,
             "render": 3}[stage]
    argv = [str(base / "scan" / f"in{k}") for k in range(n_pos)]
    assert run_stage(mod.main, argv + ["--params", str(defaults_params(tmp_path))]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {base}") and "safe" not in err and err.count("\n") == 1, err


@pytest.mark.slow
def test_dvc_repro_with_a_malicious_scan_runs_nothing(tmp_path):
    """``dvc repro`` in a copy of the pipeline with ``scan$(touch${IFS}PWNED)`` listed: check_params
    refuses it first (every stage depends on it), so nothing runs and no PWNED appears."""
    dvc = Path(sys.executable).with_name("dvc")
    if not dvc.is_file():
        pytest.fail(f"dvc not installed next to {sys.executable}")
    repo = tmp_path / "repo"
    repo.mkdir()
    for name in ("dvc.yaml", "pyproject.toml"):
        shutil.copy(ROOT / name, repo / name)
    for d in ("stages", "pipeline"):
        shutil.copytree(ROOT / d, repo / d, ignore=shutil.ignore_patterns("__pycache__"))
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data["scans"] = ["synthetic_head", EVIL]
    (repo / "params.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    (repo / "raw_scans" / EVIL).mkdir(parents=True)
    env = {**os.environ, "PATH": f"{dvc.parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    subprocess.run([str(dvc), "init", "--no-scm", "-q"], cwd=repo, check=True, env=env)
    res = subprocess.run([str(dvc), "repro"], cwd=repo, env=env, capture_output=True, text=True, timeout=300)
    text = res.stdout + res.stderr
    assert res.returncode != 0
    assert f"params.yaml: scans: {EVIL!r} is not a safe scan name" in text
    assert "Running stage 'synthetic_head'" not in text and "Running stage 'ingest" not in text
    assert not list(tmp_path.rglob("PWNED")) and not (repo / "build" / "check_params.ok").exists()
    assert not (repo / "raw_scans" / "synthetic_head").exists()


# ---------------------------------------------------------------------------- strict settings (issue 31)

def _params_text(tmp_path, edit) -> Path:
    """The repository's params.yaml with ``edit(text) -> text`` applied (comments kept)."""
    text = (ROOT / "params.yaml").read_text()
    p = tmp_path / "params.yaml"
    p.write_text(edit(text))
    return p


def _twice(text):            # samples given twice under render: (the second one would win)
    assert "\n  samples: 10 " in text
    return text.replace("\nrender:\n", "\nrender:\n  samples: 99\n", 1)


def _no_render(text):
    return text[:text.index("\nrender:\n") + 1]


def _dataset(tmp_path, params):
    from stages import dataset

    return dataset.main(["--assets", str(tmp_path / "no_asset"), "--n", "2", "--out", str(tmp_path / "ds"),
                         "--params", str(params), "--no-progress"])


def test_duplicate_key_refused_by_check_params_and_dataset(tmp_path, capsys):
    p = _params_text(tmp_path, _twice)
    assert run_stage(cp.main, [str(p), str(tmp_path / "ok")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {p}: duplicate key 'samples'") and err.count("\n") == 1, err
    assert not (tmp_path / "ok").exists()
    assert _dataset(tmp_path, p) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {p}: duplicate key 'samples'") and err.count("\n") == 1, err
    assert not (tmp_path / "ds").exists()


def test_missing_block_refused_by_check_params_and_dataset(tmp_path, capsys):
    p = _params_text(tmp_path, _no_render)
    assert run_stage(cp.main, [str(p), str(tmp_path / "ok")]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {p}: render: block is missing (every block of this pipeline must be there; " \
                  "missing: render)\n"
    assert not (tmp_path / "ok").exists()
    assert _dataset(tmp_path, p) == 2
    assert capsys.readouterr().err == f"error: {p}: {_NO_BLOCK.format(block='render')}\n"
    assert not (tmp_path / "ds").exists()


_NO_BLOCK = "no '{block}' block (every stage's block is required; see docs/settings.md)"
#: stage -> (positional arguments, the last one its output; extra arguments; the blocks it reads)
_READS = {
    "ingest": (2, [], ["ingest"]),
    "remove_eyeballs": (2, [], ["remove_eyeballs", "eyeball"]),
    "retopo": (2, [], ["retopo"]),
    "bake": (3, [], ["bake"]),
    "snap": (4, [], ["snap"]),
    "rig": (2, [], ["rig"]),
    "usd": (6, [], ["ingest", "remove_eyeballs", "retopo", "bake", "snap", "rig", "eyeball", "usd"]),
    "eyeball": (1, [], ["eyeball"]),
    "render": (3, [], ["render"]),
    "synthetic_head": (1, [], ["synthetic_head"]),
    "synthetic_head --identity": (1, ["--identity", "synthetic_head"], ["synthetic_head", "identities"]),
}


def _stage_argv(work, stage):
    n_pos, extra, _ = _READS[stage]
    return [str(work / f"in{k}") for k in range(n_pos - 1)] + [str(work / "scan"), *extra]


@pytest.mark.parametrize("stage, block", [(s, b) for s, (_, _, blocks) in _READS.items() for b in blocks])
def test_stage_refuses_an_existing_params_file_without_its_block(tmp_path, capsys, stage, block):
    """A stage run by hand (``--params FILE``) with a FILE that is there but lacks a block the
    stage reads: exit 2, one line naming the file and the block, nothing written; a stage that
    reads several blocks (remove_eyeballs, usd, synthetic_head --identity) needs each."""
    import importlib

    mod = importlib.import_module(f"stages.{stage.split()[0]}")
    p = params_file(tmp_path, drop=[block])
    work = tmp_path / "work"
    assert run_stage(mod.main, _stage_argv(work, stage) + ["--params", str(p)]) == 2
    assert capsys.readouterr().err == f"error: {p}: {_NO_BLOCK.format(block=block)}\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["params.yaml"]


@pytest.mark.parametrize("stage", ["ingest", "remove_eyeballs", "bake", "snap", "rig", "usd", "render"])
def test_a_params_path_that_is_not_there_is_refused(tmp_path, capsys, stage):
    """``--params PATH`` with nothing at PATH (a typo, a relative path from another folder): exit 2,
    one line naming PATH, nothing written; never a silent run on the defaults. Without
    ``--params`` a stage reads ./params.yaml, and where there is none every block is its defaults,
    as is a block left empty (``render:``)."""
    import importlib

    from pipeline.params_check import BLOCKS, settings_class
    from stages._common import load_params, load_settings

    none = tmp_path / "none.yaml"
    mod = importlib.import_module(f"stages.{stage}")
    work = tmp_path / "work"
    assert run_stage(mod.main, _stage_argv(work, stage) + ["--params", str(none)]) == 2
    assert capsys.readouterr().err == (f"error: {none}: no such params file "
                                       "(leave --params out to read ./params.yaml)\n")
    assert list(tmp_path.iterdir()) == []
    for block in BLOCKS:
        cls = settings_class(block)
        assert load_params(block, none) == {} and load_settings(cls, none) == cls.from_params({})
    empty = params_file(tmp_path, {"render": None})
    assert load_params("render", empty) == {}
    defaults = defaults_params(tmp_path)
    assert run_stage(mod.main, _stage_argv(work, stage) + ["--params", str(defaults)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {work}") and err.count("\n") == 1, err


def test_duplicate_key_in_a_set_value_refused(tmp_path, capsys):
    from stages import dataset

    assert dataset.main(["--assets", str(tmp_path / "a"), "--n", "2", "--out", str(tmp_path / "ds"),
                         "--params", str(ROOT / "params.yaml"), "--set", "cycles={x: 1, x: 2}"]) == 2
    assert "duplicate key 'x'" in capsys.readouterr().err
