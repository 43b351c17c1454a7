"""The grid band round each eyelid loop (retopo ``band: grid``, pipeline/retopo/eye_band.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fixtures import face_patch
import pipeline.retopo.eye_band as eb
from pipeline.geometry import mesh_checks as mc
from pipeline.retopo.eye_band import (band_report, build_band, grid_quads, ring_distances, ring_offset_steps, smooth_grid,
                                      split_quads, zip_strip_maxmin)
from pipeline.retopo.retopo import RetopoSettings, retopologize


def _planar_annulus(a=5.0, b=30.0, h=0.4, seed=0):
    """A flat disk of radius ``b`` with a round hole of radius ``a`` (z = 0, faces towards +z)."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    pts, r = [], a
    while r <= b + 1e-9:
        n = int(round(2 * np.pi * r / h))
        t = 2 * np.pi * (np.arange(n) + rng.uniform(0, 1)) / n
        pts.append(np.stack([r * np.cos(t), r * np.sin(t)], 1))
        r += 0.87 * h
    P = np.concatenate(pts)
    T = Delaunay(P).simplices
    T = T[np.linalg.norm(P[T].mean(axis=1), axis=1) > a]
    e1, e2 = P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    T[cw] = T[cw][:, [0, 2, 1]]
    return np.column_stack([P, np.zeros(len(P))]), T.astype(np.int64)


def test_ring_distances_grow_geometrically():
    d = ring_distances(6, 8.0, 0.5)
    steps = np.diff(d)
    assert d[0] == 0 and d[-1] == pytest.approx(8.0) and steps[0] == pytest.approx(0.5)
    assert np.allclose(steps[1:] / steps[:-1], steps[1] / steps[0])
    assert np.allclose(np.diff(ring_distances(4, 4.0, 1.0)), 1.0)


def test_band_on_a_disk_with_a_hole_is_the_polar_grid():
    """Known answer: on a flat annulus the spokes are radial and ring k lies d_k beyond the hole."""
    V, F = _planar_annulus()
    S, a, rings, width = 64, 5.0, 6, 8.0
    th = 2 * np.pi * np.arange(S) / S
    loop = np.stack([a * np.cos(th), a * np.sin(th), 0 * th], 1)
    hole = min(mc.boundary_loops(F), key=lambda b: np.linalg.norm(V[b], axis=1).mean())
    first = 2 * np.pi * a / S
    G, info = build_band(loop, V, F, hole, rings, width, first, 20.0)
    assert G.shape == (rings + 1, S, 3) and G.reshape(-1, 3).shape[0] == (rings + 1) * S
    assert np.array_equal(G[0], loop)
    assert info["param_inverted_triangles"] == 0 and not info["spokes_out_of_order"]
    d = ring_distances(rings, width, first)
    r = np.linalg.norm(G[..., :2], axis=2)
    assert np.abs(r - (a + d)[:, None]).max() < 0.02          # rings graded as asked
    ang = np.angle(np.exp(1j * (np.arctan2(G[..., 1], G[..., 0]) - th[None])))
    assert np.abs(ang).max() < 0.05                            # spokes radial (rad)
    assert np.abs(G[..., 2]).max() < 1e-9
    Q = split_quads(G.reshape(-1, 3), grid_quads(0, rings, S, reverse=True))
    rep = band_report(G.reshape(-1, 3), Q, V, F, S, 0)
    assert rep["flipped_faces"] == 0 and rep["min_angle_deg"] > 20.0


def test_the_band_region_shrinks_to_its_floor_itself():
    """Known answer: the region is shrunk by 0.85 from ``param_mm`` (20 mm) until it is an annulus
    clear of the locked border, and not below 1.25 x the band's width (10 mm). The steps pass that
    floor at 10.44 mm; a crop border 10.38-10.88 mm out along the mesh's edges (a flat annulus
    15.2 mm round a 5 mm hole) is within 10.44 and not within 10, so the floor itself gives the
    band (fresh47's filled_n5306_icteye_100k: the crop's back edge by its left lateral corner)."""
    from pipeline.retopo.eye_rings import edge_graph_distance

    V, F = _planar_annulus(b=15.2)
    S, a, rings, width = 64, 5.0, 6, 8.0
    th = 2 * np.pi * np.arange(S) / S
    loop = np.stack([a * np.cos(th), a * np.sin(th), 0 * th], 1)
    hole, border = sorted(mc.boundary_loops(F), key=lambda b: np.linalg.norm(V[b], axis=1).mean())
    d = edge_graph_distance(V, F, hole, 30.0)
    assert 1.25 * width < d[border].min() < 20.0 * 0.85 ** 4
    G, info = build_band(loop, V, F, hole, rings, width, 2 * np.pi * a / S, 20.0, locked=border)
    assert info["region_mm"] == pytest.approx(1.25 * width)
    assert np.linalg.norm(G[-1, :, :2], axis=1).max() < 15.2 and info["param_inverted_triangles"] == 0


