"""Checks of the lid rig over a pitch sweep (:func:`sweep_check`): margin on the eyeball, no fold,
lids never crossing (:func:`lid_opening`), skin outside the eye, the cornea not poking through the
margin (:func:`cornea_intrusion`).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.rig.eye_frame import EyeFrame, rotate_about_axis
from pipeline.rig.lid_shapes import near_eye_skin
from pipeline.rig.lids import MAX_PITCH_DEG, evaluate_shapes, lid_weights


def lid_opening(P, eye: EyeFrame, n_lines: int = 64, margin_frac: float = 0.02) -> np.ndarray:
    """Vertical opening along vertical lines: lowest upper-lid minus highest lower-lid height.

    The loop is projected on the eye's (horizontal, up) plane; vertical lines sample
    the span between the canthi (leaving ``margin_frac`` at each end).

    Parameters
    ----------
    P : (n, 3) float64
        Posed mesh points.
    eye : EyeFrame

    Returns
    -------
    (n_lines,) float64
        Opening per line, mm (negative = the upper lid crossed the lower lid);
        NaN where a lid does not reach the line.
    """
    B = eye.basis()
    loop = np.asarray(eye.loop)
    li = int(eye.lateral_index)
    Q = (np.asarray(P)[loop] - eye.center) @ B[:2].T
    up = Q[: li + 1]
    lo = np.concatenate([Q[li:], Q[:1]])
    xa, xb = sorted((Q[0, 0], Q[li, 0]))
    span = xb - xa
    xs = np.linspace(xa + margin_frac * span, xb - margin_frac * span, n_lines)

    def heights(poly, lowest):
        # every line against every segment at once (lines x segments); the crossing heights are
        # the per-line formula's, element for element, so the min/max are the same numbers
        x0, y0, x1, y1 = poly[:-1, 0], poly[:-1, 1], poly[1:, 0], poly[1:, 1]
        s = xs[:, None]
        hit = ((x0 - s) * (x1 - s) <= 0) & (np.abs(x1 - x0) > 1e-12)
        with np.errstate(divide="ignore", invalid="ignore"):
            y = y0 + (s - x0) / (x1 - x0) * (y1 - y0)
        fill = np.inf if lowest else -np.inf
        res = (np.where(hit, y, fill).min(axis=1) if lowest
               else np.where(hit, y, fill).max(axis=1))
        return np.where(hit.any(axis=1), res, np.nan)

    return heights(up, True) - heights(lo, False)


def cornea_intrusion(points, eye: EyeFrame, cornea_center, cornea_radius: float,
                     pitch_deg: float) -> np.ndarray:
    """How far the corneal bulge of the pitched eye pokes out past each margin point, mm.

    Along the ray from the eyeball centre through each point, the distance of the
    outer cornea-sphere surface (cornea rotated with the eye by ``pitch_deg``) minus
    the point's distance; 0 where the ray misses the cornea or the cornea lies inside.

    Parameters
    ----------
    points : (k, 3) float64
    eye : EyeFrame
    cornea_center : (3,) float64
        Cornea sphere centre at rest.
    cornea_radius : float
    pitch_deg : float

    Returns
    -------
    (k,) float64, >= 0
    """
    cc = rotate_about_axis(np.asarray(cornea_center, float)[None], eye.center, eye.axis,
                           math.radians(pitch_deg))[0] - eye.center
    w = np.asarray(points, float) - eye.center
    dist = np.linalg.norm(w, axis=1)
    d = w / dist[:, None]
    b = d @ cc
    disc = b * b - (cc @ cc - float(cornea_radius) ** 2)
    t = np.where(disc >= 0, b + np.sqrt(np.maximum(disc, 0.0)), -np.inf)
    return np.maximum(t - dist, 0.0)


def sweep_check(V, F, eyes, shapes, pitches_deg, max_pitch_deg: float = MAX_PITCH_DEG,
                corneas: dict | None = None, fork: bool = False) -> dict:
    """Pose the rig at every pitch and measure the lid invariants.

    The eyeball is a sphere about its centre, so rotating it by the pitch leaves
    its surface in place: the margin-to-eyeball distance is ``|v - c| - r``.

    Returns
    -------
    dict
        ``max_gap_mm`` (margin outside the sphere), ``max_penetration_mm`` (inside),
        ``rest_max_abs_mm`` (same at pitch 0), ``flipped_faces`` (max over pitches of
        faces turned over: :func:`pipeline.geometry.meshtopo.turned_over_faces`), ``min_opening_mm``
        (smallest upper-minus-lower lid height along vertical lines; < 0 = crossing),
        ``min_skin_clearance_mm`` (smallest distance outside the pitched eyeball surface of
        moved non-margin vertices within 2 r of the centre; ``rest_min_skin_clearance_mm`` the same at rest) and
        ``max_skin_sink_mm`` (largest decrease of that clearance by posing), and with
        ``corneas`` (``side -> (centre (3,), radius)``) ``max_cornea_intrusion_mm`` /
        ``rest_cornea_intrusion_mm`` (:func:`cornea_intrusion` of the margin),
        ``worst_pitch_deg`` for the gap/penetration, and ``n_pitches``. The margin is the loop
        without its corners off the globe (``EyeFrame.margin``); with corner strips,
        ``strip_max_mm`` is the largest distance of a strip's inner edge (the last vertex hanging
        from each loop vertex) outside the pitched eye surface (negative: it stays inside).
        With ``fork`` the first half of the pitches runs in a forked child (the same result).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    n0 = meshtopo.face_normals(V, F, normalize=False)
    ok = np.linalg.norm(n0, axis=1) > 1e-12
    moved = np.zeros(len(V), bool)
    for s in shapes:
        moved[s.point_indices] = True
    check_faces = ok & moved[F].any(axis=1)
    res = {"max_gap_mm": 0.0, "max_penetration_mm": 0.0, "flipped_faces": 0,
           "min_opening_mm": math.inf, "min_skin_clearance_mm": math.inf,
           "rest_min_skin_clearance_mm": math.inf, "max_skin_sink_mm": 0.0,
           "worst_pitch_deg": 0.0, "n_pitches": 0}
    skin = near_eye_skin(V, shapes, eyes)
    near_skin = {}
    for e in eyes:
        sel = skin[e.side]
        near_skin[e.side] = (sel, e.surface_distance(V[sel], 0.0))
        if len(sel):
            res["rest_min_skin_clearance_mm"] = min(res["rest_min_skin_clearance_mm"],
                                                    float(near_skin[e.side][1].min()))
    rest = max(float(np.max(np.abs(e.surface_distance(V[e.margin], 0.0)))) for e in eyes)
    res["rest_max_abs_mm"] = rest
    pitches = list(pitches_deg)
    args = (V, F, eyes, shapes, max_pitch_deg, corneas, n0, check_faces, near_skin)
    if fork and len(pitches) > 1:
        # the pitches are independent: the first half in a forked child beside the second half
        # here; min/max merge exactly, so the result equals the single-process sweep
        from pipeline.fork import fork_call, fork_result
        half = len(pitches) // 2
        job = fork_call(_sweep_pitches, pitches[:half], *args)
        second = _sweep_pitches(pitches[half:], *args)
        parts = [fork_result(job)[0], second]
    else:
        parts = [_sweep_pitches(pitches, *args)]
    worst = -1.0
    for part in parts:                   # in pitch order: the first pitch reaching the worst wins
        for k in ("max_gap_mm", "max_penetration_mm", "flipped_faces", "max_skin_sink_mm"):
            res[k] = max(res[k], part[k])
        for k in ("min_opening_mm", "min_skin_clearance_mm"):
            res[k] = min(res[k], part[k])
        if "max_cornea_intrusion_mm" in part:
            res["max_cornea_intrusion_mm"] = max(res.get("max_cornea_intrusion_mm", 0.0),
                                                 part["max_cornea_intrusion_mm"])
        if "strip_max_mm" in part:
            res["strip_max_mm"] = max(res.get("strip_max_mm", -math.inf), part["strip_max_mm"])
        if "rest_cornea_intrusion_mm" in part:
            res["rest_cornea_intrusion_mm"] = max(res.get("rest_cornea_intrusion_mm", -math.inf),
                                                  part["rest_cornea_intrusion_mm"])
        if part["worst"] > worst:
            worst, res["worst_pitch_deg"] = part["worst"], part["worst_pitch_deg"]
        res["n_pitches"] += part["n_pitches"]
    for k in ("min_opening_mm", "min_skin_clearance_mm", "rest_min_skin_clearance_mm"):
        if not math.isfinite(res[k]):
            res[k] = None
    return res


