"""Blender round trip of the per-scan asset (Blender's own USD importer, in a subprocess)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fixtures import EYES, make_inputs, usd_argv, usd_roundtrip
from stages import usd as usd_stage
from stages._common import run_stage

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.blender
POSE_DEG = 20.0


def _usd_to_blender(P_mm):
    """Stage (Y up, mm) -> Blender world (Z up, metres)."""
    P = np.asarray(P_mm, np.float64) * 0.001
    return np.stack([P[..., 0], -P[..., 2], P[..., 1]], -1)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("bl_asset")
    inp = make_inputs(root)
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    usda = inp["out"] / "tiny.usda"
    res = {}
    for key, pose in (("rest", None), ("posed", {"eye_left": [1, 0, 0, POSE_DEG]})):
        res[key] = usd_roundtrip(usda, root / f"{key}.npz", pose)
    return inp, res


def _eye_objects(meta, side):
    return {n: o for n, o in meta["objects"].items() if o["parent"] == f"eye_{side}"}


def test_mesh_uvs_materials_and_shape_keys(imported):
    inp, res = imported
    data, meta = res["rest"]
    o = meta["objects"]["EyeRegion"]
    assert o["vertices"] == len(inp["V"]) and o["polygons"] == len(inp["F"])
    assert o["uv_layers"] == ["st"]
    assert o["materials"] == ["Skin"]
    imgs = [Path(p).name for p in o["images"]["Skin"]]
    assert sorted(imgs) == ["color.png", "displacement.exr"]
    assert np.abs(data["EyeRegion.basis"] - inp["V"]).max() < 1e-4
    # Blender imports the full shapes (not the inbetweens) as shape keys
    assert o["shape_keys"] == ["lids_up", "lids_down"]
    for s in inp["shapes"]:
        off = data[f"EyeRegion.key.{s.name}"] - data["EyeRegion.basis"]
        full = np.zeros_like(off)
        full[s.point_indices] = s.offsets
        assert np.abs(off - full).max() < 1e-4, s.name            # mm


def test_armature_and_eyes(imported):
    inp, res = imported
    data, meta = res["rest"]
    arm = meta["armatures"]["Skel"]
    assert arm["bones"] == ["head", "eye_left", "eye_right"]
    for side in ("left", "right"):
        head = np.asarray(arm["heads"][arm["bones"].index(f"eye_{side}")])
        assert np.abs(head - EYES[side]["center"]).max() < 1e-4      # armature space = stage mm
        eyes = _eye_objects(meta, side)
        assert len(eyes) == 2                                        # Outer + Inner
        for name, o in eyes.items():
            assert o["modifiers"] == [["ARMATURE", "Skel"]] and o["vertex_groups"] == [f"eye_{side}"]
            assert o["world_scale"] == pytest.approx(0.001, rel=1e-5)     # placed, not scaled
        outer = next(n for n, o in eyes.items() if "Cornea" in " ".join(o["materials"]))
        W = data[f"{outer}.world"]
        c = _usd_to_blender(EYES[side]["center"])
        f = _usd_to_blender(np.asarray(EYES[side]["forward"])) * 1000
        local = data[f"{outer}.basis"]
        apex = W[np.argmax(local[:, 2])]
        d = (apex - c) / np.linalg.norm(apex - c)
        assert np.allclose(d, f, atol=1e-4)                           # looks down the fitted forward
        assert np.linalg.norm(apex - c) == pytest.approx(0.001 * local[:, 2].max(), rel=1e-4)
        # the eye placed at the fitted radius: its cornea keeps the asset's 1.5 mm protrusion
        assert local[:, 2].max() == pytest.approx(EYES[side]["radius"] + 1.5, abs=1e-3)
        inner = next(n for n in eyes if n != outer)
        assert any(Path(p).name == "iris_brown.png" for p in eyes[inner]["images"].values() for p in p)


def test_rotating_the_bone_turns_the_eye(imported):
    inp, res = imported
    (rest, meta), (posed, meta_p) = res["rest"], res["posed"]
    for side in ("left", "right"):
        c = _usd_to_blender(EYES[side]["center"])
        for name in _eye_objects(meta, side):
            A, B = rest[f"{name}.world"], posed[f"{name}.world"]
            assert np.allclose(np.linalg.norm(A - c, axis=1), np.linalg.norm(B - c, axis=1), atol=1e-6)
            a, b = A - c, B - c
            cosang = np.sum(a * b, 1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
            ang = np.degrees(np.arccos(np.clip(cosang, -1, 1))).max()
            if side == "left":
                assert ang == pytest.approx(POSE_DEG, abs=0.05)     # rigid rotation about the centre
            else:
                assert ang < 1e-3                                   # the other eye stays
    # the skin does not follow the eye bones
    assert np.abs(rest["EyeRegion.world"] - posed["EyeRegion.world"]).max() < 1e-9
