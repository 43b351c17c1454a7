"""Scanner holes in the skin: mesh_edit.fill_holes_smooth (known answers on a plane and a sphere)
and retopo filling the scan's holes inside its crop, so the asset's only boundaries are the crop's
border and the two eye openings (issue 30, item 5)."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures import face_patch, height
from pipeline.geometry import mesh_checks as mc
from pipeline.geometry.mesh_edit import fill_holes_smooth
from pipeline.retopo.retopo import RetopoSettings, retopologize


def _grid(n=41, step=0.5):
    xs = (np.arange(n) - n // 2) * step
    X, Y = np.meshgrid(xs, xs)
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    a = (np.arange(n - 1)[None, :] + n * np.arange(n - 1)[:, None]).ravel()
    F = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return V, F


def _punch(V, F, centre, radius):
    """``F`` without the faces whose centroid lies within ``radius`` of ``centre`` (in x, y)."""
    c = V[F].mean(axis=1)
    return F[np.linalg.norm(c[:, :2] - np.asarray(centre)[:2], axis=1) > radius]


def _hole_loops(F, n_outer=1):
    loops = sorted(mc.boundary_loops(F), key=len)
    return loops[:len(loops) - n_outer]


def test_plane_hole_filled_flat_and_closed():
    V, F = _grid()
    F = _punch(V, F, (0.3, -0.2), 3.0)
    holes = _hole_loops(F)
    assert len(holes) == 1
    V2, F2 = fill_holes_smooth(V, F, holes)
    rep = mc.check_mesh(V2, F2)
    assert rep.manifold and rep.degenerate_faces == 0
    assert rep.boundary_loops == 1                                  # only the grid's border
    assert np.abs(V2[len(V):, 2]).max() < 1e-9                      # on the plane
    assert len(V2) - len(V) > 1                                     # rings, not one fan vertex
    # every fill face faces the way its neighbours do (+z)
    n = mc.face_normals(V2, F2[len(F):], normalize=True)
    assert (n[:, 2] > 0.99).all()
    assert (F2[:len(F)] == F).all()                                 # old faces keep their ids


def test_sphere_hole_follows_the_curvature():
    R = 50.0
    V, F = _grid(n=61, step=0.5)
    V[:, 2] = np.sqrt(R * R - V[:, 0] ** 2 - V[:, 1] ** 2) - R      # a cap of a 50 mm sphere
    F = _punch(V, F, (2.0, 1.0), 4.0)
    holes = _hole_loops(F)
    V2, F2 = fill_holes_smooth(V, F, holes)
    assert mc.check_mesh(V2, F2).boundary_loops == 1
    new = V2[len(V):]
    off = np.linalg.norm(new - [0.0, 0.0, -R], axis=1) - R
    # a flat fan's centre would sit sag = r^2 / 2R = 0.16 mm inside the sphere
    assert np.abs(off).max() < 0.01


def test_either_loop_direction_gives_the_same_orientation():
    V, F = _grid()
    F = _punch(V, F, (0.0, 0.0), 2.0)
    loop = _hole_loops(F)[0]
    A = fill_holes_smooth(V, F, [loop])
    B = fill_holes_smooth(V, F, [loop[::-1]])
    assert mc.check_mesh(*A).inconsistent_edges == 0 and mc.check_mesh(*B).inconsistent_edges == 0


def test_a_crescent_hole_is_closed_without_a_fold():
    """A harmonic grid onto a non-convex loop can fold (Tutte's theorem holds for convex ones):
    on a crescent 1 mm wide round 300 deg it turned 1422 of its 3486 faces over, and a sparse
    scan's 15 mm slit beside the nose (``n1504_sparse_samples``) 115 of 371. Such a loop is
    closed by its own vertices, every face the way the plane faces."""
    V, F = _grid(n=61, step=0.25)
    c = V[F].mean(axis=1)
    r = np.linalg.norm(c[:, :2], axis=1)
    a = np.degrees(np.arctan2(c[:, 1], c[:, 0]))
    F = F[~((r > 2.5) & (r < 3.5) & (np.abs(a) < 160))]
    holes = _hole_loops(F)
    assert len(holes) == 1
    V2, F2 = fill_holes_smooth(V, F, holes)
    rep = mc.check_mesh(V2, F2)
    assert rep.manifold and rep.degenerate_faces == 0 and rep.boundary_loops == 1
    n = mc.face_normals(V2, F2[len(F):], normalize=True)
    assert (n[:, 2] > 0.99).all()
    assert np.abs(V2[len(V):, 2]).max() < 1e-9                      # on the plane
    # inner vertices where the slit is wide, each inside the crescent
    r_new = np.linalg.norm(V2[len(V):, :2], axis=1)
    assert len(r_new) > 0 and ((r_new > 2.4) & (r_new < 3.6)).all()


def test_a_fill_adds_no_edge_the_skin_already_has():
    """The crescent's ear clip joins loop vertices by chords; where the skin already joins two of
    them by an edge of its own (here a fin of two faces standing on that edge off the plane: the
    loop wraps a fold the plane flattens, as round n5103_icteye_300k_out_up's lower lid), that
    chord is not used, so no edge gets a third face, and the hole is still closed: the way the
    plane faces where a clip avoids the chord (a chord the plain clip can do without, and one
    it cannot), else by the folded grid, said."""
    from pipeline.geometry.mesh_edit import _ear_clip, _hole_frame, _joined_chords, _polygon_area

    V0, F0 = _grid(n=61, step=0.25)
    c = V0[F0].mean(axis=1)
    r = np.linalg.norm(c[:, :2], axis=1)
    a = np.degrees(np.arctan2(c[:, 1], c[:, 0]))
    F0 = F0[~((r > 2.5) & (r < 3.5) & (np.abs(a) < 160))]
    (L,) = _hole_loops(F0)
    P2 = _hole_frame(V0, V0[L], V0[L].mean(axis=0), np.array([0.0, 0.0, 1.0]), 1.5)[1]
    pos = {int(v): i for i, v in enumerate(L)}
    _, F_plain = fill_holes_smooth(V0, F0, [L])
    chords = sorted({tuple(sorted((pos[int(x)], pos[int(y)]))) for f in F_plain[len(F0):]
                     for x, y in zip(f, np.roll(f, -1)) if int(x) in pos and int(y) in pos}
                    - {tuple(sorted((i, (i + 1) % len(L)))) for i in range(len(L))})
    base = _joined_chords(F0, L)
    stuck = [ch for ch in chords if _ear_clip(P2, base | {ch}) is None]
    free = [ch for ch in chords if ch not in stuck]
    assert stuck and free
    for i, j in (free[len(free) // 2], stuck[0]):
        assert (i, j) not in base
        va, vc = int(L[i]), int(L[j])
        tips = np.array([V0[va] + V0[vc] + [0.0, 0.0, 2.0], V0[va] + V0[vc] - [0.0, 0.0, 2.0]]) / 2.0
        V = np.concatenate([V0, tips])
        F = np.concatenate([F0, [[va, vc, len(V) - 2], [vc, va, len(V) - 1]]])
        assert (i, j) in _joined_chords(F, L)
        V2, F2, unfilled, folded = fill_holes_smooth(V, F, [L], return_unfilled=True, return_folded=True)
        e = np.sort(np.concatenate([F2[:, [0, 1]], F2[:, [1, 2]], F2[:, [2, 0]]]), axis=1)
        assert np.unique(e, axis=0, return_counts=True)[1].max() == 2
        assert unfilled == []
        if not folded:
            n = mc.face_normals(V2, F2[len(F):], normalize=False)
            assert (n[:, 2] > 0).all()                             # every fill face turned up
            assert np.isclose(0.5 * n[:, 2].sum(), abs(_polygon_area(P2)))   # and they tile the hole


def test_ear_clip_joins_no_forbidden_pair():
    """A convex hexagon clipped with a pair forbidden: a triangulation of it that never joins
    that pair; a square with both diagonals forbidden has none."""
    from pipeline.geometry.mesh_edit import _ear_clip, _signed_areas

    t = np.radians(np.arange(6) * 60.0)
    P = np.column_stack([np.cos(t), np.sin(t)])
    for forbid in ({(0, 2)}, {(1, 3)}, {(0, 2), (0, 3), (0, 4)}):
        T = _ear_clip(P, frozenset(forbid))
        assert T is not None and len(T) == 4 and (_signed_areas(P, T) > 0).all()
        assert np.isclose(_signed_areas(P, T).sum(), 1.5 * np.sqrt(3.0))
        assert not any(tuple(sorted((int(x), int(y)))) in forbid for f in T for x, y in zip(f, np.roll(f, -1)))
    Q = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    assert _ear_clip(Q, frozenset({(0, 2), (1, 3)})) is None


def test_ear_clip_of_a_loop_pinched_at_a_point():
    """Two squares touching at one corner, walked as one loop through two copies of that corner
    (a scan's hole pinched at a bow-tie): each lobe is clipped alone, every face positive."""
    from pipeline.geometry.mesh_edit import _ear_clip, _signed_areas

    P = np.array([[0, 0], [1, 0], [1, 1], [0, 1],               # one square, to the corner...
                  [0, 2], [-1, 2], [-1, 1], [0, 1.0]])           # ...the other, to its copy
    T = _ear_clip(P)
    assert T is not None and len(T) == 4                           # two squares, two faces each
    assert (_signed_areas(P, T) > 0).all()
    assert np.isclose(_signed_areas(P, T).sum(), 2.0)
    assert _ear_clip(P[::-1]) is not None and (_signed_areas(P[::-1], _ear_clip(P[::-1])) > 0).all()


def _helicoid_slit(phi0=0.0, phi1=150.0, length=20.0, nx=41, w=0.6):
    """A strip that twists from ``phi0`` to ``phi1`` deg about the x axis over ``length`` mm
    (rows at s = 0, +-w, +-(w + h), h 3 mm at x = 0 and 0.2 mm from x = 6 mm on, so the
    skin's mean normal leans to the start), with a slit |s| < w cut along it: a scanner's thin
    slit where the skin turns (``n1402_wide``'s). Returns V, F, the slit's loop and the skin's
    normal at each x, (0, -sin phi, cos phi)."""
    xs = np.linspace(0.0, length, nx)
    phi = np.radians(phi0 + (phi1 - phi0) * xs / length)
    h = 0.2 + 2.8 * np.clip(1 - xs / 6.0, 0.0, 1.0)
    V = np.concatenate([np.c_[xs, s * np.cos(phi), s * np.sin(phi)]
                        for s in (-(w + h), -w + 0 * xs, 0 * xs, w + 0 * xs, w + h)])
    i = np.arange(nx - 1)
    F = np.concatenate([np.c_[j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1] for j in range(4)]
                       + [np.c_[j * nx + i, (j + 1) * nx + i + 1, (j + 1) * nx + i] for j in range(4)])
    c = V[F].mean(axis=1)
    F = F[~((np.abs(c[:, 1] * np.cos(np.radians(phi0 + (phi1 - phi0) * c[:, 0] / length))
                    + c[:, 2] * np.sin(np.radians(phi0 + (phi1 - phi0) * c[:, 0] / length))) < w)
            & (c[:, 0] > 1.2) & (c[:, 0] < length - 1.2))]
    loop = sorted(mc.boundary_loops(F), key=len)[0]

    def normal(x):
        a = np.radians(phi0 + (phi1 - phi0) * x / length)
        return np.c_[0 * a, -np.sin(a), np.cos(a)]
    return V, F, loop, normal


def test_a_slit_where_the_skin_turns_is_clipped_in_its_own_plane():
    """Seen along the mean normal of the skin round it, a slit along a strip that turns 150 deg
    crosses itself (its two sides swap where the skin stands edge-on), so neither the grid nor
    an ear clip in that plane closes it; in the plane the loop spans most it is simple. Before
    that second plane this 39 mm hole was left open."""
    from pipeline.geometry.mesh_edit import _ear_clip, _hole_frame, loop_perimeter

    V, F, loop, normal = _helicoid_slit()
    P = V[loop]
    fn = mc.face_normals(V, F[np.isin(F, loop).any(axis=1)], normalize=False).sum(axis=0)
    assert _ear_clip(_hole_frame(V, P, P.mean(axis=0), fn / np.linalg.norm(fn), 1.5)[1]) is None
    assert 35.0 < loop_perimeter(P) < 45.0
    V2, F2, unfilled = fill_holes_smooth(V, F, [loop], return_unfilled=True, keep_folded_mm=10.0)
    assert unfilled == []
    rep = mc.check_mesh(V2, F2)
    assert rep.manifold and rep.boundary_loops == 1 and rep.inconsistent_edges == 0
    assert rep.degenerate_faces == 0
    new = F2[len(F):]
    # every fill face faces the way the skin does where it lies
    d = (mc.face_normals(V2, new) * normal(V2[new].mean(axis=1)[:, 0])).sum(axis=1)
    assert d.min() > 0.98


def test_a_hole_no_plane_closes_keeps_its_folded_grid_and_says_so():
    """A slit along a strip turning 270 deg crosses itself seen along the skin's mean normal and
    in the plane it spans most: under ``keep_folded_mm`` it keeps the harmonic grid, folded, and
    is reported with its count of turned faces (retopo's ``scan_holes_filled_folded``); over it
    it is left open, the mesh untouched."""
    V, F, loop, _ = _helicoid_slit(phi0=0.0, phi1=270.0)
    V2, F2, unfilled, folded = fill_holes_smooth(V, F, [loop], return_unfilled=True,
                                                 return_folded=True)
    assert unfilled == [] and len(folded) == 1 and folded[0][0] == 0
    assert 0 < folded[0][1] < len(F2) - len(F)
    assert mc.check_mesh(V2, F2).boundary_loops == 1
    V3, F3, unfilled, folded = fill_holes_smooth(V, F, [loop], keep_folded_mm=10.0,
                                                 return_unfilled=True, return_folded=True)
    assert unfilled == [0] and folded == []
    assert np.array_equal(V3, V) and np.array_equal(F3, F)
    assert fill_holes_smooth(V, F, [], return_unfilled=True, return_folded=True)[2:] == ([], [])


def _refine_reference(P2, T, edge):
    """The refinement written plainly: each round, the half-edge table built afresh and the
    longest inner edge over ``1.5 * edge`` (the first met, face by face, of equal ones) whose
    faces are not too thin to halve, halved."""
    XY = [tuple(p) for p in np.asarray(P2, dtype=np.float64)]
    T = [list(map(int, t)) for t in T]

    def thin(f):
        (ax, ay), (bx, by), (cx, cy) = (XY[t] for t in f)
        return abs((bx - ax) * (cy - ay) - (by - ay) * (cx - ax)) < 2e-6 * edge ** 2

    for _ in range(20 * len(P2) + 100):
        owner = {(f[k], f[(k + 1) % 3]): fi for fi, f in enumerate(T) for k in range(3)}
        best, L2 = None, (1.5 * edge) ** 2
        for (u, v) in owner:
            if u < v and (v, u) in owner and not thin(T[owner[(u, v)]]) and not thin(T[owner[(v, u)]]):
                d2 = (XY[u][0] - XY[v][0]) ** 2 + (XY[u][1] - XY[v][1]) ** 2
                if d2 > L2:
                    best, L2 = (u, v), d2
        if best is None:
            break
        u, v = best
        XY.append(((XY[u][0] + XY[v][0]) / 2, (XY[u][1] + XY[v][1]) / 2))
        for a, b in ((u, v), (v, u)):
            fi = owner[(a, b)]
            x = next(t for t in T[fi] if t != a and t != b)
            T[fi] = [a, len(XY) - 1, x]
            T.append([len(XY) - 1, b, x])
    return np.asarray(T, dtype=np.int64), np.asarray(XY, dtype=np.float64)


def _clip_reference(P2, sgn, clearance):
    """Ear clipping written plainly: every ear judged after every clip, the fattest (height over
    its longest edge) cut, the earliest of equal ones; no ear whose new edge passes nearer than
    ``clearance`` to another vertex."""
    from pipeline.geometry.mesh_edit import _signed_areas

    idx, tris = list(range(len(P2))), []
    while len(idx) > 3:
        best, q = -1, -1.0
        for j in range(len(idx)):
            t = [idx[j - 1], idx[j], idx[(j + 1) % len(idx)]]
            A = sgn * _signed_areas(P2, np.array([t]))[0]
            if not A > 1e-12:
                continue
            a, b, c = P2[t]
            Q = P2[[k for k in idx if k not in t]]
            d1 = sgn * ((b[0] - a[0]) * (Q[:, 1] - a[1]) - (b[1] - a[1]) * (Q[:, 0] - a[0]))
            d2 = sgn * ((c[0] - b[0]) * (Q[:, 1] - b[1]) - (c[1] - b[1]) * (Q[:, 0] - b[0]))
            d3 = sgn * ((a[0] - c[0]) * (Q[:, 1] - c[1]) - (a[1] - c[1]) * (Q[:, 0] - c[0]))
            if ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)).any():
                continue
            t = np.clip((Q - a) @ (c - a) / ((c - a) @ (c - a)), 0.0, 1.0)
            if len(Q) and (np.linalg.norm(a + t[:, None] * (c - a) - Q, axis=1) < clearance).any():
                continue
            e = max(np.linalg.norm(b - a), np.linalg.norm(c - b), np.linalg.norm(a - c))
            if 2.0 * A / e ** 2 > q:
                best, q = j, 2.0 * A / e ** 2
        if best < 0:
            return None
        tris.append([idx[best - 1], idx[best], idx[(best + 1) % len(idx)]])
        idx.pop(best)
    return np.asarray(tris + [idx], dtype=np.int64)


def _polygons(seed=3):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    a = np.linspace(0.3, 2 * np.pi - 0.3, 10)
    yield np.c_[10 * np.cos(t), 10 * np.sin(t)]                                   # regular: ties
    yield np.c_[np.cos(t), np.sin(t)] * np.where(np.arange(16) % 2, 10.0, 4.0)[:, None]   # a star
    yield np.r_[np.c_[30 * np.cos(a), 30 * np.sin(a)], np.c_[20 * np.cos(a[::-1]), 20 * np.sin(a[::-1])]]
    for m in (16, 16, 16, 6, 8, 11):
        s = np.sort(rng.uniform(0, 2 * np.pi, m))
        yield np.c_[np.cos(s), np.sin(s)] * (10 * (1 + 0.4 * rng.uniform(-1, 1, m)))[:, None]
    # spiky: an ear beside a spike's tip is free only once the tip is cut (with a clearance)
    yield np.array([[8.0, 4.0], [3.3, 2.6], [3.6, 4.3], [1.4, 2.1], [-0.1, 2.0], [-2.9, 2.0],
                    [-4.7, 0.2], [-9.3, -1.6], [-8.6, -3.0], [2.8, -5.1], [3.5, -4.4]])
    yield np.array([[-3.1, 5.1], [-6.1, 4.5], [-6.3, -4.2], [-0.2, -2.0], [0.6, -2.2], [2.0, -2.5]])


def test_the_ear_clip_and_its_refinement_give_the_plain_versions_faces():
    """The fill's ear clip judges again only the ears a clip can change, and its refinement
    keeps its half-edge table and a heap of long edges up to date: both give exactly the faces
    of the plain versions (every ear judged after every clip, the table rebuilt after every
    split), on both turnings of polygons with equal edges, spikes, a C and random ones, with and
    without a clearance."""
    from pipeline.geometry.mesh_edit import _clip_simple, _polygon_area, _refine_inside

    n_split = 0
    for P in _polygons():
        for Q in (P, P[::-1]):
            sgn = 1.0 if _polygon_area(Q) > 0 else -1.0
            for clearance in (1.0, 0.0):
                T = _clip_simple(Q, list(range(len(Q))), sgn, clearance)
                R = _clip_reference(Q, sgn, clearance)
                assert (T is None and R is None) or np.array_equal(T, R)
            assert T is not None
            Tp = T if sgn > 0 else T[:, ::-1]
            edge = float(np.linalg.norm(np.roll(Q, -1, axis=0) - Q, axis=1).mean())
            for k in (1.0, 0.5):
                A, XA = _refine_inside(Q, Tp, k * edge)
                B, XB = _refine_reference(Q, Tp, k * edge)
                assert np.array_equal(A, B) and np.array_equal(XA, XB)
                n_split += len(XA) - len(Q)
    assert n_split > 500                        # the refinement did split, many times


def test_the_refinement_of_a_large_hole_stops_at_its_cap_without_a_degenerate_face():
    """A 334-vertex C-shaped hole (167 mm round at its own edge, 1.2 mm) and the same hole
    asked for edges of 0.05 mm: at most ``20 * m + 100`` splits, the polygon's area kept, and
    every face at least ``5e-7 * edge ** 2`` in area, turned the polygon's way (halving
    needles at the cap had left faces of zero area in round-off)."""
    from pipeline.geometry.mesh_edit import _ear_clip, _polygon_area, _refine_inside, _signed_areas

    a = np.linspace(0.3, 2 * np.pi - 0.3, 167)
    P = np.r_[np.c_[30 * np.cos(a), 30 * np.sin(a)], np.c_[20 * np.cos(a[::-1]), 20 * np.sin(a[::-1])]]
    T = _ear_clip(P)
    assert T is not None and len(T) == len(P) - 2
    for edge in (float(np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).mean()), 0.05):
        G, XY = _refine_inside(P, T, edge)
        assert len(XY) - len(P) <= 20 * len(P) + 100 and len(G) == len(T) + 2 * (len(XY) - len(P))
        A = _signed_areas(XY, G)
        assert np.isclose(A.sum(), _polygon_area(P), rtol=1e-9)
        assert A.min() >= 5e-7 * edge ** 2


