"""Assets built by the real chain (stage functions, scan folder -> rigged USD asset).

One module-scoped build per scan: the synthetic head (small density, always) and the real scans
``ict_neutral`` and ``james`` (only with ``EYERIG_EXTRA_SCANS``). On each:

* snap leaves no flipped face and the margin on the eyeball (stage metrics);
* the rig's pitch sweep -25..25 deg keeps the margin within 0.1 mm of the eyeball, keeps the moved
  skin out of it (within the 0.03 mm chord tolerance) and flips no face;
* Blender's USD importer (pipeline/blender/usd_roundtrip.py, a subprocess) brings in the mesh with
  its UVs, the two shape keys with the USD offsets (within 1e-4 mm), the armature with the eye
  joints, both eyes (following their bones) and the textured materials (marked ``blender``: the
  import runs once per asset, only when one of those tests runs).

The chain runs with the project's params.yaml except for a few cost knobs (bake map size, a
low-resolution eyeball, no previews, no usdz), written to a temporary params file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fixtures import extra_scans_dir, stage_commands, usd_roundtrip
from pipeline.io.rig_file import read_rig
from stages._common import run_stage

#: every test here builds assets through the stage chain, from the real scans or the home synthetic head
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
POSE_DEG = 20.0
SIDES = ("left", "right")


def _params(root: Path) -> Path:
    p = yaml.safe_load((ROOT / "params.yaml").read_text())
    p["synthetic_head"].update(target_triangles=60000, texture_size=256)
    p["bake"].update(resolution=256, metric_samples=5000, subdivision_levels=1)
    p["retopo"].update(metric_samples=5000)
    p["eyeball"].update(resolution="low", iris_texture_px=64, sclera_texture_px=[64, 32])
    p["usd"].update(usdz=False)
    out = root / "params.yaml"
    out.write_text(yaml.safe_dump(p))
    return out


@pytest.fixture(scope="module")
def chain_root(tmp_path_factory):
    """Shared folder with the params file and the eyeball asset every chain references."""
    from stages import eyeball

    root = tmp_path_factory.mktemp("chain")
    params = _params(root)
    eb = root / "rigged_assets" / "eyeball"
    assert run_stage(eyeball.main, [str(eb), "--metrics", str(root / "eyeball.json"),
                                    "--params", str(params)]) == 0
    return root, params, eb


def build_chain(root: Path, params: Path, eyeball: Path, raw: Path, name: str) -> dict:
    """ingest -> remove_eyeballs -> retopo -> bake -> snap -> rig -> usd for one scan folder, each
    stage's command as dvc.yaml has it (fixtures.stage_commands), run in this process."""
    import importlib

    b = root / "build" / name
    out = root / "rigged_assets" / name
    m = {}
    for stage, cmd in stage_commands(raw, b, eyeball, out).items():
        metrics = b / f"{stage}.metrics.json"
        main = importlib.import_module(cmd[0]).main
        assert run_stage(main, cmd[1:] + ["--metrics", str(metrics), "--params", str(params)]) == 0, \
            f"{stage} failed on {name}"
        m[stage] = json.loads(metrics.read_text())
    return {"name": name, "build": b, "usda": out / f"{name}.usda", "metrics": m}


def _build(chain_root, raw: Path, name: str) -> dict:
    root, params, eb = chain_root
    return build_chain(root, params, eb, raw, name)


def _extra(name: str) -> Path:
    base = extra_scans_dir()
    if base is None:
        pytest.skip("EYERIG_EXTRA_SCANS is not set")
    if not (base / name).is_dir():
        pytest.skip(f"{base / name} not found")
    return base / name


@pytest.fixture(scope="module")
def synthetic(chain_root):
    from stages import synthetic_head

    root, params, _ = chain_root
    raw = root / "raw_scans" / "synthetic_head"
    assert run_stage(synthetic_head.main, [str(raw), "--metrics", str(root / "synthetic_head.json"),
                                           "--params", str(params)]) == 0
    return _build(chain_root, raw, "synthetic_head")


