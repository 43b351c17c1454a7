"""The procedural head's ground truth (``ground_truth.json``): each eye's sphere, cornea, limbus
and gaze; its eyelid margin (the lid's edge, off the globe) and canthi; the line where the scanned
tissue meets the eye surface; and the eye hints. Curves are traced on the noise-free, detail-free
surface the mesh samples, so they lie on the mesh (up to its sampling).
"""

from __future__ import annotations

import numpy as np

from pipeline.synthetic_head.model import almond_curves, mm_per_t, ray_for_uv, surface_points


def _point(model, t, y):
    f = model.fields(np.atleast_1d(t), np.atleast_1d(y), detail=False)
    return surface_points(f, np.atleast_1d(y), f["h"])


def _trace(model, eye, g, n=256):
    """Closed curve where ``g(fields)`` changes sign from <= 0 (inside) to > 0, by radial
    bisection in ``(t, y)`` from the opening's centre; points on the final surface, with the
    grid parameters of each."""
    al = eye.almond
    _, up, lo = almond_curves(al, np.array([0.5]))
    t0, y0 = ray_for_uv(eye, 0.5 * (al["u_m"] + al["u_l"]), 0.5 * (up[0] + lo[0]))
    scale = mm_per_t(t0)
    phi = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    ux, uy = np.cos(phi) / scale, np.sin(phi)

    def val(rad):
        return g(model.fields(t0 + rad * ux, y0 + rad * uy, detail=False))

    lo_r = np.zeros_like(phi)
    hi_r = np.full_like(phi, np.nan)
    step = 0.25
    for r in np.arange(step, 30.0, step):
        cur = val(np.full_like(phi, r))
        hit = np.isnan(hi_r) & (cur > 0)
        hi_r[hit] = r
        lo_r[np.isnan(hi_r)] = r
        if not np.isnan(hi_r).any():
            break
    lo_r = np.where(np.isnan(hi_r), lo_r, hi_r - step)
    hi_r = np.where(np.isnan(hi_r), lo_r, hi_r)
    for _ in range(30):
        mid = 0.5 * (lo_r + hi_r)
        neg = val(mid) <= 0
        lo_r = np.where(neg, mid, lo_r)
        hi_r = np.where(neg, hi_r, mid)
    rad = 0.5 * (lo_r + hi_r)
    tt, yy = t0 + rad * ux, y0 + rad * uy
    f = model.fields(tt, yy, detail=False)
    return surface_points(f, yy, f["h"])


