"""The parametric eyeball: geometry, blend shapes, landmarks, textures, USD asset."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from pipeline.eyeball import geometry as geo
from pipeline.eyeball import textures as tex
from pipeline.eyeball.checks import mesh_edges_manifold, seam_dihedral_report
from pipeline.eyeball.surface import outer_surface_closest_point
from pipeline.geometry.meshtopo import face_normals
from stages._common import read_stage_metrics

P = geo.EyeballParams()


@pytest.fixture(scope="module")
def eye():
    return geo.build_eyeball(P, "high")


# ------------------------------------------------------------------ outer part

@pytest.mark.parametrize("res", ["low", "medium", "high", "full"])
def test_meshes_closed_manifold_outward(res):
    e = geo.build_eyeball(P, res)
    for m in (e.outer, e.inner):
        ok, bad = mesh_edges_manifold(m.F)
        assert ok, f"{bad} non-manifold / inconsistently oriented edges"
        N = face_normals(m.V, m.F, normalize=False)
        assert np.linalg.norm(N, axis=1).min() > 1e-8            # no degenerate faces
        c = m.V[m.F].mean(1)
        # star-shaped about points on the axis: normals point away from the centre
        assert np.all(np.einsum("ij,ij->i", N, c - [0, 0, 0]) > 0)
        assert len(m.poly_indices) == m.poly_counts.sum()
        assert len(m.poly_uv_indices) == len(m.poly_indices)
    assert len(e.outer.V) == 2 + e.resolution.n_around * (e.resolution.cornea_rings
                                                          + e.resolution.sclera_rings - 1)


def test_outer_radii_and_apex(eye):
    r = np.linalg.norm(eye.outer.V, axis=1)
    assert r.min() == pytest.approx(12.0, abs=1e-9)               # back: the 12 mm sphere
    assert eye.outer.V[:, 2].max() == pytest.approx(13.5, abs=1e-9)
    assert 13.0 <= eye.outer.V[:, 2].max() <= 14.0                # anatomical apex distance
    # the cornea part lies on the 8 mm sphere away from the blend band
    c = np.array([0, 0, P.cornea_center_z])
    front = eye.outer.V[r > 12.0 + P.seam_blend_mm + 1e-9]
    assert np.allclose(np.linalg.norm(front - c, axis=1), 8.0, atol=1e-9)


@pytest.mark.parametrize("res", ["medium", "high", "full"])
def test_seam_has_no_crease(res):
    """Bound: the largest dihedral angle within 15 deg of the seam <= the largest elsewhere."""
    rep = seam_dihedral_report(P, res)
    assert rep["seam_max_deg"] <= max(rep["cornea_max_deg"], rep["sclera_max_deg"])
    raw = seam_dihedral_report(P, res, smooth=False)
    assert raw["seam_max_deg"] > 1.5 * max(raw["cornea_max_deg"], raw["sclera_max_deg"])


def test_smooth_profile_is_c1():
    th = np.linspace(0, np.pi, 200001)
    R = geo.outer_radial(th, P)
    d1 = np.diff(R) / np.diff(th)
    assert np.abs(np.diff(d1)).max() < 1e-3                      # no jump in slope


# ------------------------------------------------------------------ inner part, gap

def test_inner_iris_and_gap(eye):
    iris = eye.inner.V[eye.landmarks["iris"]]
    assert 11.5 <= 2 * np.hypot(iris[:, 0], iris[:, 1]).mean() <= 12.0
    front = eye.inner.V[eye.inner.rings[0]]
    assert np.ptp(eye.inner.V[np.concatenate(eye.inner.rings[:P and 11]), 2]) < 1e-9  # planar front
    _, _, d = outer_surface_closest_point(eye.inner.V)
    assert -d.max() == pytest.approx(0.5, abs=1e-4)               # 0.5 mm gap, nothing closer
    assert np.all(d < 0)
    assert front[:, 2].max() < eye.outer.V[:, 2].max()


def test_closest_point_placed_and_rotated():
    rng = np.random.default_rng(1)
    f = np.array([0.3, -0.2, 1.0]); f /= np.linalg.norm(f)
    c = np.array([31.0, 4.0, -7.0])
    m = geo.outer_mesh(geo.placed_params(P, 15.4), "full")     # sclera 15.4 mm, cornea as is
    s = 1.0
    # a point of the unit-frame mesh, placed with the same frame as the function
    a = np.array([1.0, 0, 0])
    e1 = np.cross(a, f); e1 /= np.linalg.norm(e1)
    e2 = np.cross(f, e1)
    Rm = np.stack([e1, e2, f], 1)
    Vw = c + s * m.V @ Rm.T
    Q, N, d = outer_surface_closest_point(Vw, c, f, radius=15.4)
    assert np.abs(d).max() < 1e-4 and np.abs(Q - Vw).max() < 1e-4
    # off-surface points project back along the normal
    P0 = Vw[rng.choice(len(Vw), 200)]
    _, N0, _ = outer_surface_closest_point(P0, c, f, radius=15.4)
    Q2, _, d2 = outer_surface_closest_point(P0 + 0.3 * N0, c, f, radius=15.4)
    assert np.allclose(d2, 0.3, atol=1e-3)
    assert np.allclose(Q2, P0, atol=1e-3)


# ------------------------------------------------------------------ blend shapes

def _check_pose(e, W, rest_normals):
    Vp = geo.apply_blend_shapes(e.inner.V, e.shapes, W)
    N = face_normals(Vp, e.inner.F, normalize=False)
    assert np.linalg.norm(N, axis=1).min() > 1e-10, "degenerate face"
    cosang = np.einsum("ij,ij->i", N, rest_normals) / (
        np.linalg.norm(N, axis=1) * np.linalg.norm(rest_normals, axis=1))
    assert cosang.min() > 0.5, "flipped face"
    ok, _ = mesh_edges_manifold(e.inner.F)
    assert ok
    pr = np.hypot(*Vp[e.landmarks["pupil"], :2].T)
    ir = np.hypot(*Vp[e.landmarks["iris"], :2].T)
    assert pr.max() < ir.min() - 0.5, "pupil leaves the iris"
    _, _, d = outer_surface_closest_point(Vp)
    assert d.max() <= -0.5 + 1e-6, "inner part pokes toward/through the outer part"
    return pr.mean(), ir.mean()


def test_blend_shape_corners_and_random_interior():
    e = geo.build_eyeball(P, "medium")
    rest_N = face_normals(e.inner.V, e.inner.F, normalize=False)
    for corner in itertools.product([0.0, 1.0], repeat=4):
        _check_pose(e, dict(zip(geo.SHAPE_NAMES, corner)), rest_N)
    rng = np.random.default_rng(0)
    for w in rng.random((40, 4)):
        _check_pose(e, dict(zip(geo.SHAPE_NAMES, w)), rest_N)


def test_blend_shape_targets_hit_ranges():
    e = geo.build_eyeball(P, "medium")
    rest_N = face_normals(e.inner.V, e.inner.F, normalize=False)
    pr, _ = _check_pose(e, {"pupil_dilate": 1}, rest_N)
    assert pr == pytest.approx(4.0)
    pr, _ = _check_pose(e, {"pupil_constrict": 1}, rest_N)
    assert pr == pytest.approx(1.0)
    _, ir = _check_pose(e, {"iris_large": 1}, rest_N)
    assert ir == pytest.approx(P.iris_radius * 1.1)
    _, ir = _check_pose(e, {"iris_small": 1}, rest_N)
    assert ir == pytest.approx(P.iris_radius * 0.9)


def test_weight_rule_clamps_and_refuses():
    e = geo.build_eyeball(P, "low")
    a = geo.apply_blend_shapes(e.inner.V, e.shapes, {"pupil_dilate": 3.0, "iris_small": -2})
    b = geo.apply_blend_shapes(e.inner.V, e.shapes, {"pupil_dilate": 1.0})
    assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="finite"):
        geo.clamp_weights({"pupil_dilate": float("nan")})
    with pytest.raises(ValueError, match="unknown"):
        geo.clamp_weights({"wink": 1.0})


# ------------------------------------------------------------------ landmarks

@pytest.mark.parametrize("res", ["low", "high", "full"])
def test_landmark_order_and_count(res):
    e = geo.build_eyeball(P, res)
    for key, radius in (("iris", P.iris_radius), ("pupil", P.pupil_radius)):
        idx = e.landmarks[key]
        assert idx.shape == (8,) and len(set(idx.tolist())) == 8
        pts = e.inner.V[idx]
        ang = np.degrees(np.arctan2(pts[:, 1], pts[:, 0])) % 360
        assert np.allclose(ang, 45.0 * np.arange(8), atol=1e-6)     # start +X, counter-clockwise
        assert np.allclose(np.hypot(pts[:, 0], pts[:, 1]), radius)


def test_landmarks_follow_blend_shapes():
    e = geo.build_eyeball(P, "high")
    Vp = geo.apply_blend_shapes(e.inner.V, e.shapes, {"pupil_dilate": 1, "iris_large": 1})
    assert np.allclose(np.hypot(*Vp[e.landmarks["pupil"], :2].T), 4.0)
    assert np.allclose(np.hypot(*Vp[e.landmarks["iris"], :2].T), P.iris_radius * 1.1)


def test_bad_parameters_refused():
    with pytest.raises(ValueError, match="multiple of 8"):
        geo.Resolution(n_around=30)
    with pytest.raises(ValueError, match="unknown resolution"):
        geo.Resolution.preset("ultra")
    with pytest.raises(ValueError, match="apex"):
        geo.EyeballParams(apex=11.0)
    with pytest.raises(ValueError, match="pupil_dilated_mm .* must stay smaller than the small iris"):
        geo.EyeballParams(pupil_dilated_mm=6.0)
    with pytest.raises(ValueError, match=r"r1 must be a finite number \(got nan\)"):
        geo.EyeballParams(r1=float("nan"))
    with pytest.raises(ValueError, match="unknown eyeball geometry"):
        geo.EyeballParams.from_dict({"radius": 12})
    assert geo.EyeballParams.from_dict({"r1": "12.5", "apex": 14}).r1 == 12.5


def test_tiny_and_huge_eyes_scale_cleanly():
    e = geo.build_eyeball(geo.EyeballParams(r1=1.2, r2=0.8, apex=1.35, seam_blend_mm=0.1, gap=0.05,
                                            iris_radius=0.59, pupil_radius=0.2, pupil_dilated_mm=0.4,
                                            pupil_constricted_mm=0.1), "low")
    assert mesh_edges_manifold(e.outer.F)[0] and mesh_edges_manifold(e.inner.F)[0]
    big = geo.EyeballParams(r1=1200, r2=800, apex=1350, seam_blend_mm=100, gap=50, iris_radius=590,
                            pupil_radius=200, pupil_dilated_mm=400, pupil_constricted_mm=100)
    e2 = geo.build_eyeball(big, "low")
    assert np.allclose(e2.outer.V, 100 * geo.build_eyeball(P, "low").outer.V, rtol=1e-9, atol=1e-7)


# ------------------------------------------------------------------ placed in a scan: proportions

def _sphere_fit(X):
    """Least-squares sphere (centre (3,), radius) through points X (n, 3)."""
    A = np.c_[2 * X, np.ones(len(X))]
    sol, *_ = np.linalg.lstsq(A, (X ** 2).sum(1), rcond=None)
    return sol[:3], float(np.sqrt(sol[3] + sol[:3] @ sol[:3]))


@pytest.mark.parametrize("radius", [11.0, 12.0, 13.5, 15.4, 16.0])
def test_placed_eye_keeps_human_proportions(radius):
    """Proportions within bounds: the sclera takes the fitted radius, the visible iris (10.5-13 mm
    across over the iris blend shapes, 11.7 mm at rest), the cornea (r2) and its protrusion out
    of the sphere do not scale with it; the seam stays smooth (C2 profile, no crease)."""
    q = geo.placed_params(P, radius)
    assert q.r1 == radius and q.r2 == P.r2 and q.apex - q.r1 == pytest.approx(P.apex - P.r1)
    assert (q.iris_radius, q.pupil_radius, q.gap) == (P.iris_radius, P.pupil_radius, P.gap)
    e = geo.build_eyeball(q, "high")
    # the visible iris in mm, whatever the radius
    lm = e.landmarks["iris"]
    diam = {}
    for shape in (None, "iris_small", "iris_large"):
        V = geo.apply_blend_shapes(e.inner.V, e.shapes, {shape: 1.0} if shape else {})
        diam[shape] = 2 * np.hypot(*V[lm, :2].T).mean()
    assert diam[None] == pytest.approx(11.7, abs=1e-6)
    assert 10.5 <= diam["iris_small"] < diam[None] < diam["iris_large"] <= 13.0
    # the sclera has the fitted radius, the cornea the human one (sphere fits to the mesh)
    ring = np.concatenate(e.outer.rings)
    R = np.linalg.norm(e.outer.V[ring], axis=1)
    assert np.abs(R[R < radius + 1e-9] - radius).max() < 1e-9
    tl = geo.limbus_theta(q)
    th = np.arctan2(np.hypot(*e.outer.V[:, :2].T), e.outer.V[:, 2])
    cap = e.outer.V[th < 0.6 * tl]                       # clear of the seam blend
    c, r2 = _sphere_fit(cap)
    assert r2 == pytest.approx(P.r2, abs=1e-6) and np.allclose(c, [0, 0, q.cornea_center_z], atol=1e-6)
    assert e.outer.V[:, 2].max() == pytest.approx(radius + P.apex - P.r1, abs=1e-9)
    # the inner part (iris plane) stays inside the outer shell by the cornea thickness
    _, _, d = outer_surface_closest_point(e.inner.V, params=q)
    assert d.max() <= -q.gap + 1e-6
    # the seam: C2 smooth maximum, no crease at the tessellation
    rep = seam_dihedral_report(q, "high")
    assert rep["seam_max_deg"] <= max(rep["cornea_max_deg"], rep["sclera_max_deg"])
    t = np.linspace(0, np.pi, 200001)
    d1 = np.diff(geo.outer_radial(t, q)) / np.diff(t)
    assert np.abs(np.diff(d1)).max() < 1e-3


def test_placed_outer_surface_is_what_snap_and_rig_use():
    """snap (closest points), the rig's eye frames and the placed mesh agree on the outer surface."""
    from pipeline.rig.eye_frame import EyeFrame

    radius, f, c = 15.4, np.array([0.0, 0.0, 1.0]), np.array([3.0, -2.0, 40.0])
    m = geo.outer_mesh(geo.placed_params(P, radius), "full")
    Vw = c + m.V
    _, _, d = outer_surface_closest_point(Vw, c, f, radius=radius, params=P)
    assert np.abs(d).max() < 1e-4
    eye = EyeFrame("left", c, radius, f, np.arange(8), 4, P)
    assert np.abs(eye.surface_distance(Vw)).max() < 1e-6


