"""Safe mesh repairs and surface checks (vectorised; no per-face Python loops).

Only repairs that cannot change the shape are made: merging coincident
vertices, dropping zero-area and repeated faces, dropping small disconnected
components far from the eyes ("debris"), dropping the faces beyond two on an
edge (a fold or a patch laid over the skin: the two that continue the surface
stay), and dropping vertices no face uses.
:func:`repair_mesh` reports exactly what it removed and refuses (ScanError) when
the input is mostly degenerate or when the repairs would remove more than a
small share of the faces around an eye.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo


@dataclass(frozen=True)
class RepairSettings:
    """Thresholds for :func:`repair_mesh` (the stage fills them from ``params.yaml``).

    Attributes
    ----------
    merge_tolerance_mm : float
        Vertices on the same grid cell of this size are merged (exact duplicates for tiny values).
    degenerate_area_mm2 : float
        Faces with area below this are degenerate.
    max_degenerate_fraction : float
        Refuse when more than this share of faces is degenerate.
    debris_max_fraction : float
        A component with fewer faces than this share of the mesh (and not the largest) is debris ...
    eye_radius_mm : float
        ... unless it comes within this distance of an eye hint; this is also the eye-region radius.
    max_eye_region_removed_fraction : float
        Refuse when repairs remove more than this share of the faces within ``eye_radius_mm`` of a hint
        (zero-area faces are not counted: removing them changes no surface).
    """

    merge_tolerance_mm: float = 1e-4
    degenerate_area_mm2: float = 1e-10
    max_degenerate_fraction: float = 0.1
    debris_max_fraction: float = 0.01
    eye_radius_mm: float = 20.0
    max_eye_region_removed_fraction: float = 0.05


@dataclass
class RepairResult:
    """Output of :func:`repair_mesh`.

    Attributes
    ----------
    V : (n', 3) float64
    F : (m', 3) int64
    vertex_index : (n',) int64
        Index of each output vertex in the input ``V``.
    face_index : (m',) int64
        Index of each output face in the input ``F``.
    counts : dict
        What was removed: merged_vertices, degenerate_faces, duplicate_faces, debris_components,
        debris_faces, non_manifold_faces, unreferenced_vertices, small_components_kept_near_eyes.
    edges : dict
        :func:`edge_stats` of the output.
    eye_region : dict
        Per eye: faces with a vertex within the radius and how many repairs removed (zero-area
        faces apart: ``degenerate_removed``; they cover no surface and do not count as damage).
    """

    V: np.ndarray
    F: np.ndarray
    vertex_index: np.ndarray
    face_index: np.ndarray
    counts: dict = field(default_factory=dict)
    eye_region: dict = field(default_factory=dict)
    edges: dict = field(default_factory=dict)


_BLOCK = 1 << 16      # rows (faces, vertices, keys) per block: temporaries stay in cache, not fresh pages


def merge_vertices(V, F, tolerance: float):
    """Merge vertices that round to the same grid cell of size ``tolerance``.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    tolerance : float

    Returns
    -------
    V2 : (n', 3) float64
        The first vertex of each group (input order kept).
    F2 : (m, 3) int64
    keep : (n',) int64
        Input index of each kept vertex.
    """
    if tolerance > 0:
        cols = [np.round(V[:, k] / tolerance).astype(np.int64) for k in range(3)]
        if _keys_all_distinct(_hash_columns(*cols)):     # the usual scan: no row-wise unique needed
            return V, F, np.arange(len(V))
        q = np.stack(cols, axis=1)
        del cols
    else:
        q = V
    first, inverse = _unique_rows(q)
    if len(first) == len(V):                         # nothing to merge
        return V, F, np.arange(len(V))
    # renumber groups in order of first appearance so the output keeps the input order
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    keep = first[order]
    return V[keep], rank[inverse.reshape(-1)][F], keep


_MIX = (np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB))


def _mix(h) -> None:
    """splitmix64's finaliser on ``h`` (uint64), in place: every input bit reaches every output bit."""
    h ^= h >> np.uint64(30)
    h *= _MIX[0]
    h ^= h >> np.uint64(27)
    h *= _MIX[1]
    h ^= h >> np.uint64(31)


def _hash_columns(*cols) -> np.ndarray:
    """An int64 hash of the rows of the int64 columns ``cols`` (each (n,)), shape (n,); a block at a time.

    Each column is added to the mixed hash of the ones before it, so no small difference between
    two rows cancels: the linear ``a*K1 ^ b*K2 ^ c*K3`` it replaces collided on a 5M-vertex grid head,
    sending it down the row-wise unique (10 s). Only equality of hashes is used, never their order.
    """
    n = len(cols[0])
    out = np.empty(n, dtype=np.uint64)
    for i in range(0, n, _BLOCK):
        h = out[i:i + _BLOCK]
        h[:] = cols[0][i:i + _BLOCK].view(np.uint64)
        _mix(h)
        for c in cols[1:]:
            h += c[i:i + _BLOCK].view(np.uint64)
            _mix(h)
    return out.view(np.int64)


def _keys_all_distinct(key, kind=None) -> bool:
    """Whether the (n,) int64 ``key`` holds no value twice (sorts ``key`` in place, by ``kind``).

    Distinct hashes prove distinct rows; equal ones prove nothing (the caller then takes its
    exact path), so True is always right.
    """
    key.sort(kind=kind)
    return not np.any(key[1:] == key[:-1])


def _blockwise(fn, F, dtype=np.float64) -> np.ndarray:
    """``fn(F_block) -> (b,)`` applied to blocks of faces, shape (m,): temporaries stay block-sized."""
    out = np.empty(len(F), dtype=dtype)
    for i in range(0, len(F), _BLOCK):
        out[i:i + _BLOCK] = fn(F[i:i + _BLOCK])
    return out


def _columns(V):
    """x, y, z (n,) float64, contiguous: a gather from one column touches 8 bytes, not a 24-byte row,
    and the arithmetic runs on contiguous blocks (2.5x faster on a million faces)."""
    return tuple(np.ascontiguousarray(V[:, k], dtype=np.float64) for k in range(3))


def _cross(x, y, z, Fb):
    """x, y, z components (b,) of ``(v1 - v0) x (v2 - v0)`` of faces ``Fb`` (b, 3), from the vertex
    columns: the very operations of :func:`pipeline.geometry.meshtopo.triangle_cross`, so the same bits."""
    a, b, c = Fb[:, 0], Fb[:, 1], Fb[:, 2]
    xa, ya, za = x[a], y[a], z[a]
    abx, aby, abz = x[b] - xa, y[b] - ya, z[b] - za
    acx, acy, acz = x[c] - xa, y[c] - ya, z[c] - za
    return aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx


def _areas(x, y, z, Fb) -> np.ndarray:
    """Areas (b,) of faces ``Fb`` (b, 3) from the vertex columns (as :func:`meshtopo.face_areas`)."""
    cx, cy, cz = _cross(x, y, z, Fb)
    return 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)


def face_areas(V, F) -> np.ndarray:
    """Triangle areas, shape (m,), a block of faces at a time (an untrusted mesh at the limits)."""
    x, y, z = _columns(V)
    return _blockwise(lambda Fb: _areas(x, y, z, Fb), F)


def _degenerate_faces(V, F, area_below: float) -> np.ndarray:
    """(m,) bool: faces with a repeated corner or an area below ``area_below``, a block at a time."""
    x, y, z = _columns(V)

    def block(Fb):
        a, b, c = Fb[:, 0], Fb[:, 1], Fb[:, 2]
        return (a == b) | (b == c) | (a == c) | (_areas(x, y, z, Fb) < area_below)
    return _blockwise(block, F, dtype=bool)


def _unique_rows(q):
    """First index of each distinct row and the group of every row (int64 or float64 (n, 3)).

    Rows are hashed to one int64 key (fast 1-D unique); a hash collision falls back to
    the exact row-wise unique.
    """
    q = np.ascontiguousarray(q)
    if q.dtype.kind == "i" and len(q):
        key = _hash_columns(q[:, 0], q[:, 1], q[:, 2])
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        if np.array_equal(q[first[inverse]], q):
            return first, inverse
    rows = q.view(np.dtype((np.void, q.dtype.itemsize * q.shape[1]))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def duplicate_face_mask(F) -> np.ndarray:
    """True for every face whose vertex set repeats an earlier face (either orientation)."""
    if _faces_all_distinct(F):
        return np.zeros(len(F), dtype=bool)
    first, _ = _unique_rows(np.sort(F, axis=1))
    mask = np.ones(len(F), dtype=bool)
    mask[first] = False
    return mask


def _faces_all_distinct(F) -> bool:
    """Whether no two faces of ``F`` (m, 3) int64 share their vertex set, proven by distinct keys of their
    sorted corners ``lo < mid < hi``: ``lo`` in the top bits, below it ``mid * n + hi`` exactly when it fits
    (a scan under about 2M vertices), else a hash of ``(mid, hi)``. False when unsure:
    :func:`duplicate_face_mask` then takes the exact path."""
    if not len(F):
        return True
    n = int(F.max()) + 1
    shift = 63 - n.bit_length()                        # lo in the top bits: key order follows face order
    exact = n * n <= 1 << shift                         # mid * n + hi fits below lo
    low_mask = np.int64((1 << shift) - 1)
    key = np.empty(len(F), dtype=np.int64)
    for i in range(0, len(F), _BLOCK):                 # block-sized temporaries, written into key
        Fb = F[i:i + _BLOCK]
        a, b, c = Fb[:, 0], Fb[:, 1], Fb[:, 2]
        lo = np.minimum(np.minimum(a, b), c)
        hi = np.maximum(np.maximum(a, b), c)
        mid = a + b
        mid += c
        mid -= lo
        mid -= hi
        if exact:
            low = mid * np.int64(n)
            low += hi
        else:
            low = _hash_columns(mid, hi) & low_mask
        lo <<= np.int64(shift)
        np.bitwise_or(lo, low, out=key[i:i + _BLOCK])
    # a scan's faces come nearly in order of their lowest vertex, runs that timsort goes through
    return _keys_all_distinct(key, kind="stable")


def closest_point_on_triangles(A, B, C, p) -> np.ndarray:
    """Closest point to ``p`` on each triangle (Ericson, Real-Time Collision Detection 5.1.5).

    Parameters
    ----------
    A, B, C : (t, 3) float64
        Triangle corners.
    p : (3,) float64

    Returns
    -------
    (t, 3) float64
    """
    ab, ac, ap = B - A, C - A, p - A
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - B
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - C
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        out = A + ab * v[:, None] + ac * w[:, None]                       # interior
        # edge regions
        t_ab = np.clip(np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0), 0, 1)
        t_ac = np.clip(np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0), 0, 1)
        t_bc = np.clip(np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0), 0, 1)
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    out[m] = A[m] + ab[m] * t_ab[m, None]
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    out[m] = A[m] + ac[m] * t_ac[m, None]
    m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    out[m] = B[m] + (C[m] - B[m]) * t_bc[m, None]
    # vertex regions last (they win)
    m = (d1 <= 0) & (d2 <= 0)
    out[m] = A[m]
    m = (d3 >= 0) & (d4 <= d3)
    out[m] = B[m]
    m = (d6 >= 0) & (d5 <= d6)
    out[m] = C[m]
    return out


def face_longest_edges(V, F) -> np.ndarray:
    """Longest edge of each triangle, shape (m,)."""
    x, y, z = _columns(V)

    def longest(Fb):
        a, b, c = Fb[:, 0], Fb[:, 1], Fb[:, 2]
        xa, ya, za, xb, yb, zb, xc, yc, zc = x[a], y[a], z[a], x[b], y[b], z[b], x[c], y[c], z[c]
        # squared lengths summed (x + z) + y: the order of the pinned kernels' einsum("ij,ij->i") over a
        # row of three (two SSE lanes, x and z in one), so the same bits as the row-wise code before
        sq = [(dx * dx + dz * dz) + dy * dy for dx, dy, dz in
              ((xa - xb, ya - yb, za - zb), (xb - xc, yb - yc, zb - zc), (xc - xa, yc - ya, zc - za))]
        return np.sqrt(np.maximum(np.maximum(sq[0], sq[1]), sq[2]))
    return _blockwise(longest, F)


def point_surface_distance(V, F, p, longest_edges=None) -> float:
    """Distance from point ``p`` to the triangle surface ``(V, F)``.

    Only triangles that can hold the closest point are tested exactly: every point of a
    triangle lies within its longest edge of each of its vertices, so a triangle whose
    nearest vertex is farther than (nearest mesh vertex distance + its longest edge)
    cannot beat that vertex.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    p : (3,) float64
    longest_edges : (m,) float64, optional
        :func:`face_longest_edges`, when computed once for several points.

    Returns
    -------
    float
    """
    p = np.asarray(p, dtype=np.float64)
    if longest_edges is None:
        longest_edges = face_longest_edges(V, F)
    dv = np.sqrt(_squared_distances(V, p))
    upper = float(dv.min())                  # the nearest vertex is on the surface
    cand = []
    for i in range(0, len(F), _BLOCK):
        Fb = F[i:i + _BLOCK]
        dmin = np.minimum(np.minimum(dv[Fb[:, 0]], dv[Fb[:, 1]]), dv[Fb[:, 2]])
        dmin -= longest_edges[i:i + _BLOCK]
        cand.append(np.flatnonzero(dmin <= upper) + i)
    cand = np.concatenate(cand) if cand else np.zeros(0, dtype=np.int64)
    A, B, C = V[F[cand, 0]], V[F[cand, 1]], V[F[cand, 2]]
    q = closest_point_on_triangles(A, B, C, p) - p
    return float(np.sqrt(np.einsum("ij,ij->i", q, q)).min(initial=upper))


def repair_mesh(V, F, hints: dict, settings: RepairSettings = RepairSettings(), path="mesh") -> RepairResult:
    """Make the safe repairs and report them.

    Parameters
    ----------
    V : (n, 3) float64
        Head-frame mm.
    F : (m, 3) int64
    hints : dict[str, (3,) float64]
        Eye hints, head-frame mm.
    settings : RepairSettings
    path : str or os.PathLike
        Named in errors.

    Returns
    -------
    RepairResult
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    m0, n0 = len(F), len(V)
    V1, F1, vkeep = merge_vertices(V, F, settings.merge_tolerance_mm)
    merged = n0 - len(V1)
    degenerate = _degenerate_faces(V1, F1, settings.degenerate_area_mm2)
    n_deg = int(degenerate.sum())
    if n_deg > settings.max_degenerate_fraction * m0:
        raise ScanError(path, f"{n_deg} of {m0} faces ({100.0 * n_deg / m0:.1f}%) are degenerate (zero area), "
                              f"over the limit of {100.0 * settings.max_degenerate_fraction:g}% "
                              "(ingest.max_degenerate_fraction)")
    alive = ~degenerate
    dup = np.zeros(m0, dtype=bool)
    idx = np.flatnonzero(alive)
    dup[idx] = duplicate_face_mask(_rows(F1, idx))
    alive &= ~dup
    # debris: small components far from both eyes
    idx = np.flatnonzero(alive)
    if len(idx) == 0:
        raise ScanError(path, "no faces left after removing degenerate and duplicate faces")
    n_comp, labels = meshtopo.face_components_by_vertex(_rows(F1, idx), len(V1))
    sizes = np.bincount(labels, minlength=n_comp)
    small = (sizes < settings.debris_max_fraction * len(idx)) & (np.arange(n_comp) != np.argmax(sizes))
    # with nothing merged (V1 is V, F1 is F) the eye-region masks below are these, taken whole
    same = V1 is V and F1 is F
    near_all = {side: _faces_near(V1, F1, h, settings.eye_radius_mm) for side, h in hints.items()} if same else {}
    near = np.zeros(n_comp, dtype=bool)
    for side, h in hints.items():
        faces = _rows(near_all[side], idx) if same else _faces_near(V1, _rows(F1, idx), h, settings.eye_radius_mm)
        near[np.unique(labels[faces])] = True
    debris_comp = small & ~near
    debris = np.zeros(m0, dtype=bool)
    debris[idx] = debris_comp[labels]
    alive &= ~debris
    del idx, labels                     # the edge keys below are the peak's largest temporary
    face_index = np.flatnonzero(alive)
    F2 = F1 if len(face_index) == m0 else F1[face_index]
    # the output's edges, counted here (the stage reports them) and read for the one repair that
    # needs them: an edge with more than two faces stops every stage that walks the surface (a
    # hole fill laid over a rim face left a third face on a lid edge, and retopo found no
    # closed boundary loops); of its faces the two that continue the surface stay
    edges = edge_stats(F2, len(V1))
    n_nm = 0
    if edges["non_manifold"]:
        extra = _faces_beyond_two(V1, F2)
        n_nm = int(extra.sum())
        alive[face_index[extra]] = False
        face_index = face_index[~extra]
        F2 = F1[face_index]
        edges = edge_stats(F2, len(V1))
    # eye-region accounting (faces of the input with a vertex near the hint). Zero-area faces
    # cover no surface, so removing them damages nothing: they count neither as faces nor as lost.
    removed = ~alive & ~degenerate
    eye_region = {}
    for side, h in hints.items():
        near_hint = near_all[side] if same else _faces_near(V, F, h, settings.eye_radius_mm)
        inside = near_hint & ~degenerate
        total, lost = int(inside.sum()), int((inside & removed).sum())
        eye_region[side] = {"faces": total, "removed": lost,
                            "degenerate_removed": int((near_hint & degenerate).sum())}
        if total and lost > settings.max_eye_region_removed_fraction * total:
            raise ScanError(path, f"repairs would remove {lost} of the {total} faces ({100.0 * lost / total:.1f}%) "
                                  f"within {settings.eye_radius_mm:g} mm of the {side} eye hint, over the limit of "
                                  f"{100.0 * settings.max_eye_region_removed_fraction:g}%: the eye region is damaged")
    used = np.zeros(len(V1), dtype=bool)
    used[F2.ravel()] = True
    n_used = int(np.count_nonzero(used))
    counts = {
        "merged_vertices": int(merged),
        "degenerate_faces": n_deg,
        "duplicate_faces": int(dup.sum()),
        "debris_components": int(debris_comp.sum()),
        "debris_faces": int(debris.sum()),
        "non_manifold_faces": n_nm,
        "unreferenced_vertices": int(len(V1) - n_used),
        "small_components_kept_near_eyes": int((small & near).sum()),
        "components": int(n_comp - debris_comp.sum()),
    }
    if n_used == len(V1):                            # every vertex kept: the renumbering is the identity
        # C order as the gathers below give it (np.save writes a Fortran array's bytes otherwise)
        return RepairResult(V=np.ascontiguousarray(V1), F=np.ascontiguousarray(F2), vertex_index=vkeep,
                            face_index=face_index, counts=counts, eye_region=eye_region, edges=edges)
    remap = np.cumsum(used) - 1
    return RepairResult(V=V1[used], F=remap[F2], vertex_index=vkeep[used], face_index=face_index,
                        counts=counts, eye_region=eye_region, edges=edges)


def _faces_beyond_two(V, F) -> np.ndarray:
    """Mask (m,) of the faces to drop so that no edge of ``F`` has more than two: on each such
    edge the two faces that run it in opposite directions (a consistently wound surface) with
    the most nearly equal normals stay; where every face runs it one way, the largest. Only the
    few faces of such edges are looked at one by one."""
    key = _directed_edge_keys(F, len(V))
    und = key >> 1
    order = np.argsort(und, kind="stable")
    su = und[order]
    starts = np.flatnonzero(np.r_[True, su[1:] != su[:-1]])
    lens = np.diff(np.r_[starts, len(su)])
    drop = np.zeros(len(F), dtype=bool)
    for s0, k in zip(starts[lens > 2].tolist(), lens[lens > 2].tolist()):
        rows = order[s0:s0 + k]
        faces, fwd = rows // 3, (key[rows] & 1).astype(bool)
        P = V[F[faces]]
        N = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        area = np.linalg.norm(N, axis=1)
        N = N / np.maximum(area, 1e-300)[:, None]
        pairs = [(float(N[i] @ N[j]), i, j) for i in range(k) for j in range(i + 1, k) if fwd[i] != fwd[j]]
        keep = {max(pairs)[1], max(pairs)[2]} if pairs else {int(np.argmax(area))}
        drop[[f for i, f in enumerate(faces.tolist()) if i not in keep]] = True
    return drop


def _rows(A, idx):
    """``A[idx]`` for increasing indices ``idx``, or ``A`` itself when ``idx`` takes every row (no copy)."""
    return A if len(idx) == len(A) else A[idx]


def edge_stats(F, n_vertices: int) -> dict:
    """Boundary, non-manifold and inconsistently oriented edges of a triangle mesh.

    Parameters
    ----------
    F : (m, 3) int64
    n_vertices : int

    Returns
    -------
    dict
        ``edges`` (distinct undirected), ``boundary`` (used by one face), ``non_manifold``
        (used by more than two), ``inconsistent_winding`` (two faces traversing the edge in the
        same direction: their normals disagree).
    """
    key = _directed_edge_keys(F, n_vertices)
    key.sort(kind="stable")        # the same sorted keys; timsort finds the runs a scan's face order leaves
    n = len(key)
    if n == 0:
        return {"edges": 0, "boundary": 0, "non_manifold": 0, "inconsistent_winding": 0}
    # Keys of one edge differ in bit 0 only: the xor of neighbours is 0 (same edge, same direction),
    # 1 (same edge, opposite directions) or more (a new edge). start[i]: key i begins an edge's run,
    # with start[n] = start[n + 1] = True past the end. Runs are read from these flags (one byte per
    # key, a block at a time) instead of index arrays per edge: a tenth of the memory at the limits.
    start = np.empty(n + 2, dtype=bool)
    same_dir = np.empty(n - 1, dtype=bool)
    start[0] = start[n] = start[n + 1] = True
    for i in range(0, n - 1, _BLOCK):
        j = min(i + _BLOCK, n - 1)
        x = key[i + 1:j + 1] ^ key[i:j]
        np.greater(x, 1, out=start[i + 1:j + 1])
        np.equal(x, 0, out=same_dir[i:j])
    del key
    head, nxt, after = start[:n - 1], start[1:n], start[2:n + 1]     # runs starting at 0 .. n-2
    two = head & ~nxt & after                                         # runs of exactly two keys
    return {"edges": int(np.count_nonzero(start[:n])),
            "boundary": int(np.count_nonzero(start[:n] & start[1:n + 1])),
            "non_manifold": int(np.count_nonzero(head & ~nxt & ~after)),
            "inconsistent_winding": int(np.count_nonzero(two & same_dir))}


def _directed_edge_keys(F, n_vertices: int) -> np.ndarray:
    """One int64 per directed edge, (undirected edge key) * 2 + (traversed low -> high), shape (3m,):
    face by face, edges (0,1), (1,2), (2,0); built a block of faces at a time (temporaries in cache)."""
    key = np.empty(3 * len(F), dtype=np.int64)
    for i in range(0, len(F), _BLOCK):
        Fb = np.ascontiguousarray(F[i:i + _BLOCK], dtype=np.int64)
        v = np.empty_like(Fb)                                  # each corner's successor
        v[:, :2] = Fb[:, 1:]
        v[:, 2] = Fb[:, 0]
        u, v = Fb.ravel(), v.ravel()
        kb = key[3 * i:3 * (i + len(Fb))]
        np.minimum(u, v, out=kb)
        kb *= np.int64(n_vertices)
        kb += np.maximum(u, v)
        kb <<= 1
        kb |= u < v
    return key


def _faces_near(V, F, p, radius: float) -> np.ndarray:
    """Mask of faces with at least one vertex within ``radius`` of ``p`` (the eye region), shape (m,)."""
    return meshtopo.faces_touching(F, _squared_distances(V, np.asarray(p, dtype=np.float64)) <= radius * radius)


def _squared_distances(V, p) -> np.ndarray:
    """(n,) squared distances of the vertices ``V`` (n, 3) to ``p`` (3,), a block of rows at a time (the
    row-wise einsum of the whole ``V - p``, the same bits, without its full-size temporary)."""
    out = np.empty(len(V), dtype=np.float64)
    for i in range(0, len(V), _BLOCK):
        d = V[i:i + _BLOCK] - p
        out[i:i + _BLOCK] = np.einsum("ij,ij->i", d, d)
    return out


def mean_normal_near(V, F, p, radius: float) -> np.ndarray:
    """Area-weighted mean face normal (unnormalised) of faces with a vertex within ``radius`` of ``p``."""
    return 0.5 * meshtopo.triangle_cross(V, F[_faces_near(V, F, p, radius)]).sum(axis=0)
