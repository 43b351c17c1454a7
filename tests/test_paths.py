"""Ordinary paths work: every stage and the dataset command run from a clone whose own path holds
a space, a dot-folder and non-ASCII, given absolute paths through it. Only a scan folder's own
name is held to the safe-name rule (tests/test_check_params.py).

One run of the whole chain on a small synthetic head (about 40 s on two cores). And the chain reads
nothing outside the repository: a copy of the project with no ../shared beside it writes the same
bytes as this checkout (through retopo, about 30 s).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline.io.labels_file import read_index

ROOT = Path(__file__).resolve().parents[1]
SCAN = "synthetic_head"
#: what keeps the run short: a coarser head and bake, tiny previews, two tiny renders
CHEAP = {"synthetic_head": {"target_triangles": 120000, "texture_size": 512},
         "retopo": {"metric_samples": 5000}, "bake": {"resolution": 256, "metric_samples": 5000},
         "eyeball": {"preview_px": 16, "preview_samples": 1}, "usd": {"preview_px": 16, "preview_samples": 1},
         "render": {"n_images": 2, "width": 48, "height": 32, "samples": 1, "denoise": False, "workers": 1}}


def _commands(clone: Path) -> list[tuple[str, list[str]]]:
    """``(stage, argv)`` of every stage in dvc.yaml's order, for the scan, each quoted path made
    absolute under ``clone``."""
    stages = yaml.safe_load((clone / "dvc.yaml").read_text())["stages"]
    out = []
    for name, st in stages.items():
        cmd = st["do"]["cmd"].replace("${item}", SCAN).replace("${key}", SCAN) if "foreach" in st else st["cmd"]
        # every quoted path made absolute; an identity's name is a name, not a path
        cmd = re.sub(r"'([^']*)'", lambda m: m.group(0) if m.string[:m.start()].endswith("--identity ")
                     else shlex.quote(str(clone / m.group(1))), cmd)
        argv = shlex.split(cmd)
        assert argv[:2] == ["python", "-m"], cmd
        out.append((name, [sys.executable, *argv[1:]]))
    return out


@pytest.mark.slow
@pytest.mark.blender
def test_every_stage_and_the_dataset_command_run_from_a_clone_under_odd_folders(tmp_path):
    clone = tmp_path / "My Scans ü" / ".local" / "eyerig clone"
    clone.mkdir(parents=True)
    for d in ("pipeline", "stages"):
        shutil.copytree(ROOT / d, clone / d, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "dvc.yaml", clone / "dvc.yaml")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["scans"] = [SCAN]
    for block, values in CHEAP.items():
        params[block].update(values)
    (clone / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    for d in ("raw_scans", "rigged_assets"):
        (clone / d).mkdir()
    env = {**os.environ, "PYTHONPATH": str(clone)}          # the clone's code, not this checkout's

    commands = _commands(clone)
    assert [n for n, _ in commands][0] == "code" and [n for n, _ in commands][-1] == "preview"
    assert len(commands) == 14
    for name, argv in commands:
        r = subprocess.run(argv, cwd=clone, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0 and "error" not in r.stderr, (name, r.stderr[-2000:])
    assert (clone / "rigged_assets" / SCAN / f"{SCAN}.usdz").is_file()
    assert (clone / "rigged_assets" / f"{SCAN}.preview.png").is_file()
    assert (clone / "rigged_assets" / "eyeball.preview.png").is_file()
    assert [row["index"] for row in read_index(clone / "renders" / SCAN / "index.jsonl")] == [0, 1]

    out = clone / "renders" / "out dir" / ".set é"
    r = subprocess.run([sys.executable, "-m", "stages.dataset", "--assets", str(clone / "rigged_assets" / SCAN),
                        "--n", "2", "--out", str(out), "--no-progress"], cwd=clone, env=env, capture_output=True,
                       text=True, timeout=600)
    # nothing on stderr but the asset's own doubts, which name it where it lies
    noise = [ln for ln in r.stderr.splitlines()
             if not ln.startswith(f"warning: {clone / 'rigged_assets' / SCAN}: ")]
    assert r.returncode == 0 and noise == [], r.stderr
    assert [row["asset"] for row in read_index(out / "index.jsonl")] == [SCAN, SCAN]


#: the per-scan chain this test runs (every stage that read ../shared before stops at remove_eyeballs)
SELF_CONTAINED = ("synthetic_head", "ingest", "remove_eyeballs", "retopo")
#: a small head and a cheap retopo metric keep it short
SMALL = {"synthetic_head": {"target_triangles": 80000, "texture_size": 256}, "retopo": {"metric_samples": 5000}}


def _project_copy(dst: Path) -> Path:
    """The project's files (tracked, and new ones git does not ignore) copied to ``dst``."""
    r = subprocess.run(["git", "ls-files", "-z", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True)
    if r.returncode != 0:
        pytest.skip("not a git checkout")
    for rel in filter(None, r.stdout.decode().split("\0")):
        src = ROOT / rel
        if rel == ".venv" or src.is_symlink() or not src.is_file():
            continue
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst / rel)
    return dst


