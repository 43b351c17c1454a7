"""Local edits of a triangle mesh: a tiny editable mesh (edge collapses, boundary-edge splits and
edge flips) and hole filling.

:class:`TriMesh`: Python dicts, for the few hundred edits of the retopology's loop resampling and
flip repairs (:mod:`pipeline.retopo.eyelid_loop`, :mod:`pipeline.geometry.flips`).
:func:`fill_holes_near`: the holes near given points closed with fans (the unmeasured pupils
that remove_eyeballs closes before it places the eyes). :func:`fill_holes_smooth`: given holes
closed with patches that continue the surface round them (the scanner's holes in the skin that
retopo fills inside its crop).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.geometry import meshtopo


class TriMesh:
    """Tiny editable triangle mesh for boundary collapses/splits (Python dicts; a few hundred ops)."""

    def __init__(self, V, F):
        # rows of one float64 array and faces from one tolist(): the same values as converting
        # each row on its own, without a numpy call per row (13k faces, 9 meshes a retopo)
        self.V = list(np.asarray(V, dtype=np.float64))
        Fa = np.asarray(F, dtype=np.int64).reshape(-1, 3)
        self.F = dict(enumerate(Fa.tolist()))
        # each vertex's face set filled in face order and the vertices keyed in order of first
        # appearance, as adding face by face would (the sets' and dict's iteration orders are
        # read by the edits), from one stable sort instead of an add per corner
        flat = Fa.ravel()
        order = np.argsort(flat, kind="stable")
        sv = flat[order]
        starts = np.flatnonzero(np.r_[True, sv[1:] != sv[:-1]]) if len(sv) else np.zeros(0, dtype=np.int64)
        bounds = np.r_[starts, len(sv)].tolist()
        verts, faces = sv[starts].tolist(), (order // 3).tolist()
        self.vf = {verts[k]: set(faces[bounds[k]:bounds[k + 1]]) for k in np.argsort(order[starts]).tolist()}
        self.next_f = len(F)

    def normal(self, f, pos=None):
        P = [self.V[v] if pos is None or v not in pos else pos[v] for v in f]
        # np.cross's own products and differences on Python floats (the same bits, without its
        # array set-up on every one of ~10k calls in a retopo)
        u0, u1, u2 = (P[1] - P[0]).tolist()
        w0, w1, w2 = (P[2] - P[0]).tolist()
        n = np.array([u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0])
        ln = math.sqrt(float(n.dot(n)))      # np.linalg.norm's own sqrt(n.dot(n))
        return n / ln if ln > 0 else n, 0.5 * ln

    def neighbours(self, v):
        out = set()
        for fi in self.vf.get(v, ()):
            out.update(self.F[fi])
        out.discard(v)
        return out

    def collapse(self, a, b, min_cos=0.2, ref=None):
        """Collapse vertex ``a`` into ``b`` (along an edge). Returns False if refused.

        ``ref`` (3,) optional reference normal the moved faces must agree with
        (used to repair faces that are already flipped)."""
        common = [fi for fi in self.vf[a] if b in self.F[fi]]
        if len(common) not in (1, 2):
            return False
        opp = {[v for v in self.F[fi] if v not in (a, b)][0] for fi in common}
        if self.neighbours(a) & self.neighbours(b) != opp:
            return False
        moved = [fi for fi in self.vf[a] if fi not in common]
        if not moved:
            return False
        for fi in moved:
            n0, _ = self.normal(self.F[fi])
            nf = [b if v == a else v for v in self.F[fi]]
            n1, area = self.normal(nf)
            if area <= 1e-12 or float((n0 if ref is None else ref) @ n1) < min_cos:
                return False
        for fc in common:
            for v in self.F[fc]:
                self.vf[v].discard(fc)
            del self.F[fc]
        for fi in moved:
            self.F[fi] = [b if v == a else v for v in self.F[fi]]
            self.vf[b].add(fi)
        self.vf[a] = set()
        return True

    def split(self, a, b, p):
        """Split boundary edge a->b (directed as in its face) at point ``p``; returns new vertex."""
        common = [fi for fi in self.vf[a] if b in self.F[fi]]
        fi = common[0]
        f = self.F[fi]
        c = [v for v in f if v not in (a, b)][0]
        # rotate so the face reads (x, y, c) with x->y the shared edge in face order
        k = f.index(c)
        x, y = f[(k + 1) % 3], f[(k + 2) % 3]
        m = len(self.V)
        self.V.append(np.asarray(p, dtype=np.float64))
        self.F[fi] = [x, m, c]
        self.vf[y].discard(fi)
        self.vf.setdefault(m, set()).add(fi)
        nf = self.next_f
        self.next_f += 1
        self.F[nf] = [m, y, c]
        for v in (m, y, c):
            self.vf[v].add(nf)
        return m

    def flip_edge(self, fi, a, c, ref=None, min_cos=0.05):
        """Flip edge a-c of face ``fi`` (which reads (a, b, c) cyclically) with its twin, if the two
        new faces agree with ``ref`` (default: the twin's normal); returns True when done."""
        f = self.F[fi]
        twins = [g for g in self.vf[a] & self.vf[c] if g != fi]
        if len(twins) != 1:
            return False
        b = [v for v in f if v not in (a, c)][0]
        k = f.index(b)
        a, c = f[(k - 1) % 3], f[(k + 1) % 3]
        g = twins[0]
        fg = self.F[g]
        d = [v for v in fg if v not in (a, c)][0]
        if d in self.neighbours(b):
            return False
        if ref is None:
            ref = self.normal(fg)[0]
        n1, ar1 = self.normal([a, b, d])
        n2, ar2 = self.normal([b, c, d])
        if ar1 <= 1e-12 or ar2 <= 1e-12 or n1 @ ref <= min_cos or n2 @ ref <= min_cos:
            return False
        for v in f:
            self.vf[v].discard(fi)
        for v in fg:
            self.vf[v].discard(g)
        self.F[fi] = [a, b, d]
        self.F[g] = [b, c, d]
        for v in (a, b, d):
            self.vf[v].add(fi)
        for v in (b, c, d):
            self.vf[v].add(g)
        return True

    def flip_ears(self, min_cos=0.0):
        """Flip away 'ear' triangles (a boundary vertex with a single face) where possible."""
        flipped = 0
        for b in [v for v, fs in self.vf.items() if len(fs) == 1]:
            if len(self.vf[b]) != 1:
                continue
            fi = next(iter(self.vf[b]))
            f = self.F[fi]
            k = f.index(b)
            a, c = f[(k - 1) % 3], f[(k + 1) % 3]       # face reads (a, b, c)
            flipped += self.flip_edge(fi, a, c, min_cos=min_cos)
        return flipped

    def arrays(self):
        F = np.array(list(self.F.values()), dtype=np.int64)
        V = np.array(self.V, dtype=np.float64)
        used = np.unique(F)
        remap = -np.ones(len(V), dtype=np.int64)
        remap[used] = np.arange(len(used))
        return V[used], remap[F], remap


def fill_holes_near(V, F, centres, near_mm, max_perimeter_mm):
    """Close the mesh's holes near ``centres`` with a fan around each hole's centroid.

    Scanners often leave the dark pupil and iris unmeasured: a hole in the eye opening. The eye fit
    and the cut run on the closed surface (:mod:`pipeline.remove_eyeballs.remove_eyeballs` then
    gives each hole to the opening or to the skin).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    centres : list of (3,) float64
    near_mm : float
        A hole is closed when one of its vertices lies this close to a centre ...
    max_perimeter_mm : float
        ... and its perimeter is at most this.

    Returns
    -------
    V2 : (n + k, 3) float64
        ``V`` and one centroid vertex per closed hole.
    F2 : (m + f, 3) int64
        ``F`` and the fan faces (appended, so face ``i < m`` is still face ``i`` of ``F``).
    holes : list of (L,) int64
        The closed holes' loops (vertex ids), in the order of their centroid vertices.
    hole_of_face : (m + f,) int64
        -1 for the faces of ``F``, else the hole index.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    C = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    H = meshtopo.boundary_halfedges(F)
    loops = []
    if len(H):
        # each connected piece of the boundary near a centre that is one simple loop
        bv, Hc = np.unique(H, return_inverse=True)
        Hc = Hc.reshape(-1, 2)
        g = coo_matrix((np.ones(len(Hc)), (Hc[:, 0], Hc[:, 1])), shape=(len(bv), len(bv)))
        _, comp = connected_components(g, directed=False)
        near = np.linalg.norm(V[bv][:, None, :] - C[None], axis=2).min(axis=1) <= near_mm
        for k in np.unique(comp[near]):
            try:
                loops += meshtopo.boundary_loops(F, only=bv[comp == k], H=H)
            except ValueError:      # a bow-tie boundary: left as it is
                pass
    newV, newF, holes, owner = [], [], [], []
    for loop in loops:
        P = V[loop]
        per = float(np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).sum())
        if per > max_perimeter_mm or len(loop) < 3:
            continue
        if np.linalg.norm(P[:, None, :] - C[None], axis=2).min() > near_mm:
            continue
        k = len(holes)
        c = len(V) + k
        # the boundary half-edge a -> b belongs to a face; the fill face runs b -> a
        newF.append(np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), c)]))
        newV.append(P.mean(axis=0))
        holes.append(np.asarray(loop, dtype=np.int64))
        owner.append(np.full(len(loop), k))
    if not holes:
        return V, F, [], np.full(len(F), -1, dtype=np.int64)
    V2 = np.concatenate([V, np.asarray(newV)])
    F2 = np.concatenate([F, *newF]).astype(np.int64)
    return V2, F2, holes, np.concatenate([np.full(len(F), -1), *owner]).astype(np.int64)


def fill_holes_smooth(V, F, loops, neighbourhood: float = 1.5):
    """Close each boundary loop in ``loops`` with a patch that continues the surface round it.

    Scanners leave small holes in the skin (a shadowed pore, a specular spot). Left open they are
    black spots in every render, and a flat fan over one reads as a dent on a curved brow. Here a
    hole gets a polar grid: concentric rings of as many vertices as the loop (about one ring
    per mean loop edge length) and a fan at the centre. The grid's interior is placed, in the plane of the surrounding faces' mean normal, by
    the harmonic extension of the loop (each inner vertex the mean of its neighbours, so the
    rings follow a jagged loop smoothly), and lifted onto a quadratic height field fitted to the
    vertices within ``neighbourhood`` hole radii of the centroid.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    loops : list of (L,) int64
        Boundary loops of ``F`` (either direction; each is oriented by its boundary half-edges).
    neighbourhood : float
        The height field's support radius, in hole radii.

    Returns
    -------
    V2 : (n + k, 3) float64
        ``V`` and the fill's vertices (appended).
    F2 : (m + f, 3) int64
        ``F`` and the fill faces (appended, so face ``i < m`` is still face ``i`` of ``F``),
        oriented like the faces round each hole.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if not loops:
        return V, F
    H = meshtopo.boundary_halfedges(F)
    n = len(V)
    keys = set((H[:, 0] * n + H[:, 1]).tolist())
    FN = meshtopo.face_normals(V, F, normalize=False)
    newV, newF = [], []
    nv = n
    for loop in loops:
        L = np.asarray(loop, dtype=np.int64)
        m = len(L)
        if m < 3:
            continue
        if int(L[0]) * n + int(L[1]) not in keys:     # the half-edge a -> b must belong to a face
            L = L[::-1]
        P = V[L]
        c = P.mean(axis=0)
        nrm = FN[np.isin(F, L).any(axis=1)].sum(axis=0)
        nrm /= np.linalg.norm(nrm)
        e1 = P[0] - c
        e1 -= nrm * (e1 @ nrm)
        e1 /= np.linalg.norm(e1)
        B = np.stack([e1, np.cross(nrm, e1), nrm])          # rows: local x, y, height
        P2 = (P - c) @ B[:2].T
        r = float(np.linalg.norm(P2, axis=1).mean())
        near = np.linalg.norm(V - c, axis=1) <= neighbourhood * r + 1e-12
        Q = (V[near] - c) @ B.T
        A = np.column_stack([np.ones(len(Q)), Q[:, 0], Q[:, 1], Q[:, 0] ** 2, Q[:, 0] * Q[:, 1], Q[:, 1] ** 2])
        coef = np.linalg.lstsq(A, Q[:, 2], rcond=None)[0] if len(Q) >= 6 else np.r_[Q[:, 2].mean(), np.zeros(5)]
        edge = float(np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).mean())
        rings = max(0, int(round(r / max(edge, 1e-12))) - 1)
        # the polar grid in local ids: 0..m-1 the loop, then the rings, the centre last
        k_in = rings * m + 1
        faces = []
        outer = np.arange(m)
        for k in range(rings):
            ring = m + k * m + np.arange(m)
            a, b, ri, rj = outer, np.roll(outer, -1), ring, np.roll(ring, -1)
            faces += [np.column_stack([b, a, ri]), np.column_stack([b, ri, rj])]
            outer = ring
        centre = m + k_in - 1
        faces.append(np.column_stack([np.roll(outer, -1), outer, np.full(m, centre)]))
        G = np.concatenate(faces)
        # harmonic extension (uniform weights) of the loop's plane coordinates into the grid
        E = np.concatenate([G[:, [0, 1]], G[:, [1, 2]], G[:, [2, 0]]])
        E = np.unique(np.sort(E, axis=1), axis=0)
        N = m + k_in
        W = coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                       shape=(N, N)).tocsr()
        Lap = (coo_matrix((np.asarray(W.sum(axis=1)).ravel(), (np.arange(N), np.arange(N))), shape=(N, N))
               - W).tocsr()
        inner = np.arange(m, N)
        rhs = -(Lap[inner][:, :m] @ P2)
        XY = np.atleast_2d(spsolve(Lap[inner][:, inner].tocsc(), rhs)).reshape(-1, 2)
        h = np.column_stack([np.ones(len(XY)), XY[:, 0], XY[:, 1], XY[:, 0] ** 2, XY[:, 0] * XY[:, 1],
                             XY[:, 1] ** 2]) @ coef
        G = _unfold_fill(G, np.concatenate([P2, XY]))
        newV.append(c + XY @ B[:2] + h[:, None] * B[2])
        glob = np.concatenate([L, nv + np.arange(k_in)])
        newF.append(glob[G])
        nv += k_in
    if not newF:
        return V, F
    return np.concatenate([V, *newV]), np.concatenate([F, *newF]).astype(np.int64)


