"""Eyelids that ride on the cornea as the eye turns in yaw: per eye and direction
(``lids_look_in_<side>``, ``lids_look_out_<side>``: ARKit's ``eyeLookIn`` / ``eyeLookOut``), one
blend shape per pose of a grid of pitches and yaws, blended bilinearly.

The paper's lids follow pitch only (section 3.4), and so did ours. But the parametric eye's
cornea bulges out of the sphere by up to 2.5 mm, and a turn in yaw slides that bulge sideways
under lids that do not move: on the 48 held-out assets the lid margin sank into the eye by
0.27 mm at 5 deg of yaw and 1.36-1.39 mm at 35 deg (the median eye), the cornea poking
through the lids in every image rendered off the straight gaze (DESIGN.md: after any eyeball
rotation inside the anatomical limits no lid vertex may sink into the eyeball). A real lid is
pushed out by the cornea passing under it, and settles back where it has passed.

At each grid pose (pitch ``p_k`` of :data:`PITCH_KNOTS_DEG`, yaw ``y_m`` of :data:`YAW_KNOTS_DEG`
in one direction) the skin near the eye, posed by the pitch channels at ``p_k``, moves as
:func:`pipeline.rig.lid_shapes.follow_surface` moves it for pitch: every point gets back the
share ``w = S(|c| / H)`` of the clearance the turn cost it (or gave it), ``dr = w (c - c_turned)``
along its ray from the eye's centre, where ``c`` is its clearance from the eye's outer surface at
``p_k`` and ``c_turned`` at ``(p_k, y_m)``. The margin (``c = 0``) stays on the eye; skin ``H``
or more off it is left alone, except that nothing outside the eye comes nearer the turned eye
than ``min(c, FLOOR_MM)`` (a corner standing off the globe, which the cornea reaches). A
corner strip's inner edge keeps its depth inside the eye where the cornea comes, and the
caruncle's rows between it and the loop follow both, no nearer the turned eye than the floor. The lids move with pitch as well as yaw,
and the cornea's place under them depends on both, so no one shape per yaw serves every pitch
(made good at every pitch at once, the lids stood up to 0.34 mm off the cornea at rest and let
the background through at the medial canthus). The channel of pose ``(k, m)``,
``lids_look_<in|out>_<side>_<pitch>_y<yaw>``, has weight ``b_k(pitch) h_m(|yaw|)``: hat functions
over the knots (:func:`yaw_weights`), so the lids are exact at every grid pose and interpolated
bilinearly between.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.io.blend_shapes import BlendShape

__all__ = ["MAX_YAW_DEG", "PITCH_KNOTS_DEG", "YAW_KNOTS_DEG", "YAW_RULE", "yaw_channels", "yaw_weights",
           "yaw_rule", "yaw_gaze", "surface_distance", "build_yaw_shapes", "curve_shapes", "yaw_sweep",
           "settle_yaw_folds"]

#: DESIGN.md's anatomical limit of yaw, degrees
MAX_YAW_DEG = 35.0
#: the pitches (deg) of the grid: DESIGN.md's +-25 and between
PITCH_KNOTS_DEG = (-25.0, -12.5, 0.0, 12.5, 25.0)
#: the yaws (deg, toward one side) of the grid, to the limit
YAW_KNOTS_DEG = (7.0, 14.0, 21.0, 28.0, 35.0)
#: the least clearance (mm) a point outside the eye keeps off the turned eye (the caruncle
#: mound's own, :mod:`pipeline.geometry.corners`), or its clearance at that pitch where less
FLOOR_MM = 0.3

#: The yaw-to-weight rule, as stored in the asset (rig.json, USD metadata).
YAW_RULE = {
    "function": "pipeline.rig.yaw_shapes.yaw_weights",
    "formula": "per eye: t = yaw_deg * (+1 right eye, -1 left eye) (positive = toward the nose); "
               "direction d = in if t > 0 else out; channel lids_look_<d>_<side>_<pitch knot>_y<yaw knot> "
               "gets hat(pitch over pitch_knots_deg) * hat(|t| over [0] + yaw_knots_deg), clamped to the "
               "knots' range; every other channel 0",
    "yaw_definition": "each eye's own yaw in its eye frame, degrees: atan2(g . e_x, g . forward) for "
                      "the head-frame unit gaze g (e_x toward the head's +X, the subject's left)",
    "pitch_definition": "the lid rule's pitch (weight_rule): the mean lid pitch of both eyes",
}


def _pitch_name(p: float) -> str:
    return "level" if p == 0 else f"{'up' if p > 0 else 'down'}{abs(p):g}".replace(".", "p")


def yaw_channels(side: str, direction: str | None = None) -> list[str]:
    """The channel names of one eye (one direction: ``in`` or ``out``), pitch knot by yaw knot."""
    dirs = ("in", "out") if direction is None else (direction,)
    return [f"lids_look_{d}_{side}_{_pitch_name(p)}_y{y:g}" for d in dirs for p in PITCH_KNOTS_DEG
            for y in YAW_KNOTS_DEG]


def _in_sign(side: str) -> float:
    # e_x points to the subject's left: the nose lies at -e_x from the left eye, +e_x from the right
    return -1.0 if side == "left" else 1.0


def _hats(x: float, knots) -> np.ndarray:
    """Hat-function weights of ``x`` over ``knots`` (increasing), clamped to their range."""
    k = np.asarray(knots, float)
    x = min(max(float(x), k[0]), k[-1])
    w = np.zeros(len(k))
    j = int(np.clip(np.searchsorted(k, x, side="right") - 1, 0, len(k) - 2))
    a = (x - k[j]) / (k[j + 1] - k[j])
    w[j], w[j + 1] = 1.0 - a, a
    return w


def yaw_weights(yaw_by_side: dict, pitch_deg: float = 0.0, max_yaw_deg: float = MAX_YAW_DEG) -> dict[str, float]:
    """Channel weights for each eye's yaw (degrees, its eye frame, positive toward the subject's
    left) at the lid rule's pitch: THE yaw-to-weight rule (:data:`YAW_RULE`). Every channel of the
    sides given, zeros included. ``max_yaw_deg``: the last yaw knot (the asset's rule)."""
    m = float(max_yaw_deg)
    if not (math.isfinite(m) and m > 0):
        raise ValueError(f"max_yaw_deg must be positive, got {max_yaw_deg!r}")
    if not math.isfinite(float(pitch_deg)):
        raise ValueError(f"pitch must be finite, got {pitch_deg!r}")
    yk = np.asarray(YAW_KNOTS_DEG) * (m / MAX_YAW_DEG)
    bp = _hats(pitch_deg, PITCH_KNOTS_DEG)
    out = {}
    for side, y in yaw_by_side.items():
        y = float(y)
        if not math.isfinite(y):
            raise ValueError(f"yaw must be finite, got {y!r}")
        t = _in_sign(side) * y
        hy = _hats(abs(t), np.concatenate([[0.0], yk]))[1:]
        for d in ("in", "out"):
            on = (t > 0) == (d == "in") and t != 0
            names = yaw_channels(side, d)
            W = np.outer(bp, hy).ravel() if on else np.zeros(len(names))
            out.update({n: float(w) for n, w in zip(names, W)})
    return out


def yaw_rule(max_yaw_deg: float = MAX_YAW_DEG) -> dict:
    """The rule as metadata for the asset: :data:`YAW_RULE` plus its knots."""
    return {**YAW_RULE, "max_yaw_deg": float(max_yaw_deg), "pitch_knots_deg": list(PITCH_KNOTS_DEG),
            "yaw_knots_deg": list(YAW_KNOTS_DEG)}


def yaw_gaze(eye, pitch_deg: float, yaw_deg: float, basis=None) -> np.ndarray:
    """(3,) head-frame gaze of ``eye`` (an EyeFrame) turned by pitch and yaw in its eye frame
    (the render's :func:`pipeline.render.camera.direction_from_angles`); ``basis``: the eye's
    (3, 3) ``eye.basis()`` when the caller has it."""
    p, y = math.radians(pitch_deg), math.radians(yaw_deg)
    B = eye.basis() if basis is None else basis
    return np.array([math.cos(p) * math.sin(y), math.sin(p), math.cos(p) * math.cos(y)]) @ B


def surface_distance(eye, P, gaze, placed=None) -> np.ndarray:
    """(n,) radial distance of points ``P`` outside (+) / inside (-) the outer surface of ``eye``
    looking along ``gaze`` (:meth:`pipeline.rig.eye_frame.EyeFrame.surface_distance` for any
    gaze); ``placed``: ``placed_params(eye.profile, eye.radius)`` when the caller has it."""
    from pipeline.eyeball.geometry import outer_radial, placed_params

    w = np.asarray(P, float) - eye.center
    r = np.linalg.norm(w, axis=1)
    if eye.profile is None:
        return r - float(eye.radius)
    u = w / np.maximum(r, 1e-12)[:, None]
    g = np.asarray(gaze, float) / np.linalg.norm(gaze)
    pp = placed_params(eye.profile, eye.radius) if placed is None else placed
    return r - outer_radial(np.arccos(np.clip(u @ g, -1.0, 1.0)), pp)


def curve_shapes(shapes, side: str, edge, t) -> list[BlendShape]:
    """The yaw channels of ``side`` (from the mesh's ``shapes``) for its eyelid landmark curve:
    each landmark lies on margin edge ``edge`` (12, 2) at ``t`` (12,), so it moves by the same
    interpolation of its edge's two vertices' offsets as the mesh does (point indices 0..11)."""
    edge = np.asarray(edge, np.int64)
    t = np.asarray(t, float)[:, None]
    out = []
    mine = set(yaw_channels(side))
    for s in shapes:
        if s.name not in mine:
            continue
        w, o = s.knots()
        at = {int(v): j for j, v in enumerate(s.point_indices)}

        def lm(O):
            full = np.zeros((2, len(edge), 3))
            for k in range(2):
                for i, v in enumerate(edge[:, k]):
                    if int(v) in at:
                        full[k, i] = O[at[int(v)]]
            return (1.0 - t) * full[0] + t * full[1]

        out.append(BlendShape(name=s.name, point_indices=np.arange(len(edge), dtype=np.int64),
                              offsets=lm(o[-1]), inbetween_weights=s.inbetween_weights.copy(),
                              inbetween_offsets=np.stack([lm(o[j]) for j in range(1, len(w) - 1)])
                              if len(w) > 2 else np.zeros((0, len(edge), 3))))
    return out


def _strip_rows(strip):
    """(strip vertex, loop vertex, f) per row of ``corner_strip_<side>`` (k, 2): ``f`` the row's
    share of the way from the loop vertex to the inner edge (the last row hanging from it: 1)."""
    rows = {}
    for v, p in np.asarray(strip, np.int64):
        rows.setdefault(int(p), []).append(int(v))
    return [(v, p, (k + 1) / len(vs)) for p, vs in rows.items() for k, v in enumerate(vs)]


def build_yaw_shapes(V, eyes, follow_mm: float, lid_shapes=(), max_pitch_deg: float = 25.0,
                     max_yaw_deg: float = MAX_YAW_DEG) -> list[BlendShape]:
    """The yaw channels (module doc) of the rest mesh ``V`` (n, 3) round ``eyes`` (EyeFrames),
    with the lids posed at each pitch knot by ``lid_shapes`` (weighted by
    :func:`pipeline.rig.lids.lid_weights`); none for an eye without a corneal bulge (``profile``
    None: the sphere turns into itself). ``follow_mm``: the clearance at which the push has faded
    out (the lid rig's ``surface_follow_mm``, floor of ``H``). Returns a list of BlendShape
    without inbetweens, in :func:`yaw_channels` order per eye."""
    from pipeline.eyeball.geometry import placed_params
    from pipeline.rig.lid_shapes import smootherstep_falloff
    from pipeline.rig.lids import evaluate_shapes, lid_weights

    V = np.asarray(V, np.float64)
    posed = {p: evaluate_shapes(V, list(lid_shapes), lid_weights(p, max_pitch_deg)) for p in PITCH_KNOTS_DEG}
    yk = np.asarray(YAW_KNOTS_DEG) * (float(max_yaw_deg) / MAX_YAW_DEG)
    out = []
    for e in eyes:
        if e.profile is None:
            continue
        c0 = surface_distance(e, V, e.forward)
        near = np.flatnonzero(np.linalg.norm(V - e.center, axis=1) < 2.0 * e.radius)
        B, pp = e.basis(), placed_params(e.profile, e.radius)
        # the cornea's height over the sphere at its apex (a point 1 mm out along the gaze lies
        # R - 1 mm inside the surface)
        bulge = 1.0 - float(surface_distance(e, (e.center + B[2])[None], e.forward, pp)[0]) - float(e.radius)
        H = max(float(follow_mm), 1.25 * max(bulge, 0.0), 1e-9)
        w = smootherstep_falloff(np.abs(c0[near]) / H)
        strip = np.isin(near, e.strip_inner)
        rows = _strip_rows(e.strip) if e.strip is not None and len(e.strip) else []
        at = {int(v): k for k, v in enumerate(near)}
        inner = {p: v for v, p, f in rows if f == 1.0}
        edge = np.isin(near, list(inner.values()))
        w[strip] = 0.0
        w[edge] = 1.0
        floor = (c0[near] >= 0.0) & ~strip
        for d, sign in (("in", _in_sign(e.side)), ("out", -_in_sign(e.side))):
            names = iter(yaw_channels(e.side, d))
            for p in PITCH_KNOTS_DEG:
                Q = posed[p][near]
                # along each point's ray from the centre as the lids stand at this pitch
                ray = (Q - e.center) / np.maximum(np.linalg.norm(Q - e.center, axis=1, keepdims=True), 1e-12)
                cp = surface_distance(e, Q, yaw_gaze(e, p, 0.0, B), pp)
                for y in yk:
                    cy = surface_distance(e, Q, yaw_gaze(e, p, sign * y, B), pp)
                    dr = w * (cp - cy)
                    dr[floor] = np.maximum(dr[floor], np.minimum(cp[floor], FLOOR_MM) - cy[floor])
                    dr[edge] = np.maximum(dr[edge], 0.0)
                    pose = ray * dr[:, None]
                    for v, lp_, f in rows:
                        # a caruncle row moves as its share of the way from the loop vertex it
                        # hangs from to the inner edge says (its faces do not shear against the lid)
                        if f < 1.0 and v in at and lp_ in at and inner[lp_] in at:
                            k = at[v]
                            pose[k] = (1.0 - f) * pose[at[lp_]] + f * pose[at[inner[lp_]]]
                            # ... and comes no nearer the turned eye than the floor (following
                            # alone, the rows entered it by up to 0.83 mm on the held-out heads)
                            lift = min(cp[k], FLOOR_MM) - cy[k] - float(pose[k] @ ray[k])
                            if lift > 0.0:
                                pose[k] += lift * ray[k]
                    keep = np.abs(pose).max(axis=1) > 1e-9
                    out.append(BlendShape(name=next(names), point_indices=near[keep].astype(np.int64),
                                          offsets=pose[keep]))
    return out


class _Poser:
    """The part of a mesh that ``shapes`` move (their vertices and every face touching one),
    posed fast: each shape's stored poses kept once, two of them mixed per channel (what
    :func:`pipeline.rig.lids.evaluate_shapes` does, to rounding)."""

    def __init__(self, V, F, shapes):
        moved = np.zeros(len(V), bool)
        for sh in shapes:
            moved[sh.point_indices] = True
        self.faces = np.flatnonzero(moved[F].any(axis=1))
        self.verts = np.unique(F[self.faces])
        local = np.full(len(V), -1, np.int64)
        local[self.verts] = np.arange(len(self.verts))
        self.local = local
        self.V = np.asarray(V, float)[self.verts]
        self.F = local[F[self.faces]]
        self.shapes = [(sh, local[sh.point_indices], sh.knots()[1]) for sh in shapes]

    def pose(self, weights: dict) -> np.ndarray:
        from pipeline.rig.lids import subshape_weights

        P = self.V.copy()
        for sh, idx, offs in self.shapes:
            w = weights.get(sh.name, 0.0)
            if w == 0.0 or len(idx) == 0:
                continue
            sub = subshape_weights(sh, w)
            for j in np.flatnonzero(sub):
                P[idx] += sub[j] * offs[j + 1]
        return P


def yaw_sweep(V, F, eyes, shapes, pitches_deg, yaws_deg, max_pitch_deg: float,
              max_yaw_deg: float = MAX_YAW_DEG, faces: bool = False) -> dict:
    """The lids posed at every pitch and yaw (both eyes turned alike; ``shapes``: the lid and yaw
    channels) against the turned eyes.

    Returns ``max_penetration_mm`` / ``max_gap_mm`` (the margin inside / outside the turned eye's
    outer surface), ``max_sink_mm`` (the deepest point outside the eye at rest, within two radii
    of its centre, inside the turned eye: skin, a corner of the loop), ``max_strip_sink_mm`` (the
    same for the caruncle's rows of a corner strip, which turn with their lid), ``flipped_faces``
    (the most faces turned over against rest in one pose), each with the pose where it is worst
    (``*_at``: pitch, yaw); with ``faces``, ``turned`` (m,) bool: the faces some pose turns over."""
    from pipeline.eyeball.geometry import placed_params
    from pipeline.geometry import meshtopo
    from pipeline.rig.lids import lid_weights

    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    ps = _Poser(V, F, shapes)
    n0 = meshtopo.face_normals(ps.V, ps.F, normalize=False)
    ok = np.linalg.norm(n0, axis=1) > 1e-12
    out = {"max_penetration_mm": 0.0, "max_gap_mm": 0.0, "max_sink_mm": 0.0, "max_strip_sink_mm": 0.0,
           "flipped_faces": 0}
    at = {k: None for k in out}
    turned = np.zeros(len(ps.F), bool)
    sets = {}
    for e in eyes:
        idx = ps.verts
        c0 = surface_distance(e, V[idx], e.forward)
        near = (c0 >= 0.0) & (np.linalg.norm(V[idx] - e.center, axis=1) < 2.0 * e.radius)
        strip = np.isin(idx, e.strip_inner)
        margin = ps.local[e.margin]
        sets[e.side] = (margin, np.flatnonzero(near & ~strip), np.flatnonzero(near & strip), e.basis(),
                        None if e.profile is None else placed_params(e.profile, e.radius))

    def worse(key, value, pose):
        if value > out[key]:
            out[key], at[key] = value, pose

    for p in pitches_deg:
        for y in yaws_deg:
            P = ps.pose({**lid_weights(p, max_pitch_deg), **yaw_weights({e.side: y for e in eyes}, p, max_yaw_deg)})
            for e in eyes:
                margin, skin, rows, B, pp = sets[e.side]
                g = yaw_gaze(e, p, y, B)
                if (margin >= 0).all():
                    d = surface_distance(e, P[margin], g, pp)
                    worse("max_penetration_mm", float(-d.min()), (p, y))
                    worse("max_gap_mm", float(d.max()), (p, y))
                worse("max_sink_mm", float(-surface_distance(e, P[skin], g, pp).min(initial=0.0)), (p, y))
                worse("max_strip_sink_mm", float(-surface_distance(e, P[rows], g, pp).min(initial=0.0)), (p, y))
            t = ok & meshtopo.turned_over_faces(n0, meshtopo.face_normals(P, ps.F, normalize=False))
            turned |= t
            worse("flipped_faces", int(np.count_nonzero(t)), (p, y))
    out.update({f"{k}_at": v for k, v in at.items()})
    if faces:
        full = np.zeros(len(F), bool)
        full[ps.faces] = turned
        out["turned"] = full
    return out


#: the poses the rig checks the yaw channels at: the pitch extremes and midway between the
#: grid's pitches, and the yaws midway between its yaws (where the interpolation is worst) and at
#: the limit, both ways
CHECK_PITCHES_DEG = (-25.0, -18.75, -6.25, 0.0, 6.25, 18.75, 25.0)
CHECK_YAWS_DEG = tuple(float(x) for x in sorted(
    [sg * y for sg in (-1.0, 1.0) for y in (3.5, 10.5, 17.5, 24.5, 31.5, 35.0)]))


def settle_yaw_folds(V, F, eyes, lid_shapes, yaw_shapes, max_pitch_deg: float,
                     max_yaw_deg: float = MAX_YAW_DEG, rounds: int = 4):
    """``yaw_shapes`` with the push halved, round by round (at most ``rounds``), on the vertices
    of every face that some checked pose (:data:`CHECK_PITCHES_DEG` x :data:`CHECK_YAWS_DEG`)
    turns over and on their neighbours: where a corner's thin faces shear under the push, the
    skin there rides less high on the cornea rather than fold. First the margin's own vertices
    are kept (it stays on the cornea while a caruncle row beside it gives: fresh20's
    ``n2604_holes_debris_noise``); where that leaves a fold, the rounds run again from the start
    with the margin damped too (held-out ``id409_squint``'s medial corner, 13 vertices). Returns
    ``(shapes, rounds_run, damped_vertices, sweep)``: ``sweep`` is :func:`yaw_sweep` of the
    shapes returned over the checked poses."""
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    lid_shapes = list(lid_shapes)
    loops = np.concatenate([e.loop for e in eyes])
    best = None
    for keep_margin in (True, False):
        shapes = [BlendShape(s.name, s.point_indices.copy(), s.offsets.copy(), s.inbetween_weights.copy(),
                             s.inbetween_offsets.copy()) for s in yaw_shapes]
        damped = np.zeros(len(V), bool)
        k = 0
        while True:
            sweep = yaw_sweep(V, F, eyes, lid_shapes + shapes, CHECK_PITCHES_DEG, CHECK_YAWS_DEG,
                              max_pitch_deg, max_yaw_deg, faces=True)
            bad = sweep.pop("turned")
            if not bad.any() or k == rounds:
                break
            vs = np.unique(F[bad])
            ring = np.unique(F[np.isin(F, vs).any(axis=1)])
            if keep_margin:
                ring = np.setdiff1d(ring, loops)
            damped[ring] = True
            for s in shapes:
                m = np.isin(s.point_indices, ring)
                s.offsets[m] *= 0.5
                if len(s.inbetween_weights):
                    s.inbetween_offsets[:, m] *= 0.5
            k += 1
        got = (shapes, k, int(damped.sum()), sweep)
        if best is None or sweep["flipped_faces"] < best[3]["flipped_faces"]:
            best = got
        if not bad.any():
            break
    return best
