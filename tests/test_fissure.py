"""The fissure a texture shows (pipeline/placement/fissure.py), the eye placed behind it
(texture.place_from_fissure) and the cut along it (pipeline/remove_eyeballs/fissure_cut.py), on
constructed inputs with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.placement import texture as et
from pipeline.placement import fissure as fs
from pipeline.remove_eyeballs import fissure_cut as fc
from pipeline.retopo.retopo import subdivide_midpoint


def _map_of(theta, cell=0.25, radius=22.0, noise=0.0, seed=0):
    """A ColourMap whose cells are eye-like (+3) inside the almond ``theta``, skin-like outside."""
    n = int(np.ceil(2 * radius / cell))
    cm = fs.ColourMap(llr=np.zeros((n, n)), lum=np.full((n, n), 100.0), hint=np.zeros(3),
                      view=np.array([0.0, 0.0, 1.0]), basis=eye_basis(np.array([0.0, 0.0, 1.0]))[:2],
                      cell_mm=cell, radius_mm=radius)
    C = cm.centres().reshape(-1, 2)
    inside = fs.points_in_polygon(C, fs.almond_points(theta, 256)).reshape(n, n)
    rng = np.random.default_rng(seed)
    cm.llr = np.where(inside, 3.0, -3.0) + noise * rng.standard_normal((n, n))
    return cm


@pytest.mark.slow
@pytest.mark.parametrize("side, theta", [
    ("left", [-13.0, -1.0, 14.0, 0.5, 6.5, 3.8, 0.45, 0.55, 1.0]),
    ("right", [12.5, 0.0, -13.5, -1.5, 5.5, 4.0, 0.4, 0.5, 0.8]),
])
def test_almond_recovers_the_corners(side, theta):
    cm = _map_of(np.array(theta), noise=2.0)
    fit, _ = fs.fit_almond(cm, 1.0 if side == "left" else -1.0)
    for k in (slice(0, 2), slice(2, 4)):
        assert np.linalg.norm(fit[k] - np.array(theta)[k]) < 0.6, (fit, theta)


def test_the_soft_inside_is_the_four_logistic_edges_of_the_lid_bumps():
    """The fit's cost function against its definition: the product of the logistic edges
    (width tau) of the upper lid, the lower lid and both chord ends, the lids' heights from
    ``_bump`` (powers of the chord position). Within 1e-12 over random almonds and cells, exactly
    0 height past the canthi (1/8 at a canthus, three edges at 1/2), and 1/2 on either lid's apex."""
    rng = np.random.default_rng(3)
    Q = rng.uniform(-22.0, 22.0, size=(5000, 2))
    qx, qy = np.ascontiguousarray(Q[:, 0]), np.ascontiguousarray(Q[:, 1])
    tau = 0.375

    def sig(x):
        return 1.0 / (1.0 + np.exp(-x))

    for _ in range(40):
        th = np.array([-13, 0, 14, 0.5, 6, 4, 0.5, 0.5, 1.0]) + rng.normal(0, [2, 1, 2, 1, 2, 1, 0.2, 0.2, 0.4])
        m, l, hu, hl, pu, pl, k = fs._unpack(th)
        d = l - m
        nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        nrm = -nrm if nrm[1] < 0 else nrm
        s, t, span = (Q - m) @ d / (d @ d), (Q - m) @ nrm, np.linalg.norm(d)
        want = (sig((hu * fs._bump(s, pu, k) - t) / tau) * sig((t + hl * fs._bump(s, pl, k)) / tau)
                * sig(s * span / tau) * sig((1 - s) * span / tau))
        got = fs._soft_inside(th, qx, qy, tau)
        assert np.abs(got - want).max() < 1e-12
    # cells on the chord's line past either canthus: no lid height, one end's edge alone
    th = np.array([-10.0, 0.0, 10.0, 0.0, 5.0, 3.0, 0.5, 0.5, 1.0])
    P = np.array([[-10.0, 0.0], [10.0, 0.0], [-30.0, 0.0], [0.0, 5.0], [0.0, -3.0]])
    got = fs._soft_inside(th, np.ascontiguousarray(P[:, 0]), np.ascontiguousarray(P[:, 1]), tau)
    assert got[0] == pytest.approx(0.5 * sig(0.0) * sig(0.0), abs=1e-12)   # a canthus: three edges at 1/2
    assert got[1] == pytest.approx(0.25 * 0.5, abs=1e-12) and got[2] < 1e-20
    assert got[3] == pytest.approx(0.5, abs=1e-9) and got[4] == pytest.approx(0.5, abs=1e-9)


