"""Snap the eyelid margin onto the placed eyeball (SynthesEyes 3.3).

Each margin-loop vertex moves along its vertex normal to where that line meets the eyeball's
outer surface (the parametric eye of pipeline/eyeball with its sphere at the placed eye's
radius, ``placed_params``: 12 mm by default, ``remove_eyeballs.eye_size``; cornea, iris and pupil
keep their mm; at the placed centre and forward direction); when the line misses or grazes the surface (no
crossing within ``max_move_mm``) the vertex goes to its closest surface point instead, and
between the two the choice fades, along the loop too (:func:`line_share`), so neighbours never
snap to points millimetres apart.
With ``keep_opening`` (default) the normal first loses its part into the opening, seen along
the eye's axis (:func:`_outward_lines`), so the canthi are not pulled toward the eye's centre.
Vertices near the margin follow with a smooth falloff of the margin displacement over the
edge-graph distance ``falloff_mm``, or ``falloff_per_mm`` times the nearest margin vertex's move
where that is longer (C1 smoothstep, weight 1 at the margin, 0 beyond), so no vertex farther
than that moves. Any vertex of the falloff zone left inside the
eyeball is pushed out to the surface.

Where the margin moves far compared with the triangles next to it (coarse scans: the margin
of ``james`` sits up to 2.6 mm off the fitted eyeball), the zone can fold over. The zone's
displacement is then relaxed (Jacobi smoothing, margin and the rest held), and the free
corners of any face still flipped, or squeezed below ``min_area_fraction`` of its rest area
seen along its rest normal, are slid tangentially into the region where all their faces keep
their orientation (:func:`pipeline.geometry.flips.untangle`, small linear programs), staying
outside the eyeball.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from scipy.sparse.csgraph import dijkstra

from pipeline.geometry import meshtopo
from pipeline.geometry.corners import (CORNER_MAX_SHARE, MARGIN_OFF_GLOBE_MM, OVER_CORNEA_MM, CornerRuns, close_corners,
                                       corner_weights)
from pipeline.geometry.flips import untangle
from pipeline.results import StageResult
from pipeline.settings import Settings, setting

SIDES = ("left", "right")


@dataclass
class SnapSettings(Settings):
    """Settings (``snap:`` block of params.yaml); defaults here, checked by pipeline.settings."""

    block: ClassVar[str] = "snap"

    falloff_mm: float = setting(4.0, ge=0, le=100)        # margin displacement fades to 0 over this edge-graph distance
    falloff_per_mm: float = setting(2.5, ge=0, le=100)    # ... or over this many times a margin vertex's move, if longer
    keep_opening: bool = True                             # the snap line loses its part into the opening (module doc)
    line_smooth_mm: float = setting(2.0, ge=0, le=20)     # snap lines averaged along the loop (sigma, mm; 0: off)
    max_move_mm: float = setting(6.0, gt=0, le=100)       # search range along the normal
    ray_samples: int = setting(49, ge=2, le=10000)        # samples of the normal line before bisection
    clearance_mm: float = setting(0.0, ge=-5, le=5)       # extra offset off the eyeball surface
    max_pitch_deg: float = setting(25.0, ge=0, le=90)     # rotation range of the margin report
    max_yaw_deg: float = setting(35.0, ge=0, le=90)
    graze_ratio: float = setting(2.0, gt=0, le=1000)
    max_relax_iterations: int = setting(200, ge=0, le=100000)
    graze_slack_mm: float = setting(0.25, ge=0, le=100)
    min_area_fraction: float = setting(0.25, ge=0, le=1)  # falloff-zone faces keep this share of their rest area
    # corners off the globe (pipeline/geometry/corners.py): a lid margin rests 0.35-2.1 mm off the
    # eye (UnityEyes' eight registered eye regions); a run of the loop from a canthus standing
    # farther off is a corner: the snap fades to 0 toward that canthus over the run
    corner_off_globe_mm: float = setting(MARGIN_OFF_GLOBE_MM, ge=0, le=50)
    corner_max_share: float = setting(CORNER_MAX_SHARE, gt=0, le=0.5)  # of each lid's arc, at most, per corner run
    close_corners: bool = True                            # strip of faces from an off-globe corner into the eye (caruncle medially)
    strip_depth_mm: float = setting(0.8, gt=0, le=5)      # its inner edge this far inside the sphere: under the eye's 0.5 mm clear shell
    caruncle_mound_mm: float = setting(1.0, ge=0, le=3)   # the medial strip bulges this far toward the opening at the canthus: a mound, not a flap
    caruncle_rows: int = setting(3, ge=0, le=8)           # vertices between the loop and the inner edge of each medial segment (0: a flat strip)


@dataclass
class EyeballSurface:
    """The outer surface of the eyeball an :class:`pipeline.io.eyes_file.Eye` places (centre (3,),
    radius mm, unit forward (3,)), with the eyeball's ``params`` (None: the sphere): the solid
    the lids are snapped onto and measured against, not a second record of the eye."""

    center: np.ndarray
    radius: float
    forward: np.ndarray
    params: object = None

    def closest(self, P):
        """(Q, N, d): closest outer-surface points, normals, signed distances (n,)."""
        from pipeline.eyeball.surface import outer_surface_closest_point

        return outer_surface_closest_point(P, center=self.center, forward=self.forward,
                                           radius=self.radius, params=self.params)

    def signed_distance(self, P):
        return self.closest(P)[2]


def _ray_hit(eye: EyeballSurface, P, N, max_move, samples):
    """Parameter t (n,) of the crossing of P + t N with the surface nearest t = 0 (nan if none)."""
    ts = np.linspace(-max_move, max_move, samples)
    n = len(P)
    D = np.stack([eye.signed_distance(P + t * N) for t in ts], axis=1)  # (n, samples)
    out = np.full(n, np.nan)
    sgn = np.sign(D)
    cross = sgn[:, :-1] * sgn[:, 1:] <= 0
    has = cross.any(axis=1)
    if not has.any():
        return out
    # bracket nearest t = 0 per point
    score = np.where(cross, np.minimum(np.abs(ts[:-1]), np.abs(ts[1:]))[None, :], np.inf)
    j = np.argmin(score, axis=1)[has]
    idx = np.where(has)[0]
    a, b = ts[j].copy(), ts[j + 1].copy()
    fa = D[idx, j]
    for _ in range(48):  # vectorised bisection on the signed distance
        m = 0.5 * (a + b)
        fm = eye.signed_distance(P[idx] + m[:, None] * N[idx])
        same = np.sign(fm) == np.sign(fa)
        a = np.where(same, m, a)
        fa = np.where(same, fm, fa)
        b = np.where(same, b, m)
    out[idx] = 0.5 * (a + b)
    return out


def smooth_along_loop(N, P, sigma_mm):
    """Unit vectors ``N`` (L, 3) at the closed loop ``P`` (L, 3) averaged along it: Gaussian in
    arc length (``sigma_mm``, out to 3 sigma), each neighbour weighed also by how far it agrees
    (``max(0, N_i . N_j)``, so the two lids' lines at a canthus do not mix). A margin vertex's own
    normal comes from the band faces beside it, and one node of ring 1 out of line tilts it:
    snapped along it, that vertex leaves a notch in the lid (``id316_dome``'s left upper lid:
    1.6 mm seen from the front, its neighbours' lines within 10 deg of each other)."""
    N = np.asarray(N, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    seg = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    total = float(seg.sum())
    if total <= 0:
        return N
    d = np.abs(s[:, None] - s[None, :])
    d = np.minimum(d, total - d)
    agree = np.clip(np.einsum("ik,jk->ij", N, N), 0.0, None)
    w = np.exp(-0.5 * (d / sigma_mm) ** 2) * (d <= 3.0 * sigma_mm) * agree
    M = np.einsum("ij,jk->ik", w, N)
    n = np.linalg.norm(M, axis=1, keepdims=True)
    return np.where(n > 1e-9, M / np.maximum(n, 1e-300), N)


def _outward_lines(P, N, forward):
    """Snap lines (L, 3) of a margin loop ``P`` that never point into the opening.

    Seen along the eye's axis, each line keeps only its part along the loop and out of the
    opening: the part of the vertex normal ``N`` (L, 3) along the loop's in-plane normal toward
    the opening's inside is removed. At the canthi, where the boundary vertex has faces on one
    side only, the normal leans into the opening, and the paper's snap along it pulled each
    canthus 0.3-1.0 mm toward the eye's centre.
    """
    f = np.asarray(forward, float)
    f = f / np.linalg.norm(f)
    T = np.roll(P, -1, axis=0) - np.roll(P, 1, axis=0)
    o = np.cross(T, f)
    o /= np.maximum(np.linalg.norm(o, axis=1, keepdims=True), 1e-12)
    away = P - P.mean(axis=0)
    away -= np.outer(away @ f, f)
    if np.sum(np.einsum("ij,ij->i", o, away)) < 0:      # the loop runs the other way round
        o = -o
    into = np.minimum(np.einsum("ij,ij->i", N, o), 0.0)
    M = N - into[:, None] * o
    n = np.linalg.norm(M, axis=1, keepdims=True)
    return np.where(n > 0.2, M / np.maximum(n, 1e-12), N)


def edge_graph(V, F):
    """Edge-length graph (n, n) of (V, F), symmetric CSR."""
    from scipy.sparse import coo_matrix

    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E = np.unique(np.sort(E, axis=1), axis=0)
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    n = len(V)
    return coo_matrix((np.concatenate([w, w]), (np.concatenate([E[:, 0], E[:, 1]]),
                                                np.concatenate([E[:, 1], E[:, 0]]))),
                      shape=(n, n)).tocsr()


def smoothstep_falloff(dist, radius):
    """Weight 1 at distance 0, 0 at ``radius`` and beyond, C1 smoothstep in between."""
    x = np.clip(1.0 - np.asarray(dist, float) / radius, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def line_share(t, dc, st: SnapSettings, passes: int = 8):
    """Share (L,) of each loop vertex's target taken from its snap line's crossing ``t`` (L,)
    (nan: none), the rest from its closest surface point (``dc`` (L,): its signed distance).

    Along the line, unless it meets the surface only far away (grazing, ``|t|`` over
    ``graze_ratio |dc| + graze_slack_mm``): then the closest surface point (paper: "along their
    normals to the closest positions"). The two can lie 2-4 mm apart where lids scanned round a
    larger eye stand off the 12 mm one (``id302_up``'s lower lids: the line runs 3 mm straight
    back, the closest point lies 1.5 mm higher), and a vertex chosen unlike its neighbours made
    a tooth in the lid, with the zone behind it. So the share fades from 1 at 3/4 of the bound
    to 0 at 5/4 of it, and ``passes`` rounds each lower a share to its [1, 2, 1] / 4 average
    along the loop where that is less (never raising one): the loop leans toward the closest
    points over a few vertices either side of a grazing one.
    """
    bound = st.graze_ratio * np.abs(dc) + st.graze_slack_mm
    x = np.where(np.isfinite(t), (1.25 * bound - np.abs(np.nan_to_num(t, nan=np.inf))) / (0.5 * bound), 0.0)
    a = np.clip(x, 0.0, 1.0)
    # each pass only ever lowers a share: a line that grazes, or crosses the cornea in front,
    # gives its neighbours' choice nothing, and they lean toward the closest points instead
    for _ in range(passes):
        a = np.minimum(a, 0.25 * np.roll(a, 1) + 0.5 * a + 0.25 * np.roll(a, -1))
    return a


def snap_loop(V, F, loop, eye: EyeballSurface, st: SnapSettings | None = None, graph=None, weight=None):
    """Snap one eyelid loop (and its falloff zone) onto the eye.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    loop : (L,) int64
        Margin vertex indices.
    eye : EyeballSurface
    st : SnapSettings
    graph : scipy.sparse matrix, optional
        Edge-length graph of (V, F).
    weight : (L,) float64, optional
        Share of its way onto the eye each loop vertex goes (corners off the globe,
        :func:`pipeline.geometry.corners.corner_weights`); None = all of it.

    Returns
    -------
    V2 : (n, 3) float64
        Snapped positions.
    info : dict
        ``moved`` (k,) int64 vertices that moved, ``grazing`` count (vertices taking under half
        their target from their line, :func:`line_share`),
        ``pushed_out`` count, ``falloff_distance`` (n,) float64.
    """
    st = st or SnapSettings()
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    loop = np.asarray(loop, dtype=np.int64)
    N = meshtopo.vertex_normals(V, F)[loop]
    P = V[loop]
    if st.line_smooth_mm > 0:
        N = smooth_along_loop(N, P, st.line_smooth_mm)
    if st.keep_opening:
        N = _outward_lines(P, N, eye.forward)
    t = _ray_hit(eye, P, N, st.max_move_mm, st.ray_samples)
    Qc, _, dc = eye.closest(P)
    a = line_share(t, dc, st)
    graze = a < 0.5
    hit = P + np.nan_to_num(t)[:, None] * N
    target = np.where(a[:, None] > 0, eye.closest(a[:, None] * hit + (1.0 - a[:, None]) * Qc)[0], Qc)
    target[a >= 1.0] = hit[a >= 1.0]
    if st.clearance_mm:
        _, Nq, _ = eye.closest(target)
        target = target + st.clearance_mm * Nq
    if weight is not None:
        target = P + np.asarray(weight, float)[:, None] * (target - P)
    delta = target - P
    G = edge_graph(V, F) if graph is None else graph
    # a long move (a lid far off a smaller globe) fades over proportionally more skin, so the
    # zone's slope stays under ~1/falloff_per_mm and its faces do not turn over
    reach = np.maximum(st.falloff_mm, st.falloff_per_mm * np.linalg.norm(delta, axis=1))
    dist, _, src = dijkstra(G, directed=False, indices=loop, min_only=True,
                            return_predecessors=True, limit=float(reach.max(initial=st.falloff_mm)))
    pos_in_loop = -np.ones(len(V), dtype=np.int64)
    pos_in_loop[loop] = np.arange(len(loop))
    radius = np.full(len(V), st.falloff_mm)
    has = src >= 0
    radius[has] = reach[pos_in_loop[src[has]]]
    w = smoothstep_falloff(dist / np.maximum(radius, 1e-12), 1.0)
    w[~np.isfinite(dist)] = 0.0
    moved = np.where(w > 0)[0]
    V2 = V.copy()
    V2[moved] += w[moved, None] * delta[pos_in_loop[src[moved]]]
    V2[loop] = target
    # untangle: where a face flipped, relax the displacement of the falloff zone (Jacobi
    # smoothing, margin and everything beyond the zone held fixed) until no face flips
    free = np.zeros(len(V), bool)
    free[moved] = True
    free[loop] = False
    relax_iters = 0
    if free.any() and flipped_faces(V, V2, F):
        from scipy.sparse import diags

        A = (G > 0).astype(np.float64)
        deg = np.asarray(A.sum(axis=1)).ravel()
        Avg = diags(1.0 / np.maximum(deg, 1)) @ A
        disp = V2 - V
        for relax_iters in range(1, st.max_relax_iterations + 1):
            disp[free] = 0.5 * disp[free] + 0.5 * (Avg @ disp)[free]
            V2 = V + disp
            if flipped_faces(V, V2, F) == 0:
                break
    # nothing of the falloff zone may end up inside the eyeball
    zone = moved[~np.isin(moved, loop)]
    pushed = 0
    if len(zone):
        Q, Nq, d = eye.closest(V2[zone])
        inside = d < 0
        V2[zone[inside]] = Q[inside] + st.clearance_mm * Nq[inside]
        pushed = int(inside.sum())
    # still tangled (slivers at the margin): slide the free corners of flipped faces
    # tangentially into the region where all their faces keep their rest orientation
    # (or left as near-flipped slivers, below min_area_fraction of their rest area seen along
    # their rest normal, which the lid shapes would fold)
    untangled = 0
    n0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    need = st.min_area_fraction * np.linalg.norm(n0, axis=1)
    n0u = n0 / np.maximum(np.linalg.norm(n0, axis=1, keepdims=True), 1e-300)
    n2 = np.cross(V2[F[:, 1]] - V2[F[:, 0]], V2[F[:, 2]] - V2[F[:, 0]])
    if free.any() and (np.einsum("ij,ij->i", n2, n0u) <= need).any():
        # each vertex stays within its longest rest edge of where the relax left it: the
        # untangle is a local correction, and its steps over 30 rounds otherwise add up (one
        # vertex of id309_squint_up's upper lid walked 49 mm into the middle of the face)
        E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        reach_v = np.zeros(len(V))
        np.maximum.at(reach_v, E.ravel(), np.repeat(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1), 2))
        V2, um = untangle(V2, F, n0, free, keep_out=eye.closest, min_projected=need, max_total=reach_v)
        untangled = len(um)
    return V2, {"moved": moved, "grazing": int(graze.sum()), "pushed_out": pushed,
                "relax_iterations": relax_iters, "untangled": untangled,
                "falloff_distance": dist, "falloff_radius": radius}


def _flipped_mask(V0, V1, F):
    n0 = np.cross(V0[F[:, 1]] - V0[F[:, 0]], V0[F[:, 2]] - V0[F[:, 0]])
    n1 = np.cross(V1[F[:, 1]] - V1[F[:, 0]], V1[F[:, 2]] - V1[F[:, 0]])
    return (n0 * n1).sum(axis=1) <= 0


def flipped_faces(V0, V1, F):
    """Number of faces whose normal turned by more than 90 degrees (or collapsed)."""
    return int(_flipped_mask(V0, V1, F).sum())


def rotated(eye: EyeballSurface, pitch_deg, yaw_deg) -> EyeballSurface:
    """The eye turned by pitch (up +) and yaw (toward head +X +) about its centre."""
    p, y = np.radians(pitch_deg), np.radians(yaw_deg)
    Rx = np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]])
    Ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    f = Ry @ Rx @ np.asarray(eye.forward, float)
    return EyeballSurface(eye.center, eye.radius, f / np.linalg.norm(f), eye.params)