# ------------------------------------------------------------------ textures

def test_iris_textures_deterministic_distinct_and_structured():
    imgs = {c: tex.iris_texture(c, 256, seed=3) for c in tex.IRIS_COLORS}
    assert np.array_equal(imgs["blue"], tex.iris_texture("blue", 256, seed=3))
    assert not np.array_equal(imgs["blue"], tex.iris_texture("blue", 256, seed=4))
    n = 256
    c = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y = np.meshgrid(c, -c)                                        # image rows top = +v
    r = np.hypot(X, Y)
    t = (r - geo.IRIS_TEXTURE_PUPIL_FRACTION) / (geo.IRIS_TEXTURE_IRIS_FRACTION
                                                 - geo.IRIS_TEXTURE_PUPIL_FRACTION)
    means = {}
    for col, im in imgs.items():
        lum = im.mean(-1)
        assert lum[r < geo.IRIS_TEXTURE_PUPIL_FRACTION - 0.02].max() < 0.02    # black pupil
        mid = lum[(t > 0.4) & (t < 0.6)].mean()
        assert lum[(t > 0.93) & (t < 1.0)].mean() < 0.6 * mid                   # darker limbal ring
        ring = (t > 0.5) & (t < 0.55)
        assert lum[ring].std() > 0.1 * lum[ring].mean()                        # fibres / crypts
        means[col] = im[(t > 0.3) & (t < 0.8)].mean(0)
    assert means["blue"][2] > means["blue"][0]                                 # blue is blue
    assert means["brown"].mean() < means["amber"].mean()                       # brown darker
    assert means["amber"][0] > means["amber"][2] * 2                           # amber warm
    assert np.ptp(means["grey"]) < 0.1                                         # grey neutral
    for a, b in itertools.combinations(tex.IRIS_COLORS, 2):
        assert np.abs(means[a] - means[b]).max() > 0.05


