"""Keeping a moved or remeshed surface free of flipped faces.

Against a reference surface (the dense scan a low-poly mesh approximates): :func:`count_flipped`
counts the faces whose normal points against the reference's nearby normals; :func:`relax`
smooths tangentially without creating any; :func:`repair_flips`, :func:`mirror_flipped`,
:func:`collapse_flipped` and :func:`flip_slivers` repair them (retopology). Against per-face
reference normals: :func:`untangle` slides the free corners of flipped faces into the region
where all their faces keep their orientation (small linear programs; retopology and snap).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.geometry import mesh_checks as mc
from pipeline.geometry import meshtopo
from pipeline.geometry.mesh_edit import TriMesh


def reference_face_normals(V, F, ref_V, ref_F, nearest_faces=None, ref_normals=None):
    """Per face, the normalised sum of the reference surface's normals nearest its three vertices
    (``nearest_faces``: the reference face nearest each vertex, when already known;
    ``ref_normals``: ``mc.surface_face_normals(ref_V, ref_F)``, when already looked up)."""
    F = np.asarray(F, dtype=np.int64)
    fi = nearest_faces
    on = None
    if fi is None:
        # only F's own vertices are looked up: the band's quads and zip strips are judged against
        # a mesh of thousands of vertices (each point's answer is its own: the same faces)
        used = np.zeros(len(V), dtype=bool)
        used[F.ravel()] = True
        ids = None if used.all() else np.flatnonzero(used)
        P = V if ids is None else np.asarray(V)[ids]
        if len(np.asarray(P).reshape(-1, 3)):
            # the tree and the normals from one lookup of the scan
            on = mc.closest_points_on(ref_V, ref_F)
            found = on(P)[1]
        else:
            found = mc.closest_points(P, ref_V, ref_F)[1]
        if ids is None:
            fi = found
        else:
            fi = np.zeros(len(V), dtype=np.int64)
            fi[ids] = found
    if ref_normals is None:
        ref_normals = mc.surface_face_normals(ref_V, ref_F) if on is None else on.face_normals()
    vn = ref_normals[fi]
    n = vn[F].sum(axis=1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def relax(V, F, fixed, ref_V, ref_F, iterations=4, step=0.5, min_dot=0.3, memo=None):
    """Tangential Laplacian smoothing of free vertices, reprojected onto the reference surface.

    A face's orientation is judged against the reference surface's normals; a
    step that would turn a face further than ``min_dot`` (cosine) away from the
    reference, and away from where it was, is reverted for that face's vertices,
    so relaxing never creates flipped faces and can repair existing ones.

    ``memo``: optional dict kept by a caller that relaxes the same pieces of mesh against one
    reference surface again (the band's cut margins): the result of each local problem (the faces
    round the free vertices, renumbered), keyed by its bytes.
    """
    V_all = np.asarray(V, dtype=np.float64).copy()
    if iterations <= 0:
        return V_all
    free = np.ones(len(V_all), dtype=bool)
    free[np.asarray(fixed, dtype=np.int64)] = False
    # only the faces round a free vertex can move or turn: the rest are left out of every pass
    # (the band's zip relaxes a few hundred vertices of a mesh of thousands, 72 passes), and the
    # passes run on those faces' vertices alone, renumbered in the same order: every step is per
    # vertex or per face (sums over a vertex's faces and neighbours in the same order), so the
    # same bits as on the whole mesh
    F = np.asarray(F, dtype=np.int64)
    F = F[free[F].any(axis=1)]
    if len(F) == 0:
        return V_all
    used = np.unique(F)
    remap = np.zeros(len(V_all), dtype=np.int64)
    remap[used] = np.arange(len(used))
    F = remap[F]
    V = V_all[used]
    free = free[used]
    key = None
    if memo is not None:
        import hashlib

        h = hashlib.blake2b(repr((iterations, step, min_dot, V.shape, F.shape)).encode(), digest_size=16)
        for a in (V, F, free):
            h.update(np.ascontiguousarray(a).tobytes())
        key = h.digest()
        if key in memo:
            V_all[used] = memo[key]
            return V_all
    A = meshtopo.vertex_adjacency(F, len(V))
    deg = np.asarray(A.sum(axis=1)).ravel()
    near = None
    closest = mc.closest_points_on(ref_V, ref_F)        # the scan's tree looked up once, not per pass
    ref_normals = closest.face_normals()
    for _ in range(iterations):
        N = mc.vertex_normals(V, F)
        if near is None:                    # later passes: the faces the projection below landed on
            near = closest(V)[1]
        R = reference_face_normals(V, F, ref_V, ref_F, nearest_faces=near, ref_normals=ref_normals)
        d0 = np.einsum("ij,ij->i", mc.face_normals(V, F), R)
        L = (A @ V) / np.maximum(deg, 1)[:, None] - V
        L -= np.einsum("ij,ij->i", L, N)[:, None] * N
        Vn = V.copy()
        Vn[free] += step * L[free]
        _, fi, C = closest(Vn[free])
        Vn[free] = C
        # a projected vertex lies on face fi: no second query of where it now is. Not the same
        # answer by construction (a point on an edge ties with the face across it), but the same
        # retopo bytes on the 1.4M head and its tests
        near_n = near.copy()
        near_n[free] = fi
        d1 = np.einsum("ij,ij->i", mc.face_normals(Vn, F), R)
        bad = (d1 < min_dot) & (d1 < d0)
        if bad.any():
            back = np.unique(F[bad])
            Vn[back] = V[back]
            near_n[back] = near[back]
        V, near = Vn, near_n
    V_all[used] = V
    if key is not None:
        memo[key] = V
    return V_all


def repair_flips(V, F, fixed, ref_V, ref_F, rounds=10):
    """Move the free vertices of flipped faces to the mean of their neighbours (then onto the
    reference surface when that keeps the face unflipped); returns new V."""
    V = np.asarray(V, dtype=np.float64).copy()
    A = meshtopo.vertex_adjacency(F, len(V))
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1)
    free = np.ones(len(V), dtype=bool)
    free[np.asarray(fixed, dtype=np.int64)] = False
    last = None
    for _ in range(rounds):
        R = reference_face_normals(V, F, ref_V, ref_F)
        bad = np.einsum("ij,ij->i", mc.face_normals(V, F), R) <= 0.05
        if not bad.any() or (last is not None and bad.sum() >= last):
            break
        last = int(bad.sum())
        mv = np.unique(F[bad])
        mv = mv[free[mv]]
        if len(mv) == 0:
            break
        avg = (A[mv] @ V) / deg[mv, None]
        Vt = V.copy()
        Vt[mv] = avg
        _, _, C = mc.closest_points(avg, ref_V, ref_F)
        Vp = Vt.copy()
        Vp[mv] = C
        R2 = reference_face_normals(Vp, F, ref_V, ref_F)
        if np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(Vp, F), R2) <= 0) <= \
                np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(Vt, F), R2) <= 0):
            V = Vp
        else:
            V = Vt
    return V


def mirror_flipped(V, F, fixed, ref_V, ref_F):
    """Flipped faces with one free corner ``c`` and a fixed edge ``a-b`` (slivers at the eyelid
    loop): move ``c`` to the inner side of the edge, a third of the edge length from it, keeping
    the move only when it lowers the number of flipped faces."""
    V = np.asarray(V, dtype=np.float64).copy()
    fixed_m = np.zeros(len(V), dtype=bool)
    fixed_m[np.asarray(fixed, dtype=np.int64)] = True
    R = reference_face_normals(V, F, ref_V, ref_F)
    dots = np.einsum("ij,ij->i", mc.face_normals(V, F), R)
    for f in np.flatnonzero(dots <= 0):
        face = F[f]
        free = [k for k in range(3) if not fixed_m[face[k]]]
        if len(free) != 1:
            continue
        k = free[0]
        c, a, b = face[k], face[(k + 1) % 3], face[(k + 2) % 3]
        e = V[b] - V[a]
        inward = np.cross(R[f], e)          # for face (c, a, b) wound CCW about R, c lies on this side
        inward /= max(np.linalg.norm(inward), 1e-300)
        mid = 0.5 * (V[a] + V[b])
        before = count_flipped(V, F, ref_V, ref_F)
        old = V[c].copy()
        V[c] = mid + inward * np.linalg.norm(e) / 3.0
        if count_flipped(V, F, ref_V, ref_F) >= before:
            V[c] = old
    return V


def flip_slivers(V, F, ref_V, ref_F, min_angle_deg=10.0):
    """Flip the longest edge of sliver triangles (min angle below ``min_angle_deg``) when the edge
    is interior and both new triangles are better shaped and agree with the reference normal."""
    ang = mc.triangle_angles_deg(V, F)
    bad = np.flatnonzero(ang.min(axis=1) < min_angle_deg)
    if len(bad) == 0:
        return F
    R = reference_face_normals(V, F, ref_V, ref_F)
    tm = TriMesh(V, F)
    on_border = np.zeros(len(V), dtype=bool)
    for lp in mc.boundary_loops(F):
        on_border[lp] = True
    key = {tuple(f): i for i, f in enumerate(F.tolist())}
    P = np.array(tm.V)                  # flips move no vertex: gathered once, not per sliver
    for f in bad[np.argsort(ang[bad].min(axis=1))]:
        fi = key.get(tuple(F[f].tolist()))
        if fi is None or fi not in tm.F or tm.F[fi] != list(F[f]):
            continue
        face = tm.F[fi]
        k = int(np.argmax(ang[f]))                 # largest angle; its opposite edge is the longest
        a, c = face[(k + 1) % 3], face[(k + 2) % 3]
        twins = [g for g in tm.vf[a] & tm.vf[c] if g != fi]
        if len(twins) != 1:
            continue
        # a flip takes one face from a and from c: never leave a border vertex with a single
        # face (an 'ear' whose three corners lie on an eyelid loop is degenerate or inverted
        # on the convex opening and flips when snap moves the loop) or an interior vertex with
        # fewer than three
        if any(len(tm.vf[v]) <= (2 if on_border[v] else 3) for v in (a, c)):
            continue
        g = twins[0]
        old_min = min(ang[f].min(), mc.triangle_angles_deg(P, np.array([tm.F[g]])).min())
        b = face[k]
        d = [v for v in tm.F[g] if v not in (a, c)][0]
        new = np.array([[a, b, d], [b, c, d]])
        if mc.triangle_angles_deg(P, new).min() <= old_min:
            continue
        tm.flip_edge(fi, a, c, R[f], min_cos=0.3)
    Vn, Fn, _ = tm.arrays()
    return Fn


def _corner_deg(P, at, u, w):
    a, b = P[u] - P[at], P[w] - P[at]
    # np.linalg.norm's own sqrt(x.dot(x)) without its argument handling (~15k calls a retopo)
    c = float(a @ b) / max(math.sqrt(float(a.dot(a))) * math.sqrt(float(b.dot(b))), 1e-300)
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _delaunay_tests(V, tm: TriMesh, margin_deg=1e-4, keyed=True):
    """:func:`delaunay_flips`' test (are the angles facing edge a-c from b and d at most 180 deg?)
    of the manifold interior edges of ``tm``, keyed (b, a, c, d) as the flip loop reads them, and
    the set of face ids with an edge that fails the test or is left to the scalar test: the faces
    a pass has to visit (every other face's three edges are either not shared by exactly two
    faces or Delaunay, and the loop passes them by). ``keyed=False``: the set alone (an empty dict).

    Vectorised over the edges, the sums can differ from :func:`_corner_deg`'s scalar ones in the
    last bits (acos near 180 deg amplifies that to ~1e-6 deg): sums within ``margin_deg`` of the
    threshold are left out, so the scalar test decides those, and the flips are the same."""
    fids = np.array(list(tm.F), dtype=np.int64)
    if len(fids) == 0:
        return {}, set()
    Fa = np.array(list(tm.F.values()), dtype=np.int64)        # in fids' order
    m = len(Fa)
    b = Fa.ravel()                                          # half-edge (face j, corner k): b, a, c
    a = np.roll(Fa, -1, axis=1).ravel()
    c = np.roll(Fa, -2, axis=1).ravel()
    lo, hi = np.minimum(a, c), np.maximum(a, c)
    key = lo * (int(max(hi.max(), 0)) + 1) + hi
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.r_[True, ks[1:] != ks[:-1]]
    run = np.diff(np.r_[np.flatnonzero(start), len(ks)])
    two = np.repeat(run == 2, run)                          # edges with exactly two faces
    first = order[start & two]
    second = order[np.r_[start[1:], True] & two]
    h = np.concatenate([first, second])                     # each half-edge and its twin's
    t = np.concatenate([second, first])
    P = np.asarray(V, dtype=np.float64)

    def corner(at, u, w):
        x, y = P[u] - P[at], P[w] - P[at]
        cs = np.einsum("ij,ij->i", x, y) / np.maximum(np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1), 1e-300)
        return np.degrees(np.arccos(np.clip(cs, -1.0, 1.0)))

    d = b[t]
    total = corner(b[h], a[h], c[h]) + corner(d, a[h], c[h])
    sure = np.abs(total - (180.0 + 1e-6)) > margin_deg
    ok = total <= 180.0 + 1e-6
    # a face with a repeated corner is always visited (its edges' twin counts are not the
    # half-edge counts above)
    visit = (Fa[:, 0] == Fa[:, 1]) | (Fa[:, 1] == Fa[:, 2]) | (Fa[:, 0] == Fa[:, 2])
    visit[h[~(sure & ok)] // 3] = True
    sel = np.flatnonzero(sure) if keyed else np.zeros(0, dtype=np.int64)
    return (dict(zip(zip(b[h][sel].tolist(), a[h][sel].tolist(), c[h][sel].tolist(), d[sel].tolist()),
                     ok[sel].tolist())),
            set(fids[visit].tolist()))


def delaunay_flips(V, F, max_dihedral_deg=20.0, min_cos=0.5, passes=8):
    """Flip interior edges that are not locally Delaunay (the two angles facing the edge sum past
    180 deg) where its two faces are nearly coplanar, until none is left (or ``passes``).

    Remeshing and the loop placement leave slivers whose long edge faces an angle near 180 deg:
    a vertex lying almost on the edge of two others. Flipping that edge removes the sliver
    without moving a vertex (so the surface and the loops stay where they are); the dihedral
    bound keeps the flips from changing the shape, and each new face must stay within
    ``acos(min_cos)`` of the pair's normal. A border vertex keeps at least two faces and an
    interior one three.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64

    Returns
    -------
    F2 : (m, 3) int64
        The same vertices, flipped faces (face count unchanged).
    n_flips : int
    """
    V = np.asarray(V, dtype=np.float64)
    tm = TriMesh(V, F)
    on_border = np.zeros(len(V), dtype=bool)
    for lp in mc.boundary_loops(np.asarray(F, dtype=np.int64)):
        on_border[lp] = True
    cos_dih = math.cos(math.radians(max_dihedral_deg))
    n_flips = 0
    # the vertices never move, so an edge's Delaunay test and its two faces' dihedral test give
    # the same answer on every pass: each is computed once (all edges at once on the first pass)
    delaunay_ok, dihedral = {}, {}
    for _ in range(passes):
        flipped = 0
        # only the faces with an edge that may flip, and those a flip of this pass has touched
        # (every face round its four corners: their edges' twins or opposite corners changed),
        # can flip anything: the others are passed by, the same faces visited in the same order
        tests, visit = _delaunay_tests(V, tm, keyed=not delaunay_ok)
        delaunay_ok.update(tests)
        for fi in list(tm.F):
            if fi not in visit or fi not in tm.F:
                continue
            for k in range(3):
                f = tm.F[fi]
                b, a, c = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
                twins = [g for g in tm.vf[a] & tm.vf[c] if g != fi]
                if len(twins) != 1:
                    continue
                g = twins[0]
                d = [v for v in tm.F[g] if v not in (a, c)][0]
                ok = delaunay_ok.get((b, a, c, d))
                if ok is None:
                    ok = delaunay_ok[(b, a, c, d)] = (_corner_deg(V, b, a, c) + _corner_deg(V, d, a, c)
                                                      <= 180.0 + 1e-6)
                if ok:
                    continue
                if any(len(tm.vf[v]) <= (2 if on_border[v] else 3) for v in (a, c)):
                    continue
                key = (tuple(f), tuple(tm.F[g]))
                ref = dihedral.get(key, False)
                if ref is False:
                    n1, _ = tm.normal(f)
                    n2, _ = tm.normal(tm.F[g])
                    if float(n1 @ n2) < cos_dih:
                        ref = None
                    else:
                        ref = n1 + n2
                        ref = ref / max(float(np.linalg.norm(ref)), 1e-300)
                    dihedral[key] = ref
                if ref is None:
                    continue
                if tm.flip_edge(fi, a, c, ref=ref, min_cos=min_cos):
                    flipped += 1
                    for v in tm.F[fi] + tm.F[g]:
                        visit.update(tm.vf[v])
                    break
        n_flips += flipped
        if flipped == 0:
            break
    return np.array(list(tm.F.values()), dtype=np.int64), n_flips


def collapse_flipped(V, F, loops, fixed, ref_V, ref_F):
    """Remove flipped faces by collapsing their free vertex into one of the face's other corners."""
    R = reference_face_normals(V, F, ref_V, ref_F)
    bad = np.flatnonzero(np.einsum("ij,ij->i", mc.face_normals(V, F), R) <= 0)
    fixed = set(map(int, fixed))
    tm = TriMesh(V, F)
    for f in bad:
        face = F[f]
        fl = face.tolist()                  # one list, not a numpy conversion per face compared
        fi = [k for k, g in tm.F.items() if g == fl]
        if not fi:
            continue
        if any(tm.flip_edge(fi[0], int(face[i]), int(face[(i + 1) % 3]), R[f]) for i in range(3)):
            continue
        for c in face:
            if int(c) in fixed or not tm.vf.get(int(c)):
                continue
            done = False
            for t in face:
                if t != c and tm.collapse(int(c), int(t), min_cos=0.05, ref=R[f]):
                    done = True
                    break
            if done:
                break
    Vn, Fn, remap = tm.arrays()
    return Vn, Fn, {k: remap[v] for k, v in loops.items()}


