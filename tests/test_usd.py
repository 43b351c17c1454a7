"""Stage ``usd``: the per-scan rigged USD asset, built from small constructed inputs."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from fixtures import EYES, R1, make_inputs, usd_argv
from pipeline.geometry.frame import eye_basis
from pipeline.io.rig_file import read_rig, write_rig
from pipeline.rig import lids
from stages import usd as usd_stage
from stages._common import run_stage


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("usd")
    inp = make_inputs(root)
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    return inp


def test_asset_files_and_validation(built):
    from pipeline.usd.validate import validate_stage

    out = built["out"]
    assert sorted(p.name for p in out.iterdir()) == ["eyeball", "textures", "tiny.usda", "tiny.usdz"]
    assert sorted(p.name for p in (out / "textures").iterdir()) == ["color.png", "displacement.exr"]
    assert validate_stage(out / "tiny.usda") == []
    m = json.loads(built["metrics"].read_text())
    assert m["validation_errors"] == 0 and m["n_vertices"] == len(built["V"])


def test_stage_metadata_and_blend_shapes(built):
    from pxr import Usd, UsdGeom, UsdSkel

    import pipeline

    stage = Usd.Stage.Open(str(built["out"] / "tiny.usda"))
    root = stage.GetDefaultPrim()
    assert root.GetPath().pathString == "/tiny" and root.GetTypeName() == "SkelRoot"
    assert Usd.ModelAPI(root).GetKind() == "component"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.001 and UsdGeom.GetStageUpAxis(stage) == "Y"
    meta = root.GetCustomDataByKey("eyerig")
    assert meta["source_sha256"] == "ab" * 32 and meta["licence"] == "CC0-1.0 (test)"
    assert meta["pipeline_version"] == pipeline.__version__
    assert meta["weight_rule"]["max_pitch_deg"] == 25.0 and "formula" in meta["weight_rule"]
    assert "params" in meta and "mm" in meta["displacement"]

    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/tiny/EyeRegion"))
    P = np.asarray(mesh.GetPointsAttr().Get())
    assert np.abs(P - built["V"]).max() < 1e-4
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying" and len(st.GetIndices()) == 3 * len(built["F"])
    N = np.asarray(mesh.GetNormalsAttr().Get())
    assert N.shape == P.shape and np.allclose(N, [0, 0, 1], atol=1e-6)    # flat sheet facing +Z
    api = UsdSkel.BindingAPI(mesh.GetPrim())
    assert list(api.GetBlendShapesAttr().Get()) == ["lids_up", "lids_down"]
    for s, t in zip(built["shapes"], api.GetBlendShapeTargetsRel().GetTargets()):
        bs = UsdSkel.BlendShape(stage.GetPrimAtPath(t))
        assert np.array_equal(np.asarray(bs.GetPointIndicesAttr().Get()), s.point_indices)
        assert np.abs(np.asarray(bs.GetOffsetsAttr().Get()) - s.offsets).max() < 1e-6
        ibs = sorted(bs.GetInbetweens(), key=lambda i: i.GetWeight())
        assert [round(i.GetWeight(), 6) for i in ibs] == [round(w, 6) for w in s.inbetween_weights]
        for ib, o in zip(ibs, s.inbetween_offsets):
            assert np.abs(np.asarray(ib.GetOffsets()) - o).max() < 1e-6
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath("/tiny/Skel"))
    assert list(skel.GetJointsAttr().Get()) == ["head", "head/eye_left", "head/eye_right"]
    mat = stage.GetPrimAtPath("/tiny/Materials/Skin")
    files = {p.GetName(): p.GetAttribute("inputs:file").Get().path for p in mat.GetChildren()
             if p.GetAttribute("inputs:file")}
    assert files == {"DiffuseTexture": "./textures/color.png",
                     "DisplacementTexture": "./textures/displacement.exr"}


def test_eye_references_landmarks_and_variants(built):
    from pxr import Usd, UsdGeom, UsdShade, UsdSkel

    from pipeline.eyeball import geometry as geo

    stage = Usd.Stage.Open(str(built["out"] / "tiny.usda"))
    lm_expect = geo.landmark_indices("low")
    for side in ("left", "right"):
        eye = stage.GetPrimAtPath(f"/tiny/Eyes/eye_{side}")
        refs = eye.GetPrimStack()[0].referenceList.prependedItems
        assert [r.assetPath for r in refs] == ["./eyeball/eyeball.usda"]
        assert eye.GetTypeName() == "Xform" and Usd.ModelAPI(eye).GetKind() == "subcomponent"
        assert {c.GetName() for c in eye.GetChildren()} >= {"Outer", "Inner"}
        crv = UsdGeom.BasisCurves(stage.GetPrimAtPath(f"/tiny/Landmarks/eyelid_{side}"))
        assert len(crv.GetPointsAttr().Get()) == 12 and crv.GetWrapAttr().Get() == "periodic"
        assert list(UsdSkel.BindingAPI(crv.GetPrim()).GetBlendShapesAttr().Get()) == ["lids_up", "lids_down"]
        sc = stage.GetPrimAtPath(f"/tiny/Landmarks/eye_{side}")
        assert sc.GetRelationship("eyerig:landmarks:mesh").GetTargets()[0] == eye.GetChild("Inner").GetPath()
        for key in ("iris", "pupil"):
            assert list(sc.GetAttribute(f"eyerig:landmarks:{key}").Get()) == list(lm_expect[key])
    root = stage.GetDefaultPrim()
    assert set(root.GetVariantSets().GetNames()) == {"irisColor", "scleraTint", "veins"}
    root.GetVariantSets().GetVariantSet("irisColor").SetVariantSelection("blue")
    for side in ("left", "right"):
        tex = UsdShade.Shader(stage.GetPrimAtPath(f"/tiny/Eyes/eye_{side}/Materials/Iris/DiffuseTexture"))
        assert tex.GetInput("file").Get().path.endswith("iris_blue.png")


def _skinned_eye(stage, side, extra_deg=0.0):
    """Skinned Outer points of one eye (skeleton space = stage space), the eye joint rotated by
    ``extra_deg`` about its local X (the pitch axis)."""
    from pxr import Gf, Usd, UsdSkel

    anim = UsdSkel.Animation(stage.GetPrimAtPath("/tiny/Skel/Anim"))
    rots = list(anim.GetRotationsAttr().Get())
    j = 1 if side == "left" else 2
    rots[j] = rots[j] * Gf.Quatf(Gf.Rotation(Gf.Vec3d(1, 0, 0), extra_deg).GetQuat())
    anim.GetRotationsAttr().Set(rots)
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(stage.GetDefaultPrim())
    cache.Populate(root, Usd.PrimDefaultPredicate)
    skel_q = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/tiny/Skel")))
    xf = skel_q.ComputeSkinningTransforms(Usd.TimeCode.Default())
    prim = stage.GetPrimAtPath(f"/tiny/Eyes/eye_{side}/Outer")
    q = cache.GetSkinningQuery(prim)
    pts = prim.GetAttribute("points").Get()
    ok = q.ComputeSkinnedPoints(xf, pts, Usd.TimeCode.Default())
    assert ok
    return np.asarray(pts, np.float64), np.asarray(prim.GetAttribute("points").Get(), np.float64)


def test_eyes_placed_and_rotated_by_joints(built):
    from pxr import Usd

    stage = Usd.Stage.Open(str(built["out"] / "tiny.usda"))
    for side in ("left", "right"):
        e = EYES[side]
        c, f, r = np.asarray(e["center"]), np.asarray(e["forward"]), e["radius"]
        skinned, local = _skinned_eye(stage, side)
        expect = c + local @ eye_basis(f)
        assert np.abs(skinned - expect).max() < 1e-3           # placed and oriented, not scaled
        # the sclera has the fitted radius, the cornea keeps the eyeball asset's apex protrusion
        assert np.linalg.norm(local, axis=1).min() == pytest.approx(r, abs=1e-4)
        assert r != R1 and local[:, 2].max() == pytest.approx(r + 1.5, abs=1e-4)
        apex = skinned[np.argmax(local[:, 2])]                  # corneal apex: straight ahead
        d = apex - c
        assert np.allclose(d / np.linalg.norm(d), f, atol=1e-4)
        assert np.linalg.norm(d) == pytest.approx(local[:, 2].max(), rel=1e-5)
        posed, _ = _skinned_eye(stage, side, 20.0)
        # rigid rotation about the centre by 20 degrees
        assert np.allclose(np.linalg.norm(posed - c, axis=1), np.linalg.norm(skinned - c, axis=1), atol=1e-3)
        a = posed[np.argmax(local[:, 2])] - c
        ang = np.degrees(np.arccos(np.clip(a @ d / (np.linalg.norm(a) * np.linalg.norm(d)), -1, 1)))
        assert ang == pytest.approx(20.0, abs=1e-3)


def test_usdz_self_contained_and_folder_movable(built, tmp_path):
    from pxr import Sdf

    from pipeline.usd.asset import check_package
    from pipeline.usd.validate import validate_stage

    z = Sdf.ZipFile.Open(str(built["out"] / "tiny.usdz"))
    names = list(z.GetFileNames())
    assert names[0] == "tiny/tiny.usda"
    assert {"tiny/eyeball/eyeball.usda", "tiny/textures/color.png", "tiny/textures/displacement.exr",
            "tiny/eyeball/textures/iris_blue.png"} <= set(names)
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(built["out"] / "tiny.usdz", lone / "x.usdz")       # nothing beside it
    assert check_package(lone / "x.usdz") == []
    moved = tmp_path / "moved"
    shutil.copytree(built["out"], moved / "tiny")                  # the asset folder alone
    assert validate_stage(moved / "tiny" / "tiny.usda") == []


def _fail(inp, capsys):
    rc = run_stage(usd_stage.main, usd_argv(inp))
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("error: ")
    assert not inp["out"].exists()
    return err


def test_broken_inputs_refused(tmp_path, capsys):
    inp = make_inputs(tmp_path)
    rig = inp["dirs"]["rig"]
    doc = read_rig(rig).doc
    good = dict(inp["arrays"])
    # rig built for a bigger mesh
    bad = dict(good, **{"lids_up.point_indices": good["lids_up.point_indices"] + len(inp["V"])})
    write_rig(rig, bad, doc)
    err = _fail(inp, capsys)
    assert "rig.npz: shape lids_up indexes vertices outside" in err and "snap/mesh.npz" in err
    # non-finite offsets: refused by the rig reader before anything is written
    bad = dict(good, **{"lids_down.offsets": good["lids_down.offsets"] * np.nan})
    write_rig(rig, bad, doc)
    err = _fail(inp, capsys)
    assert "rig.npz: lids_down.offsets has non-finite values" in err
    write_rig(rig, good, doc)
    # missing displacement map
    (inp["dirs"]["bake"] / "displacement.exr").unlink()
    err = _fail(inp, capsys)
    assert "displacement.exr" in err and "not found" in err


def test_eyeball_reference_must_resolve(tmp_path, capsys):
    inp = make_inputs(tmp_path)
    (inp["eyeball"] / "eyeball.usda").write_text("#usda 1.0\n(\n    defaultPrim = \"Eyeball\"\n)\n\n"
                                                  "def Xform \"Eyeball\"\n{\n}\n")
    err = _fail(inp, capsys)
    assert "eyeball" in err


@pytest.mark.parametrize("channel,w", [("lids_up", 0.5), ("lids_down", 0.8)])
def test_usdskel_evaluation_matches_rig(built, channel, w):
    """UsdSkel's own blend-shape evaluation (inbetweens included) of the skin mesh and of the
    eyelid landmark curves equals pipeline.rig.lids.evaluate_shapes."""
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(built["out"] / "tiny.usda"))
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/tiny/Skel/Anim"))
    names = list(anim.GetBlendShapesAttr().Get())
    weights = [0.0] * len(names)
    weights[names.index(channel)] = w
    anim.GetBlendShapeWeightsAttr().Set(weights)
    paths = {"mesh": "/tiny/EyeRegion", "left": "/tiny/Landmarks/eyelid_left",
             "right": "/tiny/Landmarks/eyelid_right"}
    rest = {k: np.asarray(stage.GetPrimAtPath(p).GetAttribute("points").Get(), np.float64)
            for k, p in paths.items()}
    assert UsdSkel.BakeSkinning(stage.Traverse())
    arrays = built["arrays"]
    for k, p in paths.items():
        got = np.asarray(stage.GetPrimAtPath(p).GetAttribute("points").Get(Usd.TimeCode.Default()))
        shapes = lids.shapes_from_arrays(arrays, prefix="" if k == "mesh" else f"landmarks.{k}.")
        expect = lids.evaluate_shapes(rest[k], shapes, {channel: w})
        assert np.abs(expect - rest[k]).max() > 0.3
        assert np.abs(got - expect).max() < 1e-4, k


def _tree_bytes(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_inputs_give_byte_identical_asset(built):
    """The asset written again from the same inputs (a second later: other file times) has the
    same bytes, the usdz included (its members carry a fixed 1980-01-01 time, not the files')."""
    import time
    import zipfile

    out = built["out"]
    first = _tree_bytes(out)
    time.sleep(1.1)
    assert run_stage(usd_stage.main, usd_argv(built)) == 0
    second = _tree_bytes(out)
    assert sorted(first) == sorted(second) and "tiny.usdz" in first
    assert [k for k in first if first[k] != second[k]] == []
    with zipfile.ZipFile(out / "tiny.usdz") as zf:
        assert {i.date_time for i in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)} and zf.testzip() is None