def _order(pts, eye, n, corners=None):
    """Medial canthus first, over the upper lid to the lateral canthus, back along the lower lid;
    resampled to ``n`` points at equal arc length per lid. ``corners``: exact (medial, lateral)
    points that replace the traced extremes."""
    c = eye.center
    lat = eye.lat * ((pts - c) @ eye.e1)
    pts = np.roll(pts, -int(np.argmin(lat)), axis=0)
    if pts[len(pts) // 4] @ eye.e2 < pts[(3 * len(pts)) // 4] @ eye.e2:
        pts = np.concatenate([pts[:1], pts[1:][::-1]])
    lat = eye.lat * ((pts - c) @ eye.e1)
    i_lat = int(np.argmax(lat))
    upper, lower = pts[: i_lat + 1], np.concatenate([pts[i_lat:], pts[:1]])
    if corners is not None:
        med, lc = corners
        upper = np.vstack([med, upper[1:-1], lc])
        lower = np.vstack([lc, lower[1:-1], med])

    def resample(poly, k):
        seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        q = np.linspace(0.0, s[-1], k + 1)
        return np.stack([np.interp(q, s, poly[:, j]) for j in range(3)], 1)[:-1]

    half = n // 2
    return np.concatenate([resample(upper, half), resample(lower, n - half)]), half


def _corner(model, eye, which):
    al = eye.almond
    u, v = (al["u_m"], al["v_m"]) if which == "medial" else (al["u_l"], al["v_l"])
    t, y = ray_for_uv(eye, u, v)
    return _point(model, t, y)[0]


def _corner_record(p, eye):
    w = p - eye.center
    fwd = float(w @ eye.gaze)
    return {"point_mm": p.round(5).tolist(), "in_front_mm": round(fwd, 4),
            "off_axis_mm": round(float(np.linalg.norm(w - fwd * eye.gaze)), 4),
            "off_globe_mm": round(float(np.linalg.norm(w) - eye.radius), 4)}


def _chord_share(P, i_lat):
    """Each point's share of the way from the medial to the lateral canthus along their chord."""
    M, L = P[0], P[i_lat]
    a = L - M
    return (P - M) @ a / (a @ a)


def ground_truth(model, hints_rng, target_triangles):
    eyes, hints = {}, {}
    shape_name = {0.0: "round", 1.0: "hooded"}.get(model.hood, f"{model.hood:g}")
    n = 256
    for e in model.eyes:
        med, lc = _corner(model, e, "medial"), _corner(model, e, "lateral")
        margin, i_lat = _order(_trace(model, e, lambda f: f["d"], n), e, n, corners=(med, lc))
        contact, i_lat_c = _order(_trace(model, e, lambda f: f["h_skin"] - f["h_eye"], n), e, n)
        off = np.linalg.norm(margin - e.center, axis=1) - e.radius
        x = _chord_share(margin, i_lat)
        mid = (x > 0.2) & (x < 0.95)
        cdist = np.abs(np.linalg.norm(contact - e.center, axis=1) - e.radius)
        # the opening centre: the margin's centroid projected radially onto the eyeball sphere
        cen = margin.mean(axis=0)
        v = cen - e.center
        opening = e.center + e.radius * v / np.linalg.norm(v)
        rnd = hints_rng.normal(size=3)
        hint = opening + 2.0 * rnd / np.linalg.norm(rnd)
        gaze = e.gaze
        dcc = np.linalg.norm(e.cornea_center - e.center)
        limbus_cos = (e.radius ** 2 + dcc ** 2 - e.cornea_radius ** 2) / (2 * e.radius * dcc)
        limbus_fwd = e.radius * limbus_cos
        width = float(np.linalg.norm(margin[0] - margin[i_lat]))
        up, lo = margin[1:i_lat], margin[i_lat + 1:]
        eyes[e.side] = {
            "eyeball_sphere": {"center_mm": e.center.round(5).tolist(), "radius_mm": round(e.radius, 5)},
            "cornea_sphere": {"center_mm": e.cornea_center.round(5).tolist(),
                              "radius_mm": round(e.cornea_radius, 5)},
            "corneal_apex_mm": e.apex.round(5).tolist(),
            "corneal_apex_distance_mm": round(float(np.linalg.norm(e.apex - e.center)), 5),
            "limbus_half_angle_deg": round(float(np.degrees(np.arccos(limbus_cos))), 4),
            "limbus": {"center_mm": (e.center + limbus_fwd * gaze).round(5).tolist(),
                       "radius_mm": round(e.limbus_radius, 5),
                       "distance_from_center_mm": round(float(limbus_fwd), 5),
                       "definition": "circle where the corneal sphere meets the eyeball sphere"},
            "gaze_direction": gaze.round(6).tolist(),
            "gaze_pitch_deg": round(float(np.degrees(np.arcsin(gaze[1]))), 4),
            "gaze_yaw_deg": round(float(np.degrees(np.arctan2(gaze[0], gaze[2]))), 4),
            "eye_opening_center_mm": opening.round(5).tolist(),
            "eye_opening_center_definition": "eyelid-margin centroid projected radially onto the eyeball "
                                             "sphere; the scan.yaml hint is this point plus a 2 mm offset "
                                             "in a seeded random direction",
            "eyelid_margin": {
                "definition": "the lid's edge: where the lid skin turns from the lid's front face into "
                              "its inner face (the opening's boundary), traced on the noise-free, "
                              "detail-free surface; it stands off the globe, the corners (canthi) "
                              "farther; ordered from the medial canthus over the upper lid to the "
                              "lateral canthus and back along the lower lid",
                "closed": True,
                "points_mm": margin.round(5).tolist(),
                "medial_canthus_index": 0,
                "lateral_canthus_index": int(i_lat),
                "distance_to_eyeball_sphere_mm": {
                    "min": round(float(off.min()), 5), "max": round(float(off.max()), 5),
                    "mean": round(float(off.mean()), 5),
                    "rms": round(float(np.sqrt(np.mean(off ** 2))), 5),
                    "between_canthi": {"min": round(float(off[mid].min()), 5),
                                       "max": round(float(off[mid].max()), 5),
                                       "mean": round(float(off[mid].mean()), 5),
                                       "definition": "margin points 20-95 % of the way from the "
                                                     "medial to the lateral canthus along their chord"}},
                "medial_canthus": _corner_record(margin[0], e),
                "lateral_canthus": _corner_record(margin[i_lat], e),
                "width_mm": round(width, 4),
                "upper_lid_length_mm": round(float(np.linalg.norm(np.diff(margin[: i_lat + 1], axis=0),
                                                                  axis=1).sum()), 4),
                "height_mm": round(float(up[:, 1].max() - lo[:, 1].min()), 4),
            },
            "eye_contact": {
                "definition": "curve where the scanned tissue (lids, and the caruncle and lateral "
                              "fornix at the corners) meets the eye surface (sclera or cornea): the "
                              "edge of the scan's visible eye, inside the margin; same order",
                "closed": True,
                "points_mm": contact.round(5).tolist(),
                "medial_index": 0,
                "lateral_index": int(i_lat_c),
                "distance_to_eyeball_sphere_mm": {"max": round(float(cdist.max()), 5),
                                                  "rms": round(float(np.sqrt(np.mean(cdist ** 2))), 5)},
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
        "eye_radius_mm": round(float(model.radius), 5),
        "eye_shape_params": {
            "hoodedness": model.hood,
            "eye_spacing_mm": model.ipd,
            **{side: {k: round(float(v), 4) for k, v in e.almond.items()}
               for side, e in zip(("left", "right"), model.eyes)},
            "almond": "the opening in the eye's plane across the gaze (mm): corners (u_m, v_m) and "
                      "(u_l, v_l), u toward the lateral side, v up; f_m/f_l the corners' depth in "
                      "front of the centre; h_u/h_l upper/lower lid heights; st_mid the margin's "
                      "standoff off the globe between the canthi, st_m/st_l the corners'; "
                      "pocket_m/pocket_l how far the caruncle and lateral fornix lie behind the corners",
        },
        "target_triangles": int(target_triangles),
        "eyes": eyes,
    }
    return gt, hints
