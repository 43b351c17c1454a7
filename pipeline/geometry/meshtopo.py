"""Triangle-mesh helpers: normals and areas, face and vertex adjacency, components, boundary loops,
manifold checks."""

from __future__ import annotations

import numpy as np


def face_adjacency(F, n_vertices=None):
    """Pairs of faces sharing an edge.

    Parameters
    ----------
    F : (m, 3) int64
    n_vertices : int, optional

    Returns
    -------
    pairs : (k, 2) int64
        Face index pairs; an edge with more than two faces links consecutive ones.
    edge_vertices : (k, 2) int64
        The shared edge (sorted vertex ids) of each pair.
    """
    F = np.asarray(F, dtype=np.int64)
    n = int(F.max()) + 1 if n_vertices is None else int(n_vertices)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E.sort(axis=1)
    fid = np.tile(np.arange(len(F)), 3)
    key = E[:, 0] * n + E[:, 1]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    same = ks[1:] == ks[:-1]
    a, b = order[:-1][same], order[1:][same]
    return np.column_stack([fid[a], fid[b]]), E[a]


def vertex_adjacency(F, n):
    """(n, n) sparse 0/1 matrix (CSR, float64), 1 where two vertices share an edge of ``F``."""
    from scipy.sparse import coo_matrix

    F = np.asarray(F, dtype=np.int64)
    e = np.stack([F, np.roll(F, -1, axis=1)], axis=-1).reshape(-1, 2)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return ((A + A.T) > 0).astype(np.float64)


def face_components(n_faces, pairs, mask=None):
    """Connected components of faces over shared edges.

    Parameters
    ----------
    n_faces : int
    pairs : (k, 2) int64
        From :func:`face_adjacency`.
    mask : (n_faces,) bool, optional
        Only faces in the mask are linked (others end up in singleton components).

    Returns
    -------
    labels : (n_faces,) int64
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    p = pairs
    if mask is not None:
        keep = mask[p[:, 0]] & mask[p[:, 1]]
        p = p[keep]
    G = coo_matrix((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n_faces, n_faces))
    _, labels = connected_components(G, directed=False)
    return labels.astype(np.int64)


def face_components_by_vertex(F, n_vertices: int):
    """Connected components of faces sharing a vertex (:func:`face_components`: sharing an edge).

    Returns
    -------
    n : int
    labels : (m,) int64
        Component of each face.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(F, dtype=np.int64)
    # Each face links corners 1 and 2 to corner 0 (the components of a path through the three), in CSR
    # rows grouped by corner 0: a stable argsort runs through a scan's face order, and scipy gets its
    # own index and data types, with no COO conversion nor float copy. Labels number components by
    # their lowest vertex, whatever the edges, so they are the same.
    idx = np.int32 if max(n_vertices, 2 * len(F)) < 2**31 else np.int64
    order = np.argsort(F[:, 0], kind="stable")
    indptr = np.zeros(n_vertices + 1, dtype=idx)
    np.cumsum(2 * np.bincount(F[:, 0], minlength=n_vertices), out=indptr[1:])
    indices = F[order, 1:].astype(idx).ravel()
    del order
    graph = csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n_vertices, n_vertices))
    n, vlabels = connected_components(graph, directed=False)
    return n, vlabels[F[:, 0]].astype(np.int64)


def has_halfedge(F, a, b) -> bool:
    """Whether some face of ``F`` (m, 3) runs from vertex ``a`` to ``b`` (the directed edge a -> b)."""
    F = np.asarray(F)
    return bool(np.any((F == a) & (np.roll(F, -1, axis=1) == b)))


def faces_touching(F, vmask):
    """(m,) bool: the faces of ``F`` with a vertex in ``vmask`` (n,) bool; ``vmask[F].any(axis=1)``
    by its three columns (half the time on a million faces: no reduce over a length-3 axis)."""
    F = np.asarray(F)
    return vmask[F[:, 0]] | vmask[F[:, 1]] | vmask[F[:, 2]]


