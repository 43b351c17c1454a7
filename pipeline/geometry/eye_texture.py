"""Texture fallback of the eye fit: the opening from the colour texture, for scans too coarse to show
the eyeball geometrically (``james``). ``pipeline.geometry.eye_fit.find_eye`` calls it when the
geometric fit fails and the scan has a texture: faces near the hint whose colour differs from the
surrounding skin form the opening; the sphere is fitted to that region with the radius prior.

That opening is only as fine as the scan's faces, and its sphere holds at most a chord of its
diameter, so on a coarse scan it can come out far narrower than the eye (``james``: 18 mm, where
the photo's fissure and the hand-marked corners are 28-31 mm wide). :func:`texture_fissure`
measures the fissure in the texture itself, at texture resolution, so that the stage can say
so (``doubts`` in ``eyes.json``) instead of passing too-close canthi on silently.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry.eye_fit import EyeFit, EyeMesh, _clean_region, _crease, _patch, _unit
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.spherefit import refine_sphere, signed_distance

if TYPE_CHECKING:
    from pipeline.geometry.remove_eyeballs import EyeSettings


def _texels(texture, uv) -> np.ndarray:
    """(..., 3) float64 sRGB of the nearest texel at each UV (..., 2) (origin bottom-left,
    wrapped into [0, 1))."""
    H, W = texture.shape[:2]
    px = np.clip((uv[..., 0] % 1.0) * W, 0, W - 1).astype(np.int64)
    py = np.clip((1.0 - uv[..., 1] % 1.0) * H, 0, H - 1).astype(np.int64)
    return texture[py, px, :3].astype(np.float64)


def texture_colours(mesh_arrays, texture, faces, samples=7):
    """Median sRGB colour of the texture over each face, (k, 3) float64 (0..255)."""
    UV = np.asarray(mesh_arrays["UV"], dtype=np.float64)
    FUV = np.asarray(mesh_arrays["FUV"], dtype=np.int64)[faces]
    bary = np.array([[1 / 3, 1 / 3, 1 / 3], [0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6],
                     [0.45, 0.45, 0.1], [0.1, 0.45, 0.45], [0.45, 0.1, 0.45]])[:samples]
    return np.median(_texels(texture, np.einsum("sk,fkd->fsd", bary, UV[FUV])), axis=1)


def _colour_z(col, ring):
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
        colours.append(_texels(texture, np.einsum("sk,fkd->fsd", bary, T[sel]).reshape(-1, 2)))
    return np.concatenate(points), np.concatenate(colours)


def texture_fissure(V, F, UV, FUV, texture, hint, forward, *, radius_mm=22.0, skin_from_mm=18.0,
                    cell_mm=0.5, min_contrast=3.0) -> dict:
    """The palpebral fissure as the texture shows it: its extent along the eye's axes (mm).

    The surface within ``radius_mm`` of the hint is sampled at texture resolution
    (:func:`surface_texels`) and seen along the gaze ``forward``. Texels whose colour differs
    from the skin beyond ``skin_from_mm`` (robust z-score over ``min_contrast``, as in
    :func:`fit_texture`) are marked in a grid of ``cell_mm`` cells; the grid is closed and opened
    once, and the connected part at the hint is the fissure: sclera, iris and the lash line on
    the lid margins, so it reads a little wide (2-2.5 mm on the procedural head, whose corners
    are painted with lashes and liner).

    Returns
    -------
    dict
        ``width_mm`` (along the eye's horizontal axis, ``eye_basis(forward)[0]``), ``height_mm``
        (vertical) and ``cells`` (its area in cells); all 0 when no fissure touches the hint.
    """
    from scipy import ndimage

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    hint = np.asarray(hint, np.float64)
    faces = np.flatnonzero(np.linalg.norm(V[F].mean(axis=1) - hint, axis=1) < radius_mm + 3.0)
    P, col = surface_texels(V, F, UV, FUV, texture, faces, step_mm=cell_mm / 2.0)
    q = (P - hint) @ eye_basis(forward)[:2].T
    dq = np.linalg.norm(q, axis=1)
    keep = dq < radius_mm
    q, col, dq = q[keep], col[keep], dq[keep]
    ring = dq > skin_from_mm
    if ring.sum() < 50:
        return {"width_mm": 0.0, "height_mm": 0.0, "cells": 0}
    eye = _colour_z(col, ring) > min_contrast
    n = int(np.ceil(2.0 * radius_mm / cell_mm)) + 1
    ij = np.clip(((q + radius_mm) / cell_mm).astype(np.int64), 0, n - 1)
    votes = np.zeros((n, n))
    count = np.zeros((n, n))
    np.add.at(votes, (ij[:, 1], ij[:, 0]), eye.astype(np.float64))
    np.add.at(count, (ij[:, 1], ij[:, 0]), 1.0)
    grid = (count > 0) & (votes > 0.5 * count)
    grid = ndimage.binary_opening(ndimage.binary_closing(grid, iterations=2), iterations=1)
    labels, _ = ndimage.label(grid)
    h = int(radius_mm / cell_mm)
    near = labels[h - 2:h + 3, h - 2:h + 3]
    if not (near > 0).any():
        return {"width_mm": 0.0, "height_mm": 0.0, "cells": 0}
    ys, xs = np.nonzero(labels == np.bincount(near[near > 0]).argmax())
    return {"width_mm": float((xs.max() - xs.min() + 1) * cell_mm),
            "height_mm": float((ys.max() - ys.min() + 1) * cell_mm), "cells": int(len(xs))}


def fit_texture(mesh: EyeMesh, mesh_arrays, texture, hint, side, st: EyeSettings, source,
                 fixed_radius=None):
    """Eye opening from the colour texture (coarse scans), sphere from its vertices."""
    V, F = mesh.V, mesh.F
    patch = _patch(mesh, hint, st.patch_radius_mm)
    faces = np.where(patch)[0]
    col = texture_colours(mesh_arrays, texture, faces)
    dh = np.linalg.norm(mesh.centroids[faces] - hint, axis=1)
    ring = (dh > 14.0) & (dh < st.patch_radius_mm)
    if ring.sum() < 10:
        raise ScanError(source, f"{side} eye: too little skin around the hint to read the texture")
    eye = (_colour_z(col, ring) > st.texture_min_contrast) & (dh < 12.0)
    mask = np.zeros(len(F), bool)
    mask[faces[eye]] = True
    seed = np.zeros(len(F), bool)
    seed[faces[dh < max(4.0, 1.5 * mesh.median_edge)]] = True
    region = _clean_region(mesh, mask, seed, patch)
    if region.sum() < 2:
        raise ScanError(source, f"{side} eye: no eyeball surface found near the hint "
                                f"{np.round(hint, 2).tolist()} (geometry and texture)")
    rv = np.unique(F[region])
    P = V[rv]
    r0 = st.radius_prior_mm if fixed_radius is None else fixed_radius
    # start: sphere of the prior radius behind the region centroid along the mean normal
    N = meshtopo.face_normals(V, F)[region].mean(axis=0)
    N = _unit(N if np.linalg.norm(N) > 0 else [0, 0, 1.0])
    c0 = P.mean(axis=0) - r0 * N
    c, r = refine_sphere(P, c0, r0, scale=0.3, fixed_radius=r0, center_prior_sigma=1.0)
    d = signed_distance(P, c, r)
    rms = float(np.sqrt(np.mean(d ** 2)))
    forward = _unit(P.mean(axis=0) - c)
    dd = np.full(len(V), np.nan)
    pv = np.unique(F[patch])
    dd[pv] = signed_distance(V[pv], c, r)
    return EyeFit(side=side, center=c, radius=float(r), forward=forward, residual_rms_mm=rms,
                  n_inliers=int(len(rv)), method="texture", region=region,
                  crease_deg=_crease(mesh, region, dd), inliers=rv)
