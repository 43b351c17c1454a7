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


_CARUNCLE_SCRIPT = r"""
import json, sys
import bpy
from pipeline.blender.materials import CARUNCLE_WEIGHT_ATTRIBUTE, eye_region_materials
from pipeline.blender.scene import find_image, import_usd

objs = import_usd(sys.argv[1], unit_conversion=True)
skin = next(o for o in objs if o.name == "EyeRegion")
a = skin.data.attributes.get(CARUNCLE_WEIGHT_ATTRIBUTE)
mats = eye_region_materials(skin, find_image([skin], "Skin", "color"), None, Roughness=0.45)
out = {"domain": a.domain, "type": a.data_type, "values": [d.value for d in a.data], "materials": {}}
for m in mats:
    nt = m["nt"]
    b = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    def src(sock):
        return [(l.from_node.type, getattr(l.from_node, "attribute_name", ""), l.from_socket.name)
                for l in sock.links]
    mixes = [n for n in nt.nodes if n.type == "MIX"]
    out["materials"][m["mat"].name.split(".")[0]] = {
        "base": src(b.inputs["Base Color"]), "roughness": src(b.inputs["Roughness"]),
        "factors": [src(n.inputs["Factor"]) for n in mixes],
        "rough_ab": [[n.inputs[2].default_value, n.inputs[3].default_value] for n in mixes
                     if n.data_type == "FLOAT"]}
print("RESULT" + json.dumps(out))
"""


def test_the_caruncle_grows_out_of_the_lids_by_its_weight(tmp_path):
    """Blender imports the asset's ``primvars:caruncleWeight`` as a point attribute with the
    same values, and the caruncle material mixes the skin's colour map (weight 0, the lid margin)
    into the reddened one (weight 1) and the skin's roughness into the caruncle's by it; the
    skin material never reads it."""
    import subprocess
    import sys

    from pipeline.geometry.corners import CARUNCLE_ROUGHNESS
    from pipeline.io.meshfile import load_mesh, save_mesh

    inp = make_inputs(tmp_path)
    path = inp["dirs"]["snap"] / "mesh.npz"
    mesh = dict(load_mesh(path))
    w = np.round(np.linspace(0.0, 1.0, len(mesh["V"])), 3)
    save_mesh(path, **dict(mesh, caruncle_faces=np.arange(4, dtype=np.int64), caruncle_weight=w))
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    r = subprocess.run([sys.executable, "-c", _CARUNCLE_SCRIPT, str(inp["out"] / "tiny.usda")], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    import json

    res = json.loads(next(ln for ln in r.stdout.splitlines() if ln.startswith("RESULT"))[6:])
    assert (res["domain"], res["type"]) == ("POINT", "FLOAT")
    np.testing.assert_allclose(res["values"], w, atol=1e-6)
    car, skin = res["materials"]["Caruncle"], res["materials"]["Skin"]
    assert car["base"] == [["MIX", "", "Result"]] and car["roughness"] == [["MIX", "", "Result"]]
    assert all(f == [["ATTRIBUTE", "caruncleWeight", "Factor"]] for f in car["factors"][-2:]), car
    np.testing.assert_allclose(car["rough_ab"], [[0.45, CARUNCLE_ROUGHNESS]], atol=1e-6)
    assert not any("caruncleWeight" in str(f) for f in skin["factors"])
