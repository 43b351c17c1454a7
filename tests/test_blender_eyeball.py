"""Blender round trip of the eyeball asset (Blender's own USD importer, in a subprocess)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pipeline.eyeball import geometry as geo

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    from PIL import Image

    from pipeline.eyeball import textures as tex
    from pipeline.usd.eyeball import write_eyeball_usd

    d = tmp_path_factory.mktemp("bl_eyeball")
    (d / "textures").mkdir()
    for name, img in tex.texture_set(0, 32, (32, 16)).items():
        Image.fromarray(img).save(d / "textures" / name)
    eye = geo.build_eyeball(resolution="high")
    usda = write_eyeball_usd(eye, d / "eyeball.usda")
    out = d / "rt.npz"
    from pipeline.blender import launch

    res = subprocess.run(launch.command("pipeline.blender.usd_roundtrip", [usda, out]),
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    data = dict(np.load(out))
    return eye, data, json.loads(str(data["meta"]))


def test_meshes_and_materials_imported(imported):
    eye, data, meta = imported
    objs = meta["objects"]
    assert set(objs) == {"Outer", "Inner"}
    assert objs["Outer"]["vertices"] == len(eye.outer.V)
    assert objs["Inner"]["vertices"] == len(eye.inner.V)
    assert objs["Inner"]["polygons"] == len(eye.inner.poly_counts)
    assert set(objs["Inner"]["materials"]) == {"Pupil", "Iris", "Sclera"}
    assert set(objs["Outer"]["materials"]) == {"Cornea", "ScleraCoat"}
    # metersPerUnit 0.001 -> Blender metres; Y-up -> Z-up: the eye looks down Blender -Y
    M = data["Inner.matrix_world"]
    assert objs["Inner"]["world_scale"] == pytest.approx(0.001, rel=1e-6)
    fwd = M[:3, :3] @ [0, 0, 1.0]
    assert np.allclose(fwd / np.linalg.norm(fwd), [0, -1, 0], atol=1e-6)
    assert np.abs(data["Inner.basis"] - eye.inner.V).max() < 1e-4      # mm, float32


def test_shape_key_offsets_match_usd(imported):
    eye, data, meta = imported
    assert meta["objects"]["Inner"]["shape_keys"] == list(geo.SHAPE_NAMES)
    basis = data["Inner.basis"]
    for s in eye.shapes:
        off = data[f"Inner.key.{s.name}"] - basis
        full = np.zeros_like(off)
        full[s.point_indices] = s.offsets
        assert np.abs(off - full).max() < 1e-4, s.name          # mm


def test_eyeball_preview_stage_writes_the_sheet_beside_the_asset(tmp_path):
    """stages.eyeball_preview renders the sheet of an eyeball asset (4 colours x 4 views) into the
    file it is given, through a temporary sibling, and leaves the asset folder as it was."""
    from pipeline.usd.eyeball_asset import build_eyeball_asset
    from stages import eyeball_preview
    from stages._common import read_stage_metrics, run_stage

    folder = tmp_path / "eyeball"
    build_eyeball_asset(folder, {"resolution": "low", "iris_texture_px": 32, "sclera_texture_px": [32, 16]})
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    params = tmp_path / "params.yaml"
    params.write_text("eyeball:\n  preview_px: 16\n  preview_samples: 1\n")
    png, metrics = tmp_path / "eyeball.preview.png", tmp_path / "eyeball_preview.metrics.json"
    assert run_stage(eyeball_preview.main, [str(folder), str(png), "--params", str(params),
                                            "--metrics", str(metrics)]) == 0
    from PIL import Image

    assert Image.open(png).size == (4 * 16 + 5 * 4 + 60, 4 * 16 + 5 * 4 + 16)
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before
    assert [p.name for p in tmp_path.iterdir() if ".tmp" in p.name] == []
    m = read_stage_metrics(metrics)
    assert m["tiles"] == 16 and m["size"] == 16 and m["samples"] == 1 and m["wall_s"] > 0