def test_almond_outline_runs_medial_upper_lateral_lower():
    theta = np.array([-13.0, 0.0, 14.0, 0.0, 6.0, 4.0, 0.5, 0.5, 1.0])
    P = fs.almond_points(theta, 64)
    np.testing.assert_allclose(P[0], [-13.0, 0.0])
    np.testing.assert_allclose(P[32], [14.0, 0.0])
    assert P[1:32, 1].min() > 0 > P[33:, 1].max()                 # upper lid first
    assert P[16, 1] == pytest.approx(6.0, abs=0.05) and P[48, 1] == pytest.approx(-4.0, abs=0.05)


def test_points_in_polygon_and_lift_onto_a_tilted_plane():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2.0]])
    assert fs.points_in_polygon(np.array([[1, 1], [3, 1], [1, -0.1]]), square).tolist() == [True, False, False]
    # a plane z = 0.3 x + 5, two triangles over [-10, 10]^2, seen along +Z
    V = np.array([[-10, -10, 2.0], [10, -10, 8.0], [10, 10, 8.0], [-10, 10, 2.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    B = eye_basis(np.array([0.0, 0.0, 1.0]))[:2]
    P = fs.lift(V, F, np.array([[1.0, 2.0], [-4.0, 0.5], [30.0, 0.0]]), np.zeros(3), np.array([0, 0, 1.0]), B)
    np.testing.assert_allclose(P[:2], [[1.0, 2.0, 5.3], [-4.0, 0.5, 3.8]])
    assert np.isnan(P[2]).all()


def _anatomical_outline(c, f, r=12.0, n=64):
    """A fissure outline around a known eye: corners where the anatomy puts them (in front of the
    centre and off the axis by the means), the lids on an ellipse resting MARGIN_OFF off the
    globe."""
    B = eye_basis(f)
    s = r / et.ANATOMY_RADIUS_MM

    def corner(fwd, axis, sign):
        return c + fwd * s * f + sign * axis * s * B[0]

    M = corner(et.MEDIAL_CORNER_FWD[0], et.MEDIAL_CORNER_AXIS[0], -1.0)
    L = corner(et.LATERAL_CORNER_FWD[0], et.LATERAL_CORNER_AXIS[0], +1.0)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    x = -np.cos(t)                                     # -1 medial, +1 lateral
    y = np.where(t <= np.pi, 5.5, 3.5) * np.sin(t) * np.where(t <= np.pi, 1, 1)
    P = (1 - (x + 1) / 2)[:, None] * M + ((x + 1) / 2)[:, None] * L + y[:, None] * B[1]
    mid = (np.abs(x) < 0.9)
    # push the lids out/in radially to MARGIN_OFF off the globe
    d = P[mid] - c
    P[mid] = c + d / np.linalg.norm(d, axis=1)[:, None] * (r + et.MARGIN_OFF[0])
    return P, n // 2


def test_place_from_fissure_recovers_a_known_eye():
    c = np.array([31.0, 36.0, 70.0])
    f = np.array([0.05, -0.03, 1.0])
    f /= np.linalg.norm(f)
    P, lateral = _anatomical_outline(c, f)
    c2, f2, r2, rms = et.place_from_fissure(P, lateral, 12.0, np.array([0.0, 0.0, 1.0]))
    assert np.linalg.norm(c2 - c) < 0.5 and abs(r2 - 12.0) < 0.3
    assert np.degrees(np.arccos(np.clip(f2 @ f, -1, 1))) < 3.0
    _, _, r3, _ = et.place_from_fissure(P, lateral, 13.0, np.array([0.0, 0.0, 1.0]), fixed_radius=True)
    assert r3 == 13.0


def _textured_sheet():
    """A curved sheet (the scan around one eye, seen along +Z) with UVs = its x, y."""
    g = np.linspace(-24, 24, 17)
    X, Y = np.meshgrid(g, g)
    Z = -0.01 * (X ** 2 + Y ** 2)
    V = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
    n = len(g)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            F += [[a, b, d], [a, d, c]]
    F = np.array(F, np.int64)
    UV = V[:, :2] / 100.0 + 0.5
    return {"V": V, "F": F, "UV": UV, "FUV": F.copy(), "VC": np.full((len(V), 3), 200, np.uint8)}


def _fissure():
    theta = np.array([-13.0, 0.0, 14.0, 0.5, 6.0, 4.0, 0.5, 0.5, 1.0])
    Q = fs.almond_points(theta, 96)
    B = eye_basis(np.array([0.0, 0.0, 1.0]))[:2]
    arr = _textured_sheet()
    P = fs.lift(arr["V"], arr["F"], Q, np.zeros(3), np.array([0, 0, 1.0]), B)
    return arr, {"outline": P, "outline_2d": Q, "lateral": 48, "hint": np.zeros(3),
                 "view": np.array([0.0, 0.0, 1.0]), "basis": B}


def test_refinement_keeps_the_surface_and_the_texture_mapping():
    arr, fis = _fissure()
    out, parent = fc.refine_along(arr, [fis], edge_mm=0.8)
    V, F = out["V"], out["F"]
    assert meshtopo.is_edge_manifold(F)
    assert meshtopo.boundary_component_count(F) == meshtopo.boundary_component_count(arr["F"]) == 1
    near = np.linalg.norm(V[F].mean(axis=1), axis=1) < 20
    T = V[F[near]]
    E = np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2)
    assert np.median(E) <= 0.8 and E.max() <= 1.5 * 0.8     # a curved square grid: its diagonals
    # every new vertex lies on its parent face (the surface does not change) and its texture
    # coordinate is where that face maps it (the texture mapping does not change)
    A0 = V[arr["F"][parent]]
    for f in np.flatnonzero(near)[::97]:
        for k in range(3):
            p = V[F[f, k]]
            a, b, c = A0[f]
            M = np.array([b - a, c - a]).T
            u, v = np.linalg.lstsq(M, p - a, rcond=None)[0]
            np.testing.assert_allclose(a + u * (b - a) + v * (c - a), p, atol=1e-9)
            t = arr["UV"][arr["FUV"][parent[f]]]
            np.testing.assert_allclose(t[0] + u * (t[1] - t[0]) + v * (t[2] - t[0]),
                                       out["UV"][out["FUV"][f, k]], atol=1e-9)
    assert out["VC"].shape == (len(V), 3)
    # the same area
    def area(V, F):
        return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    assert area(V, F) == pytest.approx(area(arr["V"], arr["F"]), rel=1e-9)


def test_the_cut_follows_the_outline():
    arr, fis = _fissure()
    fits = {"left": type("Fit", (), {"fissure": fis, "region": np.zeros(len(arr["F"]), bool)})()}
    out, fits = fc.openings_at_fissures(arr, fits)
    V, F = out["V"], out["F"]
    region = fits["left"].region
    keep = F[~region]
    loops = meshtopo.boundary_loops(keep)
    opening = max(loops, key=lambda lp: -np.linalg.norm(V[lp].mean(axis=0)))
    q = V[opening] @ fis["basis"].T
    # every loop vertex within a refined face of the outline; the opening spans it corner to corner
    assert fc._outline_distance(q, fis["outline_2d"]).max() < 0.8
    moved = fc.move_loop_onto(V, keep, np.asarray(opening), fis)
    q = V[opening] @ fis["basis"].T
    d = fc._outline_distance(q, fis["outline_2d"])
    # onto the outline (a move that would turn a face over is halved: a few stop short)
    assert moved > 0 and np.mean(d < 1e-6) > 0.9 and d.max() < 0.1
    assert np.abs(q[:, 0].min() - (-13.0)) < 0.4 and np.abs(q[:, 0].max() - 14.0) < 0.4   # half an edge


def _painted_eye(theta, caruncle_share=0.14, size=1024, seed=0):
    """The textured sheet with an eye painted in its texture (1 mm = 0.01 UV, about 10 px): skin
    around, the almond ``theta`` white, an iris-coloured disc at its middle, and the medial
    ``caruncle_share`` of the fissure (along the chord from the medial canthus) pink, as the
    procedural head and a photograph show the caruncle."""
    rng = np.random.default_rng(seed)
    px = (np.arange(size) + 0.5) / size
    U, W = np.meshgrid(px, px[::-1])                   # row 0 = v 1
    Q = np.stack([(U - 0.5) * 100.0, (W - 0.5) * 100.0], -1).reshape(-1, 2)   # mm on the sheet
    img = np.empty((size * size, 3))
    img[:] = (205.0, 150.0, 125.0)
    inside = fs.points_in_polygon(Q, fs.almond_points(theta, 256))
    m, l = theta[0:2], theta[2:4]
    s = (Q - m) @ (l - m) / float((l - m) @ (l - m))
    mid = 0.5 * (m + l) + np.array([0.0, 1.0])
    img[inside] = (236.0, 226.0, 218.0)
    img[inside & (np.linalg.norm(Q - mid, axis=1) < 5.8)] = (70.0, 95.0, 120.0)
    img[inside & (s < caruncle_share)] = (200.0, 105.0, 105.0)
    img += rng.normal(0.0, 4.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8).reshape(size, size, 3)


@pytest.mark.slow
def test_the_fissure_runs_on_through_the_caruncle_to_the_medial_canthus():
    """The eye's colour is learnt from the sclera and iris at the hint, which the pink caruncle is
    not like: the first almond stops at the caruncle, ~3.5 mm short of the medial canthus (the
    far end of the caruncle, where the lids meet). The second fit learns the corner's tissue too
    (redder or brighter than the skin, unlike a lash line or a shadow) and reaches the canthus."""
    theta = np.array([-13.0, 0.0, 13.5, 0.5, 6.0, 3.8, 0.45, 0.5, 1.0])
    arr = _textured_sheet()
    tex = _painted_eye(theta)
    view = np.array([0.0, 0.0, 1.0])
    cm = fs.eye_colour_map(arr["V"], arr["F"], arr["UV"], arr["FUV"], tex, np.zeros(3), view)
    first, _ = fs.fit_almond(cm, 1.0)
    assert np.linalg.norm(first[0:2] - theta[0:2]) > 2.5          # stopped at the caruncle
    pink = fs.corner_tissue(cm, first)
    assert pink.sum() * (0.5 * cm.cell_mm) ** 2 >= fs.POCKET_MIN_AREA_MM2
    # the caruncle, and the sclera past the first almond's ends: all of it eye, none of it skin
    big = theta.copy()
    big[4:6] += 0.3
    big[0] -= 0.3
    big[2] += 0.3
    assert fs.points_in_polygon(cm.q[pink], fs.almond_points(big, 256)).all()
    assert (cm.q[pink, 0] < -8.0).mean() > 0.5                       # most of it medial
    before = cm.llr.copy()
    fit, _ = fs.fit_fissure(cm, 1.0)
    assert np.linalg.norm(fit[0:2] - theta[0:2]) < 1.0, fit
    assert np.linalg.norm(fit[2:4] - theta[2:4]) < 1.0, fit
    np.testing.assert_array_equal(cm.llr, before)           # the caller's map is left as it was


@pytest.mark.slow
def test_an_eye_without_pink_corners_is_fitted_as_before():
    """No tissue redder (or brighter) than the skin by the corners: the first almond stands (james: learning the
    eye anew from inside it moved a corner onto the shadow by the nose), and a fissure painted
    whole is found whole."""
    theta = np.array([-13.0, 0.0, 13.5, 0.5, 6.0, 3.8, 0.45, 0.5, 1.0])
    arr = _textured_sheet()
    tex = _painted_eye(theta, caruncle_share=0.0, size=512)
    cm = fs.eye_colour_map(arr["V"], arr["F"], arr["UV"], arr["FUV"], tex, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    first, _ = fs.fit_almond(cm, 1.0)
    # slivers of sclera past the ends (0.9 mm^2) are too little to learn from
    assert fs.corner_tissue(cm, first).sum() * (0.5 * cm.cell_mm) ** 2 < fs.POCKET_MIN_AREA_MM2
    fit, _ = fs.fit_fissure(cm, 1.0)
    np.testing.assert_array_equal(fit, first)
    for k in (slice(0, 2), slice(2, 4)):
        assert np.linalg.norm(fit[k] - theta[k]) < 1.0, fit