def margin_report(V, loop, eye: EyeballSurface, st: SnapSettings, n_steps=5, on_eye=None):
    """Gap/penetration of the margin at rest and over the anatomical rotation range.

    ``on_eye`` (L,) bool: the loop vertices snapped onto the eye (the corners off the globe are
    not, :mod:`pipeline.geometry.corners`); gaps are measured on them, and on the edges between
    two of them, while nothing of the loop may lie inside the eye. None = the whole loop.

    Returns
    -------
    dict
        ``gap_max_mm`` (largest |signed distance| of margin vertices at rest),
        ``edge_midpoint_min_mm`` (chord sag of margin edges, negative = inside),
        ``rotated_gap_max_mm`` / ``rotated_inside_max_mm`` (over pitch x yaw grid),
        ``meets_cornea`` (True when some rotation moves the surface under a margin vertex by
        more than 0.01 mm, i.e. the corneal bulge reaches the margin).
    """
    on = np.ones(len(loop), bool) if on_eye is None else np.asarray(on_eye, bool)
    P = V[loop]
    d = eye.signed_distance(P)
    mids = 0.5 * (P + np.roll(P, -1, axis=0))
    dm = eye.signed_distance(mids[on & np.roll(on, -1)]) if (on & np.roll(on, -1)).any() else np.zeros(1)
    gmax, imax, cornea = 0.0, 0.0, False
    base = d
    for pitch in np.linspace(-st.max_pitch_deg, st.max_pitch_deg, n_steps):
        for yaw in np.linspace(-st.max_yaw_deg, st.max_yaw_deg, n_steps):
            dr = rotated(eye, pitch, yaw).signed_distance(P)
            gmax = max(gmax, float(dr[on].max(initial=0.0)))
            imax = max(imax, float(-dr.min()))
            if np.abs(dr - base)[on].max(initial=0.0) > 0.01:  # the corneal bulge (not the sphere) under the margin
                cornea = True
    return {"gap_max_mm": float(np.abs(d[on]).max(initial=0.0)), "inside_max_mm": float(max(0.0, -d.min())),
            "edge_midpoint_min_mm": float(dm.min()),
            "rotated_gap_max_mm": gmax, "rotated_inside_max_mm": imax, "meets_cornea": cornea}


