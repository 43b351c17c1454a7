"""Eyelid corners off the globe: where the lids leave the eyeball, and the strip that closes the gap.

Anatomy (UnityEyes' eye-region files, pipeline/placement/data/README.md: eight SynthesEyes
eye regions registered to their eyeballs): along the lids the margin rests 0.35-2.1 mm outside the 12 mm globe; the
corners do not. The medial end of the fissure (past the caruncle) lies 3.0-7.4 mm off the globe,
8.6 +- 0.7 mm in front of the eye centre; the lateral corner 1.2-1.7 mm off it. So where the loop
stands off the eye by more than a lid margin can (``off_globe_mm``, 2.1), a run of it that starts
at a canthus is a corner: the snap fades out toward that canthus (:func:`corner_weights`), and
what stays open between the lid and the eye is closed by a strip of faces from the loop into the
eye (:func:`close_corners`): the caruncle at the medial corner, corner skin at the lateral one.

A run is measured from each canthus along both lids while the loop stands off more than
``off_globe_mm``; it may cover at most ``max_share`` of each lid's arc (beyond that the loop is a
lid, whatever the distance says: a mid-lid far off the eye is a placement error, which the
``remove_eyeballs`` self-checks see). Inside a run the snap weight is a smoothstep of the arc
length from the canthus over the run's length (0 at the canthus, which keeps its place, 1 where
the lid meets the eye), so the snapped margin leaves the eye smoothly, whatever the distances; a
run fades over at least ``MIN_RUN_MM`` of arc, however near the eye the next lid points lie.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: How far off the globe a lid margin rests at most (UnityEyes' eight registered eye regions:
#: 1.56-2.07 mm, mean interior margin 1.1 mm); a loop run from a canthus standing farther off is
#: a corner. The nearest the medial fissure corner comes to the globe there is 3.05 mm.
MARGIN_OFF_GLOBE_MM = 2.1
#: A corner run covers at most this share of each lid's arc (the caruncle takes the medial
#: 0.16 of the fissure's width, (15.2 - 10.8) / 27.8 mm, so this leaves room for a coarse loop).
CORNER_MAX_SHARE = 0.35
#: A corner run that the cornea cuts short (``corner_weights``' ``over_cornea``) keeps at least
#: this arc from its canthus, else it runs on as if no cornea were there.
MIN_STOPPED_RUN_MM = 2.0
#: Every corner run fades over at least this arc from its canthus (or its lid's ``max_share``):
#: a canthus just past ``off_globe_mm`` beside lid points just inside it otherwise keeps its place
#: while the next point, one loop edge away, moves its whole way onto the eye, and the lid snapped
#: so near its canthus folds there (fresh41's `n4702_icteye_cams6`: its left lateral canthus 2.35
#: mm off, its neighbours moved 1.98 / 2.35 mm, a 2 deg sliver that turned over looking down).
MIN_RUN_MM = MIN_STOPPED_RUN_MM
#: A loop point is over the cornea where the globe under it lies this far inside the eye's outer
#: surface (the cornea's bulge; the sclera's seam blend stays under it).
OVER_CORNEA_MM = 0.05


#: How far along the lids from the medial canthus the caruncle reaches (the fissure's end to the
#: lid margin's medial end, 15.2 - 10.8 mm from the gaze axis in UnityEyes' registered regions):
#: a medial strip beyond it is the inside of the lid, skin.
CARUNCLE_MM = 4.4
#: The caruncle's look in the asset (``Materials/Caruncle``, linear RGB, and its roughness): moist
#: pink mucosa, glossier than skin, no texture.
CARUNCLE_DIFFUSE = (0.72, 0.34, 0.33)
CARUNCLE_ROUGHNESS = 0.3
#: Where the skin's colour map exists, the caruncle is that colour times this tint (linear RGB):
#: the subject's own tone and the light it was scanned in, reddened like mucosa and no brighter
#: than the skin around it (a constant pink was the brightest thing in a dark-skinned preview).
CARUNCLE_TINT = (1.0, 0.62, 0.6)


def _smoothstep(x):
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass
class CornerRuns:
    """The corner parts of one eyelid loop.

    Attributes
    ----------
    weight : (L,) float64
        Snap weight of each loop vertex: 1 on the lids, fading to 0 at a canthus that stands off
        the eye.
    medial, lateral : (k,) int64
        Loop positions of each corner run in loop order (empty when that canthus rests on the
        eye); the canthus is among them.
    """

    weight: np.ndarray
    medial: np.ndarray
    lateral: np.ndarray

    @property
    def on_eye(self) -> np.ndarray:
        """(L,) bool: loop vertices snapped fully onto the eye."""
        return self.weight >= 1.0


def _arc(P):
    """Arc length along an open polyline (k, 3) from its first point, (k,)."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])