def collapse_short_edges(V, F, loops, fixed, min_len: float, min_cos: float = 0.5,
                         coincident: float = 0.0):
    """Collapse edges shorter than ``min_len`` by merging their free end into the other end.

    The flip repairs next to the loops can leave edges a tenth of the mesh's length beside a
    canthus; their faces are slivers that turn over as soon as the lids move. A vertex in
    ``fixed`` never moves; a collapse that would turn a moved face more than ``acos(min_cos)``
    is refused (:meth:`TriMesh.collapse`). On an edge shorter than ``coincident`` a vertex of
    ``fixed`` outside ``loops`` whose only faces are the edge's goes, those faces with it, and
    the other end takes its place: the decimation can leave a crop-border vertex on the very
    point of an inner one, its two faces of zero area, which nothing else removes
    (``n1702_big_holes_near``: 1.6e-8 mm apart, and retopo refused the head).

    Returns
    -------
    V2, F2 : the mesh without the collapsed vertices
    loops : dict
        ``loops`` with their vertex indices remapped.
    n : int
        Collapses done.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    E = mc.edges_of(F)
    E = np.unique(np.sort(E, axis=1), axis=0)
    L = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    short = np.flatnonzero(L < min_len)
    if len(short) == 0:
        return V, F, dict(loops), 0
    fixed = set(map(int, fixed))
    tm = TriMesh(V, F)
    n = 0
    on_loops = set(np.concatenate([np.asarray(v, dtype=np.int64) for v in loops.values()]).tolist()) if loops else set()
    for e in short[np.argsort(L[short])]:
        a, b = map(int, E[e])
        if not tm.vf.get(a) or not tm.vf.get(b) or b not in tm.neighbours(a):
            continue
        for src, dst in ((a, b), (b, a)):
            if src not in fixed and tm.collapse(src, dst, min_cos=min_cos):
                n += 1
                break
        else:
            if L[e] < coincident:
                for src, dst in ((a, b), (b, a)):
                    if (src not in on_loops and all(dst in tm.F[fi] for fi in tm.vf[src])
                            and tm.collapse(src, dst, min_cos=min_cos, lone=True)):
                        n += 1
                        break
    if n == 0:
        return V, F, dict(loops), 0
    Vn, Fn, remap = tm.arrays()
    return Vn, Fn, {k: remap[v] for k, v in loops.items()}, n


def count_flipped(V, F, ref_V, ref_F, nearest_faces=None):
    """Faces whose normal points against the reference surface's nearby normals
    (``nearest_faces``: :func:`reference_face_normals`')."""
    R = reference_face_normals(V, F, ref_V, ref_F, nearest_faces)
    return int(np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(V, F), R) <= 0))