def test_eye_doubts_carried_into_the_asset_metadata(tmp_path):
    """A doubt recorded for one eye (remove_eyeballs -> snap -> rig.json) is in the asset's
    customData ``eyerig.eyes.<side>.doubts``, where the render and dataset read it; an eye
    without doubts has no such key (USD cannot type an empty list)."""
    from pxr import Usd

    from pipeline.render.asset import load_render_asset
    from pipeline.render.dataset import DatasetAsset

    inp = make_inputs(tmp_path)
    rig_json = inp["dirs"]["rig"] / "rig.json"
    doc = json.loads(rig_json.read_text())
    doubt = "opening 18.0 mm wide where the texture's fissure is 31.5 mm"
    doc["eyes"]["left"]["doubts"] = [doubt]
    rig_json.write_text(json.dumps(doc))
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    stage = Usd.Stage.Open(str(inp["out"] / "tiny.usda"))
    meta = stage.GetDefaultPrim().GetCustomDataByKey("eyerig")
    assert list(meta["eyes"]["left"]["doubts"]) == [doubt] and "doubts" not in meta["eyes"]["right"]
    asset = load_render_asset(inp["out"], inp["dirs"]["rig"])
    entry = DatasetAsset(0, "tiny", inp["out"], inp["dirs"]["rig"], 1.0, asset, "")
    assert entry.doubts() == [f"left eye: {doubt}"]