@pytest.fixture(scope="module")
def ict_neutral(chain_root):
    raw = _extra("ict_neutral")
    try:
        return _build(chain_root, raw, "ict_neutral")
    except AssertionError as exc:
        # Known gap (docs/known-gaps.md): on the human 12 mm eye, anchored at ICT's 15.4 mm
        # globe's limbus, the right medial canthus stands 1.8 mm off the eye (a margin, not a
        # corner) and is snapped onto it; the lower lid beside it then folds one face in the
        # rig sweep looking down. Snap's falloff and corner thresholds only move the fold
        # between heads: the band built by construction (issue 30) is the fix. An xfail, not a
        # skip: the day it rigs, these tests run again.
        if "rig failed on ict_neutral" in str(exc):
            pytest.xfail("ict_neutral's medial lid folds in the rig sweep on the 12 mm eye (known gap)")
        raise


@pytest.fixture(scope="module")
def james(chain_root):
    return _build(chain_root, _extra("james"), "james")


@pytest.fixture(params=["synthetic", "ict_neutral", "james"])
def asset(request):
    return request.getfixturevalue(request.param)


@pytest.fixture(scope="module")
def blender_import(chain_root):
    """``blender_import(asset)`` -> (arrays, meta) of the asset imported into Blender, once per asset.

    One import with the left eye bone turned (shape keys and basis do not depend on the pose; the
    right eye stays at rest).
    """
    root = chain_root[0]
    done = {}

    def get(asset: dict):
        name = asset["name"]
        if name not in done:
            done[name] = usd_roundtrip(asset["usda"], root / f"{name}.npz", {"eye_left": [1, 0, 0, POSE_DEG]})
        return done[name]

    return get


# ------------------------------------------------------------------ geometry of the chain

def test_doubts_reach_the_asset_only_where_measured(asset):
    """The synthetic head is doubted at most for its stated sigma, james only for being placed
    from a photograph (its
    openings follow the fissure it shows; 18 mm openings against a 31.5 mm fissure were doubted
    before issue 21);
    ict_neutral's eyes are, by the one self-check they fail (cornea_shows: its scanner
    flattened the cornea and the eye is placed 1 mm small) and, where the iris plane moved the
    limbus (docs/remove_eyeballs.md), by their stated sigma (its truth: limbus 0.5-0.6 mm and
    axis 2.9-3.1 deg off; 1.1 mm undoubted before); what the metadata says matches the stage's
    count."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(asset["usda"]))
    eyes = stage.GetDefaultPrim().GetCustomDataByKey("eyerig")["eyes"]
    doubts = {s: list(eyes[s].get("doubts") or []) for s in SIDES}
    assert asset["metrics"]["remove_eyeballs"]["left"]["doubts"] == len(doubts["left"])
    if asset["name"] == "ict_neutral":
        assert all(any("cornea_shows" in x for x in d) and all(
            "cornea_shows" in x or x.startswith("placed from little evidence (geometry)") for x in d)
            for d in doubts.values()), doubts
    elif asset["name"] == "james":
        # placed from its photograph: the anatomy's spread (limbus +-1.2 mm, axis +-5 deg) is
        # more than the doubt thresholds, and nothing else is doubted
        assert all(d == ["placed from little evidence (texture): limbus centre +-1.20 mm, axis +-5.0 deg "
                         "(1 sigma)"] for d in doubts.values()), doubts
    else:       # the procedural head: at most its own stated sigma's doubt (docs/remove_eyeballs.md)
        assert all(all(x.startswith("placed from little evidence (geometry)") for x in d)
                   for d in doubts.values()), doubts


def test_james_canthi_are_its_annotated_corners(james):
    """Eyelid landmarks 0 and 6 at rest against james's 68-point eye corners (group reye is the
    subject's left eye), its corners off the globe closed by caruncle strips."""
    from pipeline.io.meshfile import load_mesh

    raw = _extra("james")
    L = np.load(raw / "james_landmarks68.npy")
    groups = json.loads((raw / "james_landmarks68_groups.json").read_text())
    arrays = read_rig(james["build"] / "rig").npz.arrays
    # measured: left 1.23 / 1.66 mm, right 2.35 / 3.73 mm (medial / lateral; README, Known gaps)
    bound = {"left": (2.0, 2.0), "right": (3.0, 4.5)}
    for s, group in (("left", "reye"), ("right", "leye")):
        lm = L[groups[group]]
        med, lat = (lm[0], lm[3]) if s == "left" else (lm[3], lm[0])
        P = np.asarray(arrays[f"landmarks.{s}.points"])
        assert np.linalg.norm(P[0] - med) <= bound[s][0], s
        assert np.linalg.norm(P[6] - lat) <= bound[s][1], s
    snap = load_mesh(james["build"] / "snap" / "mesh.npz")
    assert len(snap["caruncle_faces"]) > 0
    assert james["metrics"]["snap"]["left"]["medial_canthus_off_mm"] > 3.0


