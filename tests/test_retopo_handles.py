"""Handles near an eye opening, cut before the band (pipeline/retopo/handles.py)."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures import face_patch

from pipeline.geometry import mesh_checks as mc
from pipeline.retopo.eye_band import annulus_region, build_band
from pipeline.retopo.handles import cut_handles, euler_genus, region_faces
from pipeline.retopo.retopo import RetopoSettings, retopologize


def _add_tube(V, F, ca, cb, rings=8, waist=1.0):
    """A handle: a tube from the square hole of F centred at ``ca`` (x, y) to the one at ``cb``
    (the same x), the hole's border turned about x along a half circle so that it lands on the
    other hole's (the surface faces +z), its section scaled by ``waist`` half way. Returns V, F."""
    loops = mc.boundary_loops(F)
    ring_a = min(loops, key=lambda b: np.linalg.norm(V[b][:, :2].mean(axis=0) - ca))
    ring_b = min(loops, key=lambda b: np.linalg.norm(V[b][:, :2].mean(axis=0) - cb))
    h = 0.5 * (cb[1] - ca[1])
    off = V[ring_a][:, :2] - ca
    z0, z1 = V[ring_a][:, 2].mean(), V[ring_b][:, 2].mean()
    rings_ids, Vs, nv = [ring_a], [V], len(V)
    for k in range(1, rings + 1):
        th = np.pi * k / rings
        o = off * (1.0 - (1.0 - waist) * np.sin(th))
        P = np.column_stack([ca[0] + o[:, 0], ca[1] + h - h * np.cos(th) + o[:, 1] * np.cos(th),
                             z0 + (z1 - z0) * k / rings + h * np.sin(th) - o[:, 1] * np.sin(th)])
        if k == rings:                                          # onto the other hole's vertices
            d = np.linalg.norm(V[ring_b][None, :, :2] - P[:, None, :2], axis=2)
            assert np.allclose(d.min(axis=1), 0.0, atol=1e-9)
            ids = ring_b[np.argmin(d, axis=1)]
        else:
            ids = nv + np.arange(len(P))
            nv += len(P)
            Vs.append(P)
        rings_ids.append(ids)
    m = len(ring_a)
    tube = []
    for r0, r1 in zip(rings_ids[:-1], rings_ids[1:]):
        for s in range(m):
            a, b, c, d = r0[s], r0[(s + 1) % m], r1[(s + 1) % m], r1[s]
            tube += [(b, a, d), (b, d, c)]                       # against ring_a's border direction
    return np.concatenate(Vs), np.concatenate([F, np.asarray(tube, dtype=np.int64)])


def _cut_cells(V, F, centres, half):
    c = V[F].mean(axis=1)[:, :2]
    gone = np.zeros(len(F), dtype=bool)
    for x, y in centres:
        gone |= (np.abs(c[:, 0] - x) < half) & (np.abs(c[:, 1] - y) < half)
    return F[~gone]


def _plate_with_handle():
    """A 60 mm square plate (1 mm grid, z = 0, faces towards +z) with a round opening of radius
    5 mm at the origin and a handle: a tube of 2 x 2 mm section arching 3 mm high from a square
    hole at (10, -3) to one at (10, 3), 4 mm from the opening. Returns V, F, the opening loop."""
    xs = np.arange(-30, 31, dtype=np.float64)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    n = len(xs)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    F = F[np.linalg.norm(V[F].mean(axis=1)[:, :2], axis=1) >= 5.0]
    F = _cut_cells(V, F, [(10.0, -3.0), (10.0, 3.0)], 1.0)
    opening = next(b for b in mc.boundary_loops(F) if np.linalg.norm(V[b][:, :2], axis=1).max() < 6)
    V, F = _add_tube(V, F, np.array([10.0, -3.0]), np.array([10.0, 3.0]))
    return V, F, opening


def test_plate_fixture_is_one_oriented_piece_with_one_handle():
    V, F, opening = _plate_with_handle()
    rep = mc.check_mesh(V, F)
    assert rep.inconsistent_edges == 0 and rep.nonmanifold_edges == 0 and rep.nonmanifold_vertices == 0
    genus, chi, borders, pieces = euler_genus(F)
    assert (genus, borders, pieces) == (1, 2, 1)