def _snap_side(V_in, V0, F, loop, eye: EyeballSurface, st: SnapSettings, G, lateral_index=None):
    """One eye's snap of ``V_in`` (n, 3): (snapped (n, 3), margin report, metrics, moved
    vertices, corner runs).

    ``V0`` (n, 3) is the unsnapped mesh, from which ``max_move_mm`` is measured. Corner runs
    (:func:`pipeline.geometry.corners.corner_weights`) keep their canthus off the eye.
    """
    if lateral_index is None:        # the loop point farthest toward either side of the eye
        from pipeline.geometry.frame import eye_basis

        x = (V_in[loop] - eye.center) @ eye_basis(eye.forward)[0]
        lateral_index = int(np.argmax(np.abs(x - x[0])))
    off = eye.signed_distance(V_in[loop])
    # a loop vertex over the cornea (its ray from the centre passes under the cornea's bulge) is
    # a lid resting on the cornea, never a corner: a strip there would run through the cornea
    d = (V_in[loop] - eye.center) / np.linalg.norm(V_in[loop] - eye.center, axis=1)[:, None]
    over = eye.signed_distance(eye.center + eye.radius * d) < -OVER_CORNEA_MM
    if 0 < lateral_index < len(loop):
        runs = corner_weights(V_in[loop], off, lateral_index, st.corner_off_globe_mm, st.corner_max_share,
                              over_cornea=over)
        free = corner_weights(V_in[loop], off, lateral_index, st.corner_off_globe_mm, st.corner_max_share)
    else:                            # a loop without two canthi (not ordered from one): no corners
        runs = free = CornerRuns(np.ones(len(loop)), np.zeros(0, np.int64), np.zeros(0, np.int64))
    Vs, info = snap_loop(V_in, F, loop, eye, st, graph=G,
                         weight=None if runs.on_eye.all() else runs.weight)
    turned = flipped_faces(V_in, Vs, F) if not np.array_equal(runs.weight, free.weight) else 0
    if turned:
        # the lid put onto the cornea turned faces over: the corner runs as without the cornea,
        # when that turns fewer
        Vf, info_f = snap_loop(V_in, F, loop, eye, st, graph=G,
                               weight=None if free.on_eye.all() else free.weight)
        if flipped_faces(V_in, Vf, F) < turned:
            Vs, info, runs = Vf, info_f, free
    moved = info["moved"]
    far = info["falloff_distance"] > info["falloff_radius"]
    moved_far = int((np.linalg.norm(Vs - V_in, axis=1)[far] > 0).sum())
    rep = margin_report(Vs, loop, eye, st, on_eye=runs.on_eye)
    d_zone = eye.signed_distance(Vs[moved])
    d_loop = eye.signed_distance(Vs[loop])
    metrics = {"loop_length": int(len(loop)), "moved_vertices": int(len(moved)),
               "grazing_fallbacks": info["grazing"], "pushed_out": info["pushed_out"],
               "relax_iterations": info["relax_iterations"],
               "moved_outside_falloff": moved_far,
               "zone_inside_max_mm": float(max(0.0, -d_zone.min())),
               "max_move_mm": float(np.linalg.norm(Vs[moved] - V0[moved], axis=1).max()),
               "corner_vertices": int((~runs.on_eye).sum()),
               "medial_canthus_off_mm": float(d_loop[0]),
               "lateral_canthus_off_mm": float(d_loop[lateral_index]),
               **rep}
    return Vs, rep, metrics, moved, runs


