"""Handles (tunnels through the surface) round the eye openings, cut before the band is built.

The band (:mod:`pipeline.retopo.eye_band`) parametrises the dense surface within
``band_param_mm`` of each opening as an annulus; a handle there (``id339_laser``'s crop has a
tunnel within 10 mm of its left opening) leaves no annulus at any radius. A handle is cut along
a short non-separating loop: the faces round the loop are taken out and each of the two new
borders is closed with a fan, so the region loses one handle, stays one piece, and keeps every
border it had (the opening included) untouched.

The loop is the shortest of a greedy homology basis (Erickson and Whittlesey, "Greedy optimal
homotopy and homology generators", SODA 2005) through each of a few root vertices: a shortest-path
tree from the root, a maximum spanning tree of the dual graph over the other edges weighted by
the length of each edge's loop, and the 2g edges left over close the basis' loops. The region's
borders are capped with a cone first (a closed surface, so the basis spans its handles only, not
loops round a border) and every edge at a border or a cone weighs ``_FAR`` mm: no chosen loop
touches a border.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import mesh_checks as mc
from pipeline.geometry import meshtopo
from pipeline.geometry.mesh_edit import loop_perimeter

_FAR = 1e6          # mm: the weight of an edge at a border or a cap's cone (never on a cut loop)
_ROOTS = 24         # roots tried per region (spread by farthest-point sampling along the edges)
_NEAR_ROOTS = 48    # then at most about this many round the shortest loop found, up to 3 rounds


def _edge_keys(F, n):
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return e[:, 0] * n + e[:, 1]


def euler_genus(F) -> tuple[int, int, int, int]:
    """(genus, Euler characteristic, borders, pieces) of the faces ``F``, each bow-tie vertex
    split into one per fan first (a region cut out by distance pinches at some border vertices:
    no handle); ValueError when they are not edge-manifold."""
    F = meshtopo.split_fans(np.asarray(F, dtype=np.int64))[0]
    n = int(F.max()) + 1
    k, cnt = np.unique(_edge_keys(F, n), return_counts=True)
    if (cnt > 2).any():
        raise ValueError("not edge-manifold")
    chi = len(np.unique(F)) - len(k) + len(F)
    b = len(mc.boundary_loops(F))
    pairs, _ = meshtopo.face_adjacency(F, n)
    c = len(np.unique(meshtopo.face_components(len(F), pairs)))
    return (2 * c - chi - b) // 2, chi, b, c


def region_faces(V, F, hole, radius):
    """(m,) bool: the faces within ``radius`` mm (along the edges) of the loop ``hole``."""
    from pipeline.retopo.eye_rings import edge_graph_distance

    d = edge_graph_distance(V, F, hole, 1.5 * radius)
    return (d[F] < radius).all(axis=1)


def _capped(F):
    """Local ids: the region's faces, each border capped with a cone vertex. Returns (Fl, vids,
    cone_vertices, border_vertices): Fl over local ids, vids the global id of each real one."""
    vids, Fl = np.unique(F, return_inverse=True)
    Fl = Fl.reshape(-1, 3)
    n = len(vids)
    caps, cones, border = [], [], []
    H = meshtopo.boundary_halfedges(Fl)
    nxt = dict(zip(H[:, 0].tolist(), H[:, 1].tolist()))
    for lp in mc.boundary_loops(Fl):
        c = n + len(cones)
        cones.append(c)
        border.append(lp)
        for a in lp.tolist():
            caps.append((nxt[a], a, c))        # against the border's half-edge a -> nxt[a]
    Fl = np.concatenate([Fl, np.asarray(caps, dtype=np.int64).reshape(-1, 3)])
    return Fl, vids, np.asarray(cones, dtype=np.int64), (np.concatenate(border) if border else
                                                        np.zeros(0, dtype=np.int64))


def shortest_handle_loop(V, F, roots=_ROOTS):
    """The shortest non-separating loop found of the faces ``F`` (global ids; an edge-manifold
    piece), clear of their borders: (L,) global vertex ids in loop order, or None (no handle, or
    every loop found touches a border). Its length is ``loop_length(V, loop)``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra, minimum_spanning_tree

    F, parent = meshtopo.split_fans(np.asarray(F, dtype=np.int64))
    Fl, vids, cones, border = _capped(F)
    vids = parent[vids]                         # a bow-tie's copies are border vertices: never on a loop
    n = len(vids) + len(cones)
    P = np.concatenate([np.asarray(V, dtype=np.float64)[vids], np.zeros((len(cones), 3))])
    keys = _edge_keys(Fl, n)
    uk, inv = np.unique(keys, return_inverse=True)
    E = np.stack([uk // n, uk % n], axis=1)
    nf = len(Fl)
    if (np.bincount(inv, minlength=len(uk)) != 2).any():      # not closed by the caps
        return None
    ef = np.full((len(uk), 2), -1, dtype=np.int64)
    order = np.argsort(inv, kind="stable")
    ef[:, 0] = np.arange(3 * nf)[order][0::2] % nf
    ef[:, 1] = np.arange(3 * nf)[order][1::2] % nf
    off = np.zeros(n, dtype=bool)
    off[cones] = True
    off[border] = True
    w = np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1) + np.where(off[E].any(axis=1), _FAR, 0.0)
    G = coo_matrix((w, (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    G = G.maximum(G.T)
    # roots: farthest-point samples of the vertices clear of the borders
    free = np.flatnonzero(~off)
    if len(free) == 0:
        return None
    picks = [int(free[0])]
    dmin = dijkstra(G, indices=picks[0], limit=_FAR / 2)
    for _ in range(min(roots, len(free)) - 1):
        cand = np.where(off | ~np.isfinite(dmin), -1.0, dmin)
        r = int(np.argmax(cand))
        if cand[r] <= 0:
            break
        picks.append(r)
        dmin = np.minimum(dmin, dijkstra(G, indices=r, limit=_FAR / 2))
    best, best_len = None, np.inf
    tried = set()

    def through(root):
        dist, pred = dijkstra(G, indices=root, return_predecessors=True)
        tree = np.zeros(len(E), dtype=bool)
        v = np.flatnonzero(pred >= 0)
        a, b = np.minimum(v, pred[v]), np.maximum(v, pred[v])
        tree[np.searchsorted(uk, a * n + b)] = True
        co = np.flatnonzero(~tree)
        # (a region of several pieces: the other pieces' edges are out of reach, kept finite)
        loop_len = np.minimum(dist[E[co, 0]] + dist[E[co, 1]] + w[co], 4 * _FAR)
        # maximum spanning tree of the dual over the non-tree edges (weights kept positive)
        big = float(loop_len.max()) + 1.0
        D = coo_matrix((big - loop_len + 1e-9, (ef[co, 0], ef[co, 1])), shape=(nf, nf)).tocsr()
        T = minimum_spanning_tree(D).tocoo()
        in_cotree = set(zip(np.minimum(T.row, T.col).tolist(), np.maximum(T.row, T.col).tolist()))
        f0, f1 = np.minimum(ef[co, 0], ef[co, 1]), np.maximum(ef[co, 0], ef[co, 1])
        left = [i for i in range(len(co)) if (int(f0[i]), int(f1[i])) not in in_cotree]
        out = []
        for i in left:
            if loop_len[i] >= _FAR:
                continue
            pa, pb = _path(pred, E[co[i], 0]), _path(pred, E[co[i], 1])
            while len(pa) > 1 and len(pb) > 1 and pa[-2] == pb[-2]:
                pa.pop()
                pb.pop()
            out.append(pa + pb[-2::-1])
        return out

    for root in picks:
        tried.add(root)
        for lp in through(root):
            length = loop_length(P, lp)
            if length < best_len:
                best, best_len = lp, length
    for _ in range(3):
        if best is None:
            break
        # then through the vertices within the loop's length of it: a far root's basis bends to
        # the handle but may go round it where it is wide (a tube's foot, not its waist)
        d = dijkstra(G, indices=np.asarray(best), min_only=True, limit=best_len)
        near = [int(v) for v in np.flatnonzero(np.isfinite(d) & ~off) if int(v) not in tried]
        if not near:
            break
        improved = False
        for root in near[:: max(1, len(near) // _NEAR_ROOTS)]:
            tried.add(root)
            for lp in through(root):
                length = loop_length(P, lp)
                if length < best_len - 1e-12:
                    best, best_len, improved = lp, length, True
        if not improved:
            break
    return None if best is None else vids[np.asarray(best, dtype=np.int64)]


def _path(pred, v):
    out = [int(v)]
    while pred[out[-1]] >= 0:
        out.append(int(pred[out[-1]]))
    return out


def loop_length(V, loop) -> float:
    return loop_perimeter(np.asarray(V)[np.asarray(loop)])


def cut_loop(V, F, loop):
    """Cut (V, F) along the closed edge loop ``loop`` (interior vertices, in order): each loop
    vertex gets a copy for the faces on the loop's left (those wound along it), and each side's
    new border is closed with a fan round a centre a quarter of the loop's mean edge off the
    loop's centroid towards that side. Only the faces with a corner on the loop change; the
    vertices are kept (the copies and the two centres appended). Returns (V2, F2), or None where
    a loop vertex is on a border or its faces do not go round it once."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    L = [int(v) for v in loop]
    k, n = len(L), len(V)
    touch = np.flatnonzero(np.isin(F, L).any(axis=1))
    by_half = {}
    for f in touch.tolist():
        a, b, c = F[f].tolist()
        for x, y in ((a, b), (b, c), (c, a)):
            by_half[(x, y)] = f
    F2 = F.copy()
    left_faces, left_corners = set(), set()
    for i, v in enumerate(L):
        nxt, prv = L[(i + 1) % k], L[i - 1]
        f = by_half.get((v, nxt))
        for _ in range(64):
            if f is None:
                return None
            left_faces.add(f)
            left_corners.add((f, v))
            corners = F[f].tolist()
            z = corners[(corners.index(v) + 2) % 3]          # the corner before v
            if z == prv:
                break
            if z == nxt:                                      # round to the right side: not one fan
                return None
            f = by_half.get((v, z))
        else:
            return None
    # the copies: each loop vertex's corner in the faces of its left fan
    copy = {v: n + i for i, v in enumerate(L)}
    for f, v in left_corners:
        F2[f, int(np.flatnonzero(F[f] == v)[0])] = copy[v]
    P = V[L]
    cen = P.mean(axis=0)
    h = 0.25 * float(np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).mean())
    lf = np.array(sorted(left_faces), dtype=np.int64)
    rf = np.setdiff1d(touch, lf)

    def off(faces):
        dvec = V[F[faces]].mean(axis=(0, 1)) - cen
        nrm = np.linalg.norm(dvec)
        return cen + (h * dvec / nrm if nrm > 0 else 0.0)

    c_r, c_l = n + k, n + k + 1
    Lc = [copy[v] for v in L]
    caps = [(L[i], L[(i + 1) % k], c_r) for i in range(k)] + [(Lc[(i + 1) % k], Lc[i], c_l) for i in range(k)]
    V2 = np.concatenate([V, P, off(rf)[None], off(lf)[None]])
    F2 = np.concatenate([F2, np.asarray(caps, dtype=np.int64)])
    try:
        mc.boundary_loops(F2)
    except ValueError:
        return None
    return V2, F2


def cut_handles(V, F, openings, radius, max_loop_mm=np.inf, max_cuts=8, graph=None):
    """Cut the handles of (V, F) within ``radius`` mm of each opening (:func:`cut_loop` along
    :func:`shortest_handle_loop`) until none is left there, or ``max_cuts``. A handle whose
    shortest loop found is longer than ``max_loop_mm`` is left (and the band refuses it, naming
    it): a scanner's tunnel is a knot of a few faces, a longer one is shape the cut would scar.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
    openings : dict of str -> (L,) int64   each eye's opening, a boundary loop of F
    radius : float   mm along the edges from the opening
    graph : sparse (n, n), optional   :func:`pipeline.retopo.eye_rings.edge_graph` of (V, F)

    Returns
    -------
    V2, F2 : the mesh (unchanged, the same arrays, when no handle is near an opening)
    cuts : list of dict   per cut: side, the loop's centre (mm, the mesh's frame), its length and
        its distance from the opening along the edges (mm), the region's genus before
    """
    from pipeline.retopo.eye_rings import edge_graph, edge_graph_distance

    cuts = []
    for side, hole in openings.items():
        hole = np.asarray(hole, dtype=np.int64)
        while len(cuts) < max_cuts:
            if graph is None:
                graph = edge_graph(V, F)
            d = edge_graph_distance(V, F, hole, 1.5 * radius, graph)
            Fr = F[(d[F] < radius).all(axis=1)]
            if not len(Fr):
                break
            try:
                genus = euler_genus(Fr)[0]
            except ValueError:
                break
            if genus <= 0:
                break
            loop = shortest_handle_loop(V, Fr)
            if loop is None or loop_length(V, loop) > max_loop_mm:
                break
            done = cut_loop(V, F, loop)
            if done is None:
                break
            cuts.append({"side": side, "at_mm": [round(float(x), 2) for x in V[loop].mean(axis=0)],
                         "loop_mm": round(loop_length(V, loop), 2),
                         "from_opening_mm": round(float(d[loop].min()), 2), "genus_before": int(genus)})
            V, F = done
            graph = None
    return V, F, cuts