def _eccentric_slit(a=9.0, b=3.0, R=30.0, cx=16.0, h=0.6, seed=0):
    """A flat disk of radius ``R`` centred ``cx`` mm to the side of an elliptic opening (semi-axes
    ``a``, ``b``: a narrow fissure), jittered grid vertices (z = 0, faces towards +z)."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    X, Y = np.meshgrid(np.arange(-R + cx - 1, R + cx + 1, h), np.arange(-R - 1, R + 1, h))
    P = np.stack([X.ravel(), Y.ravel()], 1) + rng.uniform(-0.2, 0.2, (X.size, 2)) * h
    P = P[(np.linalg.norm(P - [cx, 0], axis=1) < R - 0.3) & ((P[:, 0] / a) ** 2 + (P[:, 1] / b) ** 2 > 1.08)]
    ring = lambda r, c, n: np.stack([r[0] * np.cos(2 * np.pi * np.arange(n) / n) + c,   # noqa: E731
                                     r[1] * np.sin(2 * np.pi * np.arange(n) / n)], 1)
    P = np.concatenate([ring((a, b), 0.0, int(np.pi * (a + b) / h)), P, ring((R, R), cx, int(2 * np.pi * R / h))])
    T = Delaunay(P).simplices
    c = P[T].mean(1)
    T = T[(c[:, 0] / a) ** 2 + (c[:, 1] / b) ** 2 > 1]
    e1, e2 = P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    T[cw] = T[cw][:, [0, 2, 1]]
    return np.column_stack([P, np.zeros(len(P))]), T.astype(np.int64)


@pytest.mark.parametrize("cx", [0.0, 16.0])
def test_spokes_step_out_of_a_narrow_opening_off_its_regions_centre(cx):
    """Known answer: a 18 x 6 mm fissure whose region reaches 25 mm on one side and 9 on the
    other. The annulus map (the opening on a circle by arc length, concentric with the border's)
    turned 61 parameter triangles there and sheared ring 1 along the loop (its step out from ring 0
    -0.53 mm at worst, -0.03 mm median: ident_s29_009's hooded left band, folded at rest); the
    disk map (harmonic_disk: the opening closed by a fan, only the border fixed) is one-to-one,
    and every spoke leaves the loop outwards, as on a centred region."""
    from pipeline.retopo.eye_band import harmonic_disk

    V, F = _eccentric_slit(cx=cx)
    S, rings, width = 64, 6, 8.0
    th = 2 * np.pi * np.arange(S) / S
    loop = np.stack([9.0 * np.cos(th), 3.0 * np.sin(th), 0 * th], 1)
    loops = mc.boundary_loops(F)
    hole = min(loops, key=lambda b: np.linalg.norm(V[b], axis=1).mean())
    G, info = build_band(loop, V, F, hole, rings, width, 0.8, 25.0)
    assert info["param_inverted_triangles"] == 0 and not info["spokes_out_of_order"]
    out = np.cross(np.roll(loop, -1, 0) - np.roll(loop, 1, 0), [0.0, 0.0, 1.0])
    out /= np.linalg.norm(out, axis=1, keepdims=True) * np.sign(np.sum(out * loop))
    step = np.einsum("ij,ij->i", G[1] - G[0], out)
    assert step.min() > 0.3, step.min()
    # the fan's vertex is the origin, the opening's image star-shaped about it
    X, centre = harmonic_disk(V, F, hole, max(loops, key=len))
    a = np.unwrap(np.arctan2(X[hole, 1], X[hole, 0]))
    assert np.all(np.diff(a) * np.sign(a[-1] - a[0]) > 0) and abs(a[-1] - a[0]) < 2 * np.pi
    assert np.allclose(np.linalg.norm(X[max(loops, key=len)] - centre, axis=1), 2.0)


def _annulus_with_a_handle():
    """:func:`_planar_annulus` with a tube joining two small holes 10 mm either side of the
    opening: one handle (Euler characteristic -2 with two borders), as in id339_laser's crop."""
    V, F = _planar_annulus()
    c = V[F].mean(axis=1)
    gone = np.zeros(len(F), bool)
    for x in (10.0, -10.0):
        gone |= np.linalg.norm(c[:, :2] - [x, 0.0], axis=1) < 1.5
    F = F[~gone]
    A, B = [min(mc.boundary_loops(F), key=lambda b: np.linalg.norm(V[b, :2].mean(0) - [x, 0.0]))
            for x in (10.0, -10.0)]
    assert len(A) == len(B)
    # the tube takes each hole edge the other way round from the plane's face beside it
    Bt, n = B[::-1], len(A)
    tube = [t for i in range(n) for t in ((A[(i + 1) % n], A[i], Bt[i]), (Bt[i], Bt[(i + 1) % n], A[(i + 1) % n]))]
    return V, np.vstack([F, np.array(tube, np.int64)])


def test_a_handle_round_the_opening_is_named_in_the_refusal():
    V, F = _annulus_with_a_handle()
    S, a = 64, 5.0
    th = 2 * np.pi * np.arange(S) / S
    loop = np.stack([a * np.cos(th), a * np.sin(th), 0 * th], 1)
    loops = mc.boundary_loops(F)
    hole = min(loops, key=lambda b: np.linalg.norm(V[b], axis=1).mean())
    outer = max(loops, key=lambda b: np.linalg.norm(V[b], axis=1).mean())
    with pytest.raises(ValueError) as ei:
        build_band(loop, V, F, hole, 6, 8.0, 2 * np.pi * a / S, 20.0, outer)
    assert str(ei.value) == ("no annulus of the dense surface 10.0 mm round the eye opening (the surface "
                             "there has 1 handle: a tunnel through the scan, Euler characteristic -2)")


POLAR_S, POLAR_A, POLAR_RINGS, POLAR_WIDTH = 64, 5.0, 6, 8.0


def _polar_grid():
    """``(d, G)``: the ring distances and the polar grid (rings + 1, spokes, 3) of the flat
    annulus's hole (:func:`_planar_annulus`), graded as a band is."""
    th = 2 * np.pi * np.arange(POLAR_S) / POLAR_S
    d = ring_distances(POLAR_RINGS, POLAR_WIDTH, 2 * np.pi * POLAR_A / POLAR_S)
    return d, np.stack([(POLAR_A + dk) * np.stack([np.cos(th), np.sin(th), 0 * th], 1) for dk in d])


def test_smoothing_keeps_the_polar_grid_and_pulls_a_cut_tip_out():
    """The polar grid of a flat annulus is (nearly) a fixed point of smooth_grid; a ring 1 node
    pulled in behind a spike of the loop (a canthus apex) is pushed back out beyond it."""
    V, F = _planar_annulus()
    a, width = POLAR_A, POLAR_WIDTH
    d, G = _polar_grid()
    Gs = smooth_grid(G, d, V, F, raise_to=None)
    assert np.array_equal(Gs[0], G[0])
    assert np.abs(Gs - G).max() < 0.1
    assert np.abs(np.linalg.norm(Gs[-1], axis=1) - (a + width)).max() < 0.05     # outer ring slides along itself
    # a spike: loop vertex 0 moved 1.5 mm out, ring 1 left where it was (inside the tip)
    G2 = G.copy()
    G2[0, 0] *= (a + 1.5) / a
    Gs2 = smooth_grid(G2, d, V, F)
    assert np.linalg.norm(Gs2[1, 0]) > np.linalg.norm(G2[0, 0]) + 0.5 * d[1]


def _grid_angles(G, V, F):
    S, rings = G.shape[1], G.shape[0] - 1
    Q = split_quads(G.reshape(-1, 3), grid_quads(0, rings, S, reverse=True), V, F)
    return band_report(G.reshape(-1, 3), Q, V, F, S, 0)


def test_thin_quads_are_raised_to_the_target_angle_with_nothing_turned():
    """Known answer: the polar grid of a flat annulus has its thinnest triangles (20.7 deg) at the
    outer ring, where the geometric grading's last step is twice the spacing round the ring; a
    ring 3 node dragged to its neighbour leaves a 2 deg sliver. Raising moves nodes only (the
    loop and the outer ring are held) until no triangle is under 28 deg
    and none is turned over (28: the target is 30)."""
    V, F = _planar_annulus()
    a, width = POLAR_A, POLAR_WIDTH
    d, G = _polar_grid()
    assert _grid_angles(G, V, F)["min_angle_deg"] == pytest.approx(20.74, abs=0.01)
    G[3, 10] = 0.97 * G[3, 11] + 0.03 * G[3, 10]
    before = _grid_angles(G, V, F)
    assert before["min_angle_deg"] < 3.0 and before["flipped_faces"] == 0
    Gr = smooth_grid(G, d, V, F, iterations=0)
    after = _grid_angles(Gr, V, F)
    assert np.array_equal(Gr[0], G[0])
    assert np.abs(np.linalg.norm(Gr[-1], axis=1) - (a + width)).max() < 0.05
    assert after["min_angle_deg"] > 28.0 and after["flipped_faces"] == 0
    # without raising, the same call leaves the sliver
    assert _grid_angles(smooth_grid(G, d, V, F, iterations=0, raise_to=None), V, F)["min_angle_deg"] < 3.0


def test_a_grid_folded_over_three_rings_is_taken_back_towards_the_maps_grid():
    """Known answer: the smoothing can fold the grid where the scan turns sharply (id339_laser's
    medial corner: two spokes crossed over rings 1-3). Each node of the fold is held by the
    others, so moving one at a time leaves it turned (5 faces); with the harmonic map's grid as
    home (the polar grid here), nodes and then the patch round a turned quad go back towards it:
    nothing turned, every triangle over 28 deg, the loop and the outer ring held."""
    V, F = _planar_annulus()
    d, H = _polar_grid()
    G = H.copy()
    G[1:4, [10, 11]] = H[1:4, [11, 10]]
    assert _grid_angles(G, V, F)["flipped_faces"] == 6
    assert _grid_angles(smooth_grid(G, d, V, F, iterations=0), V, F)["flipped_faces"] > 0
    Gr = smooth_grid(G, d, V, F, iterations=0, home=H)
    after = _grid_angles(Gr, V, F)
    assert after["flipped_faces"] == 0 and after["min_angle_deg"] > 28.0
    assert np.array_equal(Gr[0], G[0]) and np.abs(Gr[-1] - G[-1]).max() < 1e-9


def test_a_band_left_under_the_floor_climbs_again_from_the_smoothed_grid_and_keeps_the_better(monkeypatch):
    """The climb ends where each node of a thin quad is held by the others (n4505_icteye_1m's lower
    lids: 17.7 / 18.5 deg, one face turned). A band left under RAISE_AGAIN_BELOW_DEG climbs again
    from the smoothed grid with RAISE_AGAIN_TARGET_DEG, and the grid with the larger smallest angle
    is kept; a band over the floor climbs once. Both climbs keep the rings even (RAISE_ZIG); a band
    they leave under the floor climbs both ways again without that, and the better grid is kept."""
    V, F = _planar_annulus()
    d, H = _polar_grid()
    thin = H.copy()
    thin[3, 10] = 0.97 * H[3, 11] + 0.03 * H[3, 10]                 # a 2 deg sliver
    thinner = H.copy()
    thinner[3, 10] = 0.99 * H[3, 11] + 0.01 * H[3, 10]
    calls = []

    def climb(results):
        def fake(G, *args, target, home=None, zig=eb.RAISE_ZIG, **kw):
            calls.append((target, zig, G.copy()))
            return results[len(calls) - 1].copy()
        return fake

    T1, T2, Z = eb.RAISE_TARGET_DEG, eb.RAISE_AGAIN_TARGET_DEG, eb.RAISE_ZIG
    for results, kept, asked in (([thin, H], H, [(T1, Z), (T2, Z)]),
                                 ([thin, thinner, thinner, thinner], thin, [(T1, Z), (T2, Z), (T1, None), (T2, None)]),
                                 ([thin, thinner, thinner, H], H, [(T1, Z), (T2, Z), (T1, None), (T2, None)]),
                                 ([H], H, [(T1, Z)])):
        calls.clear()
        monkeypatch.setattr(eb, "_raise_angles", climb(results))
        out = smooth_grid(H, d, V, F, iterations=0)
        assert np.array_equal(out, kept)
        assert [(t, z) for t, z, _ in calls] == asked
        assert all(np.array_equal(G, calls[0][2]) for _, _, G in calls)   # each from the smoothed grid
    assert Z is not None
    assert _grid_angles(thin, V, F)["min_angle_deg"] < eb.RAISE_AGAIN_BELOW_DEG <= _grid_angles(H, V, F)["min_angle_deg"]


def test_the_climb_keeps_each_ring_even_along_the_spokes(monkeypatch):
    """Known answer: climbing the flat annulus's polar grid (an even grid: every ring at one
    distance along every spoke) to 30 deg, the free climb moves the nodes by colour and leaves them
    alternately in and out along their spokes, 0.76 of a ring's step: a saw-tooth ring (on
    n5504_icteye_scale14_in's upper lid, a crease's lip taken by every other node: a row of spikes
    in the preview). No move takes a node or its ring neighbours farther from their neighbours'
    mean than RAISE_ZIG of the ring's step (0.5 here) unless they already were: the rings stay
    within it, every triangle still over 28 deg, nothing turned."""
    V, F = _planar_annulus()
    d, H = _polar_grid()
    assert ring_offset_steps(H, d) < 1e-9
    monkeypatch.setattr(eb, "RAISE_ZIG", None)
    free = smooth_grid(H, d, V, F, iterations=0)
    assert ring_offset_steps(free, d) > 0.7
    monkeypatch.setattr(eb, "RAISE_ZIG", 0.5)
    even = smooth_grid(H, d, V, F, iterations=0)
    # a node's two neighbours of its own colour move in the same batch: a hair over, at most
    assert ring_offset_steps(even, d) <= 0.5 + 0.02
    after = _grid_angles(even, V, F)
    assert after["min_angle_deg"] > 28.0 and after["flipped_faces"] == 0
    assert np.array_equal(even[0], H[0]) and np.abs(even[-1] - H[-1]).max() < 0.05


def _walled_annulus(a=5.0, b=30.0, n_th=256):
    """A surface of revolution round a hole of radius ``a`` (faces towards +z): a ledge at z = 0
    out to ``a + 0.6``, a wall 2 mm high, then the lid's top at z = 2 out to ``b``: a lid margin
    as a 1.2M-face scan shows it. Returns ``(V, F, on_profile)``, the last mapping a distance
    along the profile from the hole (mm, (S,)) and directions ``u`` (S, 3) to points on it."""
    ledge = [(a + t, 0.0) for t in np.linspace(0.0, 0.6, 7)]
    wall = [(a + 0.6, 2.0 * s) for s in np.linspace(0.0, 1.0, 21)[1:]]
    top = [(a + 0.6 + t, 2.0) for t in np.geomspace(0.1, b - a - 0.6, 60)]
    prof = np.array(ledge + wall + top)
    th = 2 * np.pi * np.arange(n_th) / n_th
    V = np.stack([prof[:, :1] * np.cos(th)[None], prof[:, :1] * np.sin(th)[None],
                  np.repeat(prof[:, 1:], n_th, 1)], -1).reshape(-1, 3)
    ids = np.arange(len(prof) * n_th).reshape(len(prof), n_th)
    p, q, r, s = ids[:-1], np.roll(ids[:-1], -1, 1), np.roll(ids[1:], -1, 1), ids[1:]
    F = np.concatenate([np.stack([p, r, q], -1).reshape(-1, 3), np.stack([p, s, r], -1).reshape(-1, 3)])

    def on_profile(t, u):
        r = a + np.minimum(t, 0.6) + np.clip(t - 2.6, 0.0, None)
        return r[:, None] * u + np.clip(t - 0.6, 0.0, 2.0)[:, None] * np.array([0.0, 0.0, 1.0])
    return V, F, on_profile


def test_rings_held_together_at_the_foot_of_a_margin_wall_are_parted():
    """Known answer: where a dense scan's lid margin stands as a wall, rings 1 and 2 of five
    spokes sit together at its foot (0.1 mm apart along the surface, a 7 deg triangle). No point
    of the scan lies 0.6 of ring 2's distance out along the opening's plane near them (the top
    is 2 mm up), so a floor taken along that plane held them there (10 deg after raising); the
    floor taken in space, from the node inside on the spoke, lets the nodes part along the wall,
    and every triangle ends over 25 deg with none turned, the loop and the outer ring held."""
    V, F, on_profile = _walled_annulus()
    S, a, rings, width = 64, 5.0, 6, 8.0
    th = 2 * np.pi * np.arange(S) / S
    u = np.stack([np.cos(th), np.sin(th), 0 * th], 1)
    d = ring_distances(rings, width, 2 * np.pi * a / S)
    G = np.stack([on_profile(np.full(S, dk), u) for dk in d])
    G[1, 10:15] = on_profile(np.full(S, 0.55), u)[10:15]
    G[2, 10:15] = on_profile(np.full(S, 0.65), u)[10:15]
    before = _grid_angles(G, V, F)
    assert before["min_angle_deg"] < 8.0 and before["flipped_faces"] == 0
    Gr = smooth_grid(G, d, V, F, iterations=0)
    after = _grid_angles(Gr, V, F)
    assert after["min_angle_deg"] > 25.0 and after["flipped_faces"] == 0
    assert np.array_equal(Gr[0], G[0]) and np.abs(Gr[-1] - G[-1]).max() < 1e-9
    # ring 1 keeps 0.6 of the grading's first step from the loop, in space
    assert np.linalg.norm(Gr[1] - Gr[0], axis=1).min() >= 0.6 * d[1] - 1e-9


def _notched_disk(b=30.0, n_th=720, n_t=64):
    """A flat disk of radius ``b`` whose hole is round (radius 6) but for a tongue of the surface
    3.5 mm deep and about 2 mm wide poking into it at angle 0: the opening's loop turns inwards
    much more sharply than a band width there. A structured polar mesh (z = 0)."""
    th = 2 * np.pi * np.arange(n_th) / n_th
    rh = 6.0 - 3.5 * np.exp(-(np.angle(np.exp(1j * th)) / 0.2) ** 2)
    r = rh[None] + (np.linspace(0, 1, n_t) ** 1.5)[:, None] * (b - rh[None])
    P = np.stack([r * np.cos(th)[None], r * np.sin(th)[None], 0 * r], -1).reshape(-1, 3)
    ids = np.arange(n_t * n_th).reshape(n_t, n_th)
    a, nb, c, d = ids[:-1], np.roll(ids[:-1], -1, 1), np.roll(ids[1:], -1, 1), ids[1:]
    F = np.concatenate([np.stack([a, nb, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return P, F, ids[0]


def _crossings(P, Q=None):
    """Crossing edge pairs of the closed 2D polygon P (non-adjacent edges), or between the edges
    of P and those of Q."""
    def side(p, q, r):
        u, v = q - p, r - p
        return np.sign(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])
    if Q is None:
        i, j = np.triu_indices(len(P), 2)
        keep = ~((i == 0) & (j == len(P) - 1))
        i, j, Q = i[keep], j[keep], P
    else:
        i, j = (x.ravel() for x in np.meshgrid(np.arange(len(P)), np.arange(len(Q)), indexing="ij"))
    A, B, C, D = P[i], np.roll(P, -1, axis=0)[i], Q[j], np.roll(Q, -1, axis=0)[j]
    return int(np.count_nonzero((side(A, B, C) != side(A, B, D)) & (side(C, D, A) != side(C, D, B))))


def test_outer_ring_is_simple_and_the_rings_nested_beside_a_sharp_notch():
    """Known answer: beside a tongue poking into the opening the loop offset by the band width
    crosses itself (the swallowtail that folded id309_squint_up's outer rings); the outer ring
    slides along build_band's star-shaped line instead: simple, every ring nested in the next,
    the outer ring the width from the loop all round, no band face turned over."""
    from pipeline.retopo.eye_band import _inside_polygon
    from pipeline.retopo.eyelid_loop import point_at_arclength, polyline_arclength

    V, F, hole = _notched_disk()
    S, rings, width = 64, 6, 8.0
    perim = polyline_arclength(V[hole])[0][-1]
    loop = point_at_arclength(V[hole], perim * np.arange(S) / S)
    out = np.cross([0.0, 0.0, 1.0], np.roll(loop, -1, axis=0) - np.roll(loop, 1, axis=0))
    out /= np.linalg.norm(out, axis=1, keepdims=True) * np.sign(np.sum(out * loop))
    assert _crossings((loop + width * out)[:, :2]) > 0                  # the offset: a swallowtail
    G, info = build_band(loop, V, F, hole, rings, width, perim / S, 20.0)
    G = smooth_grid(G, info["ring_distances_mm"], V, F, info["_outer_line"])
    assert np.array_equal(G[0], loop)
    assert all(_crossings(G[k][:, :2]) == 0 for k in range(rings + 1))
    assert all(_inside_polygon(G[k][:, :2], G[k + 1][:, :2]).all() for k in range(rings))
    assert all(_crossings(G[k][:, :2], G[k + 1][:, :2]) == 0 for k in range(rings))
    gap = np.linalg.norm(G[-1][:, None, :2] - loop[None, :, :2], axis=2).min(axis=1)
    assert np.abs(gap - width).max() < 0.2
    Q = split_quads(G.reshape(-1, 3), grid_quads(0, rings, S), V, F)
    assert band_report(G.reshape(-1, 3), Q, V, F, S, 0)["flipped_faces"] == 0


def test_zip_strip_maxmin_is_a_strip_no_worse_than_the_greedy_one():
    from pipeline.retopo.eye_rings import _zip_strip

    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    u = np.linspace(0, 2 * np.pi, 86, endpoint=False) + 0.03
    V = np.concatenate([8 * np.stack([np.cos(t), np.sin(t), 0 * t], 1), 9 * np.stack([np.cos(u), np.sin(u), 0 * u], 1)])
    inner, outer = np.arange(64), 64 + np.arange(86)
    T = zip_strip_maxmin(inner, outer, V[inner], V[outer], 0)
    G = _zip_strip(inner, outer, V[inner], V[outer], 0)
    assert len(T) == 64 + 86 and len(np.unique(np.sort(T, 1), axis=0)) == len(T)
    assert mc.triangle_angles_deg(V, T).min() >= mc.triangle_angles_deg(V, G).min() - 1e-9
    # wound like the greedy strip
    assert np.sign(mc.face_normals(V, T)[:, 2]).sum() == np.sign(mc.face_normals(V, G)[:, 2]).sum()
    # with the surface: no triangle turned against it
    disk = np.concatenate([V, [[0.0, 0.0, 0.0]]])
    ring = np.concatenate([np.stack([np.arange(86) + 64, np.roll(np.arange(86), -1) + 64, np.full(86, 150)], 1)])
    Ts = zip_strip_maxmin(inner, outer, V[inner], V[outer], 0, disk, ring[:, [1, 0, 2]] if
                          mc.face_normals(disk, ring)[0, 2] * mc.face_normals(V, G)[0, 2] < 0 else ring)
    assert np.all(mc.face_normals(V, Ts)[:, 2] * mc.face_normals(V, G)[0, 2] > 0)


@pytest.fixture(scope="module")
def patch():
    return face_patch()


def test_grid_band_ids_are_fixed_and_built(patch):
    V, F, eyes = patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, band="grid",
                       band_rings=4, band_width_mm=6.0)
    r = retopologize(V, F, eyes, s)
    rep = mc.check_mesh(r.V, r.F)
    assert rep.manifold and rep.boundary_loops == 3
    nb = 5 * 32
    for e, side in enumerate(("left", "right")):
        ids = r.band[side]
        assert np.array_equal(ids, e * nb + np.arange(nb).reshape(5, 32))
        assert np.array_equal(r.loops[side], ids[0])
    # the quads of the band are the first polygons after the triangles: 4 x 32 per eye
    assert int(np.count_nonzero(r.poly_counts == 4)) == 2 * 4 * 32
    m = r.metrics["band"]
    assert m["kind"] == "grid" and m["ids"] == {"left": [0, nb], "right": [nb, 2 * nb]}
    # how evenly each band's rings lie along the spokes: the grid's own figure, in ring steps
    for side in ("left", "right"):
        G = r.V[r.band[side]]
        assert m[side]["ring_offset_steps"] == pytest.approx(
            ring_offset_steps(G, m[side]["ring_distances_mm"]), abs=1e-3)
        assert 0.0 <= m[side]["ring_offset_steps"] < 3.0


def test_two_heads_have_the_same_band_ids(patch):
    """A second head (the patch scaled and its eye region pushed out) gets the same band ids."""
    V, F, eyes = patch
    V2 = V.copy()
    V2[:, 2] += 0.8 * np.exp(-((V2[:, 1] - V2[:, 1].mean()) / 15.0) ** 2)
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, band="grid",
                       band_rings=4, band_width_mm=6.0)
    r1 = retopologize(V, F, eyes, s)
    r2 = retopologize(V2 * 1.05, F, {k: replace(e, center=e.center * 1.05) for k, e in eyes.items()}, s)
    for side in ("left", "right"):
        assert np.array_equal(r1.band[side], r2.band[side])
        assert np.array_equal(r1.loops[side], r2.loops[side])
    assert r1.lateral == r2.lateral


def test_the_bands_built_side_by_side_are_the_bands_built_here(patch, monkeypatch):
    """add_eye_bands' children (one eye's grid, the last cut margin: pipeline.fork) give the mesh,
    the polygons and the band report of the same steps run in this process, to the bit."""
    from fixtures.forks import strict_fork_result
    from pipeline import fork
    from pipeline.retopo import eye_band

    V, F, eyes = patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, band="grid",
                       band_rings=4, band_width_mm=6.0)
    monkeypatch.setattr(eye_band, "fork_result", strict_fork_result)
    runs = {}
    for serial in ("1", "0"):
        monkeypatch.setenv(fork.SERIAL_ENV, serial)
        runs[serial] = retopologize(V, F, eyes, s)
    a, b = runs["1"], runs["0"]
    assert np.array_equal(a.V, b.V) and np.array_equal(a.F, b.F)
    assert np.array_equal(a.poly_counts, b.poly_counts) and np.array_equal(a.poly_indices, b.poly_indices)
    assert a.metrics["band"] == b.metrics["band"]


@pytest.mark.slow
def test_former_folding_identity_rigs_without_a_fold(tmp_path):
    """ident_s0_001 folded a lid face in the rig sweep with the repaired band (issue 30)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from fixtures.chain import stage_commands

    root = Path(__file__).parents[1]
    eyeball = root / "rigged_assets" / "eyeball"
    if not (eyeball / "eyeball.usda").is_file():
        pytest.skip("rigged_assets/eyeball is not built (dvc repro eyeball)")
    params = tmp_path / "params.yaml"
    text = (root / "params.yaml").read_text()
    assert "\n  band: grid " in text                 # the default (issue 30)
    params.write_text(text)
    run = [sys.executable, "-m"]
    subprocess.run(run + ["stages.identities", "--n", "2", "--no-repro", "--params", str(params)],
                   check=True, cwd=root, capture_output=True)
    scan = tmp_path / "ident_s0_001"
    subprocess.run(run + ["stages.synthetic_head", str(scan), "--identity", "ident_s0_001", "--params",
                          str(params), "--metrics", str(tmp_path / "sh.json")], check=True, cwd=root,
                   capture_output=True)
    cmds = stage_commands(scan, tmp_path / "build", eyeball, tmp_path / "asset", through="rig")
    for name, words in cmds.items():
        r = subprocess.run(run + words + ["--params", str(params), "--metrics", str(tmp_path / f"{name}.json")],
                           cwd=root, capture_output=True, text=True)
        assert r.returncode == 0, (name, r.stderr[-2000:])
    assert json.loads((tmp_path / "retopo.json").read_text())["band"]["kind"] == "grid"
    assert json.loads((tmp_path / "rig.json").read_text())["sweep_flipped_faces"] == 0


def _steps_cell_by_cell(Vi, Vo, j0):
    """zip_strip_maxmin's programme without the scan, visiting the cells row by row (its first
    form): the strip's steps in order, 1 along the inner line, 2 along the outer."""
    N, M = len(Vi), len(Vo)
    A, B = Vi[np.arange(N + 1) % N], Vo[(j0 + np.arange(M + 1)) % M]
    ang = lambda P, Q, R: mc.triangle_angles_deg(np.stack([P, Q, R]), np.array([[0, 1, 2]])).min()   # noqa: E731
    nfl = np.full((N + 1, M + 1), 1 << 30)
    best = np.full((N + 1, M + 1), -np.inf)
    came = np.zeros((N + 1, M + 1), dtype=np.int8)
    nfl[0, 0], best[0, 0] = 0, 180.0
    for i in range(N + 1):
        for j in range(M + 1):
            if (i == 0 and j == 0) or abs(i / N - j / M) > 0.25:
                continue
            cand = []
            if i > 0 and np.isfinite(best[i - 1, j]):
                cand.append((nfl[i - 1, j], -min(best[i - 1, j], ang(A[i - 1], A[i], B[j])), 1))
            if j > 0 and np.isfinite(best[i, j - 1]):
                cand.append((nfl[i, j - 1], -min(best[i, j - 1], ang(A[i], B[j], B[j - 1])), 2))
            if cand:
                f, m, c = min(cand)
                nfl[i, j], best[i, j], came[i, j] = f, -m, c
    steps, i, j = [], N, M
    while i > 0 or j > 0:
        steps.append(int(came[i, j]))
        i, j = (i - 1, j) if came[i, j] == 1 else (i, j - 1)
    return steps[::-1]


@pytest.mark.parametrize("n_out, wobble, j0", [(16, 0.0, 0), (24, 0.0, 3), (21, 0.4, 5)])
def test_zip_strip_maxmin_by_anti_diagonals_picks_the_cell_by_cell_strip(n_out, wobble, j0):
    """Ties included (regular polygons give equal angles everywhere): the same strip as visiting
    the cells one by one."""
    rng = np.random.default_rng(n_out)
    t = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    u = np.linspace(0, 2 * np.pi, n_out, endpoint=False)
    Vi = 8 * np.stack([np.cos(t), np.sin(t), 0 * t], 1)
    Vo = (9 + wobble * rng.random(n_out))[:, None] * np.stack([np.cos(u), np.sin(u), 0 * u], 1)
    inner, outer = np.arange(16), 16 + np.arange(n_out)
    T = zip_strip_maxmin(inner, outer, Vi, Vo, j0)
    assert [1 if (t < 16).sum() == 2 else 2 for t in T] == _steps_cell_by_cell(Vi, Vo, j0)


def test_a_remesh_pinched_to_one_vertex_beside_an_opening_still_gets_its_band(patch, monkeypatch):
    """The decimation can pinch a narrow neck of a noisy scan to one vertex (two cones touching:
    a fresh 250k-face head with 0.1 mm noise, beside its left opening), which left the band no
    annulus to be cut from. Here the remesh gets such a pinch by construction, two vertices a
    few edges apart beside the left opening made one: retopo still builds the grid band, and
    its mesh is manifold."""
    from scipy.sparse.csgraph import shortest_path

    from pipeline.geometry import meshtopo
    from pipeline.retopo import retopo

    V, F, eyes = patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, band="grid",
                       band_rings=4, band_width_mm=6.0)
    real = retopo._decimate
    pinched = []

    def pinch(Vd, Fd, target):
        Vd, Fd = real(Vd, Fd, target)
        loops = sorted(mc.boundary_loops(Fd), key=len)[:2]          # the openings, not the border
        opening = min(loops, key=lambda b: np.linalg.norm(Vd[b].mean(axis=0) - eyes["left"].center))
        border = np.unique(np.concatenate(mc.boundary_loops(Fd)))
        d_open = np.min(np.linalg.norm(Vd[:, None] - Vd[opening][None], axis=2), axis=1)
        cand = np.setdiff1d(np.flatnonzero((d_open > 2.0) & (d_open < 4.0)), border)
        hops = shortest_path(meshtopo.vertex_adjacency(Fd, len(Vd)), unweighted=True, indices=cand[:1])[0]
        a, b = int(cand[0]), int(next(v for v in cand[1:] if hops[v] == 3))
        Vd = Vd.copy()
        Vd[a] = 0.5 * (Vd[a] + Vd[b])
        pinched.append(a)
        return Vd, np.where(Fd == b, a, Fd)

    monkeypatch.setattr(retopo, "_decimate", pinch)
    r = retopologize(V, F, eyes, s)
    assert pinched
    rep = mc.check_mesh(r.V, r.F)
    assert rep.manifold and rep.boundary_loops == 3
    _, parent = meshtopo.split_fans(r.F, len(r.V))
    assert len(parent) == len(r.V)                  # no vertex of the result has two fans
    assert r.metrics["band"]["kind"] == "grid"