def corner_weights(P, off, lateral_index: int, off_globe_mm: float = MARGIN_OFF_GLOBE_MM,
                   max_share: float = CORNER_MAX_SHARE, over_cornea=None) -> CornerRuns:
    """Snap weights of a loop whose corners may stand off the eye (module doc).

    Parameters
    ----------
    P : (L, 3) float64
        Loop points, medial canthus first, upper lid first.
    off : (L,) float64
        Distance of each point outside the eye (mm; negative inside).
    lateral_index : int
        Position of the lateral canthus.
    off_globe_mm : float
        A lid stands at most this far off the globe; farther, from a canthus on, is a corner.
    max_share : float
        Largest share of a lid's arc length a corner run may cover.
    over_cornea : (L,) bool, optional
        Loop points over the cornea (their ray from the eye centre passes under its bulge): a lid
        there rests on the cornea, so a run ends before the first of them, unless that leaves it
        under ``MIN_STOPPED_RUN_MM`` of arc (snapping a lid so near its canthus folds it) or the
        canthus itself is over the cornea; then the run is as without them. Otherwise the strip
        closing the corner would run through the cornea into the anterior chamber.

    Returns
    -------
    CornerRuns
    """
    P = np.asarray(P, float)
    off = np.asarray(off, float)
    L, li = len(P), int(lateral_index)
    if not 0 < li < L:
        raise ValueError(f"lateral canthus position {li} outside the loop of {L}")
    upper = np.arange(0, li + 1)                         # medial -> lateral
    lower = np.concatenate([np.arange(li, L), [0]])      # lateral -> medial
    w = np.ones(L)
    runs = {}
    over = np.zeros(L, bool) if over_cornea is None else np.asarray(over_cornea, bool)
    for name, k in (("medial", 0), ("lateral", li)):
        # a canthus over the cornea keeps its whole run: snapping it would fold the corner
        stop = over if not over[k] else np.zeros(L, bool)
        if off[k] <= off_globe_mm:
            runs[name] = np.zeros(0, np.int64)
            continue
        members = [k]
        for lid in (upper, lower):
            seq = lid if lid[0] == k else lid[::-1]      # from this canthus along the lid
            s = _arc(P[seq])
            cap = max_share * s[-1]
            end = _run_end(seq, s, off, off_globe_mm, cap, stop)
            if end < len(seq) - 1 and stop[seq[end]] and s[end] < MIN_STOPPED_RUN_MM:
                # cut short by the cornea: a lid snapped so near its canthus would fold there
                end = _run_end(seq, s, off, off_globe_mm, cap, None)
            while end < len(seq) - 1 and s[end] < min(MIN_RUN_MM, cap):
                end += 1            # too short a fade folds the lid beside its canthus (MIN_RUN_MM)
            # the lid meets the eye at seq[end]: the weight rises over the arc up to it
            span = max(s[end], 1e-9)
            for j in range(1, end):
                w[seq[j]] = min(w[seq[j]], float(_smoothstep(s[j] / span)))
                members.append(int(seq[j]))
        w[k] = 0.0
        runs[name] = np.array(sorted(set(members), key=lambda j: (j - k) % L if name == "medial"
                                     else j), np.int64)
    return CornerRuns(weight=w, medial=runs["medial"], lateral=runs["lateral"])


def _run_end(seq, s, off, off_globe_mm, cap, stop):
    """Where a corner run along ``seq`` (from its canthus) ends: the first point after the canthus
    within ``off_globe_mm`` of the eye, at ``cap`` of arc ``s``, at the lid's far end or, with a
    ``stop`` mask, on the first stopped point."""
    end = 1
    while end < len(seq) - 1 and off[seq[end]] > off_globe_mm and s[end] < cap \
            and (stop is None or not stop[seq[end]]):
        end += 1
    return end