def _independent(G, F, moved, V0, V_first):
    """True when snapping ``moved``'s eye on ``V0`` gives what snapping it on ``V_first`` (V0 with
    the other eye snapped) gives, so the two eyes can be snapped at once.

    An eye's snap reads the mesh only at its moved vertices and their neighbours (normals,
    relaxation, untangling), and, over the whole mesh, which faces are degenerate (the flip
    counts treat a zero-area face as flipped): both must be the same in ``V0`` and ``V_first``.
    """
    near = np.zeros(len(V0), bool)
    near[moved] = True
    near[G[moved].indices] = True
    if (V_first[near] != V0[near]).any():
        return False
    return bool(np.array_equal(_flipped_mask(V0, V0, F), _flipped_mask(V_first, V_first, F)))


def snap_mesh(mesh: dict, eyes: dict, params, st: SnapSettings, source="mesh.npz", graph=None):
    """Snap both eyes' loops of a mesh (the snap stage's work).

    The eyes are snapped one after the other, the first on the mesh, the second on the mesh with
    the first snapped. Since the two zones lie far apart, the first is snapped in a forked child
    while this process snaps the second on the unsnapped mesh; where the second's zone reaches
    the first's (:func:`_independent`), the second is snapped again on the first's result. The
    result is the same either way, to the bit.

    Parameters
    ----------
    mesh : dict
        ``V`` (n, 3), ``F`` (m, 3), ``loop_left``, ``loop_right`` (ordered vertex ids) and any
        other arrays (carried).
    eyes : dict
        ``side -> (center (3,), radius, forward (3,))``.
    params : EyeballParams
        The parametric eye placed in each fit.
    st : SnapSettings
    source : str
        Named in errors.
    graph : scipy.sparse matrix, optional
        Edge-length graph of (V, F) (:func:`edge_graph`), made here when not given.

    Returns
    -------
    (mesh arrays with V snapped, per-eye margin reports, metrics)
    """
    from pipeline.errors import ScanError
    from pipeline.fork import fork_call, fork_result

    V = np.asarray(mesh["V"], float)
    F = np.asarray(mesh["F"], np.int64)
    loops = {}
    for s in SIDES:
        key = f"loop_{s}"
        if key not in mesh:
            raise ScanError(source, f"missing array {key}")
        loop = np.asarray(mesh[key], np.int64)
        if loop.ndim != 1 or len(loop) < 3 or loop.min() < 0 or loop.max() >= len(V):
            raise ScanError(source, f"{key} is not a list of >= 3 vertex indices")
        loops[s] = loop
    G = edge_graph(V, F) if graph is None else graph
    placed = {s: EyeballSurface(*eyes[s], params) for s in SIDES}
    lateral = {s: lateral_position(mesh, s, V[loops[s]], placed[s]) for s in SIDES}
    first, second = SIDES
    job = fork_call(_snap_side, V, V, F, loops[first], placed[first], st, G, lateral[first])
    V2nd, rep2, met2, moved2, runs2 = _snap_side(V, V, F, loops[second], placed[second], st, G,
                                                 lateral[second])
    (V1st, rep1, met1, _, runs1), _ = fork_result(job)
    if _independent(G, F, moved2, V, V1st):
        V2 = V1st.copy()
        changed = (V2nd != V).any(axis=1)
        V2[changed] = V2nd[changed]
    else:
        V2, rep2, met2, _, runs2 = _snap_side(V1st, V, F, loops[second], placed[second], st, G,
                                              lateral[second])
    reports = {first: rep1, second: rep2}
    metrics = {first: met1, second: met2}
    out = dict(mesh)
    out["V"] = V2
    metrics["flipped_faces"] = flipped_faces(V, V2, F)
    metrics["edge_manifold"] = meshtopo.is_edge_manifold(F)
    metrics["gap_max_mm"] = max(metrics[s]["gap_max_mm"] for s in SIDES)
    metrics["inside_max_mm"] = max(max(metrics[s]["inside_max_mm"], metrics[s]["zone_inside_max_mm"])
                                   for s in SIDES)
    runs = {first: runs1, second: runs2}
    for s in SIDES:
        on, n = int(runs[s].on_eye.sum()), len(loops[s])
        if on < n // 2:
            # the corner runs cover most of the loop: the eye does not fill the opening its lids
            # outline (a coarse scan's or a closed lid's eye placed from little evidence), and the
            # rig cannot close lids on it (fresh48's 40k-face head and dome blink)
            raise ScanError(source, f"{s} eye: the lid margin rests on the eye placed in it along only {on} "
                                    f"of its {n} points (its canthi stand "
                                    f"{metrics[s]['medial_canthus_off_mm']:.1f} and "
                                    f"{metrics[s]['lateral_canthus_off_mm']:.1f} mm off it, a margin at most "
                                    f"{st.corner_off_globe_mm:g} mm): that eye does not fill the opening, and "
                                    f"no lids can be rigged on it")
        out[f"loop_snap_{s}"] = runs[s].weight
    out = _close_all_corners(out, loops, runs, placed, st)
    for s in SIDES:
        metrics[s]["strip_vertices"] = int(len(out[f"corner_strip_{s}"]))
    metrics["caruncle_faces"] = int(len(out["caruncle_faces"]))
    metrics["edge_manifold_closed"] = meshtopo.is_edge_manifold(out["F"])
    return out, reports, metrics


