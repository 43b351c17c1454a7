"""The procedural head's colour texture, painted in its ``(t, y)`` UV space from the same fields as
the shape (skin tone, redness, creases, brows, lash line, sclera, iris and pupil).
"""

from __future__ import annotations

import numpy as np

from pipeline.synthetic_head.model import T_RANGE, Y_RANGE, arc, base_curve, smoothstep

#: The painted skin's melanin tone (0 palest .. 1 darkest): the colour SKIN_RGB was chosen as.
SKIN_TONE_BASE = 0.15
#: Skin colour at SKIN_TONE_BASE (sRGB 0-255, before redness, pores and creases).
SKIN_RGB = (224.0, 172.0, 146.0)
#: Optical depth (nats) of the melanin layer at the red, green and blue primaries (~610, 550,
#: 465 nm) for a melanin amount of 1. Epidermal melanin absorbs as about lambda^-3.3; light
#: scattered back from the dermis crosses it along short paths, which softens that slope in the
#: reflectance to about lambda^-1 here.
MELANIN_DEPTH_RGB = tuple(1.45 * (lam / 555.0) ** -1.0 for lam in (610.0, 550.0, 465.0))
#: Melanin amount = tone ** this: the epidermal melanin fraction spans ~1-5 % in light skin and
#: up to ~40 % in the darkest, so equal steps of tone darken the dark end more.
MELANIN_EXPONENT = 1.6


def melanin_transmittance(skin_tone: float) -> np.ndarray:
    """(3,) factor on the skin's RGB for ``skin_tone`` against :data:`SKIN_TONE_BASE`
    (exactly 1.0 at the base tone, < 1 darker, the blue channel first). Tone 0 paints the skin
    about (239, 185, 159), tone 1 about (64, 43, 28): Monk-scale 1-2 to 9-10 under the same light."""
    m = float(skin_tone) ** MELANIN_EXPONENT - SKIN_TONE_BASE ** MELANIN_EXPONENT
    return np.exp(-m * np.asarray(MELANIN_DEPTH_RGB))


def paint_texture(model, size, rows_per_chunk=128):
    """Colour texture (size, size, 3) uint8 painted in (t, y) UV space (row 0 = top)."""
    out = np.empty((size, size, 3), dtype=np.uint8)
    u = (np.arange(size) + 0.5) / size
    for r0 in range(0, size, rows_per_chunk):
        rows = np.arange(r0, min(r0 + rows_per_chunk, size))
        vv = 1.0 - (rows + 0.5) / size
        uu, vv = np.meshgrid(u, vv)
        t = -T_RANGE + 2 * T_RANGE * uu
        y = Y_RANGE[0] + (Y_RANGE[1] - Y_RANGE[0]) * vv
        base = tuple(np.broadcast_to(b, t.shape).ravel() for b in base_curve(t[0]))
        out[rows] = _paint(model, t.ravel(), y.ravel(), base).reshape(len(rows), size, 3)
    return out


def _paint(model, t, y, base=None):
    """RGB uint8 (k, 3) of the skin/eye colour at parameters ``t``, ``y``."""
    f = model.fields(t, y, detail=True, want_texture=True, base=base)
    x = f["bx"]
    yy = y
    u = arc(t)
    tone = model.noise_tone(u / 9.0, yy / 9.0) - 0.5
    fine = model.noise_pore(u / 0.8 + 17.0, yy / 0.8) - 0.5
    skin = np.array(SKIN_RGB)
    col = skin[None, :] * (1.0 + 0.10 * tone[:, None] + 0.04 * fine[:, None])
    # redder cheeks, nose and lips; darker creases and pores
    ax = np.abs(x)
    red = 0.5 * np.exp(-(((ax - 40) / 16) ** 2 + ((yy + 28) / 14) ** 2)) \
        + 0.8 * np.exp(-((x / 21.0) ** 4 + ((yy + 72.0) / 8.0) ** 2)) \
        + 0.3 * np.exp(-((x / 8) ** 2 + ((yy + 40) / 10) ** 2))
    col = col * (1 - 0.25 * red[:, None]) + np.array([190.0, 80.0, 80.0]) * 0.25 * red[:, None]
    # melanin lies above the blood in the skin: it filters the redness too (not the hair or eyes)
    tone_now = getattr(model, "skin_tone", None)
    brow_rgb = np.array([60.0, 42.0, 32.0])
    if tone_now is not None and tone_now != SKIN_TONE_BASE:
        col = col * melanin_transmittance(tone_now)[None, :]
        # hair darkens with the skin, less steeply (else the brows vanish on dark skin)
        brow_rgb = brow_rgb * np.sqrt(melanin_transmittance(tone_now))
    crease = np.clip(-f["detail"] / 0.3, 0, 1)
    col *= (1.0 - 0.35 * crease)[:, None]
    # brows: horizontal hair strokes along the brow ridge
    ex = model.ipd / 2
    by = 17.0 + 3.0 * np.sin(np.clip((ax - ex + 20) / 45, 0, 1) * np.pi) - 0.08 * np.maximum(ax - ex, 0)
    band = np.exp(-((yy - by) / 3.2) ** 4) * smoothstep(6, 12, ax) * (1 - smoothstep(ex + 18, ex + 26, ax))
    hair = smoothstep(0.35, 0.7, model.noise_brow(x / 2.5, yy / 0.3))
    bmask = np.clip(band * (0.45 + 0.55 * hair), 0, 1)
    col = col * (1 - 0.8 * bmask[:, None]) + brow_rgb * 0.8 * bmask[:, None]
    # lash line darkening along the upper margin
    d = f["d"]
    lash = (d > -0.2) & (d < 1.2)
    col[lash] *= np.where(f["upper"][lash] > 0.5, 0.45, 0.8)[:, None]
    # the corner pockets' tissue: the caruncle and the lateral fornix, moist pink
    pk = f["pocket"]
    col[pk] = np.array([196.0, 112.0, 108.0]) * (1.0 + 0.08 * fine[pk, None])
    # the scanned eyeball: sclera, iris, pupil where the eye surface is visible
    eye = f["h_eye"] >= f["h_skin"]
    ang = f["eye_angle"][eye]
    r = np.maximum(f["eye_radius"][eye], 1.0)
    rad_mm = r * np.sin(np.minimum(ang, np.pi / 2))
    iris_r = f["iris_radius"][eye]
    sclera = np.array([236.0, 226.0, 218.0]) * (1 - 0.08 * smoothstep(8, 14, rad_mm))[:, None]
    iris_c = np.array([92.0, 118.0, 140.0])
    ring = 0.85 + 0.15 * np.cos(np.arctan2(0, 1) + rad_mm * 6.0)
    iris = iris_c[None, :] * ring[:, None]
    iris = np.where((rad_mm > iris_r - 0.45)[:, None], iris * 0.6, iris)
    ec = np.where((rad_mm < iris_r)[:, None], iris, sclera)
    ec = np.where((rad_mm < 1.9)[:, None], np.array([12.0, 10.0, 10.0]), ec)
    col[eye] = ec
    return np.clip(col, 0, 255).astype(np.uint8)