def _signed_areas(XY, T):
    p, q, r = XY[T[:, 0]], XY[T[:, 1]], XY[T[:, 2]]
    return 0.5 * ((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))


def _unfold_fill(G, XY):
    """Flip interior edges of the fill grid ``G`` (plane coordinates ``XY``, counter-clockwise
    positive) while a face has a non-positive signed area and a flip of one of its edges leaves
    both new faces larger than the worse of the two old ones. A loop edge that points at the
    centre (a scanner's staircase) lies in line with the ring vertex inside it, and the quad
    beside it only unfolds with its neighbour's diagonal."""
    G = [list(map(int, f)) for f in G]
    for _ in range(4 * len(G)):         # one flip per round; each strictly improves a bad face
        A = _signed_areas(XY, np.asarray(G))
        bad = np.flatnonzero(A <= 0)
        if not len(bad):
            break
        owner = {}
        for fi, f in enumerate(G):
            for k in range(3):
                owner[(f[k], f[(k + 1) % 3])] = fi
        changed = False
        for fi in bad.tolist():
            f = G[fi]
            for k in range(3):
                u, v, w = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
                gj = owner.get((v, u))                  # the face across u -> v
                if gj is None or gj == fi:
                    continue
                g = G[gj]
                x = next(t for t in g if t != u and t != v)
                n1, n2 = [w, u, x], [w, x, v]           # the edge u-v becomes w-x
                new = _signed_areas(XY, np.asarray([n1, n2]))
                if new.min() > min(A[fi], A[gj]) and new.min() > 0:
                    G[fi], G[gj] = n1, n2
                    A[fi], A[gj] = new
                    changed = True
                    break
            if changed:
                break
        if not changed:
            break
    return np.asarray(G, dtype=np.int64)