def _chain(root: Path, out: Path | None) -> list[list[str]]:
    """dvc.yaml's commands of :data:`SELF_CONTAINED` for the scan, as DVC runs them in ``root``;
    with ``out``, the scan and build paths moved under ``out`` (other paths left as they are)."""
    stages = yaml.safe_load((root / "dvc.yaml").read_text())["stages"]
    cmds = []
    for name in SELF_CONTAINED:
        cmd = stages[name]["do"]["cmd"].replace("${item}", SCAN).replace("${key}", SCAN)
        if out is not None:
            cmd = re.sub(r"'((?:raw_scans|build)/[^']*)'", lambda m: shlex.quote(str(out / m.group(1))), cmd)
        argv = shlex.split(cmd)
        assert argv[:2] == ["python", "-m"], cmd
        cmds.append([sys.executable, *argv[1:]])
    return cmds


@pytest.mark.slow
def test_the_chain_reads_nothing_outside_the_repository(tmp_path):
    """A copy of the project with no ../shared beside it runs the per-scan chain through retopo (every
    stage that read outside the repository: remove_eyeballs' eye-region prior) on a small procedural
    head, as DVC runs it there, and writes the same bytes as the same commands run in this checkout."""
    clone = _project_copy(tmp_path / "eyerig")
    assert not (clone.parent / "shared").exists()
    params = yaml.safe_load((clone / "params.yaml").read_text())
    params["scans"] = [SCAN]
    for block, values in SMALL.items():
        params[block].update(values)
    (clone / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    here = tmp_path / "here"
    here.mkdir()
    shutil.copyfile(clone / "params.yaml", here / "params.yaml")
    env = {k: v for k, v in os.environ.items() if k != "EYERIG_EXTRA_SCANS"}
    for cwd, cmds, params_file in ((clone, _chain(clone, None), "params.yaml"),
                                   (ROOT, _chain(ROOT, here), str(here / "params.yaml"))):
        for argv in cmds:
            r = subprocess.run(argv + ["--params", params_file], cwd=cwd, capture_output=True, text=True,
                               env={**env, "PYTHONPATH": str(cwd)}, timeout=600)
            assert r.returncode == 0 and "error" not in r.stderr, (cwd, argv, r.stderr[-2000:])
    outputs = [p.relative_to(clone) for d in (f"raw_scans/{SCAN}", "build") for p in sorted((clone / d).rglob("*"))
               if p.is_file() and not p.name.endswith(".timings.json")]
    assert any(p.name == "eyes.json" for p in outputs) and any(p.match("build/*/retopo/*") for p in outputs)
    for rel in outputs:
        mine, theirs = (clone / rel).read_bytes(), (here / rel).read_bytes()
        if rel.name == "scan.json":          # ingest records the scan folder it was given
            theirs = theirs.replace(str(here).encode() + b"/", b"")
        assert mine == theirs, rel