def test_handle_near_the_opening_is_cut_and_the_band_is_built():
    V, F, opening = _plate_with_handle()
    radius = 20.0
    assert euler_genus(F[region_faces(V, F, opening, radius)])[0] == 1
    assert annulus_region(V, F, opening, radius, ()) is None         # the refusal before
    V2, F2, cuts = cut_handles(V, F, {"left": opening}, radius, max_loop_mm=8.5)
    assert len(cuts) == 1
    cut = cuts[0]
    assert cut["genus_before"] == 1
    # the tube's section (8 mm round) is cut somewhere along it, x = 10, beside the opening
    assert cut["loop_mm"] == pytest.approx(8.0, abs=1e-6)
    assert cut["at_mm"][0] == pytest.approx(10.0, abs=1e-6)
    assert 3.0 <= cut["from_opening_mm"] <= 12.0
    genus, chi, borders, pieces = euler_genus(F2)
    assert (genus, borders, pieces) == (0, 2, 1)
    rep = mc.check_mesh(V2, F2)
    assert rep.inconsistent_edges == 0 and rep.nonmanifold_edges == 0 and rep.nonmanifold_vertices == 0
    assert len(V2) == len(V) + 8 + 2                          # the loop's copies and two fan centres
    assert euler_genus(F2[region_faces(V2, F2, opening, radius)])[0] == 0
    # the opening untouched: the same vertices, where they were, still a border, every face on it kept
    assert np.array_equal(V2[opening], V[opening])
    assert any(len(b) == len(opening) and set(b.tolist()) == set(opening.tolist()) for b in mc.boundary_loops(F2))
    on_opening = np.isin(F, opening).any(axis=1)
    kept = {tuple(f) for f in F2.tolist()}
    assert all(tuple(f) in kept for f in F[on_opening].tolist())
    region = annulus_region(V2, F2, opening, radius, ())
    assert region is not None
    G, info = build_band(V2[opening], V2, F2, opening, rings=4, width=6.0, first=1.0, param_mm=radius)
    assert G.shape == (5, len(opening), 3) and not info["spokes_out_of_order"]
    assert np.all(np.isfinite(G))


def test_a_surface_without_handles_is_returned_as_it_was():
    V, F, opening = _plate_with_handle()
    far = np.linalg.norm(V[F].mean(axis=1)[:, :2] - (10, 0), axis=1) > 6     # the tube's faces out
    Ff = F[far & (V[F][:, :, 2].max(axis=1) == 0)]
    V2, F2, cuts = cut_handles(V, Ff, {"left": opening}, 20.0)
    assert cuts == [] and V2 is V and F2 is Ff


def test_a_handle_beyond_the_radius_is_left():
    V, F, opening = _plate_with_handle()
    V2, F2, cuts = cut_handles(V, F, {"left": opening}, 3.0)
    assert cuts == [] and F2 is F


def test_a_handle_longer_round_than_allowed_is_left():
    V, F, opening = _plate_with_handle()
    V2, F2, cuts = cut_handles(V, F, {"left": opening}, 20.0, max_loop_mm=7.5)   # its loop: 8 mm
    assert cuts == [] and F2 is F


def test_retopo_cuts_a_scanner_tunnel_beside_the_opening_and_says_where():
    """face_patch with a tunnel 2 mm above the left opening (a tube 0.8 mm across at its ends,
    0.4 mm at its waist, as a scanner's knot narrows): refused before (no annulus), now cut at
    the waist, the band built, the output's borders the crop's and the two openings."""
    V, F, eyes = face_patch()
    F = _cut_cells(V, F, [(32.4, 40.4), (32.4, 42.8)], 0.4)
    V, F = _add_tube(V, F, np.array([32.4, 40.4]), np.array([32.4, 42.8]), waist=0.5)
    assert euler_genus(F)[0] == 1
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, band="grid",
                       band_rings=4, band_width_mm=6.0)
    r = retopologize(V, F, eyes, s)
    cut = r.metrics["handles_cut"]
    assert cut["count"] == 1 and cut["cuts"][0]["side"] == "left"
    c = cut["cuts"][0]
    assert c["loop_mm"] == pytest.approx(1.6, abs=1e-6) and c["genus_before"] == 1     # the waist
    assert c["at_mm"][:2] == pytest.approx([32.4, 41.6], abs=1e-6)
    rep = mc.check_mesh(r.V, r.F)
    assert rep.manifold and rep.boundary_loops == 3
    assert np.array_equal(r.band["left"], np.arange(5 * 32).reshape(5, 32))
    # no handle: no cut and no key (the metrics of such a scan keep their bytes)
    V0, F0, eyes0 = face_patch()
    assert "handles_cut" not in retopologize(V0, F0, eyes0, s).metrics