@dataclass
class SnapResult:
    """What the snap stage writes: ``mesh`` (the arrays of mesh.npz, ``V`` snapped), ``eyes``
    (side -> :class:`pipeline.io.eyes_file.Eye`, its loop on the snapped mesh and the snap's
    report) and ``result`` (its metrics)."""

    mesh: dict
    eyes: dict
    result: StageResult


def snap_eyes(mesh: Mapping, eyes: dict, params, st: SnapSettings, source="mesh.npz",
              graph=None) -> SnapResult:
    """Snap both eyes' loops of a mesh (:func:`snap_mesh`) onto the eyes of ``eyes.json``
    (side -> :class:`pipeline.io.eyes_file.Eye`); each eye's loop then refers to the snapped
    mesh and carries the snap's report."""
    out, reports, metrics = snap_mesh(mesh, {s: (e.center, e.radius, e.unit_forward) for s, e in eyes.items()},
                                      params, st, source=source, graph=graph)
    snapped = {}
    for s, e in eyes.items():
        loop = np.asarray(out[f"loop_{s}"], np.int64)
        P = out["V"][loop]
        snapped[s] = replace(e, loop_indices=loop, loop_points=P,
                             lateral_canthus_index=lateral_position(
                                 mesh, s, P, EyeballSurface(e.center, e.radius, e.unit_forward)),
                             extra={**e.extra, "snap": dict(reports[s])})
    return SnapResult(out, snapped, StageResult(metrics))


