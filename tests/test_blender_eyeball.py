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
