"""meshtopo's one-sort boundary (boundary_mask) and the cut mesh's boundary derived from it
(cut_boundary_mask), against the direct computation on the cut mesh; and remove_eyeballs'
local_mesh, which looks only near its hints when it knows the longest edge."""

from __future__ import annotations

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.placement.eye_fit import local_mesh, median_edge_length


def _grid(n=30):
    """An n x n grid of unit squares, two triangles each, consistently wound: (V, F)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    V = np.column_stack([i.ravel(), j.ravel(), np.zeros(i.size)]).astype(float)
    a = (i[:-1, :-1] * (n + 1) + j[:-1, :-1]).ravel()
    b, c, d = a + (n + 1), a + (n + 2), a + 1
    F = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return V, F


def _direct(F):
    """The boundary half-edges of F by the definition: (a, b) whose (b, a) no face has, in the
    order of the faces' first, then second, then third edges."""
    H = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    have = {(int(a), int(b)) for a, b in H}
    return np.array([(a, b) for a, b in H if (b, a) not in have], dtype=np.int64).reshape(-1, 2)


def test_the_grid_boundary_is_its_rim():
    V, F = _grid(4)
    open_, repeated = meshtopo.boundary_mask(F)
    H = meshtopo.halfedges_of(F, open_)
    assert not repeated and len(H) == 16                    # 4 unit edges on each of 4 sides
    np.testing.assert_array_equal(H, _direct(F))
    np.testing.assert_array_equal(meshtopo.boundary_halfedges(F), _direct(F))


def test_cut_boundary_is_the_cut_meshs_own():
    V, F = _grid(30)
    rng = np.random.default_rng(3)
    c = V[F].mean(axis=1)
    open_, _ = meshtopo.boundary_mask(F)
    cuts = [np.linalg.norm(c - [15.0, 15.0, 0.0], axis=1) < 6.0,          # a hole inside
            np.linalg.norm(c - [0.0, 0.0, 0.0], axis=1) < 5.0,            # a bite out of the rim
            rng.uniform(size=len(F)) < 0.05,                              # scattered faces
            np.zeros(len(F), bool), np.ones(len(F), bool)]
    for remove in cuts:
        F2 = F[~remove]
        got = meshtopo.halfedges_of(F2, meshtopo.cut_boundary_mask(F, open_, remove))
        np.testing.assert_array_equal(got, meshtopo.boundary_halfedges(F2))
        if len(F2):
            np.testing.assert_array_equal(got, _direct(F2))


def test_face_order_lists_the_same_edges_face_by_face():
    V, F = _grid(3)
    F = F[np.arange(len(F)) % 4 != 1]
    Hf = meshtopo.boundary_halfedges(F, face_order=True)
    H = meshtopo.boundary_halfedges(F)
    assert sorted(map(tuple, Hf)) == sorted(map(tuple, H))
    # face by face: the faces the edges come from never decrease
    key = {tuple(e): f for f in range(len(F)) for e in zip(F[f], np.roll(F[f], -1))}
    faces = [key[tuple(e)] for e in Hf]
    assert faces == sorted(faces)


def test_a_repeated_half_edge_is_not_edge_manifold():
    tri = np.array([[0, 1, 2], [1, 0, 3]])                   # one edge, opposite: fine
    assert meshtopo.is_edge_manifold(tri) and not meshtopo.boundary_mask(tri)[1]
    flipped = np.array([[0, 1, 2], [0, 1, 3]])               # the same direction twice
    assert not meshtopo.is_edge_manifold(flipped) and meshtopo.boundary_mask(flipped)[1]
    fin = np.array([[0, 1, 2], [1, 0, 3], [1, 0, 4]])        # three faces on one edge
    assert not meshtopo.is_edge_manifold(fin) and meshtopo.boundary_mask(fin)[1]
    assert meshtopo.is_edge_manifold(np.zeros((0, 3), np.int64))
    for F in (tri, flipped, fin, np.vstack([_grid(3)[1], [[0, 1, 20]]])):   # either path: the definition
        np.testing.assert_array_equal(meshtopo.halfedges_of(F, meshtopo.boundary_mask(F)[0]), _direct(F))


def test_local_mesh_near_its_hints_is_the_whole_scans_selection():
    V, F = _grid(40)
    # one long sliver whose centroid lies near a hint while its corners lie far off: the bound
    # (a corner within radius + the longest edge) must still find it
    V = np.vstack([V, [[10.0, -30.0, 0.0], [10.5, -30.0, 0.0], [10.2, 50.0, 0.0]]])
    F = np.vstack([F, [[len(V) - 3, len(V) - 2, len(V) - 1]]])
    med, longest = median_edge_length(V, F, with_max=True)
    assert med == median_edge_length(V, F) and longest > 79.0
    hints = [np.array([10.2, -2.0, 0.0]), np.array([30.0, 30.0, 0.0])]
    whole = local_mesh(V, F, hints, 4.0)
    near = local_mesh(V, F, hints, 4.0, max_edge=longest)
    assert len(F) - 1 in whole[2]                            # the sliver is selected
    for a, b in zip(whole, near):
        np.testing.assert_array_equal(a, b)


def test_median_edge_length_by_blocks_is_the_median_of_every_edge():
    """Blocks of faces (the last one short) give the median and the longest edge of the whole
    set, bit for bit as norm over the (m, 3, 3) gathers, and leave V and F untouched."""
    from pipeline.placement import eye_fit

    rng = np.random.default_rng(3)
    V = rng.normal(size=(5000, 3)) * [10.0, 20.0, 5.0]
    F = rng.integers(0, len(V), size=(2 * eye_fit._EDGE_BLOCK + 17, 3))
    V0, F0 = V.copy(), F.copy()
    L = np.linalg.norm(V[np.roll(F, -1, axis=1)] - V[F], axis=2)
    med, longest = median_edge_length(V, F, with_max=True)
    assert med == float(np.median(L)) and longest == float(L.max())
    np.testing.assert_array_equal(V, V0)
    np.testing.assert_array_equal(F, F0)
    one = F[:1]                                 # a single face: the middle of its three edges
    assert median_edge_length(V, one) == float(np.median(L[0]))