def test_sclera_textures():
    bs = tex.sclera_texture("bloodshot", 256, 128, seed=1)
    cl = tex.sclera_texture("clear", 256, 128, seed=1)
    redness = lambda im: (im[..., 0] - im[..., 1]).mean()  # noqa: E731
    assert redness(bs) > redness(cl) + 0.01
    assert cl.mean() > 0.8
    with pytest.raises(ValueError, match="unknown veins layer 'green'"):
        tex.sclera_texture("green")
    with pytest.raises(ValueError, match="unknown iris colour 'violet'"):
        tex.iris_texture("violet")


# ------------------------------------------------------------------ USD asset

@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    from PIL import Image

    from pipeline.usd.eyeball import write_eyeball_usd

    d = tmp_path_factory.mktemp("eyeball")
    e = geo.build_eyeball(P, "medium")
    (d / "textures").mkdir()
    for name, img in tex.texture_set(0, 64, (64, 32), resolution="medium").items():
        Image.fromarray(img).save(d / "textures" / name)
    return write_eyeball_usd(e, d / "eyeball.usda"), e


def test_usd_asset_contents(asset):
    from pxr import Kind, Usd, UsdGeom, UsdShade, UsdSkel

    from pipeline.usd.validate import validate_stage

    path, e = asset
    assert validate_stage(path) == []
    st = Usd.Stage.Open(str(path))
    root = st.GetDefaultPrim()
    assert root.GetPath().pathString == "/Eyeball"
    assert Usd.ModelAPI(root).GetKind() == Kind.Tokens.component
    assert UsdGeom.GetStageMetersPerUnit(st) == 0.001 and UsdGeom.GetStageUpAxis(st) == "Y"
    outer, inner = UsdGeom.Mesh.Get(st, "/Eyeball/Outer"), UsdGeom.Mesh.Get(st, "/Eyeball/Inner")
    assert outer and inner
    assert np.allclose(np.asarray(inner.GetPointsAttr().Get()), e.inner.V, atol=1e-5)
    pts = np.asarray(outer.GetPointsAttr().Get())
    assert pts[:, 2].max() == pytest.approx(13.5, abs=1e-5)          # still looking down +Z
    api = UsdSkel.BindingAPI(inner.GetPrim())
    assert list(api.GetBlendShapesAttr().Get()) == list(geo.SHAPE_NAMES)
    for s in e.shapes:
        bs = UsdSkel.BlendShape(st.GetPrimAtPath(f"/Eyeball/Inner/{s.name}"))
        assert np.array_equal(np.asarray(bs.GetPointIndicesAttr().Get()), s.point_indices)
        assert np.allclose(np.asarray(bs.GetOffsetsAttr().Get()), s.offsets, atol=1e-5)
    for key in ("iris", "pupil"):
        a = inner.GetPrim().GetAttribute(f"eyerig:landmarks:{key}")
        assert list(a.Get()) == e.landmarks[key].tolist()
        assert "counter-clockwise" in a.GetDocumentation()
    ior = UsdShade.Shader(st.GetPrimAtPath("/Eyeball/Materials/Cornea/PreviewSurface"))
    assert ior.GetInput("ior").Get() == pytest.approx(1.376)
    assert ior.GetInput("opacity").Get() < 0.2
    vsets = root.GetVariantSets()
    assert set(vsets.GetNames()) == {"irisColor", "scleraTint", "veins"}
    assert set(vsets.GetVariantSet("irisColor").GetVariantNames()) == set(tex.IRIS_COLORS)
    assert set(vsets.GetVariantSet("scleraTint").GetVariantNames()) == set(tex.SCLERA_TINTS)
    assert set(vsets.GetVariantSet("veins").GetVariantNames()) == set(tex.VEINS)
    # switching a variant switches the bound texture
    texs = UsdShade.Shader(st.GetPrimAtPath("/Eyeball/Materials/Iris/DiffuseTexture"))
    for c in tex.IRIS_COLORS:
        vsets.GetVariantSet("irisColor").SetVariantSelection(c)
        f = texs.GetInput("file").Get()
        assert f.path.endswith(f"iris_{c}.png") and f.resolvedPath
    vsets.GetVariantSet("scleraTint").SetVariantSelection("yellow")
    sc = UsdShade.Shader(st.GetPrimAtPath("/Eyeball/Materials/Sclera/DiffuseTexture"))
    assert tuple(sc.GetInput("scale").Get())[:3] == pytest.approx(tex.SCLERA_TINTS["yellow"])
    assert validate_stage(st) == []
    # every face has a material
    sub = UsdShade.MaterialBindingAPI(inner.GetPrim()).GetMaterialBindSubsets()
    assert sorted(len(s.GetIndicesAttr().Get()) for s in sub) and \
        sum(len(s.GetIndicesAttr().Get()) for s in sub) == len(e.inner.poly_counts)