def _loop_edge_faces(F, a, b):
    """For each loop edge (a[i], b[i]): +1 when a face holds the directed edge a -> b, -1 when
    it holds b -> a (the strip face then runs the other way), 0 when no face holds it."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    n = int(max(F.max(), np.max(a), np.max(b))) + 1
    key = set((E[:, 0] * n + E[:, 1]).tolist())
    fwd = np.array([int(x) * n + int(y) in key for x, y in zip(a, b)])
    bwd = np.array([int(y) * n + int(x) in key for x, y in zip(a, b)])
    return np.where(fwd, 1, np.where(bwd, -1, 0))


def _mound_height(p, q, forward, arc, height_mm: float) -> tuple[float, np.ndarray]:
    """(height, direction) of the caruncle's mound over one strip segment from loop vertex ``p``
    to its inner vertex ``q``: the direction is the eye's forward made perpendicular to the
    segment (toward the opening, where the skin faces), the height ``height_mm`` at the canthus,
    at most a third of the segment, fading over the caruncle's reach along the lids (a smoothstep
    from half of ``CARUNCLE_MM`` to 0 at it)."""
    u = q - p
    length = float(np.linalg.norm(u))
    if length < 1e-9 or height_mm <= 0 or not np.isfinite(arc) or arc >= CARUNCLE_MM:
        return 0.0, np.zeros(3)
    u = u / length
    n = np.asarray(forward, float) - float(np.dot(forward, u)) * u
    nn = float(np.linalg.norm(n))
    if nn < 0.2:          # the segment runs along the gaze: no side to bulge toward
        return 0.0, np.zeros(3)
    return min(height_mm, length / 3.0) * caruncle_fade(arc), n / nn


def _keep_clear(flat, up, signed_distance, clear_mm: float) -> float:
    """The share s in [0, 1] of the raise ``up`` that keeps ``flat + s up`` at least
    ``min(clear_mm, distance of flat)`` outside the eye's surface (``signed_distance``; None: 1):
    1 where the whole raise stays clear, else found by bisection (12 steps, 0.02 % of it)."""
    if signed_distance is None or not np.any(up):
        return 1.0
    need = min(clear_mm, float(signed_distance(flat[None])[0]))
    if float(signed_distance((flat + up)[None])[0]) >= need:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if float(signed_distance((flat + mid * up)[None])[0]) >= need:
            lo = mid
        else:
            hi = mid
    return lo


def caruncle_fade(arc):
    """1 within half of ``CARUNCLE_MM`` of the medial canthus along the lids, a smoothstep down
    to 0 at ``CARUNCLE_MM``: how much of the caruncle's mound and colour a strip segment has."""
    return 1.0 - _smoothstep((np.asarray(arc, float) - 0.5 * CARUNCLE_MM) / (0.5 * CARUNCLE_MM))


#: The caruncle's mound keeps this far outside the eye's outer surface (the cornea's bulge
#: included) where its flat strip would: it bulges toward the opening, and so toward the cornea.
MOUND_CLEAR_MM = 0.3

#: The caruncle's colour weight rises from 0 at the lid margin (the loop: skin) to 1 this share
#: of the way from the loop to the eye (the mound's crown and the fold beside the eye).
CARUNCLE_RIM_SHARE = 0.4