def lateral_position(mesh: dict, side: str, P, eye: EyeballSurface) -> int:
    """Position of the lateral canthus in ``loop_<side>``: retopo's ``lateral_index_<side>``, else
    the loop point farthest toward the eye's lateral side."""
    from pipeline.io.eyes_file import lateral_canthus_index

    key = f"lateral_index_{side}"
    if key in mesh:
        return int(np.asarray(mesh[key]).ravel()[0])
    return lateral_canthus_index(P, eye.center, eye.forward, side)


def _close_all_corners(mesh: dict, loops: dict, runs: dict, placed: dict, st: SnapSettings) -> dict:
    """Both eyes' corner strips (:func:`pipeline.geometry.corners.close_corners`) appended to the
    mesh: ``corner_strip_<side>`` (k, 2) [strip vertex, the loop vertex it hangs from] and ``caruncle_faces`` (the
    medial strips' faces, for the caruncle material) are added (empty when every corner rests on
    the eye); texture coordinates, vertex colours and polygons follow the new faces. With a
    caruncle, ``caruncle_weight`` (n,) float64 gives each vertex its share of the caruncle's
    colour (0 off the strips; :func:`close_corners`)."""
    out = dict(mesh)
    caruncle, weight = [], np.zeros(len(mesh["V"]))
    for s in SIDES:
        out[f"corner_strip_{s}"] = np.zeros((0, 2), np.int64)
        if not st.close_corners or runs[s].on_eye.all():
            continue
        nV, nF = len(out["V"]), len(out["F"])
        res = close_corners(out["V"], out["F"], loops[s], runs[s], placed[s].center, placed[s].radius,
                            st.strip_depth_mm, out.get("UV"), out.get("FUV"), forward=placed[s].forward,
                            mound_mm=st.caruncle_mound_mm, mound_rows=st.caruncle_rows,
                            signed_distance=placed[s].signed_distance)
        new_faces = res["F"][nF:]
        out["V"], out["F"] = res["V"], res["F"]
        if "UV" in res:
            out["UV"], out["FUV"] = res["UV"], res["FUV"]
        if "VC" in out:
            out["VC"] = np.concatenate([out["VC"], out["VC"][res["strip"][:, 1]]])
        if "poly_counts" in out:
            out["poly_counts"] = np.concatenate([out["poly_counts"], np.full(len(new_faces), 3, np.int64)])
            out["poly_indices"] = np.concatenate([out["poly_indices"], new_faces.ravel()])
        out[f"corner_strip_{s}"] = res["strip"]
        caruncle.append(res["medial_faces"])
        weight = np.concatenate([weight, res["caruncle_weight"]])
    out["caruncle_faces"] = np.concatenate(caruncle) if caruncle else np.zeros(0, np.int64)
    if len(out["caruncle_faces"]):
        out["caruncle_weight"] = weight
    return out
