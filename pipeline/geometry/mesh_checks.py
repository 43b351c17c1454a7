"""Mesh validity checks and surface-distance metrics (shared by retopo, bake, snap).

All functions take plain arrays: ``V`` (n, 3) float64 and ``F`` (m, 3) int64.
Heavy helpers (libigl) are imported lazily.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.geometry.meshtopo import face_normals, vertex_normals  # noqa: F401 (mc.*)


def edges_of(F):
    """Directed half-edges of triangles.

    Returns
    -------
    (3m, 2) int64 array of (from, to) vertex pairs, face-major order.
    """
    F = np.asarray(F, dtype=np.int64)
    return np.stack([F, np.roll(F, -1, axis=1)], axis=-1).reshape(-1, 2)


def closed_polyline_distance(P, M):
    """Distance from each point to a closed polyline.

    Parameters
    ----------
    P : (n, 3) float64
    M : (k, 3) float64
        Polyline vertices; the last joins the first.

    Returns
    -------
    (n,) float64
    """
    P = np.asarray(P, dtype=np.float64)
    A = np.asarray(M, dtype=np.float64)
    AB = np.roll(A, -1, axis=0) - A
    best = np.full(len(P), np.inf)
    for a, ab in zip(A, AB):
        t = np.clip(((P - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(P - (a + t[:, None] * ab), axis=1))
    return best


def triangle_angles_deg(V, F):
    """(m, 3) interior angles in degrees at each corner."""
    V = np.asarray(V, dtype=np.float64)
    P = V[np.asarray(F, dtype=np.int64)]
    out = np.empty((len(P), 3))
    for k in range(3):
        a = P[:, (k + 1) % 3] - P[:, k]
        b = P[:, (k + 2) % 3] - P[:, k]
        la = np.linalg.norm(a, axis=1)
        lb = np.linalg.norm(b, axis=1)
        c = np.einsum("ij,ij->i", a, b) / np.maximum(la * lb, 1e-300)
        out[:, k] = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return out


def boundary_loops(F):
    """Ordered boundary loops of an edge-manifold triangle mesh.

    Each loop follows the boundary half-edges (the direction of the faces'
    own winding), so for a mesh seen from outside the loop around a hole runs
    clockwise seen from outside. Loops are walked (:func:`meshtopo.boundary_loops`) from the
    boundary half-edges in face order: the first loop starts at the first boundary edge of the
    lowest-numbered face.

    Returns
    -------
    list of (k,) int64 arrays of vertex indices (not repeated at the end).

    Raises
    ------
    ValueError
        When a boundary vertex has more than one outgoing boundary edge
        (non-manifold boundary), or the boundary edges do not close into loops.
    """
    return meshtopo.boundary_loops(F, H=meshtopo.boundary_halfedges(F, face_order=True))


@dataclass
class MeshReport:
    """Validity figures of a triangle mesh (all counts; 0 means clean)."""

    n_vertices: int
    n_faces: int
    nonmanifold_edges: int        # undirected edges used by more than two faces
    inconsistent_edges: int       # directed edges used twice (neighbours wound oppositely)
    nonmanifold_vertices: int     # vertices whose face fan is not a single disc/half-disc
    duplicate_faces: int          # faces with the same vertex set as an earlier face
    degenerate_faces: int         # repeated index or area below the tolerance
    unreferenced_vertices: int
    boundary_loops: int

    @property
    def manifold(self) -> bool:
        return (self.nonmanifold_edges == 0 and self.inconsistent_edges == 0
                and self.nonmanifold_vertices == 0 and self.duplicate_faces == 0)

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["manifold"] = self.manifold
        return d


def check_mesh(V, F, area_tol=1e-10) -> MeshReport:
    """Count manifold/orientation/degeneracy defects of a triangle mesh."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    he = edges_of(F)
    und = np.sort(he, axis=1)
    _, ucount = np.unique(und[:, 0] * n + und[:, 1], return_counts=True)
    _, dcount = np.unique(he[:, 0] * n + he[:, 1], return_counts=True)
    sf = np.sort(F, axis=1)
    _, fcount = np.unique(sf, axis=0, return_counts=True)
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    area = meshtopo.face_areas(V, F)
    try:
        nb = len(boundary_loops(F))
        nm_vert_boundary = 0
    except ValueError:
        nb = -1
        nm_vert_boundary = 1
    # vertex manifoldness: per vertex, #faces - #interior link edges must be 0 (closed fan) or 1 (open fan)
    # count faces per vertex and boundary edges touching it; an open fan has exactly 2 boundary edges.
    fcnt = np.bincount(F.ravel(), minlength=n)
    key = he[:, 0] * n + he[:, 1]
    rkey = he[:, 1] * n + he[:, 0]
    bnd = he[~np.isin(key, rkey)]
    bcnt = np.bincount(bnd.ravel(), minlength=n)
    nm_vert = int(np.count_nonzero(bcnt > 2)) + nm_vert_boundary
    # fans: number of connected face-fans per vertex via shared edges = components; approximate check
    # by Euler characteristic of the link: for a disc/half-disc, #link edges == #faces and
    # #link vertices == #faces (closed) or #faces + 1 (open).
    both = np.concatenate([key, rkey])
    u = np.unique(both) // n
    link_v = np.bincount(u, minlength=n)
    expected = fcnt + (bcnt > 0)
    used = fcnt > 0
    nm_vert += int(np.count_nonzero(used & (link_v != expected) & (bcnt <= 2)))
    return MeshReport(
        n_vertices=n,
        n_faces=len(F),
        nonmanifold_edges=int(np.count_nonzero(ucount > 2)),
        inconsistent_edges=int(np.count_nonzero(dcount > 1)),
        nonmanifold_vertices=nm_vert,
        duplicate_faces=int(np.sum(fcount - 1)),
        degenerate_faces=int(np.count_nonzero(rep | (area <= area_tol))),
        unreferenced_vertices=int(np.count_nonzero(fcnt == 0)),
        boundary_loops=nb,
    )


