"""bake: UV unwrap, Embree displacement bake with an analytic ground truth, misses, EXR, colour, stage CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from fixtures import face_patch
from pipeline.bake.bake import BakeSettings, atlas_unwrap, bake_maps, reconstruction_error, subdivide_displaced
from pipeline.io.exr import preview_16bit, read_exr, write_exr
from pipeline.bake.uv import UnwrapError, _check_simple_boundary, conformal_unwrap, dilate, rasterize, sample_bilinear, unwrap
from pipeline.io.bake_file import read_bake, read_displacement
from pipeline.io.eyes_file import write_eyes
from pipeline.io.meshfile import load_mesh, save_mesh

ROOT = Path(__file__).resolve().parents[1]
R = 20.0      # sphere radius, mm
A = 0.4       # bump amplitude, mm


def bump(n):
    """Known bump field on the unit sphere."""
    return A * np.sin(3 * n[:, 0]) * np.cos(4 * n[:, 1]) * np.sin(2 * n[:, 2] + 0.5)


def bumpy_sphere(subdiv=6):
    s = trimesh.creation.icosphere(subdivisions=subdiv)
    n = np.asarray(s.vertices)
    return n * (R + bump(n))[:, None], np.asarray(s.faces, dtype=np.int64)


def smooth_sphere(subdiv=3):
    s = trimesh.creation.icosphere(subdivisions=subdiv)
    return np.asarray(s.vertices) * R, np.asarray(s.faces, dtype=np.int64)


@pytest.fixture(scope="module")
def sphere_bake():
    Vd, Fd = bumpy_sphere()
    V, F = smooth_sphere()
    s = BakeSettings(resolution=512, falloff_mm=0.0, max_distance_mm=2.0)
    return V, F, Vd, Fd, bake_maps(V, F, {}, {"V": Vd, "F": Fd}, None, s)


def test_unwrap_and_rasterize_cover_each_texel_once():
    V, F = smooth_sphere(2)
    UV, FUV = unwrap(V, F, 256, 2)
    assert FUV.shape == F.shape and UV.min() >= 0 and UV.max() <= 1
    rows, cols, face, bary = rasterize(UV, FUV, 256, 256)
    assert len(np.unique(rows * 256 + cols)) == len(rows)
    assert np.allclose(bary.sum(1), 1) and bary.min() >= 0
    # texel centre re-derived from barycentrics matches the pixel-centre convention
    uv = np.einsum("kj,kjc->kc", bary, UV[FUV[face]])
    assert np.allclose(uv[:, 0] * 256 - 0.5, cols, atol=1e-6)
    assert np.allclose((1 - uv[:, 1]) * 256 - 0.5, rows, atol=1e-6)


def _plate_with_two_holes(n=61, bend=0.0):
    """A 60 x 30 mm grid with two round openings (radius 6 mm at x = +-15), bent into a cylinder of
    curvature ``bend`` (1/mm) about the y axis; returns V, F and the two openings' vertex rings."""
    x, y = np.meshgrid(np.linspace(-30, 30, n), np.linspace(-15, 15, (n + 1) // 2))
    P = np.stack([x.ravel(), y.ravel()], 1)
    from scipy.spatial import Delaunay

    tri = Delaunay(P).simplices
    c = P[tri].mean(1)
    keep = (np.hypot(c[:, 0] - 15, c[:, 1]) > 6) & (np.hypot(c[:, 0] + 15, c[:, 1]) > 6)
    F = tri[keep]
    used, F = np.unique(F, return_inverse=True)
    P, F = P[used], F.reshape(-1, 3)
    if bend:
        V = np.stack([np.sin(bend * P[:, 0]) / bend, P[:, 1], (np.cos(bend * P[:, 0]) - 1) / bend], 1)
    else:
        V = np.column_stack([P, np.zeros(len(P))])
    ring = [np.nonzero(np.abs(np.hypot(P[:, 0] - cx, P[:, 1]) - 6.5) < 0.6)[0] for cx in (15, -15)]
    return V, F.astype(np.int64), ring


def test_conformal_unwrap_of_a_flat_plate_is_a_similarity_per_chart():
    """A flat plate's conformal map is the plate itself, scaled and turned: every triangle keeps
    its shape and one scale (the same in both charts), each texel is covered once, and the two
    halves become two charts (one seam, down the middle)."""
    V, F, _ = _plate_with_two_holes()
    side = (V[F].mean(1)[:, 0] > 0).astype(int)
    UV, FUV = conformal_unwrap(V, F, side, 512, 4)
    assert FUV.shape == F.shape and UV.min() >= 4 / 512 - 1e-12 and UV.max() <= 1 - 4 / 512 + 1e-12
    a3 = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    e1, e2 = UV[FUV[:, 1]] - UV[FUV[:, 0]], UV[FUV[:, 2]] - UV[FUV[:, 0]]
    a2 = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert (a2 > 0).all()                                          # the faces' winding is kept
    scale = a2 / a3
    assert np.ptp(scale) / scale.mean() < 1e-6                     # one scale: the same in both charts
    # half the plate is 30 x 30 mm, side by side: 60 mm across the 1 - 3 gaps of the atlas
    assert np.isclose(np.sqrt(scale.mean()), (1 - 3 * 4 / 512) / 60.0, rtol=1e-6)
    assert len(np.unique(FUV[side == 0])) + len(np.unique(FUV[side == 1])) == len(UV)   # a seam: no UV shared
    rows, cols, _, _ = rasterize(UV, FUV, 512, 512)
    assert len(rows) == pytest.approx(a2.sum() * 512 ** 2, rel=0.02)   # each texel once: no overlap


def test_conformal_unwrap_of_a_bent_plate_keeps_angles():
    """Bent into a cylinder (developable), the map is still isometric up to one scale."""
    V, F, _ = _plate_with_two_holes(bend=1 / 25.0)
    UV, FUV = conformal_unwrap(V, F, (V[F].mean(1)[:, 0] > 0).astype(int), 1024, 4)
    a3 = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    e1, e2 = UV[FUV[:, 1]] - UV[FUV[:, 0]], UV[FUV[:, 2]] - UV[FUV[:, 0]]
    scale = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) / a3
    assert np.ptp(scale) / scale.mean() < 1e-3


def test_atlas_unwrap_falls_back_to_xatlas_where_no_chart_opens():
    """A closed surface has no boundary for a conformal chart: xatlas unwraps it, and says why."""
    V, F = smooth_sphere(2)
    UV, FUV, method = atlas_unwrap(V, F, [], BakeSettings(resolution=256))
    assert method.startswith("xatlas (a closed chart") and FUV.shape == F.shape
    Vp, Fp, rings = _plate_with_two_holes()
    assert atlas_unwrap(Vp, Fp, rings, BakeSettings(resolution=256))[2] == "conformal"
    assert atlas_unwrap(Vp, Fp, rings, BakeSettings(resolution=256, unwrap="xatlas"))[2] == "xatlas"


def test_a_conformal_map_libigl_cannot_solve_falls_back_to_xatlas(monkeypatch):
    """libigl's solver failing on a chart (a face of zero area made ``igl::lscm failed`` on a
    fresh5 head, `n1108_blink_60k`, and the bake stopped with a traceback) is an UnwrapError:
    the atlas falls back to xatlas and says why."""
    import igl

    def singular(*a, **k):
        raise RuntimeError("igl::lscm failed")

    monkeypatch.setattr(igl, "lscm", singular)
    Vp, Fp, rings = _plate_with_two_holes()
    UV, FUV, method = atlas_unwrap(Vp, Fp, rings, BakeSettings(resolution=256))
    assert method == "xatlas (the conformal map failed (igl::lscm failed))" and FUV.shape == Fp.shape


def test_a_boundary_that_crosses_itself_is_refused():
    """Two boundary edges crossing (a chart folded over itself) raise; touching at a vertex does not."""
    UV = np.array([[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0], [4.0, 0.0]])
    with pytest.raises(UnwrapError, match="1 boundary edges cross"):
        _check_simple_boundary(UV, np.array([[0, 1], [2, 3]]))
    _check_simple_boundary(UV, np.array([[0, 2], [2, 4], [2, 1]]))


def test_displacement_matches_analytic_bump(sphere_bake):
    V, F, Vd, Fd, b = sphere_bake
    assert b.metrics["missed_texels"] == 0
    rows, cols, face, bary = rasterize(b.UV, b.FUV, 512, 512)
    from pipeline.geometry.mesh_checks import vertex_normals
    VN = vertex_normals(V, F)
    P = np.einsum("kj,kjc->kc", bary, V[F[face]])
    N = np.einsum("kj,kjc->kc", bary, VN[F[face]])
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    Q = P + b.displacement[rows, cols][:, None] * N          # displaced texel points
    r = np.linalg.norm(Q, axis=1)
    truth = R + bump(Q / r[:, None])
    err = np.abs(r - truth)
    # the dense sphere (subdiv 6, ~0.6 mm edges) is itself a chordal approximation: sag <= R(1-cos(e/2R))
    assert np.percentile(err, 95) < 0.01 and err.max() < 0.03


def test_subdivided_displaced_mesh_reduces_error(sphere_bake):
    V, F, Vd, Fd, b = sphere_bake
    e = reconstruction_error(V, F, b.UV, b.FUV, b.displacement, Vd, Fd, levels=2, n_samples=20000)
    assert e["with_displacement"]["symmetric_mean_mm"] < 0.3 * e["without_displacement"]["symmetric_mean_mm"]
    assert e["mean_error_removed"] > 0.7
    Vs, Fs = subdivide_displaced(V, F, b.UV, b.FUV, b.displacement, 2, displace=False)
    assert len(Fs) == 16 * len(F)


def test_missed_texels_are_counted_and_filled():
    Vd, Fd = bumpy_sphere(5)
    keep = Vd[Fd].mean(1)[:, 2] > 0                          # the scan covers only the front half
    V, F = smooth_sphere(2)
    b = bake_maps(V, F, {}, {"V": Vd, "F": Fd[keep]}, None,
                  BakeSettings(resolution=256, falloff_mm=0.0, max_distance_mm=1.0))
    frac = b.metrics["missed_texel_fraction"]
    assert 0.3 < frac < 0.7                                   # about the back half misses
    assert np.isfinite(b.displacement).all()


def test_prebuilt_scene_gives_the_same_maps():
    """bake_scan builds the Embree scene while the mesh unwraps and hands it to bake_maps: the maps
    (a half scan: some misses) are the same bytes as when bake_maps builds the scene itself, and as
    without the far faces (the colour lookup maps hits back through the scene's face_ids)."""
    from pipeline.bake.bake import dense_scene
    from pipeline.bake.raycast import cast_both_ways

    Vd, Fd = bumpy_sphere(5)
    keep = Vd[Fd].mean(1)[:, 2] > 0
    # faces far outside the low-poly mesh's box come first, so the scene's faces are renumbered
    Vd = np.concatenate([Vd, Vd + 100.0])
    Fd = np.concatenate([Fd[:500] + len(Vd) // 2, Fd[keep]])
    dense = {"V": Vd, "F": Fd, "VC": (np.abs(Vd) * 10 % 255).astype(np.uint8)}
    V, F = smooth_sphere(2)
    s = BakeSettings(resolution=128, falloff_mm=0.0, max_distance_mm=1.0)
    UV, FUV = unwrap(V, F, s.resolution, s.uv_padding_texels)
    scene = dense_scene(V, dense, s)
    assert scene.face_ids[0] == 500 and np.array_equal(scene.F, dense["F"][scene.face_ids])
    a = bake_maps(V, F, {}, dense, None, s, UV=UV, FUV=FUV)
    b = bake_maps(V, F, {}, dense, None, s, UV=UV, FUV=FUV, scene=scene)
    c = bake_maps(V, F, {}, {**dense, "F": Fd[500:]}, None, s, UV=UV, FUV=FUV)   # without the far faces
    assert a.metrics["missed_texels"] > 0
    for other in (b, c):
        assert np.array_equal(a.displacement, other.displacement) and np.array_equal(a.color, other.color)
    # the two-way cast picks the nearer of the forward and backward hits of intersect()
    P = V * 1.01
    N = P / np.linalg.norm(P, axis=1, keepdims=True)
    disp, face, bary = cast_both_ways(scene, P, N, 1.0)
    t, f, w = scene.intersect(np.concatenate([P - 1e-3 * N, P + 1e-3 * N]), np.concatenate([N, -N]), 1.0 + 1e-3)
    k = len(P)
    back = np.isnan(t[:k]) | (np.abs(t[k:] - 1e-3) < np.abs(t[:k] - 1e-3))
    assert np.allclose(np.where(back, -(t[k:] - 1e-3), t[:k] - 1e-3), disp, equal_nan=True)
    assert np.array_equal(np.where(back, f[k:], f[:k]), face)
    assert np.array_equal(np.where(back[:, None], w[k:], w[:k]), bary)


def test_exr_roundtrip_and_preview(tmp_path):
    rng = np.random.default_rng(1)
    a = (rng.standard_normal((37, 53)) * 0.3).astype(np.float32)
    write_exr(tmp_path / "d.exr", a)
    assert np.array_equal(read_exr(tmp_path / "d.exr"), a)
    q, scale, offset = preview_16bit(a)
    assert q.dtype == np.uint16
    assert np.abs(offset + scale * q.astype(np.float64) - a).max() <= scale / 2 + 1e-9
    with pytest.raises(ValueError, match="channel"):
        read_exr(tmp_path / "d.exr", channel="Z")


def test_colour_from_texture_and_vertex_colours():
    # dense: a fine plane with UV = position and a known gradient texture; low-poly: a coarse plane
    g = np.linspace(0, 10, 41)
    X, Y = np.meshgrid(g, g)
    Vd = np.stack([X.ravel(), Y.ravel(), 0.05 * np.sin(X.ravel())], 1)
    n = len(g)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (j * n + i).ravel()
    Fd = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    UVd = Vd[:, :2] / 10.0
    H = W = 64
    tex = np.zeros((H, W, 3), dtype=np.uint8)
    tex[..., 0] = np.round(np.linspace(0, 255, W))[None, :]           # red grows with u
    tex[..., 1] = np.round(np.linspace(255, 0, H))[:, None]           # green grows with v (rows top-down)
    Vl = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], float)
    Fl = np.array([[0, 1, 2], [0, 2, 3]])
    b = bake_maps(Vl, Fl, {}, {"V": Vd, "F": Fd, "UV": UVd, "FUV": Fd}, tex,
                  BakeSettings(resolution=128, falloff_mm=0.0, max_distance_mm=1.0))
    assert b.metrics["colour"] == "texture"
    rows, cols, face, bary = rasterize(b.UV, b.FUV, 128, 128)
    P = np.einsum("kj,kjc->kc", bary, Vl[Fl[face]])
    col = b.color[rows, cols].astype(float)
    u, v = P[:, 0] / 10, P[:, 1] / 10
    inner = (u > 0.05) & (u < 0.95) & (v > 0.05) & (v < 0.95)
    assert np.abs(col[inner, 0] - 255 * u[inner]).max() < 6
    assert np.abs(col[inner, 1] - 255 * v[inner]).max() < 6
    # vertex colours instead of a texture
    VC = np.stack([Vd[:, 0] * 25, Vd[:, 1] * 25, np.full(len(Vd), 7)], 1).astype(np.uint8)
    b2 = bake_maps(Vl, Fl, {}, {"V": Vd, "F": Fd, "VC": VC}, None,
                   BakeSettings(resolution=128, falloff_mm=0.0, max_distance_mm=1.0), UV=b.UV, FUV=b.FUV)
    col2 = b2.color[rows, cols].astype(float)
    assert np.abs(col2[:, 0] - 25 * P[:, 0]).max() < 2 and np.all(col2[:, 2] == 7)


def test_falloff_zero_at_loop_and_padding():
    Vd, Fd = bumpy_sphere(5)
    V, F = smooth_sphere(3)
    front = np.argsort(-V[:, 2])[:6]                           # a small 'eyelid loop' at the front
    s = BakeSettings(resolution=256, falloff_mm=3.0, max_distance_mm=2.0)
    b = bake_maps(V, F, {"left": front}, {"V": Vd, "F": Fd}, None, s)
    rows, cols, face, bary = rasterize(b.UV, b.FUV, 256, 256)
    P = np.einsum("kj,kjc->kc", bary, V[F[face]])
    from pipeline.bake.bake import distance_to_polylines
    d = distance_to_polylines(P, [V[front]])
    vals = b.displacement[rows, cols]
    assert np.all(np.abs(vals[d < 0.05]) < 1e-3)
    assert np.abs(vals[d > 3.0]).mean() > 0.05
    # padding: texels next to islands got values, far ones stay 0
    img, m = dilate(np.where(b.mask, 1.0, 0.0), b.mask, 3)
    assert m.sum() > b.mask.sum() and np.all(img[m] == 1.0)


def test_falloff_widens_round_a_loop_vertex_off_the_scan():
    """A loop vertex ``g`` mm off the scan fades the displacement over ``per_mm * g`` round it
    (a canthus apex under the skin: the skin slopes into it); elsewhere the fade is
    ``falloff_mm`` from the loop, as without gaps."""
    from pipeline.bake.bake import falloff_weights

    t = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    V = np.c_[10.0 * np.cos(t), 5.0 * np.sin(t), np.zeros(32)]        # a flat opening in z = 0
    loop = np.arange(32)
    P = np.array([[13.0, 0.0, 0.0],      # 3 mm beyond vertex 0 (the 'apex', 2 mm off the scan)
                  [-13.0, 0.0, 0.0],     # 3 mm beyond vertex 16 (on the scan)
                  [10.5, 0.0, 0.0]])     # 0.5 mm beyond vertex 0
    F = np.array([[0, 1, 2]])
    face = np.zeros(len(P), dtype=np.int64)
    gaps = [np.where(loop == 0, 2.0, 0.0)]
    plain = falloff_weights(V, F, P, face, [loop], 2.0)
    wide = falloff_weights(V, F, P, face, [loop], 2.0, gaps, per_mm=2.0)
    assert plain[0] == 1.0 and plain[1] == 1.0          # 3 mm > falloff_mm: full displacement
    assert 0.0 < wide[0] < 0.9 and wide[1] == 1.0       # only round the vertex off the scan
    assert wide[2] < plain[2] < 1.0
    np.testing.assert_array_equal(falloff_weights(V, F, P, face, [loop], 2.0, gaps, per_mm=0.0), plain)


def test_stage_steps_side_by_side_give_the_algorithms_bytes(tmp_path, monkeypatch):
    """bake_scan runs bake_maps' steps with the independent ones side by side (on threads, and
    both halves of the metric in forked children, which must not fail: strict); switched
    off (EYERIG_SERIAL=1) every file it writes is the same bytes, and its maps are bake_maps'
    own."""
    import pipeline.bake.build as build
    from pipeline.bake.build import bake_scan
    from fixtures.forks import strict_fork_result

    monkeypatch.setattr(build, "fork_result", strict_fork_result)

    Vd, Fd = bumpy_sphere(5)
    V, F = smooth_sphere(3)
    front = np.argsort(-V[:, 2])[:6]
    low, dense = tmp_path / "retopo", tmp_path / "dense"
    low.mkdir()
    dense.mkdir()
    back = np.argsort(V[:, 2])[:6]
    save_mesh(low / "mesh.npz", V=V, F=F, loop_left=front, loop_right=back)
    save_mesh(dense / "mesh.npz", V=Vd, F=Fd, VC=(np.abs(Vd) * 40 % 255).astype(np.uint8))
    s = BakeSettings(resolution=128, falloff_mm=3.0, max_distance_mm=2.0, padding_texels=4, metric_samples=2000)
    outs = {}
    for serial in ("0", "1"):
        monkeypatch.setenv("EYERIG_SERIAL", serial)
        out = tmp_path / f"bake{serial}"
        out.mkdir()
        outs[serial] = (bake_scan(low, dense, s, out), {p.name: p.read_bytes() for p in out.iterdir()})
    (a, fa), (b, fb) = outs["0"], outs["1"]
    assert a.metrics == b.metrics and fa == fb and len(fa) >= 4
    assert "timings_s" in a.timings and not any("time" in k for k in a.metrics)
    m = load_mesh(tmp_path / "bake0" / "mesh.npz")
    ref = bake_maps(V, F, {"left": front, "right": back}, {"V": Vd, "F": Fd, "VC": load_mesh(dense / "mesh.npz")["VC"]},
                    None, s, UV=m["UV"], FUV=m["FUV"])
    assert np.array_equal(ref.displacement, read_displacement(read_bake(tmp_path / "bake0").displacement))
    assert (np.abs(ref.displacement[ref.mask]) < 1e-6).mean() < 0.9      # not an empty bake


def test_sample_bilinear_pixel_centres():
    img = np.arange(12, dtype=float).reshape(3, 4)
    uv = np.array([[(1 + 0.5) / 4, 1 - (2 + 0.5) / 3], [(0.5 + 0.5) / 4, 1 - (0 + 0.5) / 3]])
    assert np.allclose(sample_bilinear(img, uv), [img[2, 1], 0.5])


@pytest.mark.slow
def test_stage_cli(tmp_path):
    V, F, eyes = face_patch()
    dense = tmp_path / "remove_eyeballs"
    dense.mkdir()
    save_mesh(dense / "mesh.npz", V=V, F=F, VC=np.full((len(V), 3), 180, np.uint8))
    write_eyes(dense / "eyes.json", eyes)
    params = tmp_path / "params.yaml"
    params.write_text("retopo:\n  target_polygons: 1500\n  loop_points: 32\nbake:\n  resolution: 512\n"
                      "  metric_samples: 20000\n")
    run = lambda mod, *a: subprocess.run([sys.executable, "-m", mod, *map(str, a), "--params", str(params)],
                                          capture_output=True, text=True, cwd=str(ROOT))
    r = run("stages.retopo", dense, tmp_path / "retopo", "--metrics", tmp_path / "r.json")
    assert r.returncode == 0, r.stderr
    r = run("stages.bake", tmp_path / "retopo", dense, tmp_path / "bake", "--metrics", tmp_path / "b.json")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "bake"
    m = load_mesh(out / "mesh.npz")
    assert {"V", "F", "UV", "FUV", "loop_left", "loop_right"} <= set(m)
    maps = read_bake(out)
    disp = read_displacement(maps.displacement)
    prev = np.asarray(Image.open(maps.preview)).astype(np.float64)
    assert maps.resolution == 512 and disp.shape == (512, 512) and prev.shape == (512, 512)
    inside = disp != 0
    assert np.abs(maps.preview_offset + maps.preview_scale * prev[inside] - disp[inside]).max() \
        <= maps.preview_scale
    col = np.asarray(Image.open(maps.color))
    assert col.shape == (512, 512, 3) and np.all(col[inside] == 180)
    metrics = json.loads((tmp_path / "b.json").read_text())
    assert metrics["reconstruction"]["mean_error_removed"] > 0.7
    assert metrics["missed_texel_fraction"] < 0.05


def test_faces_touching_box_finds_a_face_across_the_box_without_a_corner_in_it():
    from pipeline.bake.bake import faces_near_box, faces_touching_box

    V = np.array([[-10, -10, 0], [10, -10, 0], [0, 10, 0],            # spans the box, no corner inside
                  [20, 20, 20], [21, 20, 20], [20, 21, 20],           # far away
                  [0.5, 0.5, 0.5], [30, 0, 0], [0, 30, 0]], float)    # one corner inside
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    assert faces_touching_box(V, F, lo, hi).tolist() == [0, 2]
    assert faces_near_box(V, F, lo, hi).tolist() == [2]


def test_closest_distances_from_the_faces_round_the_points_equal_the_whole_meshs():
    """Same bits as libigl on the whole scan, whether the first search box holds the answers or
    has to grow (a point 6 mm off the scan, past the 1 mm reach)."""
    from pipeline.bake.bake import closest_distances, loop_gaps
    from pipeline.geometry import mesh_checks as mc

    Vd, Fd = bumpy_sphere(5)
    rng = np.random.default_rng(3)
    n = rng.standard_normal((40, 3))
    P = n / np.linalg.norm(n, axis=1, keepdims=True) * (R + rng.uniform(-0.8, 0.8, (40, 1)))
    P[:3] = [[0, 0, R + 6.0], [0, 0, 0.0], [R, 0, 0]]                 # off the scan, the centre, on it
    d = closest_distances(P, Vd, Fd, reach=1.0)
    assert np.array_equal(d, mc.closest_points(P, Vd, Fd)[0])
    assert d[0] > 5.0 and d[1] > R - 1
    # the loop gaps come back per loop, in the loops' order
    V = P[:10]
    gaps = loop_gaps(V, [np.array([3, 1, 2]), np.array([0, 9])], Vd, Fd)
    assert [len(g) for g in gaps] == [3, 2]
    assert np.array_equal(np.concatenate(gaps), mc.closest_points(V[[3, 1, 2, 0, 9]], Vd, Fd)[0])


def test_chunked_cast_and_colour_match_one_batch(monkeypatch):
    """The per-texel steps run in pieces of raycast.CHUNK texels, on two threads: the same bits as
    one piece (each texel's rays and colour are its own), with pieces that do not divide the count."""
    import pipeline.bake.raycast as rc
    from pipeline.bake.bake import dense_scene

    Vd, Fd = bumpy_sphere(4)
    VC = (np.abs(Vd) * 10 % 255).astype(np.uint8)
    V, F = smooth_sphere(2)
    s = BakeSettings(resolution=128, falloff_mm=0.0, max_distance_mm=1.0)
    UV, FUV = unwrap(V, F, s.resolution, s.uv_padding_texels)
    scene = dense_scene(V, {"V": Vd, "F": Fd}, s)
    P = V[F].mean(axis=1) * 1.01
    N = P / np.linalg.norm(P, axis=1, keepdims=True)
    ref = bake_maps(V, F, {}, {"V": Vd, "F": Fd, "VC": VC}, None, s, UV=UV, FUV=FUV)
    one = rc.cast_both_ways(scene, P, N, 1.0)
    monkeypatch.setattr(rc, "CHUNK", 97)
    monkeypatch.setattr(rc.in_chunks, "__defaults__", (97,))
    calls = []
    rc.in_chunks(300, lambda a, b: calls.append((a, b)))
    assert sorted(calls) == [(0, 97), (97, 194), (194, 291), (291, 300)]
    for x, y in zip(rc.cast_both_ways(scene, P, N, 1.0), one):
        assert np.array_equal(x, y, equal_nan=True)
    small = bake_maps(V, F, {}, {"V": Vd, "F": Fd, "VC": VC}, None, s, UV=UV, FUV=FUV)
    assert np.array_equal(small.displacement, ref.displacement) and np.array_equal(small.color, ref.color)


@pytest.mark.parametrize("iterations", [1, 3, 6, 40])
def test_padding_on_the_masks_box_is_the_whole_images(iterations):
    """dilation_sources transforms only the mask's bounding box grown by the padding: the same
    padded texels and the same source of each (ties between equally near texels included) as
    scipy's transform of the whole image, with the box at a border or not."""
    from scipy import ndimage

    from pipeline.bake.uv import dilation_sources

    rng = np.random.default_rng(iterations)
    masks = [np.pad(rng.random((60, 50)) > 0.9, ((30, 5), (0, 70))),      # sparse: many ties
             np.pad(rng.random((40, 40)) > 0.3, ((0, 0), (90, 2))),
             np.zeros((20, 30), bool)]
    masks[2][7, 29] = True
    for mask in masks:
        grow, sy, sx = dilation_sources(mask, iterations)
        dist, (iy, ix) = ndimage.distance_transform_edt(~mask, return_indices=True)
        full = ~mask & (dist <= iterations)
        assert np.array_equal(grow, full) and grow.any()
        assert np.array_equal(sy, iy[full]) and np.array_equal(sx, ix[full])


def _rasterize_by_boxes(UV, FUV, res):
    """Reference: every texel centre of each triangle's bounding box tested, triangle by triangle
    (the first triangle keeps a texel), sorted row-major."""
    hits = {}
    for f, tri in enumerate(np.asarray(UV, float)[FUV]):
        X, Y = tri[:, 0] * res - 0.5, (1.0 - tri[:, 1]) * res - 0.5
        (ax, bx, cx), (ay, by, cy) = X, Y
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if abs(det) <= 1e-14:
            continue
        inv = 1.0 / det                                            # as rasterize rounds them
        a0, b0 = (by - cy) * inv, (cx - bx) * inv
        a1, b1 = (cy - ay) * inv, (ax - cx) * inv
        c0, c1 = -(a0 * cx + b0 * cy), -(a1 * cx + b1 * cy)
        for y in range(max(int(np.ceil(Y.min())), 0), min(int(np.floor(Y.max())), res - 1) + 1):
            for x in range(max(int(np.ceil(X.min())), 0), min(int(np.floor(X.max())), res - 1) + 1):
                l0, l1 = a0 * x + b0 * y + c0, a1 * x + b1 * y + c1
                if min(l0, l1, 1.0 - l0 - l1) >= -1e-9:
                    hits.setdefault((y, x), f)
    keys = sorted(hits)
    return [k[0] for k in keys], [k[1] for k in keys], [hits[k] for k in keys]


def test_rasterize_row_spans_find_every_texel_of_the_bounding_boxes():
    """rasterize tests only the columns each triangle's row can reach: the texels (and which
    triangle keeps a shared one) of testing the whole bounding boxes, slivers, edges through
    texel centres and near-horizontal edges included."""
    rng = np.random.default_rng(5)
    k, res = 120, 48
    UV = rng.random((3 * k, 2)) * rng.choice([0.05, 0.3], (3 * k, 1))
    UV[0::3] += rng.random((k, 2)) * 0.7
    UV[1::3], UV[2::3] = UV[0::3] + (UV[1::3] - 0.1), UV[0::3] + (UV[2::3] - 0.1)
    UV[3:30:3, 1] = UV[4:31:3, 1] + 1e-13                         # near-horizontal edges
    UV[30:60] = (np.round(UV[30:60] * res - 0.5) + 0.5) / res      # corners on texel centres
    UV[61:90:3] = UV[60:90:3] + 1e-9 * rng.standard_normal((10, 2))   # slivers
    UV = np.clip(UV, 0.0, 1.0)
    FUV = np.arange(3 * k).reshape(-1, 3)
    FUV = np.concatenate([FUV, FUV[::-1]])                        # every texel shared: first wins
    rows, cols, face, bary = rasterize(UV, FUV, res, res)
    ref = _rasterize_by_boxes(UV, FUV, res)
    assert len(rows) > 500
    assert rows.tolist() == ref[0] and cols.tolist() == ref[1] and face.tolist() == ref[2]


def test_preview_in_pieces_is_the_float64_formula():
    """preview_16bit quantises a piece at a time: the same pixels as the whole float64 image's
    round((a - lo) / scale), lo and scale from the masked texels, over several pieces."""
    rng = np.random.default_rng(2)
    a = (rng.standard_normal((700, 600)) * 0.4).astype(np.float32)      # 420k px: two pieces
    mask = rng.random(a.shape) > 0.3
    q, scale, offset = preview_16bit(a, mask)
    a64 = a.astype(np.float64)
    lo, hi = a64[mask].min(), a64[mask].max()
    assert offset == lo and scale == (hi - lo) / 65535.0
    assert np.array_equal(q, np.clip(np.round((a64 - lo) / scale), 0, 65535).astype(np.uint16))
    assert q[mask].min() == 0 and q[mask].max() == 65535
