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
    XA = X[:, None, :] - A[None]
    p = np.einsum("kij,ij->ki", XA, AB)
    t = np.clip(p / L2, 0, 1)
    # squared distances without the (k, m, 3) closest points: smooth_grid projects its outer
    # ring onto a 512-segment line in every sweep
    j = np.argmin(np.einsum("kij,kij->ki", XA, XA) - t * (2.0 * p - t * L2), axis=1)
    k = np.arange(len(X))
    tj = t[k, j]
    C = A[j] + tj[:, None] * AB[j]
    return s[j] + tj * np.sqrt(L2[j]), C, np.linalg.norm(C - X, axis=1)


def closed_moving_average(P, half: int):
    """(n, 3) mean of each vertex of the closed polyline P and its ``half`` neighbours each side."""
    return sum(np.roll(P, j, axis=0) for j in range(-int(half), int(half) + 1)) / (2 * int(half) + 1)


def point_at_arclength(P, t, smooth=0):
    """Points at arc-length ``t`` along the closed polyline P; with ``smooth`` > 0 the arc
    length is measured on a moving-average-smoothed copy (robust to staircase loops) while
    the points stay on P itself."""
    s, Q = polyline_arclength(P)
    if smooth > 0:
        s, _ = polyline_arclength(closed_moving_average(P, smooth))
    return at_arclength(s, Q, t)


def at_arclength(s, Q, t):
    """:func:`point_at_arclength` on a closed polyline given by :func:`polyline_arclength`'s
    ``(s, Q)`` (for a caller that asks about one line again and again)."""
    t = np.mod(t, s[-1])
    j = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(Q) - 2)
    u = (t - s[j]) / np.maximum(s[j + 1] - s[j], 1e-300)
    return Q[j] + u[:, None] * (Q[j + 1] - Q[j])


def _collapse_at(tm: TriMesh, loop, el, i, refused, touched, step) -> bool:
    """Collapse loop vertex ``i`` into its nearer neighbour (the other when refused); ``el``: the
    loop's edge lengths, ``el[i]`` from vertex ``i`` to the next. Returns False when both are refused
    (the mesh is then unchanged).

    A collapse of ``a`` into ``b`` reads only the faces round ``a`` and ``b``: ``refused`` holds
    (a, b) -> the step it was refused at, and while neither has been touched since (``touched``:
    vertex -> the last step a collapse changed one of its faces) it is refused again unasked.
    On success every corner of ``a``'s old faces is marked touched at ``step``."""
    k = len(loop)
    prev_i, next_i = (i - 1) % k, (i + 1) % k
    a = loop[i]
    for j in ((next_i, prev_i) if el[i] <= el[prev_i] else (prev_i, next_i)):
        b = loop[j]
        when = refused.get((a, b))
        if when is not None and touched.get(a, -1) < when and touched.get(b, -1) < when:
            continue
        ring = {v for fi in tm.vf[a] for v in tm.F[fi]}
        if tm.collapse(a, b):
            touched.update(dict.fromkeys(ring, step))
            return True
        refused[(a, b)] = step
    return False


def resample_loop(tm: TriMesh, loop, n, curve=None):
    """Collapse/split boundary edges until the loop has ``n`` vertices; returns the new loop list.

    Collapses go cheapest vertex first (the sum of its two edges' lengths), in ``np.argsort``'s
    order of the costs, each in turn until one is allowed."""
    loop = list(map(int, loop))
    guard = 0
    if len(loop) > n:
        # a collapse moves no vertex (the crop border's coarsening is a thousand of them): the
        # edge lengths are kept from one to the next, the one new edge measured alone (a row's
        # norm is the same bits alone or among others), and the cheapest vertex is taken by argmin;
        # the whole argsort, whose order among equal costs is its own, only runs when that
        # minimum is tied or refused. A refused vertex (a crop corner) stays cheap and was asked
        # again at every step: its refusal is kept until a collapse touches its faces
        Vs = np.array(tm.V)
        ids = np.asarray(loop, dtype=np.int64)
        el = np.linalg.norm(Vs[ids] - Vs[np.roll(ids, -1)], axis=1)     # edge i -> i+1
        refused, touched = {}, {}
    while len(loop) > n and guard < 100000:
        guard += 1
        k = len(loop)
        cost = el + np.roll(el, 1)
        i = int(np.argmin(cost))
        first = i if np.count_nonzero(cost == cost[i]) == 1 else -1
        if first < 0 or not _collapse_at(tm, loop, el, i, refused, touched, guard):
            i = next((c for c in np.argsort(cost).tolist()
                      if c != first and _collapse_at(tm, loop, el, c, refused, touched, guard)), None)
            if i is None:
                break
        a, b = loop[(i - 1) % k], loop[(i + 1) % k]
        loop.pop(i)
        el = np.delete(el, i)
        el[(i - 1) % (k - 1)] = np.linalg.norm(Vs[[a]] - Vs[[b]], axis=1)[0]
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


