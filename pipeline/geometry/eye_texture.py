"""Texture fallback of the eye fit: the opening from the colour texture, for scans too coarse to show
the eyeball geometrically (``james``). ``pipeline.geometry.eye_fit.find_eye`` calls it when the
geometric fit fails and the scan has a texture: faces near the hint whose colour differs from the
surrounding skin form the opening; the sphere is fitted to that region with the radius prior.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry.eye_fit import EyeFit, EyeMesh, _clean_region, _crease, _patch, _unit
from pipeline.geometry.spherefit import refine_sphere, signed_distance

if TYPE_CHECKING:
    from pipeline.geometry.remove_eyeballs import EyeSettings


def texture_colours(mesh_arrays, texture, faces, samples=7):
    """Median sRGB colour of the texture over each face, (k, 3) float64 (0..255)."""
    UV = np.asarray(mesh_arrays["UV"], dtype=np.float64)
    FUV = np.asarray(mesh_arrays["FUV"], dtype=np.int64)[faces]
    H, W = texture.shape[:2]
    bary = np.array([[1 / 3, 1 / 3, 1 / 3], [0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6],
                     [0.45, 0.45, 0.1], [0.1, 0.45, 0.45], [0.45, 0.1, 0.45]])[:samples]
    uv = np.einsum("sk,fkd->fsd", bary, UV[FUV])
    px = np.clip((uv[..., 0] % 1.0) * W, 0, W - 1).astype(np.int64)
    py = np.clip((1.0 - uv[..., 1] % 1.0) * H, 0, H - 1).astype(np.int64)
    return np.median(texture[py, px, :3].astype(np.float64), axis=1)


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
    # chroma/brightness features; skin statistics from the ring
    lum = col.mean(axis=1)
    chroma = col / np.maximum(col.sum(axis=1, keepdims=True), 1.0)
    feat = np.column_stack([lum / 255.0, chroma[:, 0], chroma[:, 2]])
    mu = np.median(feat[ring], axis=0)
    mad = 1.4826 * np.median(np.abs(feat[ring] - mu), axis=0) + np.array([0.02, 0.005, 0.005])
    z = np.sqrt((((feat - mu) / mad) ** 2).sum(axis=1))
    eye = (z > st.texture_min_contrast) & (dh < 12.0)
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
