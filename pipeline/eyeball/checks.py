"""Checks of the eyeball meshes: closed-manifold edges, dihedral angles and the smoothness of the
sphere/cornea seam (:func:`seam_dihedral_report`).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.eyeball.geometry import EyeballParams, limbus_theta, outer_mesh
from pipeline.geometry.meshtopo import face_normals


def mesh_edges_manifold(F) -> tuple[bool, int]:
    """(closed 2-manifold edge condition, number of boundary/non-manifold edges)."""
    F = np.asarray(F, np.int64)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(e, 1)
    _, cnt = np.unique(key, axis=0, return_counts=True)
    # directed edges must be unique (consistent orientation)
    _, dcnt = np.unique(e, axis=0, return_counts=True)
    bad = int(np.sum(cnt != 2) + np.sum(dcnt != 1))
    return bad == 0, bad


def dihedral_angles(V, F):
    """Angles (deg) between normals of faces sharing each interior edge, plus the edge keys."""
    F = np.asarray(F, np.int64)
    N = face_normals(V, F)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    key = np.sort(e, 1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    k, f = key[order], fid[order]
    same = np.all(k[1:] == k[:-1], axis=1)
    a, b = f[:-1][same], f[1:][same]
    ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", N[a], N[b]), -1, 1)))
    return ang, k[:-1][same]


def seam_dihedral_report(params: EyeballParams | None = None, resolution=None,
                         smooth: bool = True, band_deg: float = 15.0) -> dict:
    """Largest dihedral angle in the seam band vs. on the cornea and sclera away from it.

    The seam is smooth when ``seam_max_deg <= max(cornea_max_deg,
    sclera_max_deg)``: no edge in the band within ``band_deg`` of the seam
    bends more than the plain tessellation bends anywhere else (the raw sphere
    union has a 15-20 deg crease there, tested).
    """
    p = params or EyeballParams()
    m = outer_mesh(p, resolution, smooth=smooth)
    ang, keys = dihedral_angles(m.V, m.F)
    mid = (m.V[keys[:, 0]] + m.V[keys[:, 1]]) / 2
    th = np.degrees(np.arctan2(np.hypot(mid[:, 0], mid[:, 1]), mid[:, 2]))
    tl = math.degrees(limbus_theta(p))
    band = np.abs(th - tl) <= band_deg
    cornea = th < tl - band_deg
    sclera = th > tl + band_deg
    return {"limbus_theta_deg": tl, "seam_max_deg": float(ang[band].max()),
            "cornea_max_deg": float(ang[cornea].max()), "sclera_max_deg": float(ang[sclera].max())}
