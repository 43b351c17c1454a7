"""Eye-region retopology: crop the dense head to the eye region and remesh it low-poly.

SynthesEyes (paper 3.3) retopologised the scan by hand-guided ZRemesher into an
animatable low-poly eye region (9,005 polygons) whose edge loops follow the
eyelids. Here two automatic routes are offered (``RetopoSettings.method``):

``quadric``
    Garland-Heckbert quadric edge collapse (``fast_simplification``) with the
    borders locked, then cleaned (duplicate / degenerate faces, non-manifold
    edges, stray components): a triangle mesh. Fast (~1-2 s on 300k faces).
``isotropic``
    Pre-decimation (``fast_simplification``) followed by isotropic explicit
    remeshing (``pymeshlab``, reprojected onto the pre-decimated surface) and a
    greedy pairing of triangles into quads: a quad-dominant mesh
    (``poly_counts``/``poly_indices``) with near-equilateral elements.

Both then share the eyelid-loop treatment: each eye's opening stays a boundary
loop of the output, resampled to exactly ``loop_points`` vertices by boundary
edge collapses/splits, its vertices placed at even arc-length steps on the
dense scan's eyelid loop (vertex 0 at the medial canthus, upper lid first, as
the input contract orders them), and the interior relaxed (tangential
Laplacian, reprojected onto the dense surface) so the triangles next to the
loop stay well shaped. The loops' vertex indices are returned as
``loop_left``/``loop_right``. A coarse scan whose eye openings have under a quarter of
``loop_points`` vertices (``james``: 11) is midpoint-subdivided first (surface unchanged), so
the loop is not reached by splitting each opening edge into a fan of slivers; edge flips never
leave a loop vertex with a single triangle (an "ear" with three loop corners, inverted on the
convex opening).

With ``eye_rings`` > 0 (off by default), :func:`add_eye_rings` then gives each loop concentric
edge flow: the faces within about ``(eye_rings + 1)`` ring spacings of the loop are replaced by
``eye_rings`` rings of ``loop_points`` vertices marched out over the dense surface, joined by
quads (``poly_counts``/``poly_indices`` gain them on both routes), and a greedy loft of
triangles out to the cut's border. An eye whose rings come out folded, flipped or with an
obtuse loft sliver (> 160 deg) gets fewer rings, down to none; ``metrics["eye_rings"]`` says
how many each eye got. On the real scans the loft next to a creased upper lid is where this
fails (ict_neutral's left eye), so it stays off by default.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from pipeline.geometry import mesh_checks as mc
from pipeline.settings import Settings, setting

METHODS = ("quadric", "isotropic")


@dataclass
class RetopoSettings(Settings):
    """Retopology knobs (the ``retopo:`` block of params.yaml); defaults here, checked by pipeline.settings."""

    block: ClassVar[str] = "retopo"

    method: Literal["quadric", "isotropic"] = "quadric"
    target_polygons: int = setting(9000, ge=100, le=2_000_000)
    margin_lateral_mm: float = setting(22.0, gt=0, le=200)   # beyond each eye centre, away from the nose (x)
    margin_above_mm: float = setting(28.0, gt=0, le=200)     # above the eye centres (brow)
    margin_below_mm: float = setting(24.0, gt=0, le=200)     # below the eye centres (upper cheek)
    margin_back_mm: float = setting(12.0, gt=0, le=200)      # behind the eye centres (z); keeps the front surface only
    loop_points: int = setting(64, ge=8, le=4096)            # vertices per eyelid loop in the output
    predecimate_faces: int = setting(120000, ge=1000, le=20_000_000)  # isotropic route: pre-decimate the crop to this many faces
    isotropic_iterations: int = setting(6, ge=0, le=100)
    quad_max_angle_dev_deg: float = setting(50.0, ge=0, le=90)
    relax_iterations: int = setting(4, ge=0, le=1000)
    eye_rings: int = setting(0, ge=0, le=20)                 # rings of quads around each eyelid loop (0 = off)
    ring_spacing_mm: float = setting(0.0, ge=0, le=20)       # between rings; 0: the loop's mean edge length
    metric_samples: int = setting(50000, ge=100, le=10_000_000)


@dataclass
class RetopoResult:
    V: np.ndarray            # (n, 3) float64
    F: np.ndarray            # (m, 3) int64 triangles (fan triangulation of the polygons)
    loops: dict              # side -> (loop_points,) int64 ordered loop vertex indices
    poly_counts: np.ndarray | None
    poly_indices: np.ndarray | None
    crop_V: np.ndarray       # the cropped dense surface the result approximates
    crop_F: np.ndarray
    metrics: dict


# ----------------------------------------------------------------------------- crop

def crop_eye_region(V, F, eyes: dict, s: RetopoSettings):
    """Crop the dense mesh to a box around both eyes.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
        Dense head with eye openings.
    eyes : dict
        ``side -> {"center": (3,), "loop_indices": (k,)}``.

    Returns
    -------
    Vc (p, 3), Fc (q, 3), vmap (p,) int64 original index of each kept vertex.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    C = np.array([eyes[k]["center"] for k in eyes], dtype=np.float64)
    lo = np.array([C[:, 0].min() - s.margin_lateral_mm, C[:, 1].min() - s.margin_below_mm,
                   C[:, 2].min() - s.margin_back_mm])
    hi = np.array([C[:, 0].max() + s.margin_lateral_mm, C[:, 1].max() + s.margin_above_mm, np.inf])
    inside = np.all((V >= lo) & (V <= hi), axis=1)
    keep = inside[F].all(axis=1)
    Fk = F[keep]
    loop_vs = np.concatenate([np.asarray(eyes[k]["loop_indices"], dtype=np.int64) for k in eyes])
    if not inside[loop_vs].all():
        raise ValueError("an eyelid loop reaches outside the crop box; increase the retopo margins")
    # keep the connected component(s) that contain the eyelid loops
    n = len(V)
    e = mc.edges_of(Fk)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, lab = connected_components(A, directed=False)
    want = np.unique(lab[loop_vs])
    Fk = Fk[np.isin(lab[Fk[:, 0]], want)]
    vmap = np.unique(Fk)
    remap = -np.ones(n, dtype=np.int64)
    remap[vmap] = np.arange(len(vmap))
    Vc, Fc = V[vmap], remap[Fk]
    # weld coincident vertices (zero-area faces then have a repeated index and are dropped),
    # so decimation sees one closed surface instead of pinholes
    _, first, inv = np.unique(Vc, axis=0, return_index=True, return_inverse=True)
    if len(first) < len(Vc):
        rep = first[inv.ravel()]
        Fc = rep[Fc]
        Fc = Fc[(Fc[:, 0] != Fc[:, 1]) & (Fc[:, 1] != Fc[:, 2]) & (Fc[:, 0] != Fc[:, 2])]
    return Vc, Fc, vmap


