"""The eye model the placement fits: a sclera sphere and, around the gaze, an anterior cap.

Per eye: a sclera sphere (centre ``c``, radius ``R``) and, around the gaze ``n``, an anterior
cap: a sphere through the limbus circle (half-angle ``tl`` off the axis, so the limbus scales
with the globe: 29 +- 1.5 deg in people, 27-33 in ICT-FaceKit's eyes) and an apex
``ha * APEX_FRACTION * R`` above the sclera, plus a ring ``hb`` that stands highest half-way
between axis and limbus. ``ha`` = 1 is a scanned cornea (the human apex stands 1.0 mm above a
12 mm sclera), < 0 a recessed iris; the iris seen through a transparent cornea is a low ring
(``ha`` ~ 0.1-0.3, ``hb`` ~ 0.3-0.5: the pupil lies deeper than the iris around it). Without
the ring, that shape biased the radius by about 1 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

APEX_FRACTION = 0.1     # corneal apex above the sclera sphere, in units of R (people 0.08, ICT 0.13)
HA_RANGE = (-1.0, 1.6)  # anterior height: recessed iris .. a prominent cornea
HB_RANGE = (-1.0, 1.6)  # anterior ring: the iris seen through a clear cornea stands highest off the axis
LIMBUS_DEG = (30.5, 2.0)        # prior on the limbus half-angle, deg (people 29 +- 1.5, ICT 30-34)
LIMBUS_RANGE = (24.0, 37.0)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass
class Eye:
    """One eye of the model: centre (3,), radius, unit gaze (3,), anterior height."""

    c: np.ndarray
    R: float
    n: np.ndarray
    ha: float = 0.5
    tl: float = LIMBUS_DEG[0]
    hb: float = 0.0


def _cap(R, ha, tl):
    """The anterior cap's sphere: centre offset along the axis and radius (mm)."""
    a = np.radians(tl)
    rl, zl = R * np.sin(a), R * np.cos(a)
    apex = R * (1.0 + APEX_FRACTION * ha)
    # centre on the axis at z0: (apex - z0)^2 = rl^2 + (zl - z0)^2
    z0 = (apex ** 2 - rl ** 2 - zl ** 2) / (2.0 * (apex - zl))
    return z0, apex - z0


def cap_height(cos_alpha, R, ha, tl, hb=0.0):
    """Height (mm) of the anterior cap above the sclera sphere along the rays at ``cos_alpha``
    from the axis (0 outside the limbus; negative for a recessed iris), (n,): the sphere
    through the limbus circle and the apex, plus a ring ``hb * APEX_FRACTION * R * 4 s^2
    (1 - s^2)`` (``s`` = angle / ``tl``) peaking half-way out: the iris seen through a clear
    cornea stands off the sclera most between pupil and limbus."""
    ca = np.clip(cos_alpha, -1.0, 1.0)
    z0, r = _cap(R, ha, tl)
    t = z0 * ca + np.sqrt(np.maximum(r * r - z0 * z0 * (1.0 - ca * ca), 0.0))
    s2 = (np.arccos(ca) / np.radians(tl)) ** 2
    ring = hb * APEX_FRACTION * R * 4.0 * s2 * (1.0 - s2)
    return np.where(ca > np.cos(np.radians(tl)), t - R + ring, 0.0)


def cornea_sphere(e: Eye):
    """The anterior cap as a sphere for the rest of the pipeline, or None when it is flat or
    recessed (the sclera sphere is then the whole eye surface)."""
    if e.ha <= 0.05:
        return None
    z0, r = _cap(e.R, e.ha, e.tl)
    return {"center": np.asarray(e.c) + z0 * np.asarray(e.n), "radius": float(r)}


def rays(P, c, n):
    """Each point's distance from ``c`` (at least 1e-9), the cosine of its direction to the
    unit gaze ``n``, and that unit direction: ``(nw, ca, u)``, (n,), (n,), (n, 3). What
    :func:`surface_residual` reads of the eye besides its radius and cap: an eye's three
    anterior heights share it (:func:`pipeline.placement.fit.hypotheses`)."""
    w = P - c
    # norm's sum of squares in its order (x, y, z), without a reduce over a length-3 axis (the
    # placement calls this thousands of times on ~1,500 points: same values, a third the time)
    nw = np.maximum(np.sqrt(w[:, 0] * w[:, 0] + w[:, 1] * w[:, 1] + w[:, 2] * w[:, 2]), 1e-9)
    return nw, (w @ n) / nw, w / nw[:, None]


