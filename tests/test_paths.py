"""Ordinary paths work: every stage and the dataset command run from a clone whose own path holds
a space, a dot-folder and non-ASCII, given absolute paths through it. Only a scan folder's own
name is held to the safe-name rule (tests/test_check_params.py).

One run of the whole chain on a small synthetic head (about 40 s on two cores).
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
#: what keeps the run short: a coarser head and bake, no previews, two tiny renders
CHEAP = {"synthetic_head": {"target_triangles": 120000, "texture_size": 512},
         "retopo": {"metric_samples": 5000}, "bake": {"resolution": 256, "metric_samples": 5000},
         "eyeball": {"preview": False}, "usd": {"preview": False},
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
    assert [n for n, _ in commands][-1] == "render" and len(commands) == 11
    for name, argv in commands:
        r = subprocess.run(argv, cwd=clone, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0 and "error" not in r.stderr, (name, r.stderr[-2000:])
    assert (clone / "rigged_assets" / SCAN / f"{SCAN}.usdz").is_file()
    assert [row["index"] for row in read_index(clone / "renders" / SCAN / "index.jsonl")] == [0, 1]

    out = clone / "renders" / "out dir" / ".set é"
    r = subprocess.run([sys.executable, "-m", "stages.dataset", "--assets", str(clone / "rigged_assets" / SCAN),
                        "--n", "2", "--out", str(out), "--no-progress"], cwd=clone, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert [row["asset"] for row in read_index(out / "index.jsonl")] == [SCAN, SCAN]
