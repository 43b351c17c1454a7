"""Self-checks of a fitted eye: facts every correct eyeball placement satisfies.

A sphere fitted to a scanned eye can be wrong with a low residual: a smaller sphere hugging the
sclera and the corneal bulge, or a larger one through lid skin draped over a down-looking or
squinting eye, both fit their inliers within noise. What they cannot do is satisfy the anatomy
around them, so each fit is checked against it (``check_eye``, ``check_pair``):

- ``inside``: nothing of the head lies inside the eyeball. Surface within ``radius_mm`` of the
  opening that lies deeper than the noise inside the sclera sphere means the
  sphere is too large or too far forward (within ``cone_depth_mm`` inside the corneal cone,
  where a scanner that sees the iris through the cornea leaves a recessed disc).
- ``radius_in_range``: the radius lies in the anatomical range.
- ``opening_fits``: the lids' part of the opening loop (a chord of the eyeball at its widest) is
  not wider than the eyeball's diameter.
- ``opening_wide``: the whole loop spans at least ``min_opening_mm`` (no palpebral fissure is
  narrower: adults' are 27 +- 1.7 mm, a newborn's about 18; a squint or a blink closes the
  opening vertically, not across). A narrower loop is a cut round part of the eye (an eye placed
  in a wrong basin, its surface labelled skin beside it) or a scan that shows less of the
  opening (sparse views). With no iris in it (the eye falls back to the opening) the stage
  refuses it (:func:`pipeline.placement.place.judge_pair`: ``id311_look_right``'s 12.4 mm loop,
  published before with the preview black through the opening); otherwise it is a doubt.
- ``loop_on_sphere``: the lids' part of the eyelid loop lies on the eyeball, sclera or fitted
  cornea (the margin is where lid meets eye).

Both leave the corners out: the loop runs from canthus to canthus, and where the lids leave the
globe near a canthus (anatomy: the medial fissure corner lies 3-7 mm off it) a run from that
canthus standing farther off than a lid margin can is a corner
(:func:`pipeline.geometry.corners.corner_weights`, at most ``corner_max_share`` of each lid).
- ``opening_convex``: the loop, seen along the gaze, fills ``min_convex_fill`` of its convex
  hull (eyelid margins are convex; a notch or a tongue of scanned eyeball left on a lid is not).
- ``cornea_shows``: every eye has a cornea, so the scanned eye surface around the gaze axis
  stands off the sclera sphere: above it where the scanner saw the corneal bulge (or, as in
  ICT-FaceKit scans, the iris through a flattened cornea), below it where it saw a recessed iris.
  A sphere that runs flush through the middle of the opening and its sides has swallowed the
  cornea: it is too small and too far forward, with a low residual.
- ``radii_agree`` (pair): the two eyes of one head have radii within ``max_radius_diff_mm``.
- ``loop_on_eye`` (:func:`loop_inside_eye`, asked only when ``loop_on_sphere`` failed): the lids'
  part of the loop does not lie inside the eye the asset carries (after the fallbacks).

Each check returns its measured value and whether it passed, so the stage can record them in
``eyes.json`` and the metrics and refuse (or fall back) with one line naming the failed check.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.geometry.corners import CORNER_MAX_SHARE, MARGIN_OFF_GLOBE_MM, corner_weights
from pipeline.geometry.meshtopo import faces_touching


@dataclass(frozen=True)
class CheckLimits:
    """Thresholds of the eye self-checks (all mm unless stated)."""

    radius_mm: float = 16.0          # surface considered around the opening centroid
    inside_noise_mm: float = 0.3     # depth inside the sclera sphere tolerated (at least 4 x fit rms)
    max_inside_area_mm2: float = 2.0
    cornea_cone_deg: float = 35.0    # around the forward axis a recessed iris disc may lie inside ...
    cone_depth_mm: float = 2.0       # ... up to this deep
    radius_range_mm: tuple = (10.0, 21.0)
    max_width_ratio: float = 1.0     # opening width / eyeball diameter
    min_opening_mm: float = 14.0     # the loop's span, at least (a newborn's fissure is ~18 mm)
    max_loop_off_mm: float = 1.0     # 90th percentile of |loop - sphere|
    min_convex_fill: float = 0.9     # loop area / convex hull area, seen along the gaze, less a
    edge_mm: float = 0.0             # strip a tenth of the scan's edge wide along the loop
    flush_band_mm: tuple = (-0.4, 0.15)  # centre minus sides of the eye surface: "no cornea"
    cornea_cone_check_deg: tuple = (12.0, 30.0)  # centre: within the first; sides: beyond the second
    min_points: int = 8              # per part, else the cornea check has too little to say
    max_radius_diff_mm: float = 2.0  # between the two eyes of one head (axial lengths rarely
                                     # differ by 2 mm; the procedural head draws up to 1.7 mm)
    corner_off_globe_mm: float = MARGIN_OFF_GLOBE_MM  # a loop run from a canthus farther off is a corner
    corner_max_share: float = CORNER_MAX_SHARE        # of each lid, at most


def limits_for(median_edge_mm: float, radius_range_mm=(10.0, 21.0)) -> CheckLimits:
    """The limits for a scan of this resolution: a vertex of a coarse mesh may sit a quarter
    edge off the surface it samples, a loop vertex half an edge off the margin, and two faces
    of area is the smallest patch a coarse mesh can show."""
    base = CheckLimits()
    e = max(float(median_edge_mm), 0.0)
    return replace(base, inside_noise_mm=max(base.inside_noise_mm, 0.25 * e),
                   max_inside_area_mm2=max(base.max_inside_area_mm2, 2 * 0.433 * e * e),
                   radius_range_mm=tuple(radius_range_mm),
                   max_loop_off_mm=max(base.max_loop_off_mm, 0.5 * e), edge_mm=e)


def vertex_areas(V, F):
    """(n,) float64: a third of the area of the faces around each vertex, mm²."""
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    a = np.zeros(len(V))
    np.add.at(a, F.ravel(), np.repeat(A / 3.0, 3))
    return a


def inside_area(V, F, center, radius, forward, around, lim: CheckLimits, rms=0.0):
    """Area (mm²) of surface near ``around`` lying deeper than the noise inside the sphere.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    center : (3,) float64
    radius : float
    forward : (3,) float64 unit
    around : (3,) float64
        Centre of the neighbourhood checked (the opening centroid).
    lim : CheckLimits
    rms : float
        Residual RMS of the fit; the tolerated depth is at least four times it.

    Returns
    -------
    float
    """
    near = np.linalg.norm(V - around, axis=1) < lim.radius_mm
    if not near.any():
        return 0.0
    Fn = F[faces_touching(F, near)]      # the faces around the neighbourhood give its areas
    a = vertex_areas(V, Fn)[near]
    w = V[near] - center
    nw = np.linalg.norm(w, axis=1)
    d = nw - radius
    in_cone = (w @ forward) > np.cos(np.radians(lim.cornea_cone_deg)) * nw
    tol = np.where(in_cone, lim.cone_depth_mm, max(lim.inside_noise_mm, 4.0 * float(rms)))
    return float(a[d < -tol].sum())


def convex_fill(loop_points, center, forward, strip_mm=0.0):
    """Area of the loop projected on the plane across ``forward`` over its convex hull's area.

    With ``strip_mm`` also returns the fill a loop may lose to a strip that wide along it
    (a loop made of coarse edges zigzags by a fraction of an edge): ``(fill, allowance)``.
    """
    from scipy.spatial import ConvexHull, QhullError

    from pipeline.geometry.frame import eye_basis

    Q = (np.asarray(loop_points, float) - center) @ eye_basis(forward)[:2].T
    area = 0.5 * abs(float(np.sum(Q[:, 0] * np.roll(Q[:, 1], -1) - np.roll(Q[:, 0], -1) * Q[:, 1])))
    try:
        hull = ConvexHull(Q).volume
    except QhullError:          # a degenerate (flat) loop
        hull = 0.0
    fill = float(area / hull) if hull > 0 else 0.0
    if not strip_mm:
        return fill
    perimeter = float(np.linalg.norm(np.roll(Q, -1, axis=0) - Q, axis=1).sum())
    return fill, (strip_mm * perimeter / hull if hull > 0 else 0.0)


#: How far from the gaze the eye's front is looked for elsewhere (deg), and the grid's step.
FRONT_REACH_DEG, FRONT_STEP_DEG = 50.0, 2.5
FRONT_MAX_POINTS = 1500


def front_elsewhere(eye_points, center, radius, forward, lim: CheckLimits,
                    reach_deg: float = FRONT_REACH_DEG, step_deg: float = FRONT_STEP_DEG):
    """The largest :func:`cornea_standoff` of the eye surface over gaze directions within
    ``reach_deg`` of ``forward`` (a grid of ``step_deg`` in yaw and pitch about the sphere's
    centre), mm, and that direction (3,); ``(None, None)`` when no direction has enough points
    on both parts. Where the scanned cornea or iris stands proud of the sclera, the direction
    with the largest standoff points near it: on the ICT-FaceKit heads whose gaze the placement
    missed by 38-50 deg, 11-17 deg from the truth; on eyes it placed right, the maximum lies
    anywhere within 10-30 deg (the iris is flat), so this finds a front, not a gaze."""
    from pipeline.geometry.frame import eye_basis

    P = np.asarray(eye_points, float)
    if len(P) > FRONT_MAX_POINTS:       # a dense scan's eye: every k-th point tells the same
        P = P[::int(np.ceil(len(P) / FRONT_MAX_POINTS))]
    n0 = np.asarray(forward, float) / np.linalg.norm(forward)
    B = eye_basis(n0)
    t = np.radians(np.arange(-reach_deg, reach_deg + 1e-9, step_deg))
    yaw, pitch = (a.ravel() for a in np.meshgrid(t, t))
    N = (np.cos(pitch)[:, None] * (np.sin(yaw)[:, None] * B[0] + np.cos(yaw)[:, None] * n0)
         + np.sin(pitch)[:, None] * B[1])
    N /= np.linalg.norm(N, axis=1)[:, None]
    N = N[np.arccos(np.clip(N @ n0, -1.0, 1.0)) <= np.radians(reach_deg) + 1e-9]
    best, at = None, None
    for n in N:
        st = cornea_standoff(P, center, radius, n, lim)
        if st is not None and (best is None or st > best):
            best, at = st, n
    return best, at


def cornea_standoff(eye_points, center, radius, forward, lim: CheckLimits):
    """Median height of the eye surface over the sphere near the gaze axis minus that on its
    sides, mm (None when either part has fewer than ``min_points`` points)."""
    P = np.asarray(eye_points, float)
    w = P - center
    nw = np.linalg.norm(w, axis=1)
    d = nw - radius
    ang = np.degrees(np.arccos(np.clip((w @ forward) / np.maximum(nw, 1e-12), -1.0, 1.0)))
    inner, outer = lim.cornea_cone_check_deg
    mid, side = d[ang < inner], d[ang > outer]
    if len(mid) < lim.min_points or len(side) < lim.min_points:
        return None
    return float(np.median(mid) - np.median(side))


def check_eye(V, F, center, radius, forward, loop_points, lim: CheckLimits, rms=0.0,
              eye_points=None, cornea=None, lateral_index=None, standoff_mm=0.0) -> dict:
    """The per-eye checks: ``{name: {"value": float, "limit": ..., "ok": bool}}``.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        The scan around the eye (before the eyeball is cut out).
    center : (3,) float64
    radius : float
    forward : (3,) float64
    loop_points : (L, 3) float64
        The eyelid-opening loop.
    lim : CheckLimits
    rms : float
        Residual RMS of the sphere fit.
    eye_points : (k, 3) float64, optional
        The scanned eye surface (the removed region) for ``cornea_shows``; None skips it (an eye
        placed from colour on a coarse scan).
    cornea : dict, optional
        ``{"center": (3,), "radius": r}`` of a fitted corneal sphere: the loop may lie on it
        (a lid margin resting on the cornea).
    lateral_index : int, optional
        Position of the lateral canthus in a loop ordered medial canthus first: corner runs
        (module doc) are then left out of ``opening_fits`` and ``loop_on_sphere``, and the lids
        may span the chord of a sphere ``corner_off_globe_mm`` larger (a lid margin rests up to
        that far off the globe).
    standoff_mm : float
        How far off the globe the loop is expected: 0 for a cut on the eye surface, the lid
        margin's mean standoff for an outline of the visible fissure (a texture placement);
        ``loop_on_sphere`` measures the loop's distance from that.
    """
    center = np.asarray(center, float)
    forward = np.asarray(forward, float)
    L = np.asarray(loop_points, float)
    off = np.linalg.norm(L - center, axis=1) - radius
    if cornea is not None:
        off = np.minimum(off, np.linalg.norm(L - np.asarray(cornea["center"], float), axis=1)
                         - float(cornea["radius"]))
    lids = np.ones(len(L), bool)
    if lateral_index is not None and len(L) >= 3:
        lids = corner_weights(L, off, lateral_index, lim.corner_off_globe_mm,
                              lim.corner_max_share).on_eye
    Ll = L[lids]
    width = float(np.max(np.linalg.norm(Ll[:, None] - Ll[None], axis=2))) if len(Ll) > 1 else 0.0
    span = float(np.max(np.linalg.norm(L[:, None] - L[None], axis=2))) if len(L) > 1 else 0.0
    off = np.abs(off[lids] - standoff_mm)
    max_ratio = lim.max_width_ratio * (1.0 + (lim.corner_off_globe_mm / radius if lateral_index is not None
                                              else 0.0))
    ins = inside_area(V, F, center, radius, forward, L.mean(axis=0), lim, rms)
    fill, allow = convex_fill(L, center, forward, max(0.1 * lim.edge_mm, 1e-9)) \
        if len(L) >= 3 else (0.0, 0.0)
    min_fill = lim.min_convex_fill - allow
    lo, hi = lim.radius_range_mm
    out = {
        "inside": {"value": round(ins, 3), "limit": round(lim.max_inside_area_mm2, 3),
                   "ok": ins <= lim.max_inside_area_mm2},
        "radius_in_range": {"value": round(float(radius), 4), "limit": [lo, hi],
                            "ok": bool(lo <= radius <= hi)},
        "opening_fits": {"value": round(width / (2 * radius), 4), "limit": round(max_ratio, 4),
                         "ok": width <= max_ratio * 2 * radius},
        "opening_wide": {"value": round(span, 3), "limit": lim.min_opening_mm,
                         "ok": span >= lim.min_opening_mm},
        "opening_convex": {"value": round(fill, 4), "limit": round(min_fill, 4),
                           "ok": fill >= min_fill},
        "loop_on_sphere": {"value": round(float(np.percentile(off, 90)), 4),
                           "limit": round(lim.max_loop_off_mm, 3),
                           "ok": float(np.percentile(off, 90)) <= lim.max_loop_off_mm,
                           "corner_vertices": int((~lids).sum())},
    }
    if eye_points is not None:
        st = cornea_standoff(eye_points, center, radius, forward, lim)
        lo, hi = lim.flush_band_mm
        out["cornea_shows"] = {"value": None if st is None else round(st, 4), "limit": [lo, hi],
                               "ok": st is None or not lo < st < hi}
    return out


def loop_inside_eye(loop_points, center, radius, forward, cornea_center, cornea_radius,
                    lim: CheckLimits, lateral_index=None) -> dict:
    """``loop_on_eye``: how deep the lids' part of the eyelid loop lies inside an eye (the
    sclera sphere and its corneal sphere; corners left out as in :func:`check_eye`), the 90th
    percentile, against ``max_loop_off_mm``. A lid margin rests on the eye or stands off it
    (a lifted margin, a corner, an eye placed from its opening behind it); it cannot lie inside
    it. The stage asks this of the eye the asset carries once ``loop_on_sphere`` has failed on the
    fitted sphere: an eye that holds the loop repairs it (a doubt), one the loop cuts into is no
    eye behind this cut (ident_s1_000's right eye before the rival restarts: a loop cut below
    the lower lid lay 2.4 mm inside the eye placed from it)."""
    center = np.asarray(center, float)
    L = np.asarray(loop_points, float)
    off = np.minimum(np.linalg.norm(L - center, axis=1) - float(radius),
                     np.linalg.norm(L - np.asarray(cornea_center, float), axis=1) - float(cornea_radius))
    lids = np.ones(len(L), bool)
    if lateral_index is not None and len(L) >= 3:
        lids = corner_weights(L, off, lateral_index, lim.corner_off_globe_mm, lim.corner_max_share).on_eye
    depth = float(np.percentile(np.maximum(-off[lids], 0.0), 90)) if lids.any() else 0.0
    return {"value": round(depth, 4), "limit": round(lim.max_loop_off_mm, 3),
            "ok": depth <= lim.max_loop_off_mm}


def check_pair(radii: dict, lim: CheckLimits) -> dict:
    """``radii_agree``: the two eyes' radii differ by at most ``max_radius_diff_mm``."""
    diff = abs(float(radii["left"]) - float(radii["right"]))
    return {"radii_agree": {"value": round(diff, 4), "limit": lim.max_radius_diff_mm,
                            "ok": diff <= lim.max_radius_diff_mm}}