def test_band_warnings_name_each_eye_whose_band_is_turned_at_rest():
    from pipeline.retopo.eye_band import band_warnings

    clean = {"min_angle_deg": 28.1, "flipped_faces": 0, "flipped_at_ring_spoke": []}
    folded = {"min_angle_deg": 0.325, "flipped_faces": 179,
              "flipped_at_ring_spoke": [[0, 5], [0, 6], [1, 6], [3, 40]]}
    assert band_warnings({"left": clean, "right": clean}) == []
    assert band_warnings({}) == [] and band_warnings({"ids": None}) == []
    (line,) = band_warnings({"left": folded, "right": clean, "ids": {"rings": 6}})
    assert line.startswith("left eye's band: 179 triangles turned against the scan at rest")
    assert "4 ring and spoke cells, rings 0, 1, 3" in line and "smallest angle 0.3 deg" in line


def test_only_a_point_on_the_band_region_is_inside_its_outer_ring():
    """Known answer for the cut's "inside the outer ring" (seen in the region's parameter plane):
    a point on the region inside the ring is in, one on it outside the ring is out, and a point
    far off the region is out even where its closest point maps inside the ring (the opposite
    crop border of `filled_n1002_down`, 81 mm off, was taken for the right band's inside and its
    cut was no annulus)."""
    from pipeline.retopo.eye_band import _inside_ring

    n = 41
    x, y = np.meshgrid(np.linspace(-10, 10, n), np.linspace(-10, 10, n))
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    F = np.concatenate([np.column_stack([i, i + 1, i + n + 1]), np.column_stack([i, i + n + 1, i + n])])
    X = V[:, :2].copy()                     # the plane is its own parameter plane
    t = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    ring = np.column_stack([6 * np.cos(t), 6 * np.sin(t), np.zeros_like(t)])
    P = np.array([[1.0, 2.0, 0.1], [8.0, 0.0, 0.0], [0.5, 0.5, 50.0], [2.0, -1.0, -30.0]])
    assert _inside_ring(P, ring, V, F, X).tolist() == [True, False, False, False]