def surface_residual(P, e: Eye, ray=None):
    """Signed distance (mm) of ``P`` (n, 3) off the eye model, whether each point lies on the
    anterior cap (inside the limbus), the plain distance off the sclera sphere, and unit
    directions from the centre. ``ray``: :func:`rays` of ``P`` from ``e.c`` along ``e.n``, when
    made already."""
    nw, ca, u = rays(P, e.c, e.n) if ray is None else ray
    h = cap_height(ca, e.R, e.ha, e.tl, e.hb)
    ant = ca > np.cos(np.radians(e.tl))
    return nw - e.R - h, ant, nw - e.R, u


def limbus_center(e: Eye) -> np.ndarray:
    """Centre of the eye model's limbus circle (the rim of its anterior cap), (3,)."""
    return np.asarray(e.c, float) + e.R * np.cos(np.radians(e.tl)) * np.asarray(e.n, float)


def _cap_partials(R, ha, tl, step=1e-6):
    """``(z0, r)`` of :func:`_cap` and their partials in ``(R, ha, tl)``, (2, 3): central
    differences of the scalar function (cheap, and exact to ~1e-9 here)."""
    out = np.empty((2, 3))
    for j, (dR, dh, dt) in enumerate(((step, 0, 0), (0, step, 0), (0, 0, step))):
        a = np.array(_cap(R + dR, ha + dh, tl + dt))
        b = np.array(_cap(R - dR, ha - dh, tl - dt))
        out[:, j] = (a - b) / (2.0 * step)
    return np.array(_cap(R, ha, tl)), out


def cap_height_partials(cos_alpha, R, ha, tl, hb=0.0):
    """:func:`cap_height` and its partials along ``cos_alpha``, ``R``, ``ha``, ``tl`` and
    ``hb``: ``(h, dh)``, ``dh`` (n, 5). Analytic Jacobians of the fit need them; the limbus
    itself (where the cap meets the sphere at height 0) is a kink, its one-sided slope taken."""
    ca = np.clip(cos_alpha, -1.0, 1.0)
    (z0, r), dzr = _cap_partials(R, ha, tl)
    q = np.maximum(r * r - z0 * z0 * (1.0 - ca * ca), 0.0)
    sq = np.sqrt(q)
    isq = np.where(sq > 1e-12, 1.0 / np.maximum(sq, 1e-12), 0.0)
    t = z0 * ca + sq
    tlr = np.radians(tl)
    a = np.arccos(ca)
    s2 = (a / tlr) ** 2
    k = hb * APEX_FRACTION * R * 4.0
    ring = k * s2 * (1.0 - s2)
    inside = ca > np.cos(tlr)
    h = np.where(inside, t - R + ring, 0.0)
    sin_a = np.sqrt(np.maximum(1.0 - ca * ca, 0.0))
    a_over_sin = np.where(sin_a > 1e-9, a / np.maximum(sin_a, 1e-300), 1.0)
    dt_dca = z0 + z0 * z0 * ca * isq
    dt_dz0 = ca - z0 * (1.0 - ca * ca) * isq
    dt_dr = r * isq
    dring_ds2 = k * (1.0 - 2.0 * s2)
    dh = np.empty((len(ca), 5))
    dh[:, 0] = dt_dca + dring_ds2 * (-2.0 / tlr ** 2) * a_over_sin
    dh[:, 1] = dt_dz0 * dzr[0, 0] + dt_dr * dzr[1, 0] - 1.0 + ring / R
    dh[:, 2] = dt_dz0 * dzr[0, 1] + dt_dr * dzr[1, 1]
    dh[:, 3] = dt_dz0 * dzr[0, 2] + dt_dr * dzr[1, 2] + dring_ds2 * (-2.0 * s2 / tl)
    dh[:, 4] = APEX_FRACTION * R * 4.0 * s2 * (1.0 - s2)
    dh[~inside] = 0.0
    return h, dh