_TREES: list = []          # small cache of libigl AABB trees: [(V copy, F copy, tree, last queries, derived)]
_TREES_LOCK = threading.Lock()


def _same_bits(a, b) -> bool:
    """``a`` and ``b`` hold the same bytes (same shape and dtype): -0.0 and 0.0 differ, a NaN equals itself.
    Compared as 8-byte words where the size allows, in chunks, stopping at the first that differs
    (a relaxed copy of a mesh is told from the cached one without reading all of it)."""
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    x, y = a.reshape(-1).view(np.uint8), b.reshape(-1).view(np.uint8)
    if len(x) % 8 == 0:
        x, y = x.view(np.uint64), y.view(np.uint64)
    step = 1 << 16
    return all(np.array_equal(x[i:i + step], y[i:i + step]) for i in range(0, len(x), step))


def _tree(V, F):
    """libigl AABB tree of (V, F), cached by content (a few trees are kept, each with its own
    copy of the arrays it was built on: a byte comparison with them costs a fraction of hashing,
    and the repairs look the same scan up dozens of times). The cache is locked: threads may
    look trees up side by side (the bake's steps); a tree itself is only read by queries."""
    import igl

    with _TREES_LOCK:
        for entry in _TREES:
            # faces first: the band's regions share the crop's vertices and differ in face count
            if _same_bits(F, entry[1]) and _same_bits(V, entry[0]):
                return entry
        V, F = V.copy(), F.copy()
        V.flags.writeable = F.flags.writeable = False
        t = igl.AABB()
        t.init(V, F)
        _TREES.insert(0, (V, F, t, {}, {}))
        del _TREES[4:]
        return _TREES[0]