# ----------------------------------------------------------------------------- cleaning

def clean_mesh(V, F, area_tol=1e-12):
    """Remove degenerate and duplicate faces, non-manifold extras and unreferenced vertices.

    Faces beyond the second one on an edge are dropped (smallest first kept out),
    then only the largest connected component... is *not* enforced here.

    Returns
    -------
    V (n', 3), F (m', 3)
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    area = 0.5 * np.linalg.norm(mc.face_normals(V, F, normalize=False), axis=1)
    F = F[~rep & (area > area_tol)]
    _, first = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
    F = F[np.sort(first)]
    for _ in range(5):
        n = len(V)
        he = mc.edges_of(F)
        und = np.sort(he, axis=1)
        ukey = und[:, 0] * n + und[:, 1]
        _, inv, cnt = np.unique(ukey, return_inverse=True, return_counts=True)
        dkey = he[:, 0] * n + he[:, 1]
        _, dinv, dcnt = np.unique(dkey, return_inverse=True, return_counts=True)
        bad_he = (cnt[inv] > 2) | (dcnt[dinv] > 1)
        if not bad_he.any():
            break
        bad_face = bad_he.reshape(-1, 3).any(axis=1)
        # drop the bad faces with the smallest area; one pass removes the worst offenders
        idx = np.flatnonzero(bad_face)
        area = 0.5 * np.linalg.norm(mc.face_normals(V, F[idx], normalize=False), axis=1)
        drop = idx[np.argsort(area)[: max(1, len(idx) // 2)]]
        F = np.delete(F, drop, axis=0)
    for _ in range(10):
        # boundary vertices with two outgoing boundary edges (pinched boundary): drop their faces
        n = len(V)
        he = mc.edges_of(F)
        key = he[:, 0] * n + he[:, 1]
        bnd = he[~np.isin(key, he[:, 1] * n + he[:, 0])]
        pinched = np.bincount(bnd[:, 0], minlength=n) > 1
        if not pinched.any():
            break
        F = F[~pinched[F].any(axis=1)]
    used = np.unique(F)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def largest_components(V, F, min_share=0.0, keep_faces_with=None):
    """Keep the largest connected component (and any containing ``keep_faces_with`` vertices)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(V)
    e = mc.edges_of(F)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, lab = connected_components(A, directed=False)
    fl = lab[F[:, 0]]
    counts = np.bincount(fl)
    F = F[fl == np.argmax(counts)]
    used = np.unique(F)
    remap = -np.ones(n, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


# ----------------------------------------------------------------------------- local mesh editing

class _TriMesh:
    """Tiny editable triangle mesh for boundary collapses/splits (Python dicts; a few hundred ops)."""

    def __init__(self, V, F):
        self.V = [np.asarray(v, dtype=np.float64) for v in V]
        self.F = {i: list(map(int, f)) for i, f in enumerate(F)}
        self.vf = {}
        for fi, f in self.F.items():
            for v in f:
                self.vf.setdefault(v, set()).add(fi)
        self.next_f = len(F)

    def normal(self, f, pos=None):
        P = [self.V[v] if pos is None or v not in pos else pos[v] for v in f]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        ln = np.linalg.norm(n)
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

    def flip_edge(self, fi, a, c, ref, min_cos=0.05):
        """Flip edge a-c of face ``fi`` (which reads (a, b, c) cyclically) with its twin, if the two
        new faces agree with ``ref``; returns True when done."""
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
            twins = [g for g in self.vf[a] & self.vf[c] if g != fi]
            if len(twins) != 1:
                continue
            g = twins[0]
            fg = self.F[g]
            d = [v for v in fg if v not in (a, c)][0]
            if d in self.neighbours(b):
                continue
            n_old = self.normal(fg)[0]
            n1, ar1 = self.normal([a, b, d])
            n2, ar2 = self.normal([b, c, d])
            if ar1 <= 1e-12 or ar2 <= 1e-12 or n1 @ n_old <= min_cos or n2 @ n_old <= min_cos:
                continue
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
            flipped += 1
        return flipped

    def arrays(self):
        F = np.array(list(self.F.values()), dtype=np.int64)
        V = np.array(self.V, dtype=np.float64)
        used = np.unique(F)
        remap = -np.ones(len(V), dtype=np.int64)
        remap[used] = np.arange(len(used))
        return V[used], remap[F], remap


def _polyline_arclength(P, closed=True):
    Q = np.vstack([P, P[:1]]) if closed else P
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)]), Q


def _project_to_polyline(X, P):
    """Arc-length parameter and point of the closest point on the closed polyline P for each X."""
    s, Q = _polyline_arclength(P)
    A, B = Q[:-1], Q[1:]
    AB = B - A
    L2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    t = np.clip(np.einsum("kij,ij->ki", X[:, None, :] - A[None], AB) / L2, 0, 1)
    C = A[None] + t[..., None] * AB[None]
    d = np.linalg.norm(C - X[:, None, :], axis=2)
    j = np.argmin(d, axis=1)
    k = np.arange(len(X))
    return s[j] + t[k, j] * np.sqrt(L2[j]), C[k, j], d[k, j]


def _point_at_arclength(P, t, smooth=0):
    """Points at arc-length ``t`` along the closed polyline P; with ``smooth`` > 0 the arc
    length is measured on a moving-average-smoothed copy (robust to staircase loops) while
    the points stay on P itself."""
    s, Q = _polyline_arclength(P)
    if smooth > 0:
        k = 2 * int(smooth) + 1
        Ps = sum(np.roll(P, j, axis=0) for j in range(-int(smooth), int(smooth) + 1)) / k
        s, _ = _polyline_arclength(Ps)
    t = np.mod(t, s[-1])
    j = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(Q) - 2)
    u = (t - s[j]) / np.maximum(s[j + 1] - s[j], 1e-300)
    return Q[j] + u[:, None] * (Q[j + 1] - Q[j])


