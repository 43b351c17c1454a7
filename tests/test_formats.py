"""The label-writer registry (pipeline/render/formats/): a format is one module, and everything
that names formats derives from the registry: the settings' choices, the dataset card's file
table, the files a re-planned render removes and what a finished image writes."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.render import formats
from pipeline.render.settings import RenderSettings
from pipeline.settings import SettingsError

ROOT = Path(__file__).resolve().parents[1]

TOY = '''"""A toy label format: the pupil centre as text."""
from pathlib import Path

NAME = "toy"
FILES = {"toy/NNNNNN.txt": "the pupil centre, pixels"}


def job(asset, smp):
    return None


def write(out_dir, index, label, job, png):
    p = Path(out_dir) / "toy" / f"{index:06d}.txt"
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(" ".join(map(str, label["landmarks"]["pupil_center_px"])))
    return [p]
'''


def test_every_format_module_has_the_interface():
    assert formats.NAMES[0] == formats.REQUIRED == "eyerig"
    assert set(formats.NAMES) >= {"unityeyes", "pts", "coco", "webdataset"}
    for name, m in formats.FORMATS.items():
        assert m.NAME == name and callable(m.job) and callable(m.write)
        dataset_files = getattr(m, "DATASET_FILES", {})
        assert m.FILES or dataset_files, name
        assert all("NNNNNN" in f for f in m.FILES), name
        assert bool(dataset_files) == callable(getattr(m, "finish", None)), name   # files <=> who writes them


def test_dataset_files_are_found_and_removed_with_the_derived_files(tmp_path):
    """Dataset-level files (coco.json, shards) are found by name, and every run removes them first."""
    from pipeline.render import run as rr

    names = ["coco.json", "shards/shard-000000.tar", "shards/shard-000012.tar"]
    others = ["coco.jsonl", "shards/shard-00001.tar", "shards/shard-000001.tar.gz", "shards/x.tar", "shard-000000.tar"]
    for n in names + others:
        (tmp_path / n).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / n).write_text("x")
    found = sorted(p.relative_to(tmp_path).as_posix() for _, p in formats.dataset_files(tmp_path))
    assert found == sorted(names)
    assert set(formats.dataset_table(tmp_path)) == {"coco.json", "shards/shard-SSSSSS.tar"}
    doomed = {p.relative_to(tmp_path).as_posix() for p in rr.doomed_files(tmp_path, lambda i: True)}
    assert doomed == set(names)


def test_finish_runs_the_listed_formats_only(tmp_path, monkeypatch):
    called = []
    for name in ("coco", "webdataset"):
        monkeypatch.setattr(formats.FORMATS[name], "finish",
                            lambda out, n, s, name=name: called.append((name, n)) or [])
    formats.finish_formats(tmp_path, 4, RenderSettings.from_params({"label_formats": ["eyerig", "webdataset"]}))
    assert called == [("webdataset", 4)]


def test_a_format_that_reads_masks_needs_them():
    with pytest.raises(SettingsError, match="render.masks must be true for label format coco"):
        RenderSettings.from_params({"label_formats": ["eyerig", "coco"], "masks": False})
    RenderSettings.from_params({"label_formats": ["eyerig", "webdataset"], "masks": False})


def test_settings_accept_exactly_the_registered_formats():
    s = RenderSettings.from_params({"preset": "unityeyes", "label_formats": list(formats.NAMES)})   # unityeyes needs it
    assert s.label_formats == formats.NAMES


def test_image_files_finds_every_format_file_and_nothing_else(tmp_path):
    names = [n.replace("NNNNNN", f"{i:06d}") for i in (0, 7) for n in formats.file_table()]
    for n in names + ["000001.txt", "notes.json", "00001.png", "000003_seg.jpg", "unityeyes/x.json"]:
        (tmp_path / n).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / n).write_text("x")
    found = sorted((i, p.relative_to(tmp_path).as_posix()) for i, p in formats.image_files(tmp_path))
    assert found == sorted((int(n.rpartition("/")[2][:6]), n) for n in names)


def test_write_formats_writes_the_label_last(tmp_path, monkeypatch):
    order = []
    for name, m in formats.FORMATS.items():
        monkeypatch.setattr(m, "write", lambda out, i, label, job, png, name=name: order.append(name) or [])
    formats.write_formats(tmp_path, 3, {}, {"formats": ["pts", "unityeyes"]}, None)
    assert order == ["pts", "unityeyes", "eyerig"]
    order.clear()
    formats.write_formats(tmp_path, 3, {}, None, None)          # only the required label
    assert order == ["eyerig"]


def test_a_new_format_is_one_module(tmp_path):
    """In a copy of the project, one new file in pipeline/render/formats/ is accepted by the
    settings, written for an image, described on the card, removed with its image and counted in
    the render stage's code (dvc deps, fingerprint)."""
    shutil.copytree(ROOT / "pipeline", tmp_path / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "stages", tmp_path / "stages", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "pipeline" / "render" / "formats" / "toy.py").write_text(TOY)
    script = """
import json, sys
from pathlib import Path
from pipeline import sources
from pipeline.render import formats
from pipeline.render.settings import RenderSettings
out = Path(sys.argv[1])
s = RenderSettings.from_params({"label_formats": ["eyerig", "toy"]})
job = formats.format_job(None, None, s.label_formats)
written = formats.write_formats(out, 5, {"landmarks": {"pupil_center_px": [1.5, 2.5]}}, job, None)
print(json.dumps({"names": list(formats.NAMES), "written": [p.relative_to(out).as_posix() for p in written],
                  "card": formats.describe("toy/NNNNNN.txt"),
                  "found": sorted(p.relative_to(out).as_posix() for _, p in formats.image_files(out)),
                  "closure": "pipeline/render/formats/toy.py" in sources.stage_closure("render")}))
"""
    (tmp_path / "out").mkdir()
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path / "out")], cwd=tmp_path,
                       capture_output=True, text=True, env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(tmp_path)})
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert "toy" in got["names"]
    assert got["written"] == ["toy/000005.txt", "000005.json"]
    assert got["card"] == "the pupil centre, pixels"
    assert got["found"] == ["000005.json", "toy/000005.txt"]
    assert got["closure"]
    assert np.allclose([float(x) for x in (tmp_path / "out" / "toy" / "000005.txt").read_text().split()], [1.5, 2.5])