def failed(checks: dict) -> list:
    """Names of the failed checks, in order."""
    return [k for k, c in checks.items() if not c["ok"]]


def describe(name: str, check: dict) -> str:
    """One phrase for a failed check (used in the stage's one-line refusal)."""
    v, lim = check["value"], check["limit"]
    if name == "inside":
        return f"{v:.1f} mm² of the head lies inside the fitted eyeball (limit {lim} mm²)"
    if name == "radius_in_range":
        return f"radius {v:.2f} mm outside {lim[0]:g}-{lim[1]:g} mm"
    if name == "opening_fits":
        return f"the opening is {v:.2f} x the eyeball's diameter"
    if name == "opening_wide":
        return (f"the eyelid loop spans {v:.1f} mm, narrower than any eye's fissure (limit {lim:g} "
                f"mm): the cut went round part of the eye, or the scan shows less of the opening")
    if name == "opening_convex":
        return (f"the eyelid loop fills {100 * v:.0f} % of its convex hull (limit "
                f"{100 * lim:.0f} %: a notch, or scanned eyeball left on a lid)")
    if name == "cornea_shows":
        return (f"the eye surface runs flush with the fitted sphere across the opening (centre "
                f"{v:+.2f} mm against its sides): the sphere has taken in the cornea and sits too "
                f"far forward")
    if name == "loop_on_sphere":
        return f"the eyelid loop lies {v:.2f} mm off the eyeball (90th percentile, limit {lim} mm)"
    if name == "loop_on_eye":
        return (f"the eyelid loop lies {v:.2f} mm inside the eye the asset would carry (90th "
                f"percentile, limit {lim} mm)")
    if name == "radii_agree":
        return f"the two eyes' radii differ by {v:.2f} mm (limit {lim} mm)"
    return name