def close_corners(V, F, loop, runs: CornerRuns, center, radius: float, depth_mm: float,
                  UV=None, FUV=None, min_gap_mm: float = 1e-3, pad: int = 1,
                  forward=None, mound_mm: float = 0.0, mound_rows: int = 0,
                  signed_distance=None, mound_clear_mm: float = MOUND_CLEAR_MM):
    """Close the gap between the corner runs of a snapped loop and the eye with strips of faces.

    Each loop vertex ``p`` of a run that stands off the eye gets an inner vertex ``q`` on the ray
    from the eye centre through it, ``depth_mm`` inside the sphere (deep enough to hide in the
    eye's opaque sclera, under its clear shell); consecutive loop vertices and their inner
    vertices make two triangles; the strip takes in ``pad`` loop vertices resting on the eye at
    each end of the run and closes with one triangle to the next.

    The medial strip is the caruncle, a mound of tissue, not a flat flap: with ``forward`` and
    ``mound_rows`` > 0 each medial segment p -> q gets ``mound_rows`` vertices between them (at
    most one per mm of it, less one: none on a segment under 2 mm),
    raised toward the opening by ``mound_mm`` sin(pi t) at the canthus (t from p to q; at most a
    third of the segment, fading to 0 at ``CARUNCLE_MM`` along the lids: :func:`_mound_height`),
    and neighbouring segments are joined row by row. With ``signed_distance`` (points -> (n,)
    mm outside the eye's outer surface, the cornea's bulge included) a mound vertex is lowered
    until it stands at least ``min(mound_clear_mm, its flat point's distance)`` outside that
    surface, so the mound never enters the cornea where the flat strip would not. Each such
    vertex hangs from its loop vertex like ``q`` (``strip``), so the rig turns the whole segment
    rigidly with its lid. The strip uses each loop edge the other way round from the skin
    face beside it, so the mesh stays manifold and consistently oriented. Texture coordinates of
    an inner vertex are those of its loop vertex (the strip shows the colour of the lid margin).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    loop : (L,) int64
    runs : CornerRuns
    center : (3,) float64
    radius : float
        The eye's sphere radius, mm.
    depth_mm : float
    UV : (t, 2) float64, optional
    FUV : (m, 3) int64, optional
    min_gap_mm : float
        A run whose loop vertices all lie closer to the sphere than this needs no strip.
    pad : int
        Loop vertices resting on the eye that the strip takes in at each end of a run.

    Returns
    -------
    dict
        ``V``, ``F`` (strip faces appended), ``UV``, ``FUV`` (when given), ``strip`` ((k, 2)
        int64: a strip vertex, the loop vertex it hangs from, in the order the vertices were
        added: each segment's mound vertices from the loop inward, then its inner vertex ``q``,
        ``depth_mm`` inside the sphere), ``caruncle_weight`` ((k,) float64, each strip vertex's
        share of the caruncle's colour: 0 at the lid margin, rising to 1 ``CARUNCLE_RIM_SHARE`` of
        the way to the eye, times :func:`caruncle_fade` along the lids; 0 on lateral strips),
        ``medial_faces`` (the medial strip's faces within
        ``CARUNCLE_MM`` of the canthus along the lids: the caruncle; beyond, the inside of the lid)
        and ``lateral_faces`` (the lateral strip's).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    loop = np.asarray(loop, np.int64)
    c = np.asarray(center, float)
    L = len(loop)
    out = {"V": V, "F": F, "strip": np.zeros((0, 2), np.int64),
           "medial_faces": np.zeros(0, np.int64), "lateral_faces": np.zeros(0, np.int64),
           "caruncle_weight": np.zeros(0)}
    if UV is not None:
        out["UV"], out["FUV"] = np.asarray(UV, float), np.asarray(FUV, np.int64)
    newV, newF, newFUV, newUV, strip, weight = [], [], [], [], [], []
    uv_of = {}
    if UV is not None:
        for f, fu in zip(F.tolist(), np.asarray(FUV).tolist()):
            for v, t in zip(f, fu):
                uv_of.setdefault(v, t)
    nv, nuv = len(V), 0 if UV is None else len(out["UV"])
    off = np.linalg.norm(V[loop] - c, axis=1) - radius
    # arc length of each loop vertex from the medial canthus along its lid: the caruncle takes
    # the medial end of the fissure only (CARUNCLE_MM), a strip beyond it is the lid's inside
    arc = np.full(L, np.inf)
    for step in (1, -1):
        j, acc = 0, 0.0
        arc[0] = 0.0
        for _ in range(L // 2):
            nxt = (j + step) % L
            acc += float(np.linalg.norm(V[loop[nxt]] - V[loop[j]]))
            arc[nxt] = min(arc[nxt], acc)
            j = nxt
    for name in ("medial", "lateral"):
        pos = getattr(runs, name)
        if len(pos) == 0 or off[pos].max() <= min_gap_mm:
            continue
        # the run in loop order, one contiguous stretch (the medial one wraps past position 0;
        # a run covers at most max_share of each lid, so never half the loop)
        order = np.sort(pos) if name == "lateral" else np.array(sorted(pos, key=lambda j: (j + L // 2) % L))
        # one loop vertex that rests on the eye joins each end: the strip ends in a quad, not in
        # a sliver from the last corner vertex (where the lid's motion changes fastest) to the eye
        order = np.concatenate([[(order[0] - k) % L for k in range(pad, 0, -1)], order,
                                [(order[-1] + k) % L for k in range(1, pad + 1)]]).astype(np.int64)
        rows = int(mound_rows) if name == "medial" and forward is not None else 0
        column = {}       # loop position -> the segment's vertices from p (excluded) to q
        for j in order:
            p = V[loop[j]]
            d = (p - c) / max(np.linalg.norm(p - c), 1e-12)
            q = c + (radius - depth_mm) * d
            pts = []
            # at most a row per mm of the segment (one edge where the loop vertex is within 2 mm
            # of the inner edge): closer rows would be slivers the lid's motion turns over
            rows_j = min(rows, int(np.linalg.norm(q - p)) - 1)
            if rows_j > 0:
                h, n = _mound_height(p, q, forward, arc[j], mound_mm)
                for k in range(1, rows_j + 1):
                    t = k / (rows_j + 1)
                    flat, up = p + t * (q - p), h * np.sin(np.pi * t) * n
                    pts.append(flat + _keep_clear(flat, up, signed_distance, mound_clear_mm) * up)
            pts.append(q)
            column[int(j)] = []
            fade = float(caruncle_fade(arc[j])) if name == "medial" and np.isfinite(arc[j]) else 0.0
            for k, x in enumerate(pts, start=1):
                column[int(j)].append(nv + len(newV))
                newV.append(x)
                weight.append(fade * float(_smoothstep(k / len(pts) / CARUNCLE_RIM_SHARE)))
                strip.append((column[int(j)][-1], int(loop[j])))
                if UV is not None:
                    newUV.append(out["UV"][uv_of[int(loop[j])]])
        seq = [int((order[0] - 1) % L)] + [int(j) for j in order] + [int((order[-1] + 1) % L)]
        a = loop[np.array(seq[:-1])]
        b = loop[np.array(seq[1:])]
        sense = _loop_edge_faces(F, a, b)
        faces, near = [], []
        for i in range(len(seq) - 1):
            ja, jb = seq[i], seq[i + 1]
            A = [int(loop[ja])] + column.get(ja, [])
            B = [int(loop[jb])] + column.get(jb, [])
            tA, tB = np.linspace(0, 1, len(A)), np.linspace(0, 1, len(B))
            # the skin holds pa -> pb (sense +1): the strip runs pb -> pa; the two columns are
            # zipped inward by their share of the way to the eye (row by row where both have
            # the same rows, a fan where one is the bare loop vertex that rests on the eye)
            tri, ia, ib = [], 0, 0
            while ia < len(A) - 1 or ib < len(B) - 1:
                if ib == len(B) - 1 or (ia < len(A) - 1 and tA[ia + 1] <= tB[ib + 1] + 1e-9):
                    tri.append((B[ib], A[ia], A[ia + 1]))
                    ia += 1
                else:
                    tri.append((B[ib], A[ia], B[ib + 1]))
                    ib += 1
            for t in tri:
                faces.append(t if sense[i] >= 0 else t[::-1])
                near.append(max(arc[seq[i]], arc[seq[i + 1]]) <= CARUNCLE_MM)
        first = len(F) + len(newF)
        for t in faces:
            newF.append(t)
            if UV is not None:
                newFUV.append([uv_of[v] if v < nv else nuv + (v - nv) for v in t])
        ids = np.arange(first, first + len(faces), dtype=np.int64)
        out[f"{name}_faces"] = ids[np.asarray(near, bool)] if name == "medial" else ids
    if not newF:
        return out
    out["V"] = np.concatenate([V, np.asarray(newV)])
    out["F"] = np.concatenate([F, np.asarray(newF, np.int64)])
    out["strip"] = np.asarray(strip, np.int64)
    out["caruncle_weight"] = np.asarray(weight, float)
    if UV is not None:
        out["UV"] = np.concatenate([out["UV"], np.asarray(newUV, float).reshape(-1, 2)])
        out["FUV"] = np.concatenate([out["FUV"], np.asarray(newFUV, np.int64).reshape(-1, 3)])
    return out
