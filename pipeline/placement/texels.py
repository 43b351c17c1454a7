"""Colours of a scan's texture on its surface: the texel at a UV, texels sampled over faces,
and how far a colour lies from the skin's (read by the texture fallback and the fissure fit)."""

from __future__ import annotations

import numpy as np


def texels_at(texture, uv) -> np.ndarray:
    """(..., 3) float64 sRGB of the nearest texel at each UV (..., 2) (origin bottom-left,
    wrapped into [0, 1))."""
    H, W = texture.shape[:2]
    px = np.clip((uv[..., 0] % 1.0) * W, 0, W - 1).astype(np.int64)
    py = np.clip((1.0 - uv[..., 1] % 1.0) * H, 0, H - 1).astype(np.int64)
    return texture[py, px, :3].astype(np.float64)


def colour_z(col, ring):
    """Robust z-score (k,) of each sRGB colour from the skin statistics of ``col[ring]``: brightness
    and red / blue chromaticity, scaled by their MAD (floored, so that an evenly lit skin does not
    make every shade an outlier)."""
    lum = col.mean(axis=1)
    chroma = col / np.maximum(col.sum(axis=1, keepdims=True), 1.0)
    feat = np.column_stack([lum / 255.0, chroma[:, 0], chroma[:, 2]])
    mu = np.median(feat[ring], axis=0)
    mad = 1.4826 * np.median(np.abs(feat[ring] - mu), axis=0) + np.array([0.02, 0.005, 0.005])
    return np.sqrt((((feat - mu) / mad) ** 2).sum(axis=1))


def surface_texels(V, F, UV, FUV, texture, faces, step_mm=0.25):
    """Points on ``faces`` about every ``step_mm`` and the texture colour there.

    Returns
    -------
    points : (k, 3) float64
    colours : (k, 3) float64, sRGB 0..255 (nearest texel)
    """
    A = np.asarray(V, np.float64)[np.asarray(F, np.int64)[faces]]
    T = np.asarray(UV, np.float64)[np.asarray(FUV, np.int64)[faces]]
    longest = np.linalg.norm(A - np.roll(A, 1, axis=1), axis=2).max(axis=1)
    n_div = np.maximum(1, np.ceil(longest / step_mm)).astype(np.int64)
    points, colours = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for n in np.unique(n_div):
        sel = n_div == n
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        tri = (i + j) <= n
        bary = np.stack([i[tri], j[tri], n - i[tri] - j[tri]], axis=1) / n
        points.append(np.einsum("sk,fkd->fsd", bary, A[sel]).reshape(-1, 3))
        colours.append(texels_at(texture, np.einsum("sk,fkd->fsd", bary, T[sel]).reshape(-1, 2)))
    return np.concatenate(points), np.concatenate(colours)