def boundary_mask(F):
    """Which half-edges of ``F`` have no opposite: ``(open, repeated)``.

    ``open`` (3, m) bool: row ``k`` holds the edges ``F[:, k] -> F[:, (k + 1) % 3]``, True where
    no face runs the other way. ``repeated``: some directed half-edge belongs to two faces,
    which is exactly when ``F`` is not edge-manifold (:func:`is_edge_manifold`; three faces on
    one edge repeat a direction too).

    One sort of the edges, each keyed by its two vertices and its direction: an interior edge
    of an edge-manifold mesh is two adjacent keys that differ in the direction only, a boundary
    edge one key alone; the few lone keys are then looked up among the half-edges between
    boundary vertices (a search of every half-edge among all of them took as long as the sort).
    """
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return np.zeros((3, 0), bool), False
    n = int(F.max()) + 1
    # rows laid out as the (3, m) result (its ravel a view), the key built in place: at 1.4M
    # faces each fresh 34 MB temporary is first touched page by page, which cost more than the sort
    a = np.ascontiguousarray(F.T)
    b = np.roll(a, -1, axis=0)
    key = np.minimum(a, b)
    key *= n
    key += np.maximum(a, b)
    key *= 2
    key += a > b
    key = key.ravel()
    s = np.sort(key)
    if (s[1:] == s[:-1]).any():                 # a repeated direction: not edge-manifold
        rev = (b * n + a).ravel()
        sf = np.sort((a * n + b).ravel())
        i = np.minimum(np.searchsorted(sf, rev), len(sf) - 1)
        return (sf[i] != rev).reshape(3, -1), True
    und = s >> 1
    differs = und[1:] != und[:-1]
    alone = np.ones(len(s), bool)
    alone[1:] &= differs
    alone[:-1] &= differs
    lone = s[alone]                             # sorted keys of the boundary half-edges
    open_ = np.zeros(key.shape, bool)
    if len(lone):
        on = np.zeros(n, bool)
        u = lone >> 1
        on[u // n] = True
        on[u % n] = True
        cand = np.flatnonzero(on[a.ravel()] & on[b.ravel()])
        j = np.minimum(np.searchsorted(lone, key[cand]), len(lone) - 1)
        open_[cand] = lone[j] == key[cand]
    return open_.reshape(3, -1), False


def cut_boundary_mask(F, open_, remove):
    """:func:`boundary_mask`'s ``open`` of ``F[~remove]`` from that of ``F`` (``open_``), (3, m')
    bool. Removing faces opens only half-edges whose two vertices both lie on removed faces
    (their opposite may have gone with a removed face), so only those are looked up again,
    among the kept faces that have such an edge: a few thousand of a scan's million faces
    instead of a second sort of every edge (0.35 s at 1.4M faces)."""
    F = np.asarray(F, dtype=np.int64)
    keep = ~np.asarray(remove, bool)
    out = open_[:, keep]
    if keep.all() or not keep.any():
        return out.copy() if keep.all() else out
    n = int(F.max()) + 1
    touched = np.zeros(n, bool)
    touched[F[~keep].ravel()] = True
    Fk = F[keep]
    tk = touched[Fk]
    both = tk & np.roll(tk, -1, axis=1)          # (m', 3): edge k of the face has both ends touched
    rows = np.flatnonzero(both.any(axis=1))
    if len(rows) == 0:
        return out
    Fc, bc = Fk[rows], both[rows]
    a, b = Fc, np.roll(Fc, -1, axis=1)
    keys = np.sort((a * n + b)[bc])              # every kept half-edge with both ends touched
    rev = (b * n + a)[bc]
    i = np.minimum(np.searchsorted(keys, rev), len(keys) - 1)
    f, k = np.nonzero(bc)
    out[k, rows[f]] = keys[i] != rev
    return out


def halfedges_of(F, open_, face_order: bool = False):
    """The half-edges (a, b) of ``F`` marked in ``open_`` (3, m), (k, 2) int64, in the order of
    :func:`boundary_halfedges`."""
    F = np.asarray(F, dtype=np.int64)
    f, k = np.nonzero(open_.T) if face_order else np.nonzero(open_)[::-1]
    return np.column_stack([F[f, k], F[f, (k + 1) % 3]]) if len(f) else np.zeros((0, 2), np.int64)


def boundary_halfedges(F, face_order: bool = False):
    """Directed edges (a, b) of faces whose opposite (b, a) belongs to no face, (k, 2) int64.

    In the order of the faces' first edges, then their second and third edges; with
    ``face_order`` face by face (face 0's edges first).
    """
    F = np.asarray(F, dtype=np.int64)
    return halfedges_of(F, boundary_mask(F)[0], face_order)


def boundary_component_count(F, H=None) -> int:
    """Number of connected pieces of the boundary-edge graph (= boundary loops when simple).

    ``H``: the mesh's :func:`boundary_halfedges`, when already computed.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H = boundary_halfedges(F) if H is None else H
    if len(H) == 0:
        return 0
    u, inv = np.unique(H.ravel(), return_inverse=True)
    inv = inv.reshape(-1, 2)
    G = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(len(u), len(u)))
    return int(connected_components(G, directed=False)[0])


def boundary_loops(F, only=None, H=None):
    """Boundary loops of a triangle mesh as ordered vertex-index arrays.

    ``only`` (vertex ids): walk just the loops through these vertices.
    ``H``: the mesh's :func:`boundary_halfedges`, when already computed.

    Raises
    ------
    ValueError
        When a boundary vertex has more than one outgoing boundary edge (a bow-tie).
    """
    H = boundary_halfedges(F) if H is None else H
    if only is not None:
        H = H[np.isin(H[:, 0], only) | np.isin(H[:, 1], only)]
    if len(H) == 0:
        return []
    starts, counts = np.unique(H[:, 0], return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"{int((counts > 1).sum())} boundary vertices are bow-ties")
    nxt = dict(zip(H[:, 0].tolist(), H[:, 1].tolist()))
    seen = set()
    loops = []
    for s in H[:, 0].tolist():
        if s in seen:
            continue
        loop = [s]
        seen.add(s)
        v = nxt[s]
        while v != s:
            if v in seen or v not in nxt:
                raise ValueError("boundary edges do not form closed loops")
            loop.append(v)
            seen.add(v)
            v = nxt[v]
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def split_fans(F, n_vertices=None):
    """Give each fan of faces round a vertex its own copy of the vertex: a vertex whose faces fall
    into several groups that share no edge through it (a bow-tie, where two boundary loops touch,
    or two cones meeting at a point) becomes one vertex per group. The surface is unchanged (the
    copies sit where the vertex was); its boundary loops then never touch. Edges with more than
    two faces are left as they are (their faces stay in one fan).

    Parameters
    ----------
    F : (m, 3) int64
    n_vertices : int, optional (default ``F.max() + 1``)

    Returns
    -------
    F2 : (m, 3) int64
        ``F`` with the corners of every fan but a vertex's first (lowest face) renumbered.
    parent : (n2,) int64
        The original vertex of every vertex of ``F2``: ``arange(n)`` then one entry per copy.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(F, dtype=np.int64)
    n = (int(F.max()) + 1 if len(F) else 0) if n_vertices is None else int(n_vertices)
    if len(F) == 0:
        return F.copy(), np.arange(n, dtype=np.int64)
    pairs, ev = face_adjacency(F, n)
    # two faces sharing the edge (a, b) join their corners at a and at b into one fan
    corner = lambda f, v: 3 * f + np.argmax(F[f] == v[:, None], axis=1)     # noqa: E731
    rows = np.concatenate([corner(pairs[:, 0], ev[:, 0]), corner(pairs[:, 0], ev[:, 1])])
    cols = np.concatenate([corner(pairs[:, 1], ev[:, 0]), corner(pairs[:, 1], ev[:, 1])])
    m3 = 3 * len(F)
    _, lab = connected_components(coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)),
                                             shape=(m3, m3)), directed=False)
    v = F.ravel()
    # one fan per (vertex, component): fan index of every corner, its vertex and first corner
    _, first, fan = np.unique(v * m3 + lab, return_index=True, return_inverse=True)
    fan_v = v[first]
    # the fan whose first corner comes first (the lowest face) keeps the vertex's id
    by = np.lexsort((first, fan_v))
    extra = np.zeros(len(first), dtype=bool)
    extra[by[1:]] = fan_v[by[1:]] == fan_v[by[:-1]]
    new_id = fan_v.copy()
    new_id[by[extra[by]]] = n + np.arange(int(extra.sum()))
    parent = np.concatenate([np.arange(n, dtype=np.int64), fan_v[by[extra[by]]]])
    return new_id[fan.ravel()].reshape(-1, 3), parent