def _resample_loop(tm: _TriMesh, loop, n, curve=None):
    """Collapse/split boundary edges until the loop has ``n`` vertices; returns the new loop list."""
    loop = list(map(int, loop))
    guard = 0
    while len(loop) > n and guard < 100000:
        guard += 1
        k = len(loop)
        P = np.array([tm.V[v] for v in loop])
        el = np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)   # edge i -> i+1
        cost = el + np.roll(el, 1)
        done = False
        for i in np.argsort(cost):
            a = loop[i]
            prev_i, next_i = (i - 1) % k, (i + 1) % k
            # merge into the nearer neighbour
            order = (next_i, prev_i) if el[i] <= el[prev_i] else (prev_i, next_i)
            for j in order:
                if tm.collapse(a, loop[j]):
                    loop.pop(i)
                    done = True
                    break
            if done:
                break
        if not done:
            break
    while len(loop) < n:
        k = len(loop)
        P = np.array([tm.V[v] for v in loop])
        el = np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)
        i = int(np.argmax(el))
        a, b = loop[i], loop[(i + 1) % k]
        p = 0.5 * (P[i] + P[(i + 1) % k])
        if curve is not None:
            p = _project_to_polyline(p[None], curve)[1][0]
        m = tm.split(a, b, p)
        loop.insert(i + 1, m)
    return loop


def _orient_and_place(V, loop, curve, start_point):
    """Order the loop like the reference curve (same direction, vertex 0 nearest ``start_point``)
    and return target positions evenly spaced along the curve."""
    loop = np.asarray(loop, dtype=np.int64)
    sp, _, _ = _project_to_polyline(V[loop], curve)
    total = _polyline_arclength(curve)[0][-1]
    ds = np.diff(np.unwrap(sp / total * 2 * np.pi))
    if np.sum(ds) < 0:
        loop = loop[::-1]
        sp = sp[::-1]
    i0 = int(np.argmin(np.linalg.norm(V[loop] - start_point, axis=1)))
    loop = np.roll(loop, -i0)
    s0 = _project_to_polyline(start_point[None], curve)[0][0]
    # even steps of the smoothed curve's arc length, starting at the start point's parameter
    sm = 2
    k = 2 * sm + 1
    Ps = sum(np.roll(curve, j, axis=0) for j in range(-sm, sm + 1)) / k
    ss, _ = _polyline_arclength(Ps)
    so, _ = _polyline_arclength(curve)
    s0s = np.interp(s0, so, ss)
    targets = _point_at_arclength(curve, s0s + np.arange(len(loop)) * ss[-1] / len(loop), smooth=sm)
    return loop, targets


def _vertex_adjacency(F, n):
    from scipy.sparse import coo_matrix

    e = mc.edges_of(F)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    return A


def _reference_face_normals(V, F, ref_V, ref_F):
    """Per face, the normalised sum of the reference surface's normals nearest its three vertices."""
    _, fi, _ = mc.closest_points(V, ref_V, ref_F)
    vn = mc.face_normals(ref_V, np.asarray(ref_F)[fi])
    n = vn[F].sum(axis=1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def relax(V, F, fixed, ref_V, ref_F, iterations=4, step=0.5, min_dot=0.3):
    """Tangential Laplacian smoothing of free vertices, reprojected onto the reference surface.

    A face's orientation is judged against the reference surface's normals; a
    step that would turn a face further than ``min_dot`` (cosine) away from the
    reference, and away from where it was, is reverted for that face's vertices,
    so relaxing never creates flipped faces and can repair existing ones.
    """
    V = np.asarray(V, dtype=np.float64).copy()
    if iterations <= 0:
        return V
    A = _vertex_adjacency(F, len(V))
    deg = np.asarray(A.sum(axis=1)).ravel()
    free = np.ones(len(V), dtype=bool)
    free[np.asarray(fixed, dtype=np.int64)] = False
    for _ in range(iterations):
        N = mc.vertex_normals(V, F)
        R = _reference_face_normals(V, F, ref_V, ref_F)
        d0 = np.einsum("ij,ij->i", mc.face_normals(V, F), R)
        L = (A @ V) / np.maximum(deg, 1)[:, None] - V
        L -= np.einsum("ij,ij->i", L, N)[:, None] * N
        Vn = V.copy()
        Vn[free] += step * L[free]
        _, _, C = mc.closest_points(Vn[free], ref_V, ref_F)
        Vn[free] = C
        d1 = np.einsum("ij,ij->i", mc.face_normals(Vn, F), R)
        bad = (d1 < min_dot) & (d1 < d0)
        if bad.any():
            Vn[np.unique(F[bad])] = V[np.unique(F[bad])]
        V = Vn
    return V


def repair_flips(V, F, fixed, ref_V, ref_F, rounds=10):
    """Move the free vertices of flipped faces to the mean of their neighbours (then onto the
    reference surface when that keeps the face unflipped); returns new V."""
    V = np.asarray(V, dtype=np.float64).copy()
    A = _vertex_adjacency(F, len(V))
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1)
    free = np.ones(len(V), dtype=bool)
    free[np.asarray(fixed, dtype=np.int64)] = False
    last = None
    for _ in range(rounds):
        R = _reference_face_normals(V, F, ref_V, ref_F)
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
        R2 = _reference_face_normals(Vp, F, ref_V, ref_F)
        if np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(Vp, F), R2) <= 0) <= \
                np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(Vt, F), R2) <= 0):
            V = Vp
        else:
            V = Vt
    return V


def _mirror_flipped(V, F, fixed, ref_V, ref_F):
    """Flipped faces with one free corner ``c`` and a fixed edge ``a-b`` (slivers at the eyelid
    loop): move ``c`` to the inner side of the edge, a third of the edge length from it, keeping
    the move only when it lowers the number of flipped faces."""
    V = np.asarray(V, dtype=np.float64).copy()
    fixed_m = np.zeros(len(V), dtype=bool)
    fixed_m[np.asarray(fixed, dtype=np.int64)] = True
    R = _reference_face_normals(V, F, ref_V, ref_F)
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


def _flip_slivers(V, F, ref_V, ref_F, min_angle_deg=10.0):
    """Flip the longest edge of sliver triangles (min angle below ``min_angle_deg``) when the edge
    is interior and both new triangles are better shaped and agree with the reference normal."""
    ang = mc.triangle_angles_deg(V, F)
    bad = np.flatnonzero(ang.min(axis=1) < min_angle_deg)
    if len(bad) == 0:
        return F
    R = _reference_face_normals(V, F, ref_V, ref_F)
    tm = _TriMesh(V, F)
    on_border = np.zeros(len(V), dtype=bool)
    for lp in mc.boundary_loops(F):
        on_border[lp] = True
    key = {tuple(f): i for i, f in enumerate(F.tolist())}
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
        old_min = min(ang[f].min(), mc.triangle_angles_deg(np.array(tm.V), np.array([tm.F[g]])).min())
        b = face[k]
        d = [v for v in tm.F[g] if v not in (a, c)][0]
        new = np.array([[a, b, d], [b, c, d]])
        if mc.triangle_angles_deg(np.array(tm.V), new).min() <= old_min:
            continue
        tm.flip_edge(fi, a, c, R[f], min_cos=0.3)
    Vn, Fn, _ = tm.arrays()
    return Fn