def surface_face_normals(V, F):
    """(m, 3) :func:`face_normals` of the mesh (V, F), computed once and kept with its cached tree
    (:func:`closest_points`; built here if the mesh has none): the retopo repairs and band judge
    faces against the normals of the scan faces nearest them hundreds of times, and a row of the
    whole mesh's normals is the same bits as the normal of that face alone. Read-only."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    return _entry_normals(_tree(V, F))


def _entry_normals(entry):
    V, F, _, _, derived = entry
    N = derived.get("face_normals")
    if N is None:
        N = face_normals(V, F)
        N.flags.writeable = False
        derived["face_normals"] = N
    return N


# a mesh's vertices are asked about again; the bake's one-off queries of 0.2-1M texels or samples
# are not kept (their copies cost more in page faults than any reuse could save)
_REMEMBER_POINTS = 1 << 16


# queries of more points than this go to libigl in Morton order (below)
_SORT_FROM = 4096


def _morton_order(P):
    """An order of the points ``P`` (k, 3) along a Morton (Z-order) curve of a 1024³ grid over
    their box: neighbours in the order are near in space (non-finite coordinates count as the
    box's corner)."""
    finite = np.isfinite(P)
    lo = np.where(finite, P, np.inf).min(axis=0)
    lo = np.where(np.isfinite(lo), lo, 0.0)
    span = np.where(finite, P - lo, 0.0)
    scale = 1023.0 / max(float(span.max()), 1e-300)
    q = np.clip(span * scale, 0, 1023).astype(np.uint64)
    code = np.zeros(len(P), dtype=np.uint64)
    for a in range(3):                     # spread the 10 bits of each axis 3 apart, interleave
        x = q[:, a]
        x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
        x = (x | (x << np.uint64(2))) & np.uint64(0x09249249)
        code |= x << np.uint64(a)
    return np.argsort(code, kind="stable")


def _squared_distance(tree, V, F, P):
    """libigl's ``tree.squared_distance(V, F, P)`` as (sq float64, face int64, C float64), in the
    points' order. Many points are asked in Morton order: libigl answers each point on its own
    (from the root of the tree, so the same bits in any order), and points near each other walk
    the same branches while they are in the cache. Sampled points come in random order: 100k of
    them on a 150-200k-face mesh took 0.30 CPU-s as they came, 0.10 s in this order."""
    if len(P) < _SORT_FROM:
        sq, fi, C = tree.squared_distance(V, F, P)
        return np.asarray(sq, dtype=np.float64), np.asarray(fi, dtype=np.int64), np.asarray(C)
    order = _morton_order(P)
    sq_o, fi_o, C_o = tree.squared_distance(V, F, np.ascontiguousarray(P[order]))
    sq, fi, C = np.empty(len(P)), np.empty(len(P), dtype=np.int64), np.empty((len(P), 3))
    sq[order], fi[order], C[order] = sq_o, fi_o, C_o
    return sq, fi, C


def closest_points(P, V, F):
    """Closest points on mesh (V, F) to points P (libigl AABB tree, cached per mesh).

    Returns
    -------
    dist : (k,) float64 unsigned distances
    face : (k,) int64 face index of the closest point
    C : (k, 3) float64 closest points
    """
    if len(np.asarray(P).reshape(-1, 3)) == 0:
        return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    return closest_points_on(V, F)(P)


def closest_points_on(V, F):
    """:func:`closest_points` on the mesh (V, F) as a function of the points alone: the cached
    tree is looked up once (a byte comparison of V and F, ~1 ms on a 1.4M-triangle scan's crop),
    not on every call. Same answers, same bytes; for loops that ask about one surface hundreds of
    times (the band's smoothing sweeps, relax). The caller must not change V or F in place
    between calls. ``query.face_normals()``: :func:`surface_face_normals` of the mesh without a
    second lookup (each compares the mesh's bytes with the cached copy's: ~0.7 ms on the 1.4M
    head's crop, and relax, the band and the flip counts asked for both ~150 times)."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    entry = _tree(V, F)
    V, F, tree, last, _ = entry

    def query(P):
        P = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, 3)
        if len(P) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        # the retopo repairs ask about a whole mesh's vertices again and again with a few of them
        # moved (a flip count per candidate move, a repair round): the points whose bytes equal
        # those of the last query with as many points keep its answers. Each point's answer is its
        # own (libigl queries them one by one from the root), so the results are the same bytes.
        prev = last.get(len(P))
        if prev is None:
            moved = None
            sq, fi, C = _squared_distance(tree, V, F, P)
        else:
            P0, sq, fi, C = prev
            moved = np.flatnonzero((P.view(np.uint64) != P0.view(np.uint64)).any(axis=1))
            if len(moved) == len(P):
                # every point moved (the band's sweeps, most relax passes): no copies to patch
                sq, fi, C = _squared_distance(tree, V, F, P)
            else:
                sq, fi, C = sq.copy(), fi.copy(), C.copy()
            if 0 < len(moved) < len(P):
                s1, f1, c1 = _squared_distance(tree, V, F, np.ascontiguousarray(P[moved]))
                sq[moved], fi[moved], C[moved] = s1, f1, c1
        if (moved is None or len(moved)) and len(P) <= _REMEMBER_POINTS:
            if len(last) >= 4 and len(P) not in last:
                last.pop(next(iter(last)))
            last[len(P)] = (P.copy(), sq, fi.copy(), C.copy())
        return np.sqrt(np.maximum(sq, 0.0)), fi, C

    query.face_normals = lambda: _entry_normals(entry)
    return query


def sample_surface(V, F, n, seed=0):
    """``n`` points sampled uniformly by area, plus their face indices."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    rng = np.random.default_rng(seed)
    area = meshtopo.face_areas(V, F)
    cdf = np.cumsum(area)
    fi = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1]), len(F) - 1)
    r1 = np.sqrt(rng.random(n))
    r2 = rng.random(n)
    b = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
    P = np.einsum("ij,ijk->ik", b, V[F[fi]])
    return P, fi