def test_the_usd_stage_starts_no_blender(tmp_path, monkeypatch):
    """Writing the asset runs no Blender worker: the door refuses to open during the usd stage."""
    from pipeline.blender import launch
    from stages._common import read_stage_metrics

    def refuse(*a, **k):
        raise AssertionError("the usd stage started Blender")

    monkeypatch.setattr(launch, "command", refuse)
    inp = make_inputs(tmp_path)
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    assert not (inp["out"] / "preview.png").exists()
    assert "preview_s" not in read_stage_metrics(inp["metrics"])


def test_the_band_ids_are_in_the_asset_metadata(tmp_path):
    """A mesh with retopo's grid round each opening (``band_<side>``: ids ``e * R * S + k * S + i``)
    gives the asset customData ``eyerig.band`` with its counts and id ranges; a band whose ids
    break the rule (the older ``march`` band) gives none."""
    from pxr import Usd

    from pipeline.io.meshfile import load_mesh, save_mesh
    from pipeline.usd.build import band_record

    inp = make_inputs(tmp_path)
    path = inp["dirs"]["snap"] / "mesh.npz"
    mesh = dict(load_mesh(path))
    rings, spokes = 3, 8
    mesh["band_left"] = np.arange(rings * spokes).reshape(rings, spokes)
    mesh["band_right"] = mesh["band_left"] + rings * spokes
    save_mesh(path, **mesh)
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    stage = Usd.Stage.Open(str(inp["out"] / "tiny.usda"))
    band = stage.GetDefaultPrim().GetCustomDataByKey("eyerig")["band"]
    assert (band["rings"], band["spokes"], band["lateral_canthus_spoke"]) == (3, 8, 4)
    assert list(band["left_vertex_ids"]) == [0, 23] and list(band["right_vertex_ids"]) == [24, 47]
    assert "ring 0 is the eyelid margin" in band["vertex_id"]

    shuffled = {"left": mesh["band_left"][:, ::-1], "right": mesh["band_right"]}
    assert band_record(shuffled, len(mesh["V"])) is None
    assert band_record({"left": mesh["band_left"], "right": mesh["band_right"]}, 40) is None   # ids past V
    assert band_record(None, 100) is None