def test_snap_keeps_orientation_and_margin_on_eye(asset):
    m = asset["metrics"]["snap"]
    if asset["name"] == "ict_neutral" and m["flipped_faces"]:
        # the same known gap as the ict_neutral fixture's: its lids, 1-2.7 mm off the 12 mm eye
        # near the medial canthus, turn a few faces over on their way onto it (issue 30's band)
        pytest.xfail(f"ict_neutral: snap turns {m['flipped_faces']} faces over (known gap)")
    assert m["flipped_faces"] == 0, asset["name"]
    assert m["edge_manifold"]
    assert m["gap_max_mm"] <= 0.05 and m["inside_max_mm"] <= 0.05
    for s in SIDES:
        assert m[s]["moved_outside_falloff"] == 0


def test_rig_sweep_bounds_and_no_flips(asset):
    m = asset["metrics"]["rig"]
    assert m["sweep_n_pitches"] >= 101                       # -25..25 deg every 0.5 deg
    assert m["sweep_flipped_faces"] == 0, asset["name"]
    assert m["sweep_max_gap_mm"] <= 0.1 and m["sweep_max_penetration_mm"] <= 0.1
    assert m["sweep_min_opening_mm"] > 0                     # the lids never cross
    # no moved skin vertex sinks into the turning eyeball deeper than the margin's chord tolerance
    assert m["sweep_min_skin_clearance_mm"] >= -0.03, asset["name"]


def test_retopo_loops_have_no_ears(asset):
    """No eyelid-loop vertex with a single face: such an 'ear' has three loop corners and
    is degenerate or inverted on the convex opening (it flips once the loop moves)."""
    from pipeline.io.meshfile import load_mesh

    mesh = load_mesh(asset["build"] / "retopo" / "mesh.npz")
    count = np.bincount(mesh["F"].ravel(), minlength=len(mesh["V"]))
    for s in SIDES:
        assert count[mesh[f"loop_{s}"]].min() >= 2, s


# ------------------------------------------------------------------ Blender round trip

def _usd_to_blender(P_mm):
    """Stage (Y up, mm) -> Blender world (Z up, metres)."""
    P = np.asarray(P_mm, np.float64) * 0.001
    return np.stack([P[..., 0], -P[..., 2], P[..., 1]], -1)


def _eye_objects(meta, side):
    return {n: o for n, o in meta["objects"].items() if o["parent"] == f"eye_{side}"}