def test_stage_cli_builds_asset_without_blender(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    params = tmp_path / "params.yaml"
    params.write_text("eyeball:\n  resolution: low\n  iris_texture_px: 64\n"
                      "  sclera_texture_px: [64, 32]\n")
    out = tmp_path / "rigged_assets" / "eyeball"
    res = subprocess.run([sys.executable, "-m", "stages.eyeball", str(out), "--params", str(params),
                          "--metrics", str(tmp_path / "m.json")], cwd=root, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    m = read_stage_metrics(tmp_path / "m.json")
    assert m["validation_errors"] == 0 and m["outer_vertices"] == 338
    assert (out / "eyeball.usda").is_file() and len(list((out / "textures").glob("*.png"))) == 8
    assert not (out / "preview.png").exists()          # the eyeball_preview stage's, beside the folder
    assert not any(p.name.startswith(".eyeball.tmp") for p in out.parent.iterdir())
    assert math.isfinite(m["wall_time_s"])


def test_sclera_bump_maps_smooth_cornea_and_unit_normals():
    res = geo.Resolution.preset("medium")
    th = geo.outer_thetas(P, res)
    args = (th, geo.limbus_theta(P), lambda t: geo.outer_radial(t, P))
    h, n = tex.sclera_bump_maps(*args, size=(128, 64), seed=2)
    h2, _ = tex.sclera_bump_maps(*args, size=(128, 64), seed=2)
    assert np.array_equal(h, h2)
    N = n * 2 - 1
    assert np.allclose(np.linalg.norm(N, axis=-1), 1, atol=1e-5) and N[..., 2].min() > 0.9
    # rows over the cornea (v near 1, image top) carry no bumps; the sclera does
    rows = len(th) + 2
    v = 1 - (np.arange(64) + 0.5) / 64
    theta = np.interp((1 - v) * (rows - 1), np.arange(rows), np.concatenate([[0], th, [np.pi]]))
    cornea = theta < geo.limbus_theta(P)
    assert np.allclose(h[cornea], 0.5) and h[theta > geo.limbus_theta(P) + 0.2].std() > 0.02
    a = tex.solid_noise(np.array([[1.0, 2.0, 3.0]]), seed=0)
    b = tex.solid_noise(np.array([[1.01, 2.0, 3.0]]), seed=0)
    assert abs(a - b).max() < 0.1                                 # smooth at 0.01 mm


def test_usd_sclera_normal_map(asset):
    from pxr import Usd, UsdShade

    path, _ = asset
    st = Usd.Stage.Open(str(path))
    surf = UsdShade.Shader(st.GetPrimAtPath("/Eyeball/Materials/ScleraCoat/PreviewSurface"))
    src = surf.GetInput("normal").GetConnectedSources()[0][0].source
    nt = UsdShade.Shader(src.GetPrim())
    assert nt.GetInput("file").Get().path.endswith("sclera_normal.png")
    assert nt.GetInput("sourceColorSpace").Get() == "raw"


def test_stage_cli_refuses_bad_settings(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    params = tmp_path / "params.yaml"
    params.write_text("eyeball:\n  resolution: {n_around: 30}\n")
    out = tmp_path / "eyeball"
    res = subprocess.run([sys.executable, "-m", "stages.eyeball", str(out), "--params", str(params)],
                         cwd=root, capture_output=True, text=True)
    assert res.returncode == 2 and "multiple of 8" in res.stderr and "Traceback" not in res.stderr
    assert not out.exists()


# ------------------------------------------------------------------ one limit per value

def _eyeball_limits(expensive: bool):
    from pipeline.settings import boundaries

    big = {("iris_texture_px", 4096), ("sclera_texture_px", 8192)}
    out = []
    for key, value, ok in boundaries(geo.EyeballSettings):
        if not ok or key[0].startswith("preview"):          # the eyeball_preview stage's (tests/test_blender_eyeball.py)
            continue
        edge = (key[0], value[0] if isinstance(value, list) else value)
        if (edge in big) == expensive:
            out.append((key, value))
    return out


def _build_at(tmp_path, key, value):
    from pipeline.settings import SettingsError
    from pipeline.usd.eyeball_asset import build_eyeball_asset

    small = {"resolution": "low", "iris_texture_px": 16, "sclera_texture_px": [16, 16]}
    raw = dict(small)
    if len(key) == 2:
        raw[key[0]] = {key[1]: value}
    else:
        raw[key[0]] = value
    try:
        s = geo.EyeballSettings.from_params(raw)
    except SettingsError as exc:           # a limit that collides with another default: one line
        assert "\n" not in str(exc)
        return
    build_eyeball_asset(tmp_path, s)              # builds, writes and validates (an error raises)
    assert (tmp_path / "eyeball.usda").is_file()


@pytest.mark.parametrize("key, value", _eyeball_limits(expensive=False))
def test_every_value_the_settings_accept_builds_a_valid_asset(tmp_path, key, value):
    """Issue 22: each value the eyeball block accepts at its limits builds and validates."""
    _build_at(tmp_path, key, value)


@pytest.mark.slow
@pytest.mark.parametrize("key, value", _eyeball_limits(expensive=True))
def test_the_largest_accepted_textures_build(tmp_path, key, value):
    _build_at(tmp_path, key, value)


def test_library_guards_agree_with_the_settings():
    """Guards kept in library functions (they also take values read from assets) accept every
    value the settings accept: the iris texture size, the rig's canthus widths and pitch limit."""
    from pipeline.rig.lid_shapes import canthus_taper
    from pipeline.rig.lids import RigSettings, lid_weights
    from pipeline.settings import boundaries

    for key, value, ok in boundaries(geo.EyeballSettings):
        if ok and key == ("iris_texture_px",) and value <= 512:
            assert tex.iris_texture("brown", value, 0).shape == (value, value, 3)
    u = np.linspace(0, 1, 9)
    for key, value, ok in boundaries(RigSettings):
        if ok and key[0] in ("canthus_width", "lateral_canthus_width"):
            assert np.isfinite(canthus_taper(u, value, 1.0, value)).all()
        if ok and key[0] == "max_pitch_deg":
            w = lid_weights(10.0, value)
            assert 0.0 <= min(w.values()) <= max(w.values()) <= 1.0
