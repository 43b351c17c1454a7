"""The ingest repair's fast paths against its general paths and plain references (issue 32).

Each fast path answers only when a cheap check proves that nothing needs doing (no vertex to
merge, no repeated face, no vertex to drop); these tests build meshes with and without those
defects and require the same arrays, counts and bits as the general path.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fixtures import head_mesh
from pipeline.geometry import frame, meshtopo
from pipeline.ingest import repair
from pipeline.kernels import pinned_env


def _general(monkeypatch):
    """Make every distinctness proof say "unsure", so repair takes its exact paths."""
    monkeypatch.setattr(repair, "_keys_all_distinct", lambda key: False)
    monkeypatch.setattr(repair, "_faces_all_distinct", lambda F: False)


def _ref_merge(V, F, tol):
    """merge_vertices by an exact row-wise unique (first vertex of each cell, input order kept)."""
    q = np.round(V / tol).astype(np.int64)
    _, first, inverse = np.unique(q, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return V[first[order]], rank[inverse.reshape(-1)][F], first[order]


def _ref_duplicates(F):
    _, first = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
    mask = np.ones(len(F), dtype=bool)
    mask[first] = False
    return mask


def _dirty_head():
    """head_mesh(3) with one duplicated vertex in use, one unused vertex, a repeated face (flipped)
    and a face with a repeated corner; returns the clean V, F, hints and the dirty V, F."""
    V, F, hints = head_mesh(3)
    n, m = len(V), len(F)
    low = int(np.argmin(V[:, 1]))                                   # the chin, far from the eyes
    f = int(np.flatnonzero((F == low).any(axis=1))[0])
    Vd = np.vstack([V, V[low], [[0.0, -300.0, 0.0]]])               # n: copy of low, n + 1: unused
    Fd = np.vstack([F, F[f, ::-1], [[F[f, 0], F[f, 0], F[f, 1]]]])  # m: repeat of f, m + 1: degenerate
    Fd[f] = np.where(Fd[f] == low, n, Fd[f])
    assert len(Fd) == m + 2
    return V, F, hints, Vd, Fd


def test_merge_fast_path_returns_the_input_when_nothing_merges():
    V, F, _ = head_mesh(3)
    V2, F2, keep = repair.merge_vertices(V, F, 1e-4)
    assert V2 is V and F2 is F and np.array_equal(keep, np.arange(len(V)))


@pytest.mark.parametrize("tol", [1e-4, 0.5])
def test_merge_matches_the_exact_unique(tol):
    rng = np.random.default_rng(3)
    V = np.round(rng.normal(size=(400, 3)) * 20, 1)
    V = np.vstack([V, V[rng.integers(0, 400, 60)] + 1e-6])          # near copies: merged at either tolerance
    F = rng.integers(0, len(V), size=(700, 3))
    got, want = repair.merge_vertices(V, F, tol), _ref_merge(V, F, tol)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    assert len(got[0]) < len(V)


def test_keys_all_distinct():
    assert repair._keys_all_distinct(np.array([5, 1, 9, 2], dtype=np.int64))
    assert not repair._keys_all_distinct(np.array([5, 1, 9, 5], dtype=np.int64))
    assert repair._keys_all_distinct(np.zeros(0, dtype=np.int64))


@pytest.mark.parametrize("offset", [0, 2**22])                      # exact keys; hashed keys (n**3 > int64)
def test_faces_all_distinct_and_duplicate_mask(offset):
    V, F, _ = head_mesh(3)
    F = F + offset
    assert repair._faces_all_distinct(F)
    assert not repair.duplicate_face_mask(F).any()
    Fd = np.vstack([F, F[[7]][:, [2, 1, 0]], F[[3]][:, [1, 2, 0]], F[[7]]])  # flipped, rotated, same
    assert not repair._faces_all_distinct(Fd)
    mask = repair.duplicate_face_mask(Fd)
    assert np.array_equal(mask, _ref_duplicates(Fd))
    assert np.flatnonzero(mask).tolist() == [len(F), len(F) + 1, len(F) + 2]


def test_repair_of_a_clean_mesh_keeps_the_arrays(monkeypatch):
    V, F, hints = head_mesh(3)
    fast = repair.repair_mesh(V, F, hints)
    assert np.array_equal(fast.V, V) and np.array_equal(fast.F, F)
    assert np.array_equal(fast.face_index, np.arange(len(F)))
    assert np.array_equal(fast.vertex_index, np.arange(len(V)))
    assert fast.V.flags.c_contiguous and fast.F.flags.c_contiguous
    _general(monkeypatch)
    slow = repair.repair_mesh(V, F, hints)
    _same_result(fast, slow)


def test_repair_of_a_dirty_mesh_known_answer_and_same_as_general(monkeypatch):
    V, F, hints, Vd, Fd = _dirty_head()
    fast = repair.repair_mesh(Vd, Fd, hints)
    assert np.array_equal(fast.V, V) and np.array_equal(fast.F, F)  # the copy merged back, the rest dropped
    assert np.array_equal(fast.face_index, np.arange(len(F)))
    assert np.array_equal(fast.vertex_index, np.arange(len(V)))
    c = fast.counts
    assert (c["merged_vertices"], c["degenerate_faces"], c["duplicate_faces"], c["unreferenced_vertices"]) == \
        (1, 1, 1, 1)
    _general(monkeypatch)
    _same_result(fast, repair.repair_mesh(Vd, Fd, hints))


def test_repair_fortran_order_input_gives_c_order(monkeypatch):
    V, F, hints = head_mesh(3)
    r = repair.repair_mesh(np.asfortranarray(V), np.asfortranarray(F), hints)
    assert r.V.flags.c_contiguous and r.F.flags.c_contiguous
    assert np.array_equal(r.V, V) and np.array_equal(r.F, F)


def _same_result(a, b):
    for k in ("V", "F", "vertex_index", "face_index"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype and np.array_equal(x, y), k
    assert a.counts == b.counts and a.eye_region == b.eye_region


_LONGEST_BITS = """
import numpy as np
from pipeline.ingest import repair
rng = np.random.default_rng(5)
V = rng.normal(size=(300, 3)) * 50                   # float64 coordinates: the summation order shows
F = rng.integers(0, 300, size=(5000, 3))
a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
sq = [np.einsum("ij,ij->i", x, x) for x in (a - b, b - c, c - a)]
want = np.sqrt(np.maximum(np.maximum(sq[0], sq[1]), sq[2]))
assert np.array_equal(repair.face_longest_edges(V, F).view(np.int64), want.view(np.int64))
"""


def test_face_areas_and_longest_edges_bits():
    rng = np.random.default_rng(5)
    V = rng.normal(size=(300, 3)) * 50
    F = rng.integers(0, 300, size=(5000, 3))
    assert np.array_equal(repair.face_areas(V, F).view(np.int64), meshtopo.face_areas(V, F).view(np.int64))
    # the longest edges have the row-wise einsum's bits on the kernels every pipeline program runs
    r = subprocess.run([sys.executable, "-c", _LONGEST_BITS], env=pinned_env(), capture_output=True, text=True,
                       cwd=Path(repair.__file__).resolve().parents[2])
    assert r.returncode == 0, r.stderr


def test_degenerate_faces_known_answer():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 0, 2], [0, 1, 3], [2, 1, 0]])      # good, repeated corner, collinear, good
    assert repair._degenerate_faces(V, F, 1e-10).tolist() == [False, True, True, False]


def _ref_edge_stats(F):
    u = F.ravel()
    v = F[:, [1, 2, 0]].ravel()
    e = np.stack([np.minimum(u, v), np.maximum(u, v)], axis=1)
    _, inv, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    up = np.bincount(inv.reshape(-1), weights=(u < v) * 2 - 1, minlength=len(counts))
    return {"edges": len(counts), "boundary": int((counts == 1).sum()), "non_manifold": int((counts > 2).sum()),
            "inconsistent_winding": int(((counts == 2) & (up != 0)).sum())}


def test_edge_stats_matches_reference():
    V, F, _ = head_mesh(3)
    assert repair.edge_stats(F, len(V)) == _ref_edge_stats(F)
    rng = np.random.default_rng(9)
    Fr = rng.integers(0, 40, size=(300, 3))
    assert repair.edge_stats(Fr, 40) == _ref_edge_stats(Fr)
    Fo = np.vstack([F[:500], F[500:520, ::-1]])                      # open, with flipped faces
    assert repair.edge_stats(Fo, len(V)) == _ref_edge_stats(Fo)
    Fb = rng.integers(0, 300, size=(3 * repair._BLOCK // 2, 3))         # keys over several blocks
    assert repair.edge_stats(Fb, 300) == _ref_edge_stats(Fb)
    assert repair.edge_stats(F[:1], len(V)) == {"edges": 3, "boundary": 3, "non_manifold": 0,
                                                "inconsistent_winding": 0}


def test_point_surface_distance_and_near_faces_over_blocks():
    rng = np.random.default_rng(4)
    V = rng.normal(size=(repair._BLOCK + 500, 3)) * 40
    F = rng.integers(0, len(V), size=(repair._BLOCK + 700, 3))
    p = np.array([3.0, -2.0, 41.0])
    d = V - p
    sq = np.einsum("ij,ij->i", d, d)
    assert np.array_equal(repair._squared_distances(V, p).view(np.int64), sq.view(np.int64))
    assert np.array_equal(repair._faces_near(V, F, p, 20.0), (sq <= 400.0)[F].any(axis=1))
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    q = repair.closest_point_on_triangles(A, B, C, p) - p
    want = float(np.sqrt(np.einsum("ij,ij->i", q, q)).min())          # every face, no pruning
    assert repair.point_surface_distance(V, F, p) == want


def _ref_components(F, n):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.concatenate([F[:, 0], F[:, 1]])
    cols = np.concatenate([F[:, 1], F[:, 2]])
    k, lab = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    return k, lab[F[:, 0]]


def test_face_components_by_vertex_same_labels():
    rng = np.random.default_rng(11)
    V, F, _ = head_mesh(3)
    cases = [(F, len(V)), (np.zeros((0, 3), np.int64), 5), (F[rng.permutation(len(F))], len(V) + 3)]
    for _ in range(20):
        n = int(rng.integers(3, 200))
        cases.append((rng.integers(0, n, size=(int(rng.integers(1, 60)), 3)), n + int(rng.integers(0, 4))))
    for Fc, n in cases:
        k, lab = meshtopo.face_components_by_vertex(Fc, n)
        k0, lab0 = _ref_components(Fc, n)
        assert k == k0 and lab.dtype == np.int64 and np.array_equal(lab, lab0)


def test_bounds_and_float32_step():
    rng = np.random.default_rng(2)
    V = rng.normal(size=(1000, 3)) * [30, 80, -5]
    lo, hi = frame.bounds(V)
    assert np.array_equal(lo, V.min(axis=0)) and np.array_equal(hi, V.max(axis=0))
    step = frame.check_float32(V, "m")
    assert step == float(np.spacing(np.float32(np.abs(V).max())))
    assert frame.check_float32(np.zeros((0, 3)), "m") == float(np.spacing(np.float32(0.0)))


def test_a_third_face_on_an_edge_is_dropped_and_the_surface_kept():
    """A flap laid on a skin edge (a hole fill over a rim face leaves one on a lid): that edge has
    three faces, which no later stage can walk. The two that run it in opposite directions with
    the most nearly equal normals stay (the skin); the flap goes, and is counted."""
    V, F, hints = head_mesh(3)
    back = int(np.argmin(V[F].mean(axis=1)[:, 2]))               # a face far from both eyes
    a, b, c = F[back]
    n = np.cross(V[b] - V[a], V[c] - V[a])
    tip = 0.5 * (V[a] + V[b]) - 3.0 * n / np.linalg.norm(n)      # folded 3 mm inward off the edge
    Vx = np.vstack([V, tip])
    Fx = np.vstack([F, [[a, b, len(V)]]])                        # runs a -> b as the face (a, b, c) does
    assert repair.edge_stats(Fx, len(Vx))["non_manifold"] == 1
    r = repair.repair_mesh(Vx, Fx, hints)
    assert np.array_equal(r.V, V) and np.array_equal(r.F, F)
    assert r.counts["non_manifold_faces"] == 1 and r.counts["unreferenced_vertices"] == 1
    assert r.edges == repair.edge_stats(F, len(V)) and r.edges["non_manifold"] == 0
    # on a lid it is damage in the eye region, counted there
    near = int(np.argmin(np.linalg.norm(V[F].mean(axis=1) - hints["left"], axis=1)))
    a, b, c = F[near]
    Fy = np.vstack([F, [[a, b, len(V)]]])
    Vy = np.vstack([V, 0.5 * (V[a] + V[b]) + np.array([0.0, 0.0, 2.0])])
    r = repair.repair_mesh(Vy, Fy, hints)
    assert np.array_equal(r.F, F) and r.eye_region["left"]["removed"] == 1


def test_faces_beyond_two_keep_the_consistent_pair():
    """Three faces on one edge, two running it one way: the one whose normal agrees with the
    face running it the other way stays. Four faces (two sheets crossing): one pair stays."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 1, 0.3], [0.5, 0, -1]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    # faces 0 and 1 are the flat sheet; face 2 runs 0 -> 1 too, tilted 17 deg from face 0
    assert repair._faces_beyond_two(V, F).tolist() == [False, False, True]
    F4 = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 5], [1, 0, 4]])
    keep = ~repair._faces_beyond_two(V, F4)
    assert keep.sum() == 2 and repair.edge_stats(F4[keep], len(V))["inconsistent_winding"] == 0