def distance_stats(d) -> dict:
    """mean / rms / p95 / max of a distance sample (mm)."""
    d = np.asarray(d, dtype=np.float64)
    if len(d) == 0:
        return {"mean_mm": None, "rms_mm": None, "p95_mm": None, "max_mm": None}
    return {"mean_mm": float(d.mean()), "rms_mm": float(np.sqrt((d * d).mean())),
            "p95_mm": float(np.percentile(d, 95)), "max_mm": float(d.max())}


def surface_distance(VA, FA, VB, FB, n_samples=50000, seed=0) -> dict:
    """Two-sided surface distance between meshes A and B (mm).

    Returns
    -------
    dict with ``a_to_b`` and ``b_to_a`` stats (see :func:`distance_stats`) and
    ``symmetric_mean_mm`` (mean of the two means).
    """
    PA, _ = sample_surface(VA, FA, n_samples, seed)
    PB, _ = sample_surface(VB, FB, n_samples, seed + 1)
    dab, _, _ = closest_points(PA, VB, FB)
    dba, _, _ = closest_points(PB, VA, FA)
    a, b = distance_stats(dab), distance_stats(dba)
    return {"a_to_b": a, "b_to_a": b, "symmetric_mean_mm": 0.5 * (a["mean_mm"] + b["mean_mm"])}


def flipped_faces(V, F, VR, FR, max_distance=None):
    """Faces of (V, F) whose normal points against the reference surface (VR, FR).

    A face is flipped when its unit normal has a negative dot product with the
    normal of the reference face closest to its centroid. Faces farther than
    ``max_distance`` from the reference are not judged.

    Returns
    -------
    (m,) bool mask
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    cen = V[F].mean(axis=1)
    d, fi, _ = closest_points(cen, VR, FR)
    nr = face_normals(VR, np.asarray(FR)[fi])
    dots = np.einsum("ij,ij->i", face_normals(V, F), nr)
    bad = dots < 0
    if max_distance is not None:
        bad &= d <= max_distance
    return bad


def angle_stats(V, F) -> dict:
    """Minimum-angle statistics of the triangles (degrees)."""
    a = triangle_angles_deg(V, F).min(axis=1)
    return {"min_angle_min_deg": float(a.min()), "min_angle_p5_deg": float(np.percentile(a, 5)),
            "min_angle_mean_deg": float(a.mean()),
            "share_min_angle_below_10deg": float(np.mean(a < 10.0))}
