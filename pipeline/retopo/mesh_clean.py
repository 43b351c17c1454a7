"""Cleaning a remeshed triangle mesh without opening holes (:func:`clean_mesh`, retopo's).

A decimated mesh can hold faces that are degenerate (repeated or collinear corners), duplicate
or non-manifold, and boundary vertices pinched between two boundary edges. Where a face can be
repaired instead of dropped it is: vertices put on one spot are welded, and collinear "caps"
get their long edge flipped (:func:`_flip_caps`); what is dropped is the rest.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import mesh_checks as mc


def _weld_coincident(V, F, tol_mm=1e-9):
    """Faces re-pointed so that vertices within ``tol_mm`` of each other are one (the lowest id).

    The decimation can put two vertices on the same spot (1e-13 mm apart); the faces between
    them are slits, which :func:`clean_mesh` then drops as repeated-index faces without opening
    a hole (dropped as zero-area faces with distinct corners, they would)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(V).query_pairs(tol_mm, output_type="ndarray")
    if len(pairs) == 0:
        return F
    n = len(V)
    _, comp = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                              shape=(n, n)), directed=False)
    lowest = np.full(comp.max() + 1, n)
    np.minimum.at(lowest, comp, np.arange(n))
    return lowest[comp][F]


def _flip_caps(V, F, area_tol, passes=4):
    """Flip the longest edge of zero-area faces with three distinct, collinear corners ("caps").

    A decimated mesh whose input had split edges (vertices at edge midpoints, as a coarse scan
    refined along its eye openings has) keeps some faces whose corners lie on one line; dropping
    them would open holes. Flipping the edge they lie along with the face across it gives two
    proper faces (when the fourth corner is off that line and the new edge is not already
    there).
    """
    F = F.copy()
    for _ in range(passes):
        area = 0.5 * np.linalg.norm(mc.face_normals(V, F, normalize=False), axis=1)
        distinct = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
        caps = np.flatnonzero(distinct & (area <= area_tol))
        if len(caps) == 0:
            break
        n = len(V)
        he = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        owner = {int(a) * n + int(b): i % len(F) for i, (a, b) in enumerate(he.tolist())}
        edges = {min(a, b) * n + max(a, b) for a, b in he.tolist()}
        done = set()
        flipped = 0
        for f in caps.tolist():
            if f in done:
                continue
            tri = F[f]
            L = [np.linalg.norm(V[tri[(k + 1) % 3]] - V[tri[k]]) for k in range(3)]
            k = int(np.argmax(L))
            a, b, c = int(tri[k]), int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3])
            g = owner.get(b * n + a)
            if g is None or g in done:
                continue
            d = int(next(v for v in F[g] if v not in (a, b)))
            if min(c, d) * n + max(c, d) in edges or c == d:
                continue
            t1, t2 = np.array([a, d, c]), np.array([d, b, c])
            a1 = np.linalg.norm(np.cross(V[t1[1]] - V[t1[0]], V[t1[2]] - V[t1[0]]))
            a2 = np.linalg.norm(np.cross(V[t2[1]] - V[t2[0]], V[t2[2]] - V[t2[0]]))
            if min(a1, a2) <= 2 * area_tol:
                continue
            F[f], F[g] = t1, t2
            edges.add(min(c, d) * n + max(c, d))
            done.update((f, g))
            flipped += 1
        if not flipped:
            break
    return F


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
    F = _weld_coincident(V, F)
    F = _flip_caps(V, F, area_tol)
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