def _collapse_flipped(V, F, loops, fixed, ref_V, ref_F):
    """Remove flipped faces by collapsing their free vertex into one of the face's other corners."""
    R = _reference_face_normals(V, F, ref_V, ref_F)
    bad = np.flatnonzero(np.einsum("ij,ij->i", mc.face_normals(V, F), R) <= 0)
    fixed = set(map(int, fixed))
    tm = _TriMesh(V, F)
    for f in bad:
        face = F[f]
        fi = [k for k, g in tm.F.items() if list(g) == list(face)]
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


def count_flipped(V, F, ref_V, ref_F):
    """Faces whose normal points against the reference surface's nearby normals."""
    R = _reference_face_normals(V, F, ref_V, ref_F)
    return int(np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(V, F), R) <= 0))


# ----------------------------------------------------------------------------- quads

def pair_triangles(V, F, keep_boundary_edges=(), max_angle_dev_deg=35.0, max_dihedral_deg=30.0):
    """Greedy pairing of adjacent triangles into quads (best-shaped first).

    Returns
    -------
    poly_counts (p,) int64, poly_indices (sum,) int64 (quads as (a, d, b, c)
    for triangles (a, b, c) and (b, a, d)), and F_fan (m, 3) their fan
    triangulation (same triangles as ``F``, reordered).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    m, n = len(F), len(V)
    he = mc.edges_of(F)
    key = he[:, 0] * n + he[:, 1]
    rkey = he[:, 1] * n + he[:, 0]
    order = np.argsort(key)
    pos = np.searchsorted(key[order], rkey)
    pos = np.minimum(pos, len(key) - 1)
    has_twin = key[order][pos] == rkey
    twin = np.where(has_twin, order[pos], -1)
    h = np.flatnonzero(has_twin & (np.arange(len(he)) < twin))
    f1, f2 = h // 3, twin[h] // 3
    a, b = he[h, 0], he[h, 1]
    c = F[f1, (h % 3 + 2) % 3]
    d = F[f2, (twin[h] % 3 + 2) % 3]
    Q = np.stack([a, d, b, c], axis=1)
    P = V[Q]
    dev = np.zeros(len(h))
    angsum = np.zeros(len(h))
    for k in range(4):
        u = P[:, (k + 1) % 4] - P[:, k]
        w = P[:, (k - 1) % 4] - P[:, k]
        cs = np.einsum("ij,ij->i", u, w) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300)
        ang = np.degrees(np.arccos(np.clip(cs, -1, 1)))
        dev = np.maximum(dev, np.abs(ang - 90.0))
        angsum += ang
    fn = mc.face_normals(V, F)
    dih = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", fn[f1], fn[f2]), -1, 1)))
    ok = (dev < max_angle_dev_deg) & (dih < max_dihedral_deg) & (np.abs(angsum - 360.0) < 5.0)
    used = np.zeros(m, dtype=bool)
    quads = []
    # two greedy passes: well-shaped quads first, then looser ones for the triangles left over
    for limit in (0.6 * max_angle_dev_deg, max_angle_dev_deg):
        cand = np.flatnonzero(ok & (dev < limit))
        cand = cand[np.argsort(dev[cand])]
        for i in cand:
            if used[f1[i]] or used[f2[i]]:
                continue
            used[f1[i]] = used[f2[i]] = True
            quads.append(i)
    quads = np.asarray(quads, dtype=np.int64)
    tris = F[~used]
    counts = np.concatenate([np.full(len(quads), 4), np.full(len(tris), 3)]).astype(np.int64)
    indices = np.concatenate([Q[quads].ravel(), tris.ravel()]).astype(np.int64)
    qf = Q[quads]
    F_fan = np.concatenate([qf[:, [0, 1, 2]], qf[:, [0, 2, 3]], tris]) if len(qf) else tris
    return counts, indices, F_fan


# ----------------------------------------------------------------------------- eye rings

def _band_faces(V, F, loop, radius, locked):
    """Faces of an annulus around ``loop`` reaching about ``radius`` (edge-graph distance) out.

    Every face with a corner nearer than ``radius`` is taken; pockets the band encloses are
    filled and pinch vertices (more than two band/rest edges) grown over until the band is
    an annulus: its border is ``loop`` plus one simple closed loop. Returns the (m,) bool face
    mask, or None when no such band exists (it would touch a ``locked`` vertex).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from pipeline.geometry.meshtopo import face_adjacency, face_components

    n, m = len(V), len(F)
    e = mc.edges_of(F)
    w = np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)
    G = coo_matrix((w, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    G = G.maximum(G.T)
    d = dijkstra(G, indices=np.asarray(loop), min_only=True, limit=2.0 * radius)
    band = (d[F] < radius).any(axis=1)
    pairs, pair_edges = face_adjacency(F, n)
    for _ in range(50):
        rest = ~band
        # pockets: rest components other than the largest join the band
        lab = face_components(m, pairs, rest)
        sizes = np.bincount(lab[rest], minlength=m)
        band |= rest & (lab != int(np.argmax(sizes)))
        # the band/rest interface must be a simple loop: grow over pinch vertices
        inter = band[pairs[:, 0]] != band[pairs[:, 1]]
        cnt = np.bincount(pair_edges[inter].ravel(), minlength=n)
        pinch = np.flatnonzero(cnt > 2)
        if len(pinch) == 0:
            break
        band |= np.isin(F, pinch).any(axis=1)
    else:
        return None
    if len(locked) and np.isin(F[band], locked).any():
        return None
    # annulus: one component, Euler characteristic 0, two border loops (the eye loop + B)
    Fb = F[band]
    if len(np.unique(face_components(m, pairs, band)[band])) != 1:
        return None
    nv = len(np.unique(Fb))
    ne = len(np.unique(np.sort(mc.edges_of(Fb), axis=1), axis=0))
    if nv - ne + len(Fb) != 0:
        return None
    try:
        if len(mc.boundary_loops(Fb)) != 2:
            return None
    except ValueError:
        return None
    return band


def _outward_directions(P, normals, inside, smooth=3):
    """Unit directions in the surface, across the closed loop ``P`` towards ``inside``.

    Parameters
    ----------
    P : (N, 3) loop points ; normals : (N, 3) surface normals there
    inside : (N, 3) a point on the side the directions must point to, per loop vertex
    smooth : int
        Rounds of neighbour averaging: a staircase loop's kinks would cross the offset rings.

    Returns
    -------
    (N, 3) float64
    """
    T = np.roll(P, -1, axis=0) - np.roll(P, 1, axis=0)
    O = np.cross(T, normals)
    if np.sum(np.einsum("ij,ij->i", O, inside - P)) < 0:
        O = -O
    O /= np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    for _ in range(smooth):
        O = 0.5 * O + 0.25 * (np.roll(O, 1, axis=0) + np.roll(O, -1, axis=0))
        O -= np.einsum("ij,ij->i", O, normals)[:, None] * normals
        O /= np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    return O


def _march_rings(P, normals, inside, h, rings, ref_V, ref_F, smooth=1):
    """Rings of points marched out from the loop ``P`` in steps of ``h`` over the surface.

    Each step goes ``h`` across the current ring in the tangent plane and back onto the
    surface: short steps follow a surface that curls (the skin folding over an upper lid)
    where one long straight offset would land on the wrong side of the fold.

    Returns
    -------
    (rings, N, 3) float64
    """
    out = []
    Pk, Nk = P, normals
    for _ in range(rings):
        O = _outward_directions(Pk, Nk, inside)
        X = Pk + h * O
        # a little smoothing along the ring: where the loop has a notch the offsets converge
        # and would cross a few steps out
        for _ in range(smooth):
            X = 0.5 * X + 0.25 * (np.roll(X, 1, axis=0) + np.roll(X, -1, axis=0))
        _, fi, C = mc.closest_points(X, ref_V, ref_F)
        Nf = mc.face_normals(ref_V, np.asarray(ref_F)[fi])
        Nk = np.where(np.einsum("ij,ij->i", Nf, Nk)[:, None] < 0, -Nf, Nf)   # keep the side
        inside = C + O                                                       # keep going outward
        Pk = C
        out.append(C)
    return np.stack(out)


def _zip_strip(inner, outer, Vi, Vo, j0):
    """Greedy loft between two closed polylines: triangles (a, b, c) wound like the quads
    ``(inner[i], inner[i+1], outer[j+1], outer[j])``, each step closing the shorter diagonal."""
    N, M = len(inner), len(outer)
    i = j = 0
    tris = []
    while i < N or j < M:
        a, b = i % N, (i + 1) % N
        c, d = (j0 + j) % M, (j0 + j + 1) % M
        adv_inner = j >= M or (i < N and np.linalg.norm(Vi[b] - Vo[c]) <= np.linalg.norm(Vi[a] - Vo[d]))
        if adv_inner:
            tris.append((inner[a], inner[b], outer[c]))
            i += 1
        else:
            tris.append((inner[a], outer[d], outer[c]))
            j += 1
    return np.asarray(tris, dtype=np.int64)


def add_eye_rings(V, F, loops, ref_V, ref_F, rings=3, spacing=0.0, relax_iterations=4):
    """Concentric rings of quads around each eyelid loop.

    The faces within a band of ``(rings + 1) * spacing`` (edge-graph distance) around the loop
    are replaced by ``rings`` rings of ``N = len(loop)`` vertices (ring k marched out from the
    loop in ``k`` steps of ``spacing`` over the reference surface, :func:`_march_rings`), ``N``
    quads between consecutive rings (the loop is ring 0) and a loft of triangles from the
    outermost ring to the band's outer border B (:func:`_zip_strip`). An eye whose band cannot
    be made an annulus, or whose rings come out folded, flipped or with an obtuse loft sliver,
    is retried with fewer rings and keeps its old faces at none.

    Parameters
    ----------
    V : (n, 3) float64 ; F : (m, 3) int64
        Low-poly mesh, edge-manifold; eye loops are boundary loops.
    loops : dict side -> (N,) int64
        Ordered loop vertex indices (unchanged in the output, up to renumbering).
    ref_V : (r, 3) float64 ; ref_F : (s, 3) int64
        Dense surface the new vertices are projected onto (orientation reference too).
    rings : int
        New vertex rings per eye (= quad rings); 0 returns the input.
    spacing : float
        Ring spacing in mm; <= 0 uses the loop's mean edge length (square quads at the loop).
    relax_iterations : int

    Returns
    -------
    V2 : (n2, 3) float64
    F2 : (t, 3) int64
        Triangles other than the ring quads.
    Q : (q, 4) int64
        Ring quads, wound like ``F2``.
    loops2 : dict side -> (N,) int64
    info : dict side -> {"rings", "quads", "loft_triangles", "outer_vertices"} or {"skipped": why}
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    loops = {k: np.asarray(v, dtype=np.int64) for k, v in loops.items()}
    Q_all = np.zeros((0, 4), dtype=np.int64)
    info = {}
    if rings <= 0:
        return V, F, Q_all, loops, info
    flips0 = count_flipped(V, F, ref_V, ref_F)
    for side in list(loops):
        lp = loops[side]
        P = V[lp]
        h = float(spacing) if spacing > 0 else float(np.mean(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)))
        # fewer rings where the full count folds (skin creasing close over a lid): the rings
        # stay where the surface allows them
        why = "band around the loop is not an annulus"
        for nr in range(int(rings), 0, -1):
            out = _ring_one_eye(V, F, Q_all, lp, ref_V, ref_F, nr, h, relax_iterations, flips0)
            if isinstance(out, str):
                why = out
                continue
            V, F, Q_all, remap, stats = out
            loops = {k: remap[v] for k, v in loops.items()}
            info[side] = stats
            break
        else:
            info[side] = {"rings": 0, "skipped": why}
    return V, F, Q_all, loops, info


def _ring_one_eye(V, F, Q_all, lp, ref_V, ref_F, rings, h, relax_iterations, flips0,
                  max_angle_deg=160.0):
    """One eye of ``add_eye_rings``: (V, F, Q_all, remap, stats), or why it failed (str)."""
    N = len(lp)
    # the quads of an eye done before are part of the surface but never of a band
    Fw = np.concatenate([F, Q_all[:, [0, 1, 2]], Q_all[:, [0, 2, 3]]])
    others = [np.asarray(b) for b in mc.boundary_loops(Fw) if not set(map(int, b)) & set(map(int, lp))]
    locked = np.unique(np.concatenate(others + [Q_all.ravel()]))
    band = _band_faces(V, Fw, lp, (rings + 1) * h, locked)
    if band is None:
        return "band around the loop is not an annulus"
    band = band[:len(F)]
    Fb, Fk = F[band], F[~band]
    # loop direction of the faces at the loop: the quads must keep it
    he = set(map(tuple, np.concatenate([Fb[:, [0, 1]], Fb[:, [1, 2]], Fb[:, [2, 0]]]).tolist()))
    Lh = lp if (int(lp[0]), int(lp[1])) in he else lp[::-1]
    lp_set = set(map(int, lp))
    B = next(b for b in mc.boundary_loops(Fb) if not set(map(int, b)) & lp_set)
    B = B[::-1]                     # the rest's faces run along B the way the band's run along the loop
    # new ring vertices marched out across the loop over the surface (offsets of a convex
    # opening diverge, so rings neither cross nor pinch at the canthi)
    Pl = V[Lh]
    Nl = mc.vertex_normals(V, Fb)[Lh]
    inside = np.zeros_like(Pl)
    for k, v in enumerate(Lh):                    # centroid of the band faces at the vertex
        inside[k] = V[Fb[(Fb == v).any(axis=1)]].mean(axis=(0, 1))
    C = _march_rings(Pl, Nl, inside, h, rings, ref_V, ref_F).reshape(-1, 3)
    j0 = int(np.argmin(np.linalg.norm(V[B] - C[-N], axis=1)))
    base = len(V)
    V2 = np.concatenate([V, C])
    R = np.vstack([Lh[None], base + np.arange(rings * N).reshape(rings, N)])     # (rings + 1, N)
    nxt = np.roll(np.arange(N), -1)
    quads = np.concatenate([np.stack([R[k], R[k][nxt], R[k + 1][nxt], R[k + 1]], axis=1)
                            for k in range(rings)])
    loft = _zip_strip(R[-1], B, V2[R[-1]], V2[B], j0)
    # drop the band's inner vertices (not on the loop or B), renumber
    Ftri = np.concatenate([Fk, loft])
    Qnew = np.concatenate([Q_all, quads])
    Fall = np.concatenate([Ftri, Qnew[:, [0, 1, 2]], Qnew[:, [0, 2, 3]]])
    used = np.unique(np.concatenate([Fall.ravel(), lp]))
    remap = -np.ones(len(V2), dtype=np.int64)
    remap[used] = np.arange(len(used))
    Vt, Fall_t = V2[used], remap[Fall]
    # B is the jagged edge of a face cut: relaxing it keeps the loft's triangles from
    # folding over its notches. The rings are not relaxed (a Laplacian shortens them,
    # pinching them onto the loop at the canthi), only repaired where a face came out flipped
    fixed = np.setdiff1d(np.arange(len(Vt)), remap[B])
    Vt = relax(Vt, Fall_t, fixed, ref_V, ref_F, iterations=max(relax_iterations, 8))
    if count_flipped(Vt, Fall_t, ref_V, ref_F) > flips0:
        fixed = np.setdiff1d(fixed, remap[R[1:].ravel()])
        Vt = repair_flips(Vt, Fall_t, fixed, ref_V, ref_F)
    rep = mc.check_mesh(Vt, Fall_t)
    flips = count_flipped(Vt, Fall_t, ref_V, ref_F)
    # an obtuse sliver in the loft (a B vertex on the outer ring's edge) folds as soon as the
    # lids move: no fewer rings would make one, so it counts as a failure
    new_faces = np.concatenate([remap[loft], remap[quads][:, [0, 1, 2]], remap[quads][:, [0, 2, 3]]])
    max_angle = float(mc.triangle_angles_deg(Vt, new_faces).max())
    if not rep.manifold or rep.degenerate_faces or flips > flips0 or max_angle > max_angle_deg:
        return (f"{rings} rings: manifold {rep.manifold}, {rep.degenerate_faces} degenerate, "
                f"{flips - flips0} flipped faces, largest angle {max_angle:.0f} deg")
    stats = {"rings": int(rings), "spacing_mm": round(h, 4), "quads": int(len(quads)),
             "loft_triangles": int(len(loft)), "outer_vertices": int(len(B))}
    return Vt, remap[Ftri], remap[Qnew], remap, stats


# ----------------------------------------------------------------------------- main entry

def subdivide_midpoint(V, F):
    """1-to-4 midpoint subdivision (the surface is unchanged: new vertices at edge midpoints).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64

    Returns
    -------
    V2 : (n + e, 3) float64
        ``V`` followed by one midpoint per unique edge.
    F2 : (4 m, 3) int64
        Same winding as ``F``.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    uniq, inv = np.unique(np.sort(E, axis=1), axis=0, return_inverse=True)
    mid = len(V) + inv.reshape(3, len(F)).T                  # (m, 3): midpoints of edges 01, 12, 20
    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    F2 = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                         np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    return np.concatenate([V, 0.5 * (V[uniq[:, 0]] + V[uniq[:, 1]])]), F2


def refine_coarse_crop(V, F, min_loop_vertices, eye_loop_lengths, max_levels=4):
    """Midpoint-subdivide a crop whose eye openings have fewer than half ``min_loop_vertices``
    boundary vertices, until each has at least ``min_loop_vertices``.

    A coarse scan (a few hundred faces around the eyes, ~10 vertices per eyelid opening)
    would otherwise reach ``loop_points`` only by splitting each opening edge several times,
    leaving fans of sliver triangles from one interior vertex to a run of collinear loop
    vertices, which fold as soon as the loop moves (snap, lid shapes). Subdividing first
    gives the remesher interior vertices next to the loop; the surface is unchanged.

    Returns
    -------
    V, F, levels : the refined mesh and the number of subdivisions applied (0 = unchanged).
    """
    levels = 0
    n_loop = min(eye_loop_lengths) if len(eye_loop_lengths) else min_loop_vertices
    if 2 * n_loop >= min_loop_vertices:
        return V, F, 0
    while levels < max_levels and n_loop < min_loop_vertices:
        V, F = subdivide_midpoint(V, F)
        n_loop *= 2
        levels += 1
    return V, F, levels


def _decimate(V, F, target_faces):
    import fast_simplification

    if len(F) <= target_faces:
        return V, F
    Vd, Fd = fast_simplification.simplify(V, F.astype(np.int32), target_count=int(target_faces),
                                          preserve_border=True)
    return clean_mesh(Vd, np.asarray(Fd, dtype=np.int64))


def _isotropic(V, F, target_len, iterations):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.meshing_isotropic_explicit_remeshing(
        iterations=int(iterations), targetlen=pymeshlab.PureValue(float(target_len)),
        featuredeg=180.0, checksurfdist=True, maxsurfdist=pymeshlab.PureValue(float(target_len) * 0.25),
        reprojectflag=True)
    m = ms.current_mesh()
    return clean_mesh(np.asarray(m.vertex_matrix(), dtype=np.float64),
                      np.asarray(m.face_matrix(), dtype=np.int64))


def retopologize(V, F, eyes: dict, settings: RetopoSettings) -> RetopoResult:
    """Crop the dense head to the eye region and remesh it (see module docstring).

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
        Dense head with eye openings (mm, head frame).
    eyes : dict
        ``{"left": {"center": (3,), "loop_indices": (k,) ordered}, "right": {...}}``
        (``remove_eyeballs``' eyes.json).
    settings : RetopoSettings

    Returns
    -------
    RetopoResult
    """
    s = settings
    t0 = time.perf_counter()
    timings = {}
    Vc, Fc, vmap = crop_eye_region(V, F, eyes, s)
    inv = {int(v): i for i, v in enumerate(vmap)}
    curves = {}
    for side, e in eyes.items():
        li = np.asarray(e["loop_indices"], dtype=np.int64)
        curves[side] = np.asarray(V, dtype=np.float64)[li]
    timings["crop_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    tri_target = s.target_polygons if s.method == "quadric" else int(round(s.target_polygons / 0.58))
    if s.eye_rings > 0:
        # the rings replace a band of triangles by fewer, longer-sided polygons: ask the
        # remesher for about that many more so the polygon count stays on target
        area = 0.5 * np.linalg.norm(mc.face_normals(Vc, Fc, normalize=False), axis=1).sum()
        L0 = np.sqrt(4.0 * area / (np.sqrt(3.0) * tri_target))
        lost = 0.0
        for cur in curves.values():
            per = float(_polyline_arclength(cur)[0][-1])
            h = s.ring_spacing_mm if s.ring_spacing_mm > 0 else per / s.loop_points
            w = (s.eye_rings + 1) * h
            band = (per * w + np.pi * w * w) / (np.sqrt(3.0) / 4.0 * L0 * L0)
            new = (s.eye_rings + 1) * s.loop_points + (per + 2 * np.pi * w) / L0
            lost += max(0.0, band - new)
        tri_target += int(round(lost * (1.0 if s.method == "quadric" else 1.0 / 0.58)))
    # eye openings with under a quarter of the output loop's vertices (coarse scans) are
    # subdivided first, so that opening edges are not split into fans of slivers at the loop
    cbl = mc.boundary_loops(Fc)
    eye_loop_lengths = []
    for side, e in eyes.items():
        li = set(int(inv[int(v)]) for v in e["loop_indices"] if int(v) in inv)
        eye_loop_lengths += [len(b) for b in cbl if li & set(map(int, b))][:1]
    Vr, Fr, refine_levels = refine_coarse_crop(Vc, Fc, (s.loop_points + 1) // 2, eye_loop_lengths)
    if s.method == "quadric":
        # the borders are locked during decimation and coarsened afterwards (each boundary vertex
        # collapsed removes one face): ask for that many more faces so the result lands on target
        area = 0.5 * np.linalg.norm(mc.face_normals(Vc, Fc, normalize=False), axis=1).sum()
        L = np.sqrt(4.0 * area / (np.sqrt(3.0) * tri_target))
        cb = mc.boundary_loops(Fr)
        n_border = sum(len(b) for b in cb)
        perim = sum(float(np.linalg.norm(Vr[b] - np.roll(Vr[b], -1, axis=0), axis=1).sum()) for b in cb)
        extra = max(0, n_border - int(perim / L) - 2 * s.loop_points // 2)
        Vl, Fl = _decimate(Vr, Fr, tri_target + extra)
    else:
        Vp, Fp = _decimate(Vr, Fr, max(s.predecimate_faces, 4 * tri_target))
        area = 0.5 * np.linalg.norm(mc.face_normals(Vp, Fp, normalize=False), axis=1).sum()
        L = np.sqrt(4.0 * area / (np.sqrt(3.0) * tri_target))
        Vl, Fl = _isotropic(Vp, Fp, L, s.isotropic_iterations)
    Vl, Fl = largest_components(Vl, Fl)
    timings["remesh_s"] = time.perf_counter() - t1

    # ---- eyelid loops: find each eye's boundary loop, resample to loop_points, place on the curve
    t2 = time.perf_counter()
    bl = mc.boundary_loops(Fl)
    if len(bl) < 3:
        raise ValueError(f"remeshed eye region has {len(bl)} boundary loops; expected 2 eye openings + the crop border")
    assigned = {}
    for side, cur in curves.items():
        cen = cur.mean(axis=0)
        best, bd = None, np.inf
        for k, lp in enumerate(bl):
            if k in assigned.values():
                continue
            d = np.mean(_project_to_polyline(Vl[lp], cur)[2]) + np.linalg.norm(Vl[lp].mean(axis=0) - cen)
            if d < bd:
                best, bd = k, d
        assigned[side] = best
    tm = _TriMesh(Vl, Fl)
    new_loops = {}
    for side, k in assigned.items():
        new_loops[side] = _resample_loop(tm, bl[k], s.loop_points, curves[side])
    # outer border: coarsen to about the mean edge length of the interior
    edge_len = float(np.mean(np.linalg.norm(Vl[Fl[:, 1]] - Vl[Fl[:, 0]], axis=1)))
    outer = [lp for k, lp in enumerate(bl) if k not in assigned.values()]
    for lp in outer:
        per = float(np.sum(np.linalg.norm(Vl[lp] - np.roll(Vl[lp], -1, axis=0), axis=1)))
        want = max(8, int(round(per / edge_len)))
        if want < len(lp):
            _resample_loop(tm, lp, want)
    tm.flip_ears()
    Vn, Fn, remap = tm.arrays()
    loops = {}
    all_boundary = np.concatenate(mc.boundary_loops(Fn))
    for side, lp in new_loops.items():
        lp = remap[np.asarray(lp, dtype=np.int64)]
        lp, targets = _orient_and_place(Vn, lp, curves[side], curves[side][0])
        # move in a few steps, keeping faces from flipping
        for alpha in (0.2, 0.4, 0.6, 0.8, 1.0):
            Vt = Vn.copy()
            Vt[lp] = (1 - alpha) * Vn[lp] + alpha * targets
            Vn = Vt
            Vn = relax(Vn, Fn, all_boundary, Vc, Fc, iterations=1)
        loops[side] = lp
    tm = _TriMesh(Vn, Fn)
    if tm.flip_ears():
        Vn, Fn, remap = tm.arrays()          # no vertex is dropped by flips: remap is the identity
        loops = {k: remap[v] for k, v in loops.items()}
    timings["loops_s"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    fixed = np.unique(np.concatenate([np.concatenate(mc.boundary_loops(Fn))]))
    Vn = relax(Vn, Fn, fixed, Vc, Fc, iterations=s.relax_iterations)
    for _ in range(3):
        if count_flipped(Vn, Fn, Vc, Fc):   # repair remaining flips next to the (fixed) loops
            Vn = repair_flips(Vn, Fn, fixed, Vc, Fc)
        if count_flipped(Vn, Fn, Vc, Fc):   # slivers at the loop: move the free corner inside
            Vn = _mirror_flipped(Vn, Fn, fixed, Vc, Fc)
        if count_flipped(Vn, Fn, Vc, Fc):   # still flipped: collapse their free vertex into a neighbour
            Vn, Fn, loops = _collapse_flipped(Vn, Fn, loops, fixed, Vc, Fc)
            fixed = np.unique(np.concatenate(mc.boundary_loops(Fn)))
    if count_flipped(Vn, Fn, Vc, Fc):       # last resort: slide free corners into their kernel
        from pipeline.geometry.snap import untangle

        free = np.ones(len(Vn), dtype=bool)
        free[fixed] = False
        R = _reference_face_normals(Vn, Fn, Vc, Fc)
        nf = mc.face_normals(Vn, Fn, normalize=False)
        bad_v = np.unique(Fn[np.einsum("ij,ij->i", nf, R) <= 0])
        # the faces around them keep a quarter of the typical face area (no new slivers)
        near = np.isin(Fn, bad_v).any(axis=1)
        floor = np.where(near, 0.25 * float(np.median(np.linalg.norm(nf, axis=1))), 0.0)
        Vn, _ = untangle(Vn, Fn, R, free, min_projected=floor)
    Fs = _flip_slivers(Vn, Fn, Vc, Fc)
    if len(Fs) == len(Fn) and count_flipped(Vn, Fs, Vc, Fc) <= count_flipped(Vn, Fn, Vc, Fc):
        Fn = Fs
    timings["relax_quads_s"] = time.perf_counter() - t3

    t4 = time.perf_counter()
    Vn, Fn, ring_quads, loops, ring_info = add_eye_rings(
        Vn, Fn, loops, Vc, Fc, s.eye_rings, s.ring_spacing_mm, s.relax_iterations)
    if len(ring_quads):
        # the lofts' slivers: flips among the triangles only (the quads' edges are borders there)
        Fs = _flip_slivers(Vn, Fn, Vc, Fc)
        Fq = np.concatenate([ring_quads[:, [0, 1, 2]], ring_quads[:, [0, 2, 3]]])
        if len(Fs) == len(Fn) and (count_flipped(Vn, np.concatenate([Fs, Fq]), Vc, Fc)
                                   <= count_flipped(Vn, np.concatenate([Fn, Fq]), Vc, Fc)):
            Fn = Fs
    poly_counts = poly_indices = None
    if s.method == "isotropic":
        poly_counts, poly_indices, Fn = pair_triangles(Vn, Fn, max_angle_dev_deg=s.quad_max_angle_dev_deg)
    elif len(ring_quads):
        poly_counts = np.full(len(Fn), 3, dtype=np.int64)
        poly_indices = Fn.ravel()
    if len(ring_quads):
        poly_counts = np.concatenate([poly_counts, np.full(len(ring_quads), 4, dtype=np.int64)])
        poly_indices = np.concatenate([poly_indices, ring_quads.ravel()])
        Fn = np.concatenate([Fn, ring_quads[:, [0, 1, 2]], ring_quads[:, [0, 2, 3]]])
    timings["eye_rings_s"] = time.perf_counter() - t4
    timings["total_s"] = time.perf_counter() - t0

    metrics = retopo_metrics(Vn, Fn, loops, Vc, Fc, curves, s.metric_samples)
    metrics.update({
        "method": s.method,
        "polygons": int(len(poly_counts) if poly_counts is not None else len(Fn)),
        "triangles": int(len(Fn)),
        "quads": int(np.count_nonzero(poly_counts == 4)) if poly_counts is not None else 0,
        "vertices": int(len(Vn)),
        "crop_faces": int(len(Fc)),
        "crop_subdivisions": int(refine_levels),
        "eye_rings": ring_info,
        "timings_s": {k: round(v, 4) for k, v in timings.items()},
        "time_s": round(timings["total_s"], 4),
    })
    return RetopoResult(Vn, Fn, loops, poly_counts, poly_indices, Vc, Fc, metrics)


def retopo_metrics(V, F, loops, Vc, Fc, curves, n_samples=50000) -> dict:
    """Validity, distance-to-scan, angle and loop figures of a retopo result."""
    rep = mc.check_mesh(V, F)
    dist = mc.surface_distance(V, F, Vc, Fc, n_samples=n_samples)
    flipped = count_flipped(V, F, Vc, Fc)
    bset = set()
    for lp in mc.boundary_loops(F):
        bset.update(map(int, lp))
    loop_info = {}
    for side, lp in loops.items():
        lp = np.asarray(lp)
        d = _project_to_polyline(V[lp], curves[side])[2]
        seg = np.linalg.norm(V[lp] - np.roll(V[lp], -1, axis=0), axis=1)
        loop_info[side] = {"points": int(len(lp)), "all_on_boundary": bool(all(int(v) in bset for v in lp)),
                           "max_distance_to_scan_loop_mm": float(d.max()),
                           "edge_cv": float(seg.std() / seg.mean())}
    return {
        "mesh": rep.as_dict(),
        "flipped_faces": flipped,
        "distance_lowpoly_to_scan": dist["a_to_b"],
        "distance_scan_to_lowpoly": dist["b_to_a"],
        "distance_symmetric_mean_mm": dist["symmetric_mean_mm"],
        "angles": mc.angle_stats(V, F),
        "loops": loop_info,
    }