def orient_and_place(V, loop, curve, start_point, end_index=None, split=None):
    """Order the loop like the reference curve (same direction, vertex 0 nearest ``start_point``)
    and return target positions evenly spaced along the curve.

    With ``end_index`` (the lateral canthus: index of a ``curve`` point, ``start_point`` being
    ``curve[0]``, the medial canthus) each lid is spaced evenly on its own and the lateral canthus
    is a target itself, as vertex ``k``: the loop's vertices are shared between the lids in
    proportion to their arc lengths. Without it one even spacing runs round the whole loop, and
    the lateral canthus falls between two vertices: up to half a spacing short of the corner,
    which the canthus landmark (the most lateral loop vertex) then misses by as much (0.3-0.8 mm
    on the synthetic heads at 64 loop vertices). With ``split`` the upper lid gets that many
    vertices whatever the lids' lengths (the lateral canthus is vertex ``split`` in every asset).

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
    lat = int(np.clip(round(L * upper / ss[-1]) if split is None else int(split), 3, L - 3))
    steps = np.concatenate([s0s + np.arange(lat) * upper / lat,
                            s0s + upper + np.arange(L - lat) * lower / (L - lat)])
    return loop, point_at_arclength(curve, steps, smooth=sm), lat


def _line(Q):
    """Centroid (3,) and unit direction (3,) of the least-squares line through points Q (k, 3)."""
    c = Q.mean(axis=0)
    return c, np.linalg.svd(Q - c)[2][0]


def canthus_apex(curve, lateral: int, window=(1.0, 6.0), max_reach_mm: float = 3.0,
                 max_gap_mm: float = 2.0):
    """The canthi where the lid lines meet: a sharpened copy of a closed margin curve.

    A loop that follows the scan where its surface lifts off the eye rounds each canthus off:
    the canthus is an acute wedge, and a line a fixed height above the eye leaves its apex.
    Near each canthus the upper and the lower lid are each fitted with a straight line over the
    arc length ``window`` (mm from the canthus); where the two lines meet (the midpoint of their
    closest approach) is the apex. It replaces the curve's points within ``window[0]`` of the
    canthus when it lies beyond the canthus (away from the other canthus) by at most
    ``max_reach_mm`` and the lines pass within ``max_gap_mm`` of each other; otherwise that
    canthus is kept (a lid too short for the window, lines too far apart or nearly parallel, or
    an apex inside the loop): unsure, recorded in the info.

    Parameters
    ----------
    curve : (n, 3) float64
        Closed margin curve, medial canthus first, upper lid first.
    lateral : int
        Index of the lateral canthus in ``curve``.

    Returns
    -------
    curve : (m, 3) float64
        Medial canthus (apex or kept) first, upper lid first.
    lateral : int
        Index of the lateral canthus in the returned curve.
    info : dict
        Per canthus (``medial``, ``lateral``): ``moved`` (bool), ``reach_mm`` (how far the apex
        lies beyond the curve's canthus; None when none was found) and ``why`` when kept.
    """
    P = np.asarray(curve, dtype=np.float64)
    n, li = len(P), int(lateral)
    upper = P[: li + 1]                         # medial .. lateral
    lower = np.vstack([P[li:], P[:1]])          # lateral .. medial
    other = {"medial": P[li], "lateral": P[0]}
    lids = {"medial": (upper, lower[::-1]), "lateral": (upper[::-1], lower)}
    keep = {"medial": (0, 0), "lateral": (0, 0)}   # points dropped on each lid next to the canthus
    apex, info = {}, {}
    for name, (a, b) in lids.items():
        corner = a[0]
        lines, drop = [], []
        for lid in (a, b):
            s = polyline_arclength(lid, closed=False)[0]
            m = (s >= window[0]) & (s <= window[1])
            if m.sum() < 2:
                break
            lines.append(_line(lid[m]))
            drop.append(int(np.count_nonzero(s < window[0])) - 1)   # the canthus itself not counted
        if len(lines) < 2:
            info[name] = {"moved": False, "reach_mm": None, "why": "lid shorter than the window"}
            continue
        (c1, u1), (c2, u2) = lines
        w = c1 - c2
        b12, d1, d2 = float(u1 @ u2), float(u1 @ w), float(u2 @ w)
        den = 1.0 - b12 * b12
        if den < 1e-3:
            info[name] = {"moved": False, "reach_mm": None, "why": "lid lines parallel"}
            continue
        t1, t2 = (b12 * d2 - d1) / den, (d2 - b12 * d1) / den
        q1, q2 = c1 + t1 * u1, c2 + t2 * u2
        q = 0.5 * (q1 + q2)
        axis = corner - other[name]
        reach = float((q - corner) @ axis / np.linalg.norm(axis))
        gap = float(np.linalg.norm(q1 - q2))
        if gap > max_gap_mm or not 0.0 < reach <= max_reach_mm:
            info[name] = {"moved": False, "reach_mm": reach,
                          "why": f"lines {gap:.2f} mm apart" if gap > max_gap_mm
                          else f"apex {reach:.2f} mm beyond the canthus"}
            continue
        apex[name] = q
        keep[name] = tuple(drop)
        info[name] = {"moved": True, "reach_mm": reach}
    (mu, ml), (lu, ll) = keep["medial"], keep["lateral"]
    up = P[1 + mu: li - lu]                        # upper lid without the rounded ends
    lo = P[li + 1 + ll: n - ml]                    # lower lid without the rounded ends
    med = apex.get("medial", P[0])
    lat = apex.get("lateral", P[li])
    out = np.vstack([med[None], up, lat[None], lo])
    return out, 1 + len(up), info


def _smooth_lid(P, sigma, max_move, sigma_mid=None):
    """One lid (k, 3), canthus to canthus, low-passed with both ends fixed (see smooth_margin);
    the bandwidth ``sigma`` at the canthi widens to ``sigma_mid`` (when larger) ``sigma_mid``
    of arc length away from both."""
    k = len(P)
    if k < 4 or sigma <= 0:
        return P.copy()
    # chord-length parameter of a lightly averaged copy: a zigzag's own arc length is inflated
    # unevenly by its teeth
    A = P.copy()
    A[1:-1] = (P[:-2] + P[1:-1] + P[2:]) / 3.0
    s = polyline_arclength(A, closed=False)[0]
    # residual from the canthus-to-canthus chord is 0 at both ends; its odd reflection about each
    # end keeps a local quadratic fit there at exactly 0 (odd data, symmetric weights), so the
    # canthi stay put and each lid leaves its canthus along its own straight line (sharp corner)
    line = P[0] + (s / s[-1])[:, None] * (P[-1] - P[0])
    # and from the lid's parabola through both canthi: the odd reflection of a curved residual
    # has a kink in curvature at the canthus that the local fit would round off (0.1 mm bias)
    q = (s * (s[-1] - s))[:, None]
    line = line + q * (((P - line) * q).sum(axis=0) / max(float((q * q).sum()), 1e-300))
    R = P - line
    S = np.concatenate([-s[:0:-1], s, 2 * s[-1] - s[-2::-1]])
    RR = np.concatenate([-R[:0:-1], R, -R[-2::-1]])
    D = S[None, :] - s[:, None]                              # (k, 3k-2)
    if sigma_mid is not None and sigma_mid > sigma:
        # per output point: sigma at a canthus, sigma_mid from sigma_mid along the lid inwards
        reach = np.minimum(s, s[-1] - s) / sigma_mid
        sig = (sigma + (sigma_mid - sigma) * np.clip(reach, 0.0, 1.0))[:, None]
    else:
        sig = sigma
    G = np.exp(-0.5 * (D / sig) ** 2)
    X = np.stack([np.ones_like(D), D, D * D], axis=2)       # (k, 3k-2, 3)
    robust = np.ones(len(S))
    for it in range(3):
        # bisquare reweighting (LOWESS): a notch of a few points is an outlier, not a lid shape
        W = G * robust[None, :]
        XtW = np.einsum("kjp,kj->kpj", X, W)
        A = XtW @ X + 1e-12 * np.eye(3)
        out = np.linalg.solve(A, XtW @ RR)[:, 0, :]
        out[0] = out[-1] = 0.0
        if it == 2:
            break
        res = np.linalg.norm(RR - np.concatenate([-out[:0:-1], out, -out[-2::-1]]), axis=1)
        scale = 6.0 * max(float(np.median(res)), 1e-9)
        robust = np.clip(1.0 - (res / scale) ** 2, 0.0, None) ** 2
    Q = line + out
    # bounded: a tooth is a fraction of a millimetre; a larger move would be a real feature
    dv = Q - P
    n = np.linalg.norm(dv, axis=1, keepdims=True)
    return P + dv * np.minimum(1.0, max_move / np.maximum(n, 1e-300))


def smooth_margin(curve, lateral: int, sigma_mm: float = 3.0, max_move_mm: float = 2.0,
                  mid_sigma_mm: float | None = None):
    """A closed margin curve with the saw-teeth of the scan's triangles taken out.

    The cut's boundary loop zigzags along the scan's triangles (0.5-1 mm teeth at 0.7 mm
    spacing on ``ict_neutral``); a real lid margin is a smooth curve. Each lid (canthus to
    canthus) is fitted by a Gaussian-weighted local quadratic in arc length (bandwidth
    ``sigma_mm``): a smooth lid keeps its curvature (no shrinkage of the arc), teeth shorter than
    the bandwidth average out. Both canthi are kept exactly and each lid ends along its own
    direction, so the corners stay sharp. No point moves more than ``max_move_mm``.
    ``curve`` (n, 3) and ``lateral`` as :func:`canthus_apex` takes and returns them.

    Returns ``(curve, lateral)``: the curve (m, 3) with edges no longer than ``sigma_mm / 4``
    (points are added on long edges before smoothing) and its lateral canthus index.
    """
    P = np.asarray(curve, dtype=np.float64)
    li = int(lateral)
    if not 0 < li < len(P) - 1:
        raise ValueError(f"lateral canthus index {li} outside 1..{len(P) - 2}")
    step = max(sigma_mm / 4.0, 1e-3)
    upper = _smooth_lid(_densify(P[: li + 1], step), sigma_mm, max_move_mm, mid_sigma_mm)
    lower = _smooth_lid(_densify(np.vstack([P[li:], P[:1]]), step), sigma_mm, max_move_mm, mid_sigma_mm)
    return np.vstack([upper, lower[1:-1]]), len(upper) - 1


def smooth_lids(curve, lateral: int, sigma_mm: float = 3.0, max_move_mm: float = 2.0,
                mid_sigma_mm: float = 0.0, notch_mm: float = 1.0, keep: float = 0.7,
                mid_max_move_mm: float | None = None, off_eye=None, min_on_eye: float = 0.6):
    """:func:`smooth_margin`, and again with the window widening to ``mid_sigma_mm`` mid-lid
    where the smoothed curve is still notched deeper than ``notch_mm`` seen along +z (the head
    frame's forward; :func:`pipeline.geometry.opening.polygon_notch` of its x, y): a fissure is
    convex, and a notch 6-10 loop points wide is scanned eyeball the cut left on a lid, which the
    narrow window takes for lid shape. The wider curve is kept only where its notch is at most
    ``keep`` of the first one's (a window that barely moves a notch is following the lid), and,
    given ``off_eye`` (points (k, 3) -> their signed distance outside the eye, mm), only where it
    leaves at least ``min(min_on_eye, the first curve's share)`` of its points resting on the eye
    (:func:`pipeline.geometry.corners.corner_weights`): the rig refuses a loop under half on the
    eye, and a lid standing 2 mm off a looking-up eye (``id302_up``) sits at that edge.

    Returns ``(curve, lateral, tried)``: ``tried`` is None, or ``(notch, wider notch, kept)``
    in mm when the wider window was tried."""
    from pipeline.geometry.opening import polygon_notch

    out, li = smooth_margin(curve, lateral, sigma_mm, max_move_mm)
    if mid_sigma_mm <= sigma_mm:
        return out, li, None
    notch = polygon_notch(out[:, :2])
    if notch <= notch_mm:
        return out, li, None
    wide, wli = smooth_margin(curve, lateral, sigma_mm,
                              max_move_mm if mid_max_move_mm is None else mid_max_move_mm, mid_sigma_mm)
    after = polygon_notch(wide[:, :2])
    kept = after <= keep * notch
    if kept and off_eye is not None:
        kept = _on_eye_share(wide, wli, off_eye) >= min(min_on_eye, _on_eye_share(out, li, off_eye))
    if kept:
        return wide, wli, (notch, after, True)
    return out, li, (notch, after, False)


def _on_eye_share(curve, lateral: int, off_eye) -> float:
    """Share of a margin curve's points that :func:`corner_weights` puts on the eye (not in a
    corner run standing off it)."""
    from pipeline.geometry.corners import corner_weights

    return float(corner_weights(curve, off_eye(curve), lateral).on_eye.mean())


def _densify(P, step):
    """Open polyline (k, 3) with points added on its edges so none is longer than ``step``: a
    coarse cut (``james``: 11 points round the eye) would otherwise stay a polygon whose
    corners the loop placed on it inherits."""
    out = [P[:1]]
    for a, b in zip(P[:-1], P[1:]):
        m = int(np.ceil(np.linalg.norm(b - a) / step))
        out.append(a + (b - a) * (np.arange(1, m + 1) / m)[:, None])
    return np.vstack(out)


def margin_jag(P, corners=(0,), skip: int = 6):
    """Saw-teeth of a closed margin loop: each vertex's distance to the mean of itself and its
    +-1, +-2 neighbours, (n,) float64, over the vertices more than ``skip`` places from every
    index in ``corners`` (the canthi, where the loop bends sharply on purpose). A smooth lid of
    curvature k at spacing h scores about k h^2 (0.1 mm for a 12 mm arc at 1.1 mm spacing);
    a zigzag of amplitude a scores 0.8 a.

    Parameters
    ----------
    P : (n, 3) float64
        Closed loop.
    corners : sequence of int
        Loop positions left out with their ``skip`` neighbours each side.
    """
    P = np.asarray(P, dtype=np.float64)
    return _away_from_corners(np.linalg.norm(P - closed_moving_average(P, 2), axis=1), corners, skip)


def _away_from_corners(dev, corners, skip):
    """``dev`` (n,) without the entries within ``skip`` places of any index in ``corners``."""
    keep = np.ones(len(dev), dtype=bool)
    for c in corners:
        if c is not None:
            keep[(int(c) + np.arange(-skip, skip + 1)) % len(dev)] = False
    return dev[keep]


def margin_teeth(P, corners=(0,), skip: int = 6):
    """Like :func:`margin_jag` without its curvature floor: each vertex's distance to the cubic
    through its +-1, +-2 neighbours, ``(4 (P[i-1] + P[i+1]) - (P[i-2] + P[i+2])) / 6``, which a
    smooth curve meets to third order at even spacing (0 on any cubic); a zigzag of amplitude a
    scores 2.67 a. (n,) float64 over the same vertices as :func:`margin_jag`."""
    P = np.asarray(P, dtype=np.float64)
    C = (4.0 * (np.roll(P, 1, axis=0) + np.roll(P, -1, axis=0))
         - (np.roll(P, 2, axis=0) + np.roll(P, -2, axis=0))) / 6.0
    return _away_from_corners(np.linalg.norm(P - C, axis=1), corners, skip)