def test_the_caruncle_weight_is_a_primvar_of_the_eye_region(tmp_path, capsys):
    """snap's ``caruncle_weight`` (each vertex's share of the caruncle's colour) becomes the
    EyeRegion's ``primvars:caruncleWeight`` (vertex), with the caruncle subset; a weight outside
    [0, 1] or of the wrong length is refused naming the mesh."""
    from pxr import Usd, UsdGeom

    from pipeline.io.meshfile import load_mesh, save_mesh

    inp = make_inputs(tmp_path)
    path = inp["dirs"]["snap"] / "mesh.npz"
    mesh = dict(load_mesh(path))
    n = len(mesh["V"])
    w = np.linspace(0.0, 1.0, n)
    save_mesh(path, **dict(mesh, caruncle_faces=np.arange(3, dtype=np.int64), caruncle_weight=w))
    assert run_stage(usd_stage.main, usd_argv(inp)) == 0
    stage = Usd.Stage.Open(str(inp["out"] / "tiny.usda"))
    region = stage.GetDefaultPrim().GetChild("EyeRegion")
    pv = UsdGeom.PrimvarsAPI(region).GetPrimvar("caruncleWeight")
    assert pv and pv.GetInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_allclose(np.asarray(pv.Get()), w, atol=1e-7)
    assert UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(region))
    shutil.rmtree(inp["out"])
    for bad in (np.full(n, 1.5), np.zeros(n - 1)):
        save_mesh(path, **dict(mesh, caruncle_faces=np.arange(3, dtype=np.int64), caruncle_weight=bad))
        err = _fail(inp, capsys)
        assert "mesh.npz" in err and "caruncle_weight must hold one weight in [0, 1] per vertex" in err