@pytest.mark.blender
def test_blender_mesh_uvs_materials_and_shape_keys(asset, blender_import):
    from pipeline.io.meshfile import load_mesh
    from pipeline.rig import lids

    data, meta = blender_import(asset)
    snap = load_mesh(asset["build"] / "snap" / "mesh.npz")
    o = meta["objects"]["EyeRegion"]
    assert o["vertices"] == len(snap["V"])
    assert o["uv_layers"] == ["st"]
    # the caruncle strips' material where a medial corner stands off the globe (james)
    caruncle = len(snap["caruncle_faces"]) > 0
    assert o["materials"] == (["Skin", "Caruncle"] if caruncle else ["Skin"])
    assert sorted(Path(p).name for p in o["images"]["Skin"]) == ["color.png", "displacement.exr"]
    assert np.abs(data["EyeRegion.basis"] - snap["V"]).max() < 1e-4
    shapes = read_rig(asset["build"] / "rig").npz.shapes
    # the pitch channels, then each eye's yaw channels (pipeline/rig/yaw_shapes.py)
    assert o["shape_keys"] == [s.name for s in shapes]
    assert o["shape_keys"][:2] == [lids.SHAPE_UP, lids.SHAPE_DOWN]
    assert all(n.startswith("lids_look_") for n in o["shape_keys"][2:]) and len(o["shape_keys"]) > 2
    for s in shapes:
        off = data[f"EyeRegion.key.{s.name}"] - data["EyeRegion.basis"]
        full = np.zeros_like(off)
        full[s.point_indices] = s.offsets
        if s.name in (lids.SHAPE_UP, lids.SHAPE_DOWN):
            assert np.abs(full).max() > 0.5, s.name              # the lids really move
        assert np.abs(off - full).max() < 1e-4, s.name           # mm
    # the skin does not follow the eye bones
    W = data["EyeRegion.world"]
    assert np.abs(W - _usd_to_blender(snap["V"])).max() < 1e-6


@pytest.mark.blender
def test_blender_armature_and_eyes_follow_bones(asset, blender_import):
    from pipeline.geometry.frame import eye_basis

    rig = read_rig(asset["build"] / "rig")
    data, meta = blender_import(asset)
    arm_name, arm = next(iter(meta["armatures"].items()))
    assert {"eye_left", "eye_right"} <= set(arm["bones"])
    for side in SIDES:
        e = rig.eyes[side]
        c_mm = e.center
        head = np.asarray(arm["heads"][arm["bones"].index(f"eye_{side}")])
        assert np.abs(head - c_mm).max() < 1e-3                  # armature space = stage mm
        eyes = _eye_objects(meta, side)
        assert len(eyes) == 2                                     # Outer + Inner
        assert any(p for o in eyes.values() for p in o["images"].values())   # textured
        c = _usd_to_blender(c_mm)
        outer = max(eyes, key=lambda n: data[f"{n}.basis"][:, 2].max())
        for name, o in eyes.items():
            assert o["modifiers"] == [["ARMATURE", arm_name]] and o["vertex_groups"] == [f"eye_{side}"]
            W, local = data[f"{name}.world"], data[f"{name}.basis"]
            # rigid: every point keeps its distance from the centre (the eye is placed at the
            # fitted radius, not scaled: its points are head mm)
            np.testing.assert_allclose(np.linalg.norm(W - c, axis=1),
                                       0.001 * np.linalg.norm(local, axis=1), atol=1e-6)
        W, local = data[f"{outer}.world"], data[f"{outer}.basis"]
        assert np.linalg.norm(local, axis=1).min() == pytest.approx(e.radius, abs=1e-3)   # sclera
        apex = W[np.argmax(local[:, 2])] - c                      # corneal apex direction
        f = e.forward
        a = np.radians(POSE_DEG if side == "left" else 0.0)     # bone turned about its pitch axis
        errs = []
        for sign in (1.0, -1.0):
            g = _usd_to_blender(np.cos(a) * f + sign * np.sin(a) * eye_basis(f)[1]) * 1000
            errs.append(np.degrees(np.arccos(np.clip(apex @ g / np.linalg.norm(apex), -1, 1))))
        assert min(errs) < 0.05, (side, errs)