def untangle(V, F, ref_normals, free, keep_out=None, rounds=30, max_step=None, min_projected=None,
             max_total=None):
    """Move free vertices of flipped faces tangentially until no face points against its reference.

    A face (a, b, v) with ``a``, ``b`` held has normal ``(b - a) x (v - a)``, whose dot product
    with the face's reference normal ``r`` is ``(v - a) . (r x (b - a))``: linear in ``v``. So
    with its neighbours held, the positions of ``v`` that leave all its faces unflipped form a
    convex region (the kernel of its one-ring, seen along the references). Each round visits
    the free corners of the flipped faces one by one (Gauss-Seidel) and solves two small linear
    programs in the tangent plane of the vertex (normal = mean reference normal of its faces):
    the largest reachable clearance ``t*`` from every face's edge line, then the smallest move
    (L1) that reaches ``t*/2``. A vertex whose region is empty within ``max_step`` stays.
    With ``min_projected`` a face also counts as bad (and is kept above it) while its doubled
    area seen along its reference, ``n . r / |r|``, is at most that value (near-flipped slivers).

    Parameters
    ----------
    V : (n, 3) float64
        Current positions.
    F : (m, 3) int64
    ref_normals : (m, 3) float64
        Reference direction per face (any length), e.g. the rest normals.
    free : (n,) bool
        Vertices that may move.
    keep_out : callable, optional
        ``keep_out(P) -> (Q, N, d)`` closest surface points, unit normals and signed distances
        (e.g. :meth:`pipeline.snap.snap.EyeballSurface.closest`); moved vertices stay on the outer
        side of the surface's tangent plane at their closest point (outside a convex surface).
    rounds : int
    max_step : float, optional
        Largest move per coordinate and round, mm (default: the vertex's longest edge).
    min_projected : (m,) float64, optional
        Smallest acceptable doubled projected area per face, mm^2 (default 0: flips only).
    max_total : float or (n,) float64, optional
        Farthest a vertex may end from where it started, per tangent coordinate, mm (default:
        no limit). The rounds' steps add up: a vertex whose faces cannot all clear keeps taking
        its least-violation step, and without a limit walked 49 mm off id309_squint_up's upper
        lid (30 rounds of its 1.7 mm edges) into the middle of the face.

    Returns
    -------
    V2 : (n, 3) float64
    moved : (k,) int64
        Vertices that were moved.
    """
    from scipy.optimize import linprog

    V = np.array(V, dtype=np.float64, copy=True)
    F = np.asarray(F, dtype=np.int64)
    R = np.asarray(ref_normals, dtype=np.float64)
    R = R / np.maximum(np.linalg.norm(R, axis=1, keepdims=True), 1e-300)
    free = np.asarray(free, dtype=bool)
    need = np.zeros(len(F)) if min_projected is None else np.asarray(min_projected, np.float64)
    order = np.argsort(F.ravel(), kind="stable")
    starts = np.searchsorted(F.ravel()[order], np.arange(len(V) + 1))
    moved = set()
    start = V.copy()
    limit = None if max_total is None else np.broadcast_to(np.asarray(max_total, np.float64), (len(V),))

    def faces_of(v):
        return order[starts[v]:starts[v + 1]] // 3

    def bad_faces():
        n = meshtopo.triangle_cross(V, F)
        return np.flatnonzero(np.einsum("ij,ij->i", n, R) <= need)

    for _ in range(rounds):
        bad = bad_faces()
        if len(bad) == 0:
            break
        cand = np.unique(F[bad].ravel())
        cand = cand[free[cand]]
        if len(cand) == 0:
            break
        changed = False
        for v in cand:
            fs = faces_of(v)
            x0 = V[v]
            rows, rhs, extra = [], [], []
            for fi in fs:
                f = F[fi]
                k = int(np.flatnonzero(f == v)[0])
                a, b = V[f[(k + 1) % 3]], V[f[(k + 2) % 3]]
                g = np.cross(R[fi], b - a)
                gn = np.linalg.norm(g)
                if gn < 1e-12:
                    continue
                rows.append(g / gn)
                rhs.append(float((g / gn) @ a))
                extra.append(need[fi] / gn)
            if not rows:
                continue
            G = np.array(rows)
            nrm = R[fs].sum(axis=0)
            if np.linalg.norm(nrm) < 1e-12:
                continue
            nrm /= np.linalg.norm(nrm)
            e1 = np.cross(nrm, [1.0, 0.0, 0.0])
            if np.linalg.norm(e1) < 0.1:
                e1 = np.cross(nrm, [0.0, 1.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(nrm, e1)
            E = np.stack([e1, e2], axis=1)                        # x = x0 + E @ (alpha, beta)
            A = G @ E                                              # slack_k = A_k . ab + s0_k
            step = max_step
            if step is None:
                step = float(np.max(np.linalg.norm(V[F[fs]] - x0, axis=2)))
            box = [(-step, step), (-step, step)]
            if limit is not None:
                # the tangent coordinates of the way already gone, kept within +-limit in all
                o = E.T @ (x0 - start[v])
                box = [(max(-step, min(0.0, -limit[v] - o[i])), min(step, max(0.0, limit[v] - o[i])))
                       for i in range(2)]
            A_ub, b_ub = [], []
            if keep_out is not None:
                Q, Nq, _ = keep_out(x0[None])
                # stay outside: Nq . (x - Q) >= 0
                A_ub.append(np.concatenate([-(Nq[0] @ E), [0.0]]))
                b_ub.append(float(Nq[0] @ (x0 - Q[0])))
            ko_rows = [np.array(A_ub)] if A_ub else []
            bounds = box + [(None, step)]
            A1 = np.hstack([-A, np.ones((len(A), 1))])

            def max_clearance(s0, floor=None):
                """max t: slack_k = A_k . ab + s0_k >= t (and A_k . ab + s_flip_k >= floor)."""
                rows, rhs_ = [A1] + ko_rows, [s0, b_ub]
                if floor is not None:
                    rows.append(np.hstack([-A, np.zeros((len(A), 1))]))
                    rhs_.append(floor[0] - floor[1])
                return linprog([0.0, 0.0, -1.0], A_ub=np.vstack(rows),
                               b_ub=np.concatenate(rhs_), bounds=bounds, method="highs")

            s_flip = G @ x0 - np.array(rhs)                        # projected heights
            s_need = s_flip - np.array(extra)                      # ... above the area floor
            lpf = max_clearance(s_flip)
            t_flip = -lpf.fun if lpf.status == 0 else -np.inf
            floor = (s_flip, 0.5 * t_flip) if t_flip > 0 else None
            lp1 = max_clearance(s_need, floor)
            if lp1.status != 0:
                continue
            if -lp1.fun <= 0:
                # no spot clears every floor: take the one with the least violation when it
                # improves on the current one (its neighbours' faces then turn bad and get
                # their own turn, spreading the correction into the free zone)
                if -lp1.fun > s_need.min() + 1e-9:
                    V[v] = x0 + E @ lp1.x[:2]
                    moved.add(int(v))
                    changed = True
                continue
            want = 0.5 * (-lp1.fun)
            # smallest L1 move reaching half that clearance: variables (ab+, ab-) >= 0
            A_ub2 = [np.hstack([-A, A])]
            b_ub2 = [s_need - want]
            if floor is not None:
                A_ub2.append(np.hstack([-A, A]))
                b_ub2.append(s_flip - 0.5 * t_flip)
            if A_ub:
                ko = np.array(A_ub)[:, :2]
                A_ub2.append(np.hstack([ko, -ko]))
                b_ub2.append(np.array(b_ub))
            # (ab+, ab-) >= 0 within the same box: ab+ <= max(hi, 0), ab- <= max(-lo, 0)
            lp2 = linprog(np.ones(4), A_ub=np.vstack(A_ub2), b_ub=np.concatenate(b_ub2),
                          bounds=[(0, max(box[0][1], 0.0)), (0, max(box[1][1], 0.0)),
                                  (0, max(-box[0][0], 0.0)), (0, max(-box[1][0], 0.0))], method="highs")
            ab = (lp2.x[:2] - lp2.x[2:]) if lp2.status == 0 else lp1.x[:2]
            V[v] = x0 + E @ ab
            moved.add(int(v))
            changed = True
        if not changed:
            break
    return V, np.array(sorted(moved), dtype=np.int64)


def move_guarded(V, F, loop, target, min_cos=0.5, min_area_ratio=0.1, halvings=4):
    """Move ``V[loop]`` (in place) toward ``target`` (k, 3) without folding the faces around it.

    A face touching the loop must keep its normal within ``acos(min_cos)`` of where it was and
    at least ``min_area_ratio`` of its area; the move of each loop vertex of a face that does
    not is halved, ``halvings`` tries in all, after which the whole move is dropped. Returns
    the mean move, mm."""
    loop = np.asarray(loop)
    start = V[loop].copy()
    on = np.zeros(len(V), bool)         # a vertex mask: np.isin sorted the whole mesh's indices
    on[loop] = True
    Fa = F[meshtopo.faces_touching(F, on)]

    def normals(X):
        return np.cross(X[Fa[:, 1]] - X[Fa[:, 0]], X[Fa[:, 2]] - X[Fa[:, 0]])

    N0 = normals(V)
    A0 = np.linalg.norm(N0, axis=1)
    frac = np.ones(len(loop))
    for _ in range(halvings):
        V[loop] = start + frac[:, None] * (target - start)
        N1 = normals(V)
        A1 = np.linalg.norm(N1, axis=1)
        bad = ((N0 * N1).sum(axis=1) < min_cos * A0 * A1) | (A1 < min_area_ratio * A0)
        if not bad.any():
            break
        frac[np.isin(loop, Fa[bad])] *= 0.5
    else:
        V[loop] = start
    return float(np.linalg.norm(V[loop] - start, axis=1).mean())
