"""The reusable USD validator catches deliberately broken assets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.eyeball import geometry as geo
from pipeline.usd.validate import validate_stage, validate_stage_report


@pytest.fixture()
def good(tmp_path):
    from pipeline.usd.eyeball import write_eyeball_usd

    from PIL import Image

    from pipeline.eyeball import textures as tex

    (tmp_path / "textures").mkdir()
    for name, img in tex.texture_set(0, 32, (32, 16)).items():
        Image.fromarray(img).save(tmp_path / "textures" / name)
    return write_eyeball_usd(geo.build_eyeball(resolution="low"), tmp_path / "eyeball.usda")


def _open(path):
    from pxr import Usd

    return Usd.Stage.Open(str(path))


def test_good_asset_has_no_errors(good):
    rep = validate_stage_report(good)
    assert rep["errors"] == []
    assert rep["meshes"] == 2 and rep["blend_shapes"] == 4


def test_wrong_point_indices(good):
    from pxr import UsdSkel

    st = _open(good)
    bs = UsdSkel.BlendShape(st.GetPrimAtPath("/Eyeball/Inner/pupil_dilate"))
    idx = list(bs.GetPointIndicesAttr().Get())
    idx[3] = 10 ** 6                                       # out of range
    bs.GetPointIndicesAttr().Set(idx)
    errs = validate_stage(st)
    assert any("pupil_dilate" in e and "pointIndices" in e for e in errs), errs
    idx[3] = idx[4]                                        # duplicate index
    bs.GetPointIndicesAttr().Set(idx)
    assert any("pupil_dilate" in e for e in validate_stage(st))


def test_nan_point(good):
    from pxr import UsdGeom

    st = _open(good)
    m = UsdGeom.Mesh(st.GetPrimAtPath("/Eyeball/Outer"))
    pts = np.array(m.GetPointsAttr().Get())
    pts[5, 1] = np.nan
    m.GetPointsAttr().Set(pts.astype(np.float32))
    errs = validate_stage(st)
    assert any("/Eyeball/Outer" in e and "not finite" in e for e in errs), errs


def test_mismatched_offsets(good):
    from pxr import UsdSkel

    st = _open(good)
    bs = UsdSkel.BlendShape(st.GetPrimAtPath("/Eyeball/Inner/iris_large"))
    off = np.array(bs.GetOffsetsAttr().Get())
    bs.GetOffsetsAttr().Set(off[:-2])
    errs = validate_stage(st)
    assert any("iris_large" in e and "offsets" in e for e in errs), errs


def test_nan_offset_and_dangling_target(good):
    from pxr import Sdf, UsdSkel

    st = _open(good)
    bs = UsdSkel.BlendShape(st.GetPrimAtPath("/Eyeball/Inner/iris_small"))
    off = np.array(bs.GetOffsetsAttr().Get())
    off[0, 0] = np.inf
    bs.GetOffsetsAttr().Set(off)
    api = UsdSkel.BindingAPI(st.GetPrimAtPath("/Eyeball/Inner"))
    api.GetBlendShapeTargetsRel().AddTarget(Sdf.Path("/Eyeball/Nowhere"))
    errs = validate_stage(st)
    assert any("iris_small" in e and "not finite" in e for e in errs)
    assert any("skel:blendShapeTargets" in e for e in errs)


def test_bad_topology(good):
    from pxr import UsdGeom

    st = _open(good)
    m = UsdGeom.Mesh(st.GetPrimAtPath("/Eyeball/Inner"))
    idx = list(m.GetFaceVertexIndicesAttr().Get())
    idx[0] = -1
    m.GetFaceVertexIndicesAttr().Set(idx)
    assert any("topology" in e for e in validate_stage(st))
    counts = list(m.GetFaceVertexCountsAttr().Get())
    counts[0] += 1
    m.GetFaceVertexCountsAttr().Set(counts)
    assert any("topology" in e for e in validate_stage(st))


def test_primvar_count_and_stage_metadata(good):
    from pxr import UsdGeom

    st = _open(good)
    m = UsdGeom.Mesh(st.GetPrimAtPath("/Eyeball/Inner"))
    pv = UsdGeom.PrimvarsAPI(m).GetPrimvar("st")
    pv.SetIndices(list(pv.GetIndices())[:-3])
    UsdGeom.SetStageMetersPerUnit(st, 1.0)
    UsdGeom.SetStageUpAxis(st, UsdGeom.Tokens.z)
    errs = validate_stage(st)
    assert any("primvar st" in e for e in errs)
    assert any("metersPerUnit" in e for e in errs)
    assert any("upAxis" in e for e in errs)
    assert not any("metersPerUnit" in e for e in validate_stage(st, meters_per_unit=None, up_axis=None))


def test_missing_material_and_default_prim(good):
    st = _open(good)
    st.RemovePrim("/Eyeball/Materials/Pupil")
    st.ClearDefaultPrim()
    errs = validate_stage(st)
    assert any("default prim" in e for e in errs)
    assert any("Pupil" in e for e in errs)


def test_unreadable_file(tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\n( this is not usd")
    errs = validate_stage(bad)
    assert len(errs) == 1 and "cannot be opened" in errs[0]
    assert "cannot be opened" in validate_stage(tmp_path / "missing.usda")[0]
    assert math.isfinite(len(errs))


def test_missing_texture(good):
    st = _open(good)
    (good.parent / "textures" / "iris_brown.png").unlink()   # the default irisColor variant
    errs = validate_stage(good)
    assert any("iris_brown.png" in e and "does not resolve" in e for e in errs), errs
    # UsdValidation's dependency check also sees files of variants that are not selected
    st.GetDefaultPrim().GetVariantSets().GetVariantSet("irisColor").SetVariantSelection("blue")
    assert any("iris_brown.png" in e for e in validate_stage(st))


def test_a_blend_shape_that_folds_the_mesh_is_an_error(good):
    """The rig's geometry check on what the asset stores: an offset that pushes one vertex of
    the pupil through its neighbours turns faces over at full weight."""
    from pxr import UsdGeom, UsdSkel

    st = _open(good)
    assert validate_stage(st) == []
    bs = UsdSkel.BlendShape(st.GetPrimAtPath("/Eyeball/Inner/pupil_dilate"))
    idx = np.asarray(bs.GetPointIndicesAttr().Get())
    off = np.array(bs.GetOffsetsAttr().Get(), np.float64)
    P = np.asarray(UsdGeom.Mesh(st.GetPrimAtPath("/Eyeball/Inner")).GetPointsAttr().Get(), np.float64)
    c = P.mean(axis=0)
    k = int(np.argmax(np.linalg.norm(P[idx] - c, axis=1)))      # push one vertex through the middle
    off[k] = 2.0 * (c - P[idx[k]])
    bs.GetOffsetsAttr().Set(off.astype(np.float32))
    errs = validate_stage(st)
    assert any("pupil_dilate" in e and "flips" in e for e in errs), errs


def _polygon_normals_loop(P, counts, idx):
    """The per-polygon Python loop the vectorised fan replaced (the reference)."""
    N = np.zeros((len(counts), 3))
    s = 0
    for f, c in enumerate(counts):
        for k in range(1, c - 1):
            a, b, d = idx[s], idx[s + k], idx[s + k + 1]
            N[f] += np.cross(P[b] - P[a], P[d] - P[a])
        s += c
    return N


def test_polygon_normals_equal_the_loop_on_mixed_polygons():
    from pipeline.usd.validate import _fan_triangles, _polygon_normals
    rng = np.random.default_rng(3)
    counts = rng.choice([3, 4, 5, 7, 12, 2], size=400)     # a 2-gon has no area: a zero normal
    idx = rng.integers(0, 300, size=int(counts.sum()))
    P = rng.normal(size=(300, 3)) * 10.0
    ref = _polygon_normals_loop(P, counts, idx)
    got = _polygon_normals(P, counts, idx)
    np.testing.assert_array_equal(got, ref)                # the same bits, summed in the same order
    assert np.all(got[counts == 2] == 0) and np.abs(got[counts > 2]).max() > 1.0
    face, a, b, c = _fan_triangles(counts, idx)
    assert len(face) == int(np.maximum(counts - 2, 0).sum())
    np.testing.assert_array_equal(_polygon_normals(P, counts, idx, (face, a, b, c)), ref)
    assert _polygon_normals(P, [], []).shape == (0, 3)


def test_posed_flips_count_skin_folding_under_not_a_crease_unrolling():
    """A quad grid (facing +z) whose last row, folded under at rest (facing -z), is turned out
    again by the offsets folds nothing; its centre pushed past a neighbour does
    (pipeline/geometry/meshtopo.turned_over_faces)."""
    from pipeline.usd.validate import _posed_flips

    g = np.linspace(0.0, 4.0, 5)
    X, Y = np.meshgrid(g, g)
    P = np.column_stack([X.ravel(), Y.ravel(), np.zeros(25)])
    P = np.vstack([P, P[20:25] + [0.0, -0.8, -0.4]])               # the row folded back under the top edge
    quads = [[i * 5 + j, i * 5 + j + 1, (i + 1) * 5 + j + 1, (i + 1) * 5 + j] for i in range(4) for j in range(4)]
    quads += [[20 + j, 21 + j, 26 + j, 25 + j] for j in range(4)]     # the sheet carried on: facing -z
    counts, idx = [4] * len(quads), np.ravel(quads)
    O = np.zeros_like(P)
    O[25:] = [0.0, 1.6, 0.0]                                        # the crease unrolls past the edge
    assert _posed_flips(P, counts, idx, None, [np.zeros_like(P)]) == 0
    assert _posed_flips(P, counts, idx, None, [O]) == 0
    O = np.zeros_like(P)
    O[12] = 2.0 * (P[13] - P[12])                                   # the centre pushed past its right neighbour
    assert _posed_flips(P, counts, idx, None, [O]) >= 1
