"""The procedural head's ground truth (``ground_truth.json``): each eye's sphere, cornea and
gaze, its eyelid margin traced as the crossing of skin and eye depths, and the eye hints.
"""

from __future__ import annotations

import numpy as np

from pipeline.synthetic_head.model import almond_curves, base_curve, surface_points, t_for_x



def _trace_margin(model, eye, n=256):
    """Eyelid margin = crossing of skin and eye depths, by radial bisection in (t, y).

    Returns points (n, 3) ordered from the medial canthus over the upper lid to the
    lateral canthus and back along the lower lid, and the lateral index.
    """
    c = eye.center
    # opening centre in parameter space: the ray through the almond's centre on the eye
    al = eye.almond
    a0 = 0.5 * (al["a_m"] + al["a_l"])
    _, up, lo = almond_curves(al, np.array([0.5]))
    b0 = 0.5 * (up[0] + lo[0])
    dirn = np.array([eye.lat * np.sin(a0) * np.cos(b0), np.sin(b0), np.cos(a0) * np.cos(b0)])
    p = c + eye.radius * dirn
    t0, y0 = t_for_x(p[0]), p[1]
    # parameter-space scale: mm per radian of t near the eye
    bx, bz, _, _ = base_curve(np.array([t0 - 1e-3, t0 + 1e-3]))
    mm_per_t = np.hypot(bx[1] - bx[0], bz[1] - bz[0]) / 2e-3
    phi = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    ux, uy = np.cos(phi) / mm_per_t, np.sin(phi)

    def g(rad):
        f = model.fields(t0 + rad * ux, y0 + rad * uy, detail=False)
        return f["h_skin"] - f["h_eye"]

    # march outward to bracket the first sign change, then bisect
    lo_r = np.zeros_like(phi)
    hi_r = np.full_like(phi, np.nan)
    prev = g(lo_r)
    step = 0.5
    steps = np.arange(step, 30.0, step)
    for r in steps:
        cur = g(np.full_like(phi, r))
        hit = np.isnan(hi_r) & (cur > 0) & (prev <= 0)
        hi_r[hit] = r
        lo_r[np.isnan(hi_r)] = r
        prev = cur
        if not np.isnan(hi_r).any():
            break
    lo_r = np.where(np.isnan(hi_r), lo_r, hi_r - step)
    hi_r = np.where(np.isnan(hi_r), lo_r, hi_r)
    for _ in range(32):
        mid = 0.5 * (lo_r + hi_r)
        neg = g(mid) <= 0
        lo_r = np.where(neg, mid, lo_r)
        hi_r = np.where(neg, hi_r, mid)
    rad = 0.5 * (lo_r + hi_r)
    tt, yy = t0 + rad * ux, y0 + rad * uy
    f = model.fields(tt, yy, detail=False)
    pts = surface_points(f, yy, f["h_eye"])
    # order: medial canthus first, over the upper lid to the lateral canthus, back below
    lat = eye.lat * (pts[:, 0] - c[0])
    i_med = int(np.argmin(lat))
    pts = np.roll(pts, -i_med, axis=0)
    # phi increases counter-clockwise in (x, y); for the left eye medial is -x so CCW from
    # medial goes down first: reverse so the upper lid comes first.
    if pts[len(pts) // 4, 1] < pts[(3 * len(pts)) // 4, 1]:
        pts = np.concatenate([pts[:1], pts[1:][::-1]])
    # resample to n points: equal arc length per lid with both canthi as samples
    lat = eye.lat * (pts[:, 0] - c[0])
    i_lat = int(np.argmax(lat))
    upper, lower = pts[: i_lat + 1], np.concatenate([pts[i_lat:], pts[:1]])

    def resample(poly, k):
        seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        q = np.linspace(0.0, s[-1], k + 1)
        return np.stack([np.interp(q, s, poly[:, j]) for j in range(3)], 1)[:-1]

    half = n // 2
    ring = np.concatenate([resample(upper, half), resample(lower, n - half)])
    return ring, half


def ground_truth(model, hints_rng, target_triangles):
    eyes, hints = {}, {}
    shape_name = {0.0: "round", 1.0: "hooded"}.get(model.hood, f"{model.hood:g}")
    for e in model.eyes:
        margin, i_lat = _trace_margin(model, e)
        # project the margin centroid onto the eye surface along the ray from the centre
        cen = margin.mean(axis=0)
        v = cen - e.center
        opening = e.center + e.radius * v / np.linalg.norm(v)
        dist = np.abs(np.linalg.norm(margin - e.center, axis=1) - e.radius)
        rnd = hints_rng.normal(size=3)
        hint = opening + 2.0 * rnd / np.linalg.norm(rnd)
        gaze = e.gaze
        limbus_cos = (e.radius ** 2 + np.linalg.norm(e.cornea_center - e.center) ** 2
                      - e.cornea_radius ** 2) / (2 * e.radius * np.linalg.norm(e.cornea_center - e.center))
        width = float(np.linalg.norm(margin[0] - margin[i_lat]))
        up, lo = margin[1:i_lat], margin[i_lat + 1:]
        eyes[e.side] = {
            "eyeball_sphere": {"center_mm": e.center.round(5).tolist(), "radius_mm": round(e.radius, 5)},
            "cornea_sphere": {"center_mm": e.cornea_center.round(5).tolist(),
                              "radius_mm": round(e.cornea_radius, 5)},
            "corneal_apex_mm": e.apex.round(5).tolist(),
            "corneal_apex_distance_mm": round(float(np.linalg.norm(e.apex - e.center)), 5),
            "limbus_half_angle_deg": round(float(np.degrees(np.arccos(limbus_cos))), 4),
            "gaze_direction": gaze.round(6).tolist(),
            "gaze_pitch_deg": round(float(np.degrees(np.arcsin(gaze[1]))), 4),
            "gaze_yaw_deg": round(float(np.degrees(np.arctan2(gaze[0], gaze[2]))), 4),
            "eye_opening_center_mm": opening.round(5).tolist(),
            "eye_opening_center_definition": "eyelid-margin centroid projected radially onto the eyeball "
                                             "sphere; the scan.yaml hint is this point plus a 2 mm offset "
                                             "in a seeded random direction",
            "eyelid_margin": {
                "definition": "curve where the lid skin surface crosses the scanned eye surface "
                              "(traced on the noise-free, detail-free surface); ordered from the "
                              "medial canthus over the upper lid to the lateral canthus and back "
                              "along the lower lid",
                "closed": True,
                "points_mm": margin.round(5).tolist(),
                "medial_canthus_index": 0,
                "lateral_canthus_index": int(i_lat),
                "distance_to_eyeball_sphere_mm": {"max": round(float(dist.max()), 5),
                                                  "rms": round(float(np.sqrt(np.mean(dist ** 2))), 5)},
                "width_mm": round(width, 4),
                "upper_lid_length_mm": round(float(np.linalg.norm(np.diff(margin[: i_lat + 1], axis=0),
                                                                  axis=1).sum()), 4),
                "height_mm": round(float(up[:, 1].max() - lo[:, 1].min()), 4),
            },
        }
        hints[e.side] = hint.round(4).tolist()
    gt = {
        "tool": "eyerig pipeline.synthetic_head",
        "units": "mm",
        "frame": {"up": "+Y", "forward": "+Z (out of the face)", "x": "+X = subject's left"},
        "seed": int(model.seed),
        "skin_detail_amplitude_mm": None,  # filled by the caller (measured)
        "eye_shape": shape_name,
        "eye_shape_params": {
            "hoodedness": model.hood,
            "eye_spacing_mm": model.ipd,
            **{side: {k: (round(float(np.degrees(v)), 4) if k.startswith(("a_", "b_", "h_")) else round(v, 4))
                      for k, v in e.almond.items()}
               for side, e in zip(("left", "right"), model.eyes)},
            "almond_angles": "a_m/a_l medial/lateral corner azimuth, b_m/b_l corner elevation, "
                             "h_u/h_l upper/lower lid height (deg, about the eyeball centre)",
        },
        "target_triangles": int(target_triangles),
        "eyes": eyes,
    }
    return gt, hints