def _sweep_pitches(pitches_deg, V, F, eyes, shapes, max_pitch_deg, corneas, n0, check_faces,
                   near_skin) -> dict:
    """:func:`sweep_check`'s measures over some of the pitches (merged by the caller), with
    ``worst`` the largest gap/penetration and ``worst_pitch_deg`` its first pitch."""
    res = {"max_gap_mm": 0.0, "max_penetration_mm": 0.0, "flipped_faces": 0,
           "min_opening_mm": math.inf, "min_skin_clearance_mm": math.inf,
           "max_skin_sink_mm": 0.0, "worst_pitch_deg": 0.0, "n_pitches": 0}
    worst = -1.0
    # the strip's inner edge: the last vertex hanging from each loop vertex (the caruncle's
    # mound rows come before it, outside the eye)
    deep_strip = {e.side: np.fromiter({int(p): int(v) for v, p in e.strip}.values(), np.int64)
                  for e in eyes if e.strip is not None}
    for p in pitches_deg:
        P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch_deg))
        for e in eyes:
            d = e.surface_distance(P[e.margin], p)
            gap, pen = float(max(d.max(), 0.0)), float(max(-d.min(), 0.0))
            res["max_gap_mm"] = max(res["max_gap_mm"], gap)
            res["max_penetration_mm"] = max(res["max_penetration_mm"], pen)
            if max(gap, pen) > worst:
                worst, res["worst_pitch_deg"] = max(gap, pen), float(p)
            if corneas and e.side in corneas:
                cin = cornea_intrusion(P[e.margin], e, *corneas[e.side], p)
                res["max_cornea_intrusion_mm"] = max(res.get("max_cornea_intrusion_mm", 0.0),
                                                     float(cin.max()))
                if p == 0:          # the worse of the two eyes, like every other measure
                    res["rest_cornea_intrusion_mm"] = max(res.get("rest_cornea_intrusion_mm", -math.inf),
                                                          float(cin.max()))
            op = lid_opening(P, e)
            if np.isfinite(op).any():
                res["min_opening_mm"] = min(res["min_opening_mm"], float(np.nanmin(op)))
            if e.strip is not None:     # a corner strip's inner edge stays inside the eye
                deep = deep_strip[e.side]
                res["strip_max_mm"] = max(res.get("strip_max_mm", -math.inf),
                                          float(e.surface_distance(P[deep], p).max()))
            sel, rest_clear = near_skin[e.side]
            if len(sel):
                ds = e.surface_distance(P[sel], p)
                res["min_skin_clearance_mm"] = min(res["min_skin_clearance_mm"], float(ds.min()))
                res["max_skin_sink_mm"] = max(res["max_skin_sink_mm"],
                                              float(np.max(rest_clear - ds)))
        n1 = meshtopo.face_normals(P, F, normalize=False)
        flipped = int(np.count_nonzero(meshtopo.turned_over_faces(n0, n1)[check_faces]))
        res["flipped_faces"] = max(res["flipped_faces"], flipped)
        res["n_pitches"] += 1
    res["worst"] = worst
    return res
