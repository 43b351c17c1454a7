"""Smoothed texture variant for down-looking lids (SynthesEyes paper, section 3.4, optional).

When the eye looks down the upper-lid skin is stretched and its wrinkles and
folds flatten. The paper renders down-looking lids with smoothed colour and
displacement textures. Here that is a per-vertex mask (where the lids_down shape
moves skin, 0..1) and a smoothed copy of each texture; a renderer mixes

    texture_down = mix(texture, smoothed_texture, w_lids_down * mask)

with ``w_lids_down`` from :func:`pipeline.rig.lids.lid_weights`. The mask can
be used as a mesh primvar (per vertex) or rasterised into UV space
(:func:`rasterize_vertex_scalar`) to bake the mixed texture directly.
"""

from __future__ import annotations

import numpy as np


def motion_mask(n_vertices: int, point_indices, offsets, power: float = 0.5) -> np.ndarray:
    """Per-vertex mask in [0, 1]: the shape's displacement magnitude, normalised, ``** power``.

    Parameters
    ----------
    n_vertices : int
    point_indices : (k,) int64
    offsets : (k, 3) float64
        Full-weight offsets of the shape (e.g. lids_down).
    power : float
        < 1 widens the mask toward the edge of the support.

    Returns
    -------
    (n,) float64
    """
    m = np.zeros(int(n_vertices))
    mag = np.linalg.norm(np.asarray(offsets, float), axis=1)
    if mag.size and mag.max() > 0:
        m[np.asarray(point_indices)] = (mag / mag.max()) ** float(power)
    return m


def texels_per_mm(V, F, UV, FUV, size) -> float:
    """Average texture resolution of a UV-mapped mesh, texels per mm.

    Parameters
    ----------
    V : (n, 3), F : (m, 3), UV : (k, 2), FUV : (m, 3)
    size : (width, height) of the texture in texels
    """
    V, UV = np.asarray(V, float), np.asarray(UV, float)
    F, FUV = np.asarray(F, np.int64), np.asarray(FUV, np.int64)
    a3 = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    t = UV[FUV] * np.asarray(size, float)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    a2 = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return float(np.sqrt(a2.sum() / max(a3.sum(), 1e-12)))


def rasterize_vertex_scalar(UV, FUV, F, values, size) -> np.ndarray:
    """Rasterise a per-vertex scalar into UV space (barycentric interpolation per triangle).

    Parameters
    ----------
    UV : (k, 2) float64, origin bottom-left
    FUV : (m, 3) int64
    F : (m, 3) int64
        Triangles (``values`` are indexed by ``F``).
    values : (n,) float64
    size : (width, height)

    Returns
    -------
    (height, width) float64
        Image rows top to bottom (row 0 = v near 1); texels no triangle covers are 0.
    """
    w, h = int(size[0]), int(size[1])
    out = np.zeros((h, w))
    UV = np.asarray(UV, float)
    vals = np.asarray(values, float)[np.asarray(F, np.int64)]
    # pixel-centre coordinates: x = u * w - 0.5, y (row) = (1 - v) * h - 0.5
    P = np.stack([UV[:, 0] * w - 0.5, (1.0 - UV[:, 1]) * h - 0.5], axis=1)[np.asarray(FUV)]
    for tri, val in zip(P, vals):
        if not val.any():
            continue
        x0, y0 = np.floor(tri.min(axis=0)).astype(int)
        x1, y1 = np.ceil(tri.max(axis=0)).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
        if x1 < x0 or y1 < y0:
            continue
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        a, b, c = tri
        den = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(den) < 1e-12:
            continue
        l0 = ((b[1] - c[1]) * (xs - c[0]) + (c[0] - b[0]) * (ys - c[1])) / den
        l1 = ((c[1] - a[1]) * (xs - c[0]) + (a[0] - c[0]) * (ys - c[1])) / den
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        out[ys[inside], xs[inside]] = (l0 * val[0] + l1 * val[1] + l2 * val[2])[inside]
    return out


def smoothed_variant(image, mask, sigma_px: float) -> np.ndarray:
    """``mix(image, gaussian_blur(image, sigma_px), mask)`` per texel.

    Parameters
    ----------
    image : (h, w) or (h, w, c) array (float displacement or uint8 colour)
    mask : (h, w) float in [0, 1]
    sigma_px : float
        Blur radius in texels (``sigma_mm * texels_per_mm``).

    Returns
    -------
    Same shape and dtype as ``image``.
    """
    from scipy.ndimage import gaussian_filter

    img = np.asarray(image)
    f = img.astype(np.float64)
    sig = (float(sigma_px), float(sigma_px)) + (0.0,) * (f.ndim - 2)
    blur = gaussian_filter(f, sigma=sig, mode="nearest")
    m = np.clip(np.asarray(mask, float), 0.0, 1.0)
    if f.ndim == 3:
        m = m[..., None]
    out = f * (1.0 - m) + blur * m
    if np.issubdtype(img.dtype, np.integer):
        info = np.iinfo(img.dtype)
        return np.clip(np.rint(out), info.min, info.max).astype(img.dtype)
    return out.astype(img.dtype)
