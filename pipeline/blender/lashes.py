"""Eyelashes of the render worker: lash polylines grown from a posed eyelid margin
(:func:`lash_curves`, pure numpy) and the Cycles hair-curves objects that carry them
(:func:`add_lash_objects`; ``bpy`` is handed in, never imported here).
"""

from __future__ import annotations

import numpy as np

# eyelashes (mm): count, max length, root / tip radius, curl angles (deg from the eye's forward
# toward "away from the opening") at the root and at the tip
LASHES = {"upper": {"count": 90, "length": 9.0, "root_angle": 25.0, "tip_angle": 80.0, "radius": 1.0},
          "lower": {"count": 45, "length": 5.5, "root_angle": 35.0, "tip_angle": 70.0, "radius": 0.7}}
LASH_ROOT_RADIUS_MM = 0.07
LASH_TIP_RADIUS_MM = 0.02
LASH_POINTS = 6
LASH_VERTICAL_BIAS = 1.0
LASH_OFFSET_MM = (0.5, 0.35)     # root: in front of the margin along forward, away from the opening


def lash_curves(margin, lateral_index: int, forward, rng_table: dict) -> tuple[np.ndarray, np.ndarray]:
    """Eyelash polylines grown from a posed eyelid margin.

    Parameters
    ----------
    margin : (L, 3) float64
        Posed margin loop, head mm; starts at the medial canthus, runs over the upper lid to
        ``lateral_index`` (lateral canthus) and back along the lower lid.
    lateral_index : int
    forward : (3,) float64
        The eye's rest forward (unit, head frame).
    rng_table : dict
        ``{"upper"|"lower": (n, 4) float64}`` per-lash random numbers in [0, 1) (position
        jitter, length, curl, sideways tilt): fixed per worker so lashes keep their identity.

    Returns
    -------
    points : (N * LASH_POINTS, 3) float64
        Polyline points, head mm, lash after lash (root first).
    radius : (N * LASH_POINTS,) float64
        Radius per point, mm (tapering root to tip).
    """
    P = np.asarray(margin, float)
    f = np.asarray(forward, float)
    f = f / np.linalg.norm(f)
    centre = P.mean(0)
    up = np.array([0.0, 1.0, 0.0]) - f[1] * f
    up /= np.linalg.norm(up)
    upper = P[:lateral_index + 1]
    lower = np.concatenate([P[lateral_index:], P[:1]])
    pts, rad = [], []
    s = np.linspace(0.0, 1.0, LASH_POINTS)
    for name, poly in (("upper", upper), ("lower", lower)):
        cfg = LASHES[name]
        rnd = rng_table[name]
        n = len(rnd)
        seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        # roots evenly spread over 8..92 % of the lid, jittered by up to half a spacing
        u = 0.08 + 0.84 * (np.arange(n) + 0.5 + (rnd[:, 0] - 0.5)) / n
        target = np.clip(u, 0.0, 1.0) * cum[-1]
        k = np.clip(np.searchsorted(cum, target, side="right") - 1, 0, len(seg) - 1)
        t = np.where(seg[k] > 0, (target - cum[k]) / np.maximum(seg[k], 1e-12), 0.0)
        root = poly[k] + t[:, None] * (poly[k + 1] - poly[k])
        tang = poly[k + 1] - poly[k]
        tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
        # "away from the opening": radial from the opening centre, biased toward head up (upper
        # lid) / down (lower lid) so lashes near the canthi still curl up / down, not sideways
        away = root - centre
        away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-12)
        away = away + LASH_VERTICAL_BIAS * (1.0 if name == "upper" else -1.0) * up
        away -= (away @ f)[:, None] * f
        away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-12)
        root = root + LASH_OFFSET_MM[0] * f + LASH_OFFSET_MM[1] * away
        # longest in the middle of the lid, shorter toward the canthi (more so medially)
        prof = np.sin(np.pi * np.clip(u, 0, 1)) * (0.75 + 0.25 * u)
        length = cfg["length"] * (0.25 + 0.75 * prof) * (0.85 + 0.3 * rnd[:, 1])
        a0 = np.radians(cfg["root_angle"] + 10.0 * (rnd[:, 2] - 0.5))
        a1 = np.radians(cfg["tip_angle"] + 15.0 * (rnd[:, 2] - 0.5))
        tilt = 0.25 * (rnd[:, 3] - 0.5)                # sideways spread along the lid
        # every lash at once (n, LASH_POINTS, 3): direction per point, trapezoid steps along it
        ang = a0[:, None] + (a1 - a0)[:, None] * s ** 1.5
        d = (np.cos(ang)[..., None] * f + np.sin(ang)[..., None] * away[:, None]
             + (tilt[:, None] * tang)[:, None])
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        step = (length / (LASH_POINTS - 1))[:, None, None] * 0.5 * (d[:, :-1] + d[:, 1:])
        p = np.concatenate([root[:, None], root[:, None] + np.cumsum(step, axis=1)], axis=1)
        pts.append(p.reshape(-1, 3))
        r = cfg["radius"] * (LASH_ROOT_RADIUS_MM + (LASH_TIP_RADIUS_MM - LASH_ROOT_RADIUS_MM) * s)
        rad.append(np.tile(r, n))
    return np.concatenate(pts), np.concatenate(rad)


def add_lash_objects(bpy, scene, sides, material) -> dict:
    """One hair-curves object per eye (every lash of :data:`LASHES`, :data:`LASH_POINTS` points each)
    with ``material``, linked into ``scene``; returns ``side -> (object, curves, radius attribute)``."""
    n_curves = sum(v["count"] for v in LASHES.values())
    lashes = {}
    for side in sides:
        curves = bpy.data.hair_curves.new(f"Lashes_{side}")
        curves.add_curves([LASH_POINTS] * n_curves)
        curves.materials.append(material)
        obj = bpy.data.objects.new(f"Lashes_{side}", curves)
        scene.collection.objects.link(obj)
        rad = curves.attributes.get("radius") or curves.attributes.new("radius", "FLOAT", "POINT")
        lashes[side] = (obj, curves, rad)
    return lashes
