"""The eyelid loop of a remeshed eye region: resampled to a fixed vertex count and placed evenly
along the dense scan's eyelid loop.

:func:`resample_loop` collapses or splits boundary edges of a :class:`TriMesh` until the loop
has the wanted number of vertices; :func:`orient_and_place` orders it like the reference curve
(same direction, vertex 0 nearest the medial canthus) and gives target positions at even
arc-length steps along each lid, both canthi among them. The polyline helpers measure and project along closed polylines.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry.mesh_edit import TriMesh


def polyline_arclength(P, closed=True):
    Q = np.vstack([P, P[:1]]) if closed else P
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)]), Q


def project_to_polyline(X, P):
    """Arc-length parameter and point of the closest point on the closed polyline P for each X."""
    s, Q = polyline_arclength(P)
    A, B = Q[:-1], Q[1:]
    AB = B - A
    L2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    t = np.clip(np.einsum("kij,ij->ki", X[:, None, :] - A[None], AB) / L2, 0, 1)
    C = A[None] + t[..., None] * AB[None]
    d = np.linalg.norm(C - X[:, None, :], axis=2)
    j = np.argmin(d, axis=1)
    k = np.arange(len(X))
    return s[j] + t[k, j] * np.sqrt(L2[j]), C[k, j], d[k, j]


def point_at_arclength(P, t, smooth=0):
    """Points at arc-length ``t`` along the closed polyline P; with ``smooth`` > 0 the arc
    length is measured on a moving-average-smoothed copy (robust to staircase loops) while
    the points stay on P itself."""
    s, Q = polyline_arclength(P)
    if smooth > 0:
        k = 2 * int(smooth) + 1
        Ps = sum(np.roll(P, j, axis=0) for j in range(-int(smooth), int(smooth) + 1)) / k
        s, _ = polyline_arclength(Ps)
    t = np.mod(t, s[-1])
    j = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(Q) - 2)
    u = (t - s[j]) / np.maximum(s[j + 1] - s[j], 1e-300)
    return Q[j] + u[:, None] * (Q[j + 1] - Q[j])


def resample_loop(tm: TriMesh, loop, n, curve=None):
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
            p = project_to_polyline(p[None], curve)[1][0]
        m = tm.split(a, b, p)
        loop.insert(i + 1, m)
    return loop


def orient_and_place(V, loop, curve, start_point, end_index=None):
    """Order the loop like the reference curve (same direction, vertex 0 nearest ``start_point``)
    and return target positions evenly spaced along the curve.

    With ``end_index`` (the lateral canthus: index of a ``curve`` point, ``start_point`` being
    ``curve[0]``, the medial canthus) each lid is spaced evenly on its own and the lateral canthus
    is a target itself, as vertex ``k``: the loop's vertices are shared between the lids in
    proportion to their arc lengths. Without it one even spacing runs round the whole loop, and
    the lateral canthus falls between two vertices: up to half a spacing short of the corner,
    which the canthus landmark (the most lateral loop vertex) then misses by as much (0.3-0.8 mm
    on the synthetic heads at 64 loop vertices).

    Returns
    -------
    loop : (L,) int64
    targets : (L, 3) float64
    lateral : int or None
        Position of the lateral canthus target in the loop (None without ``end_index``).
    """
    loop = np.asarray(loop, dtype=np.int64)
    sp, _, _ = project_to_polyline(V[loop], curve)
    total = polyline_arclength(curve)[0][-1]
    ds = np.diff(np.unwrap(sp / total * 2 * np.pi))
    if np.sum(ds) < 0:
        loop = loop[::-1]
        sp = sp[::-1]
    i0 = int(np.argmin(np.linalg.norm(V[loop] - start_point, axis=1)))
    loop = np.roll(loop, -i0)
    s0 = project_to_polyline(start_point[None], curve)[0][0]
    # even steps of the smoothed curve's arc length, starting at the start point's parameter
    sm = 2
    k = 2 * sm + 1
    Ps = sum(np.roll(curve, j, axis=0) for j in range(-sm, sm + 1)) / k
    ss, _ = polyline_arclength(Ps)
    so, _ = polyline_arclength(curve)
    s0s = np.interp(s0, so, ss)
    L = len(loop)
    if end_index is None or not 0 < int(end_index) < len(curve) or L < 6:
        steps = s0s + np.arange(L) * ss[-1] / L
        return loop, point_at_arclength(curve, steps, smooth=sm), None
    upper = float(ss[int(end_index)] - s0s)
    lower = float(ss[-1] - upper)
    lat = int(np.clip(round(L * upper / ss[-1]), 3, L - 3))
    steps = np.concatenate([s0s + np.arange(lat) * upper / lat,
                            s0s + upper + np.arange(L - lat) * lower / (L - lat)])
    return loop, point_at_arclength(curve, steps, smooth=sm), lat