@pytest.fixture(scope="module")
def holed_patch():
    V, F, eyes = face_patch()
    F = _punch(V, F, (0.0, 50.0), 2.5)       # between the brows
    F = _punch(V, F, (45.0, 15.0), 1.5)      # on the cheek
    F = _punch(V, F, (0.0, 6.0), 2.0)        # on the crop's lower edge: a notch of the border, not a hole
    return V, F, eyes


def test_retopo_fills_the_scans_holes_inside_its_crop(holed_patch):
    V, F, eyes = holed_patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32)
    r = retopologize(V, F, eyes, s)
    rep = mc.check_mesh(r.V, r.F)
    assert rep.manifold
    assert rep.boundary_loops == 3                      # two eye openings + the crop border
    assert r.metrics["scan_holes_filled"] == 2
    # the filled crop continues the skin: within the skin's own 0.3 mm ripple of the truth
    from scipy.spatial import cKDTree

    fill = r.crop_V[cKDTree(V).query(r.crop_V)[0] > 1e-9]      # the crop's new vertices
    assert len(fill) > 10
    assert np.abs(fill[:, 2] - height(fill[:, 0], fill[:, 1])).max() < 0.3
    # and the low-poly mesh over the holes lies on it as everywhere else
    near = np.linalg.norm(r.V[:, :2] - [0.0, 50.0], axis=1) < 3.0
    assert near.any()
    assert np.abs(r.V[near, 2] - height(r.V[near, 0], r.V[near, 1])).max() < 0.4


