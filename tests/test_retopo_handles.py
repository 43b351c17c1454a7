"""Handles near an eye opening, cut before the band (pipeline/retopo/handles.py)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import mesh_checks as mc
from pipeline.retopo.eye_band import annulus_region, build_band
from pipeline.retopo.handles import cut_handles, euler_genus, region_faces


def _plate_with_handle(tube_rings=8):
    """A 60 mm square plate (1 mm grid, z = 0, faces towards +z) with a round opening of radius
    5 mm at the origin and a handle: a tube of 2 x 2 mm section arching 3 mm high from a square
    hole at (10, -3) to one at (10, 3), 4 mm from the opening. Returns V, F, the opening loop."""
    xs = np.arange(-30, 31, dtype=np.float64)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    n = len(xs)
    vid = lambda i, j: i * n + j                                     # noqa: E731
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            F += [(vid(i, j), vid(i + 1, j), vid(i + 1, j + 1)), (vid(i, j), vid(i + 1, j + 1), vid(i, j + 1))]
    F = np.asarray(F, dtype=np.int64)
    c = V[F].mean(axis=1)
    hole = np.linalg.norm(c[:, :2], axis=1) < 5.0
    sq_a = (np.abs(c[:, 0] - 10) < 1) & (np.abs(c[:, 1] + 3) < 1)
    sq_b = (np.abs(c[:, 0] - 10) < 1) & (np.abs(c[:, 1] - 3) < 1)
    F = F[~(hole | sq_a | sq_b)]
    loops = mc.boundary_loops(F)
    ring_a = next(b for b in loops if np.allclose(V[b][:, :2].mean(axis=0), (10, -3)))
    opening = next(b for b in loops if np.linalg.norm(V[b][:, :2], axis=1).max() < 6)
    # the tube: the square ring turned about x along the arch, so that it lands on the other hole
    off = V[ring_a] - (10.0, -3.0, 0.0)
    rings = [ring_a]
    Vs = [V]
    for k in range(1, tube_rings + 1):
        th = np.pi * k / tube_rings
        P = np.column_stack([10 + off[:, 0], -3 * np.cos(th) + off[:, 1] * np.cos(th),
                             3 * np.sin(th) - off[:, 1] * np.sin(th)])
        if k == tube_rings:
            ids = np.array([int(np.argmin(np.linalg.norm(V - p, axis=1))) for p in P])
            assert np.allclose(V[ids], P)
        else:
            ids = np.arange(len(P)) + sum(len(v) for v in Vs)
            Vs.append(P)
        rings.append(ids)
    V = np.concatenate(Vs)
    tube = []
    m = len(ring_a)
    for r0, r1 in zip(rings[:-1], rings[1:]):
        for s in range(m):
            a, b, c2, d = r0[s], r0[(s + 1) % m], r1[(s + 1) % m], r1[s]
            tube += [(b, a, d), (b, d, c2)]                          # against ring_a's border direction
    F = np.concatenate([F, np.asarray(tube, dtype=np.int64)])
    return V, F, opening


def test_plate_fixture_is_one_oriented_piece_with_one_handle():
    V, F, opening = _plate_with_handle()
    rep = mc.mesh_report(V, F) if hasattr(mc, "mesh_report") else None
    if rep is not None:
        assert rep.inconsistent_edges == 0 and rep.nonmanifold_edges == 0
    genus, chi, borders, pieces = euler_genus(F)
    assert (genus, borders, pieces) == (1, 2, 1)


def test_handle_near_the_opening_is_cut_and_the_band_is_built():
    V, F, opening = _plate_with_handle()
    radius = 20.0
    assert euler_genus(F[region_faces(V, F, opening, radius)])[0] == 1
    assert annulus_region(V, F, opening, radius, ()) is None         # the refusal before
    V2, F2, cuts = cut_handles(V, F, {"left": opening}, radius)
    assert len(cuts) == 1
    cut = cuts[0]
    assert cut["genus_before"] == 1
    # the tube's section (8 mm round) is cut somewhere along it, x = 10, beside the opening
    assert cut["loop_mm"] == pytest.approx(8.0, abs=1e-6)
    assert cut["at_mm"][0] == pytest.approx(10.0, abs=1e-6)
    assert 3.0 <= cut["from_opening_mm"] <= 12.0
    genus, chi, borders, pieces = euler_genus(F2)
    assert (genus, borders, pieces) == (0, 2, 1)
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
