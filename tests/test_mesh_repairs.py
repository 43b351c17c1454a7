"""Mesh repairs after the retopology's loop placement (pipeline/geometry/flips.py): Delaunay edge
flips and short-edge collapses, on constructed meshes with known answers."""

from __future__ import annotations

import numpy as np

from pipeline.geometry import mesh_checks as mc
from pipeline.geometry.flips import _corner_deg, _delaunay_tests, collapse_short_edges, delaunay_flips
from pipeline.geometry.mesh_edit import TriMesh
from pipeline.retopo.retopo import refine_coarse_crop


def _grid(n=6, h=1.0):
    """(n x n) vertex grid in the z = 0 plane, two triangles per cell, normals +z."""
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h)
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F, dtype=np.int64)


def _not_delaunay(V, F):
    """Interior edges whose two facing angles sum past 180 deg."""
    ang = mc.triangle_angles_deg(V, F)
    facing = {}
    for f, tri in enumerate(F):
        for k in range(3):
            e = tuple(sorted((int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3]))))
            facing.setdefault(e, []).append(ang[f, k])
    return [e for e, a in facing.items() if len(a) == 2 and sum(a) > 180.0 + 1e-6]


def _pushed_grid():
    """A grid whose interior vertex 14 is pushed 0.45 mm along both axes: edge 7-14 faces two
    angles summing past 180 deg (its cell's other diagonal, 8-13, is the Delaunay one)."""
    V, F = _grid()
    V[14] += [0.45, 0.45, 0.0]
    return V, F


def _edges(F):
    return {tuple(sorted(e)) for e in mc.edges_of(F).tolist()}