def test_retopo_says_which_holes_are_too_large_to_fill(holed_patch):
    """A hole over ``fill_holes_mm`` round stays open and is listed with its perimeter and
    centre (the stage prints each as a warning: renders see through it)."""
    V, F, eyes = holed_patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, fill_holes_mm=16.0)
    r = retopologize(V, F, eyes, s)
    assert r.metrics["scan_holes_filled"] == 1                      # the cheek's, 13.8 mm round
    (big,) = r.metrics["scan_holes_left_open"]
    assert 16.0 < big["perimeter_mm"] < 2 * np.pi * 3.5             # round the 2.5 mm punch
    assert np.linalg.norm(np.asarray(big["centre_mm"])[:2] - [0.0, 50.0]) < 1.0
    assert mc.check_mesh(r.V, r.F).boundary_loops == 4


def test_retopo_leaves_the_holes_open_when_told(holed_patch):
    V, F, eyes = holed_patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, fill_holes_mm=0)
    r = retopologize(V, F, eyes, s)
    assert r.metrics["scan_holes_filled"] == 0
    assert mc.check_mesh(r.V, r.F).boundary_loops == 5


def test_a_hole_pinched_at_a_split_bow_tie_is_closed_whole():
    """Two square holes in a plane grid touching at one corner, that corner split into one copy
    per fan of skin (as the crop splits a scan's bow-ties: fresh37's ``n4303_icteye_dome_wide``),
    so the hole is one loop through both copies: the fill closes it completely, lobe by lobe,
    the copies welded into one vertex. Without the weld each lobe closed at its own copy and a
    sliver of boundary edges stayed open at the pinch, 1 mm from the eye's opening."""
    from pipeline.geometry import meshtopo

    n = 8
    xs, ys = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    V = np.c_[xs.ravel(), ys.ravel(), 0.01 * (xs.ravel() - 3.5) ** 2]
    cells = [(i, j) for i in range(n - 1) for j in range(n - 1) if (i, j) not in {(2, 2), (3, 3)}]
    F = np.concatenate([[[i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1],
                         [i * n + j, (i + 1) * n + j + 1, i * n + j + 1]] for i, j in cells])
    F, parent = meshtopo.split_fans(F, len(V))
    V = V[parent]
    assert len(V) == n * n + 1                              # the pinch in two copies
    loops = mc.boundary_loops(F)
    hole = next(lp for lp in loops if len(lp) == 8)
    assert len(np.unique(V[hole], axis=0)) == 7             # one loop through both copies
    V2, F2, unfilled = fill_holes_smooth(V, F, [hole], return_unfilled=True)
    assert unfilled == []
    left = mc.boundary_loops(F2)
    assert len(left) == 1 and len(left[0]) == 4 * (n - 1)   # only the grid's outer border
    e = np.sort(np.concatenate([F2[:, [0, 1]], F2[:, [1, 2]], F2[:, [2, 0]]]), axis=1)
    assert np.unique(e, axis=0, return_counts=True)[1].max() == 2
    N = meshtopo.face_normals(V2, F2)
    assert (N[:, 2] > 0).all()                              # every face up, the fill's as the skin's
    assert len(np.unique(F2)) == len(V2) - 1                # the other copy is left unused