def is_edge_manifold(F) -> bool:
    """True when every edge has at most two faces and opposite orientations where it has two
    (no directed half-edge repeats: three faces on one edge repeat a direction too)."""
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return True
    n = int(F.max()) + 1
    fwd = np.sort((F * n + np.roll(F, -1, axis=1)).ravel())
    return not bool((fwd[1:] == fwd[:-1]).any())


# Triangle normals and areas, the one place (measured on a 164k-vertex, 328k-face sphere, loaded
# 2-core machine: np.cross 97 ms, the components below 69 ms, the same bits; np.add.at 68 ms,
# one bincount per axis 36 ms, the same bits: both add in face order, corner 0 first. libigl's
# per_vertex_normals takes 29 ms but sums in another order: its normals differ in the last bit,
# which would change the bake's maps and every product after them, so it is not used.)

def _cross_components(V, F):
    """x, y, z components (m,) of ``(v1 - v0) x (v2 - v0)`` of every face."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    a = V[F[:, 0]]
    ab, ac = V[F[:, 1]] - a, V[F[:, 2]] - a
    return (ab[:, 1] * ac[:, 2] - ab[:, 2] * ac[:, 1],
            ab[:, 2] * ac[:, 0] - ab[:, 0] * ac[:, 2],
            ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])


def triangle_cross(V, F):
    """(m, 3) ``(v1 - v0) x (v2 - v0)`` of every face: the normal times twice the area."""
    return np.stack(_cross_components(V, F), axis=1)


def face_areas(V, F):
    """(m,) triangle areas (from the components: a norm along a length-3 axis is slow in numpy)."""
    cx, cy, cz = _cross_components(V, F)
    return 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)


def face_normals(V, F, normalize=True):
    """(m, 3) face normals: unit (zero for degenerate faces), or with ``normalize=False`` the
    plain cross products (length twice the face area)."""
    N = triangle_cross(V, F)
    if not normalize:
        return N
    L = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, L, out=np.zeros_like(N), where=L > 0)


def vertex_normals(V, F):
    """Area-weighted unit vertex normals (n, 3) (zero for unreferenced vertices)."""
    F = np.asarray(F, dtype=np.int64)
    corner = F.T.ravel()                   # every face's corner 0, then corner 1, then corner 2
    VN = np.stack([np.bincount(corner, np.tile(c, 3), minlength=len(V)) for c in _cross_components(V, F)],
                  axis=1)
    L = np.linalg.norm(VN, axis=1, keepdims=True)
    return np.divide(VN, L, out=np.zeros_like(VN), where=L > 0)


#: A mesh whose area-weighted normals sum to less than this share of its area faces no one way
#: (a closed surface: an eyeball): its faces turn over by the normal's turn alone.
FACING_MIN_SHARE = 0.5


def turned_over_faces(n0, n1) -> np.ndarray:
    """(m,) bool: the faces that turn over between two poses of one mesh, from their
    area-weighted normals at rest ``n0`` and posed ``n1`` (m, 3): turned by more than 90 degrees
    from rest, and, where the mesh faces one way (an eye region: its normals' area-weighted sum
    at rest, at least ``FACING_MIN_SHARE`` of its area), turned away from that way. Skin folding
    under turns from facing out to facing in; a crease unrolling turns the other way, from its
    underside to facing out, and is no fold (the lid skin a look up draws into the upper lid's
    crease unrolls by 130 degrees as the lid comes down: fresh21's `n2701_look_up_out_250k`,
    a sliver whose cosine with the eye region's facing is -0.62 at rest and 0.68 looking down 25 deg)."""
    n0 = np.asarray(n0, np.float64)
    n1 = np.asarray(n1, np.float64)
    turned = np.einsum("ij,ij->i", n0, n1) <= 0
    if not turned.any():
        return turned
    l0 = np.linalg.norm(n0, axis=1)
    o = n0.sum(axis=0)
    if np.linalg.norm(o) < FACING_MIN_SHARE * l0.sum():
        return turned
    o = o / np.linalg.norm(o)
    l1 = np.linalg.norm(n1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        before = np.where(l0 > 0, (n0 @ o) / l0, 0.0)
        after = np.where(l1 > 0, (n1 @ o) / l1, 0.0)
    return turned & (after < before)