def test_delaunay_flips_turn_a_long_diagonal():
    # a lone rhombus split along its long diagonal: its corners are border vertices with one or
    # two faces, which a flip would leave with fewer; nothing is flipped
    V = np.array([[0.0, 0, 0], [1, -0.5, 0], [2, 0, 0], [1, 0.5, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    F2, n = delaunay_flips(V, F)
    assert n == 0 and np.array_equal(F2, F)
    V, F = _pushed_grid()
    assert _not_delaunay(V, F) == [(7, 14)]
    F2, n = delaunay_flips(V, F)
    assert n == 1 and len(F2) == len(F)
    assert _edges(F) - _edges(F2) == {(7, 14)} and _edges(F2) - _edges(F) == {(8, 13)}
    assert _not_delaunay(V, F2) == []
    # the cell's two faces: their smallest angle grows (Delaunay maximises it), the mesh's never falls
    def cell_min(Fx):
        sel = np.isin(Fx, [7, 8, 13, 14]).sum(axis=1) == 3
        return mc.triangle_angles_deg(V, Fx[sel]).min()
    assert cell_min(F2) > cell_min(F) + 5.0
    assert mc.triangle_angles_deg(V, F2).min() >= mc.triangle_angles_deg(V, F).min()
    # still a consistently oriented surface over the same vertices
    assert np.all(mc.face_normals(V, F2)[:, 2] > 0)
    assert set(np.unique(F2)) == set(np.unique(F))


def test_delaunay_flips_keep_a_crease():
    """Lifting the pushed vertex 0.5 mm creases the cell past the 20 deg dihedral bound: the edge
    stays (a flip would change the surface's shape); at 0.2 mm it is flipped."""
    V, F = _pushed_grid()
    V[14, 2] = 0.5
    F2, n = delaunay_flips(V, F, max_dihedral_deg=20.0)
    assert n == 0 and np.array_equal(F2, F) and _not_delaunay(V, F2) == [(7, 14)]
    V[14, 2] = 0.2
    F2, n = delaunay_flips(V, F, max_dihedral_deg=20.0)
    assert n == 1 and _not_delaunay(V, F2) == []


def test_delaunay_tests_vectorised_agree_with_the_scalar_test():
    """The flips' Delaunay tests, computed for all edges at once, give the scalar test's answer on
    every edge they decide, and decide every interior edge but those at the threshold (a grid
    with exact 90 + 90 deg cells sits on it: the scalar test decides those). A face left out of
    the faces to visit has no interior edge the scalar test fails or leaves at the threshold."""
    rng = np.random.default_rng(3)
    for jitter in (0.0, 0.1, 0.3):
        V, F = _grid(8)
        V = V + np.concatenate([rng.normal(scale=jitter, size=(len(V), 2)), np.zeros((len(V), 1))], axis=1)
        tm = TriMesh(V, F)
        tests, visit = _delaunay_tests(V, tm)
        assert _delaunay_tests(V, tm, keyed=False) == ({}, visit)
        for (b, a, c, d), ok in tests.items():
            assert ok == (_corner_deg(V, b, a, c) + _corner_deg(V, d, a, c) <= 180.0 + 1e-6)
        interior = 0
        for fi, f in tm.F.items():
            for k in range(3):
                b, a, c = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
                twins = [g for g in tm.vf[a] & tm.vf[c] if g != fi]
                if len(twins) == 1:
                    d = [v for v in tm.F[twins[0]] if v not in (a, c)][0]
                    interior += 1
                    total = _corner_deg(V, b, a, c) + _corner_deg(V, d, a, c)
                    assert (b, a, c, d) in tests or abs(total - 180.0) < 1e-3
                    if fi not in visit:
                        assert tests[(b, a, c, d)] and total <= 180.0 + 1e-6
        assert interior > 0 and (jitter == 0.0 or len(tests) == interior)


def test_delaunay_flips_same_as_visiting_every_face(monkeypatch):
    """Skipping the faces with no edge to flip (and the vectorised tests) flips the same edges in
    the same order as visiting every face with scalar tests, on jittered grids with slivers."""
    from pipeline.geometry import flips

    rng = np.random.default_rng(5)
    cases = []
    for jitter in (0.2, 0.35):
        V, F = _grid(14)
        V = V + np.concatenate([rng.normal(scale=jitter, size=(len(V), 2)),
                                rng.normal(scale=0.05, size=(len(V), 1))], axis=1)
        cases.append((V, F, delaunay_flips(V, F)))
    # every face visited, no test known beforehand: each decided by the scalar test in the loop
    monkeypatch.setattr(flips, "_delaunay_tests", lambda V, tm, **kw: ({}, set(tm.F)))
    for V, F, (F2, n) in cases:
        F1, n1 = delaunay_flips(V, F)
        assert n == n1 and n > 10 and np.array_equal(F1, F2)


def test_collapse_short_edges_merges_the_free_end():
    V, F = _grid()
    V[14] = V[15] + [0.03, 0.0, 0.0]        # 0.03 mm from its neighbour (interior, free)
    loops = {"left": np.array([0, 1, 2, 3, 4, 5])}
    V2, F2, loops2, n = collapse_short_edges(V, F, loops, fixed=loops["left"], min_len=0.2)
    assert n == 1
    assert len(V2) == len(V) - 1 and len(F2) == len(F) - 2
    E = mc.edges_of(F2)
    assert np.linalg.norm(V2[E[:, 0]] - V2[E[:, 1]], axis=1).min() > 0.2
    # the fixed loop keeps its points, under new indices
    np.testing.assert_array_equal(V2[loops2["left"]], V[loops["left"]])
    assert np.all(mc.face_normals(V2, F2)[:, 2] > 0)


def test_collapse_short_edges_never_moves_a_fixed_vertex():
    V, F = _grid()
    V[1] = V[0] + [0.05, 0.0, 0.0]          # a short border edge, both ends fixed
    loops = {"border": np.array([0, 1, 2, 3, 4, 5])}
    V2, F2, loops2, n = collapse_short_edges(V, F, loops, fixed=loops["border"], min_len=0.2)
    assert n == 0 and np.array_equal(F2, F) and np.array_equal(V2, V)


def _border_twin(V, F, x=2):
    """The grid with its bottom-border vertex ``x`` pushed inside: a new border vertex 1e-8 mm
    from it takes its place on the border, its two faces (to the border neighbours and ``x``)
    of zero area, as the decimation left one on ``n1702_big_holes_near``'s crop border."""
    t = len(V)
    V = np.vstack([V, V[x] + [1e-8, 0.0, 0.0]])
    extra = []
    for nb in (x - 1, x + 1):
        f = next(f for f in F.tolist() if x in f and nb in f)
        k = f.index(x)
        u, v = (x, nb) if f[(k + 1) % 3] == nb else (nb, x)
        extra.append([v, u, t])                 # the half-edge v -> u, twin of the face's u -> v
    return V, np.vstack([F, extra])


def test_collapse_short_edges_drops_a_border_vertex_on_an_inner_ones_point():
    """A fixed border vertex whose only faces lie on a zero-length edge goes, and the inner
    vertex on its point takes its place: one border loop, no face of zero area. Without
    ``coincident`` it stays (retopo then refused the head: two corners on one point). The inner
    one is held here: on that head it could not go the other way (a face of its would have
    lost all its area)."""
    V, F = _grid()
    V1, F1 = _border_twin(V, F)
    border = np.concatenate(mc.boundary_loops(F1))
    assert len(V1) - 1 in border and 2 not in border
    border = np.r_[border, 2]
    V2, F2, _, n = collapse_short_edges(V1, F1, {}, fixed=border, min_len=0.2)
    assert n == 0 and np.array_equal(F2, F1)
    V3, F3, loops3, n = collapse_short_edges(V1, F1, {"left": np.array([30, 31])}, fixed=border,
                                             min_len=0.2, coincident=1e-6)
    assert n == 1 and len(F3) == len(F) and len(V3) == len(V)
    rep = mc.check_mesh(V3, F3)
    assert rep.manifold and rep.boundary_loops == 1 and rep.inconsistent_edges == 0
    E = mc.edges_of(F3)
    assert np.linalg.norm(V3[E[:, 0]] - V3[E[:, 1]], axis=1).min() > 0.5
    np.testing.assert_array_equal(V3[loops3["left"]], V[[30, 31]])
    # a twin on a loop is never dropped
    _, F4, _, n = collapse_short_edges(V1, F1, {"left": np.array([len(V1) - 1])}, fixed=border,
                                       min_len=0.2, coincident=1e-6)
    assert n == 0 and np.array_equal(F4, F1)


def test_a_face_the_remesher_dropped_is_put_back_but_not_a_hole_of_its_input():
    """A hole of three edges that the remesher's input lacked (the decimation dropped a face of
    ``n1802_depth10_noise``'s noisy crop, and its band met the hole) gets its face back, turned
    as its neighbours; one the input had stays open."""
    from pipeline.retopo.retopo import close_opened_triangles

    V, F = _grid()
    holed = np.delete(F, 17, axis=0)                 # an inner face of the grid
    assert sorted(len(b) for b in mc.boundary_loops(holed)) == [3, 20]
    F2 = close_opened_triangles(V, holed, V, F)
    rep = mc.check_mesh(V, F2)
    assert len(F2) == len(F) and rep.boundary_loops == 1 and rep.inconsistent_edges == 0
    assert np.all(mc.face_normals(V, F2)[:, 2] > 0)
    assert np.array_equal(close_opened_triangles(V, holed, V, holed), holed)
    assert np.array_equal(close_opened_triangles(V, F, V, F), F)


def test_refine_when_an_opening_has_fewer_vertices_than_the_loop():
    """An opening of 34 boundary vertices for a 64-point loop (a narrow half blink) is subdivided
    once (68 >= 64); one of 64 or more is left alone."""
    V, F = _grid(3)
    _, F1, levels = refine_coarse_crop(V, F, 64, [34])
    assert levels == 1 and len(F1) == 4 * len(F)
    _, F0, levels = refine_coarse_crop(V, F, 64, [64])
    assert levels == 0 and np.array_equal(F0, F)
    _, _, levels = refine_coarse_crop(V, F, 64, [15])
    assert levels == 3


def test_relax_of_a_few_free_vertices_ignores_the_rest_of_the_mesh():
    """relax works on the faces round its free vertices only (the band's zip relaxes a few
    hundred vertices of thousands): a fixed part far away, joined or not, changes nothing."""
    from pipeline.geometry.flips import relax

    V, F = _pushed_grid()
    free = [14, 15, 20]
    fixed = np.setdiff1d(np.arange(len(V)), free)
    alone = relax(V, F, fixed, V, F, iterations=3)
    # the same grid next to a second, fixed grid (another component) and its reference
    V2, F2 = _grid()
    V2 = V2 + [20.0, 0.0, 0.0]
    Vb = np.concatenate([V, V2])
    Fb = np.concatenate([F, F2 + len(V)])
    both = relax(Vb, Fb, np.concatenate([fixed, len(V) + np.arange(len(V2))]), Vb, Fb, iterations=3)
    np.testing.assert_array_equal(both[:len(V)], alone)
    np.testing.assert_array_equal(both[len(V):], V2)
    assert np.abs(alone[free] - V[free]).max() > 1e-3           # the free ones did move
    np.testing.assert_array_equal(alone[fixed], V[fixed])


def test_trimesh_face_sets_in_the_order_adding_face_by_face_gives():
    """TriMesh's vertex -> faces sets are filled in face order and keyed by first appearance, as
    adding the faces one by one does: the edits read those sets' and that dict's iteration order."""
    rng = np.random.default_rng(2)
    V = rng.normal(size=(300, 3))
    F = rng.integers(0, 300, (1000, 3))                # repeated corners and unused vertices too
    ref = {}
    for fi, f in enumerate(F.tolist()):
        for v in f:
            ref.setdefault(v, set()).add(fi)
    tm = TriMesh(V, F)
    assert list(tm.vf) == list(ref)
    assert all(list(tm.vf[v]) == list(s) for v, s in ref.items())
    assert tm.F == dict(enumerate(F.tolist())) and tm.next_f == len(F)


def test_relax_of_two_apart_zones_one_by_one_is_the_joint_relax_and_remembered():
    """Free vertices in two zones sharing no face move by their own faces only: relaxing the zones
    one after the other gives the joint relax's bits (the band relaxes each eye's border so), and
    a memo hands back the same bits for the same local problem."""
    from pipeline.geometry.flips import relax

    V, F = _pushed_grid()
    V2, F2 = _grid()
    Vb = np.concatenate([V, V2 + [20.0, 0.0, 0.3]])
    Vb[len(V) + 14] += [0.3, -0.2, 0.0]
    Fb = np.concatenate([F, F2 + len(V)])
    za, zb = np.array([14, 15, 20]), len(V) + np.array([14, 21])
    rest = lambda *zones: np.setdiff1d(np.arange(len(Vb)), np.concatenate(zones))   # noqa: E731
    joint = relax(Vb, Fb, rest(za, zb), Vb, Fb, iterations=3)
    memo = {}
    one = relax(relax(Vb, Fb, rest(za), Vb, Fb, iterations=3, memo=memo), Fb, rest(zb), Vb, Fb,
                iterations=3, memo=memo)
    assert joint.tobytes() == one.tobytes() and len(memo) == 2
    assert np.abs(joint[zb] - Vb[zb]).max() > 1e-3 and np.abs(joint[za] - Vb[za]).max() > 1e-3
    again = relax(Vb, Fb, rest(za), Vb, Fb, iterations=3, memo=memo)
    assert len(memo) == 2 and again[za].tobytes() == one[za].tobytes()
