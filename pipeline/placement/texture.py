"""Texture fallback of the eye fit: the opening from the colour texture, for scans too coarse to show
the eyeball geometrically (``james``). :func:`pipeline.placement.place.place_pair` calls it when the
geometric fit fails and the scan has a texture (:func:`fit_texture`): the palpebral fissure the
photograph shows, from canthus to canthus, seen along the head's forward axis
(:mod:`pipeline.placement.fissure`: an almond fitted to how eye-like each texel's colour is), is
lifted onto the scan surface; the eye is placed behind it by the anatomy of the corners and the
lid margin around a globe of the prior radius (:func:`place_from_fissure`). The corners lie off
that globe, as real ones do (:mod:`pipeline.geometry.corners`). ``remove_eyeballs`` then refines
the scan's faces along the outline and cuts the opening there
(:mod:`pipeline.remove_eyeballs.fissure_cut`), so the photographed eye leaves the lids with it.

:func:`texture_fissure` measures the fissure's extent independently (every texel that differs
from the skin, a connected blob at the hint; it reads 2-2.5 mm wide, lashes included), so that
the stage can doubt an opening much narrower than that (``doubts`` in ``eyes.json``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.spherefit import signed_distance
from pipeline.placement.eye_fit import EyeFit, EyeMesh, lid_crease_deg, patch_faces, unit_vector
from pipeline.placement.texels import colour_z, surface_texels

if TYPE_CHECKING:
    from pipeline.placement.settings import PlacementSettings


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
    eye = colour_z(col, ring) > min_contrast
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


class NoEyeInTexture(ScanError):
    """The texture shows no eye colours near the hint (no sclera or iris against the skin)."""


@dataclass
class TextureEyeFit(EyeFit):
    """An eye placed from the fissure its texture shows. ``fissure``: ``outline`` (k, 3) the
    opening on the scan surface (medial canthus first, upper lid first, lateral canthus at
    ``lateral``), ``outline_2d`` (k, 2) the same seen along ``view`` in the plane ``basis``
    through ``hint``, ``theta`` the almond's parameters (:mod:`pipeline.placement.fissure`)."""

    fissure: dict | None = field(default=None, repr=False)


#: Where the fissure's corners lie around a 12.05 mm eye (mean, SD; mm), measured on the eight
#: SynthesEyes eye regions registered to their eyeballs (UnityEyes' eye-region files, MIT; see
#: pipeline/placement/data/README.md): in front of the centre along the gaze, and from the gaze axis. The
#: medial corner is the far end of the caruncle, where the lids meet.
MEDIAL_CORNER_FWD, MEDIAL_CORNER_AXIS = (8.56, 0.69), (15.19, 1.93)
LATERAL_CORNER_FWD, LATERAL_CORNER_AXIS = (4.51, 1.18), (12.68, 0.41)
#: The lid margin between the corners rests this far off the globe (mean, SD of the interior
#: margin points, mm).
MARGIN_OFF = (1.1, 0.45)
ANATOMY_RADIUS_MM = 12.05
#: Spread of the eyeball's radius in adults (axial length 23.4 +- 0.9 mm, issue 21): the radius
#: of a texture-placed eye is free about the prior within it (a wide fissure, a larger eye).
RADIUS_SIGMA_MM = 0.5
#: A scanned subject looks ahead: the gaze's spread about the head's forward axis (1 sigma, deg).
#: The corners alone leave the eye free to turn about the line through them.
GAZE_SIGMA_DEG = 5.0
#: The lid margin points together weigh as this many independent observations (the outline is one
#: curve sampled densely, not ninety measurements).
LID_OBSERVATIONS = 10.0


def place_from_fissure(outline, lateral: int, radius: float, start_forward, fixed_radius=False):
    """Eye centre and gaze from the fissure's outline on the scan and the anatomy around a globe.

    The corners' place in front of the centre and off the gaze axis (``*_CORNER_*``, scaled
    with ``radius``) and the lid margin's distance off the globe (``MARGIN_OFF``, the lid parts
    between 20 % and 95 % of the way from the medial corner) are weighted least squares in the
    centre and the gaze direction, with the gaze near the head's forward axis (a MAP estimate
    under the population's spread).

    Parameters
    ----------
    outline : (k, 3) float64
        Medial canthus first, upper lid first.
    lateral : int
        Position of the lateral canthus.
    radius : float
        The radius prior (``RADIUS_SIGMA_MM``), or the radius with ``fixed_radius``.
    start_forward : (3,) float64
        The head's forward axis: start and prior of the gaze (``GAZE_SIGMA_DEG``).

    Returns
    -------
    center (3,), forward (3,) unit, radius, rms (float: RMS of the lid residuals, mm)
    """
    from scipy.optimize import least_squares

    P = np.asarray(outline, np.float64)
    k = len(P)
    M, Lc = P[0], P[lateral]
    x = (P - M) @ unit_vector(Lc - M) / max(np.linalg.norm(Lc - M), 1e-9)
    lids = (x > 0.2) & (x < 0.95)
    lids[[0, lateral]] = False
    Pl = P[lids]
    f0 = unit_vector(start_forward)
    e1 = unit_vector(np.cross(f0, [0.0, 1.0, 0.0]) if abs(f0[1]) < 0.9 else np.cross(f0, [1.0, 0.0, 0.0]))
    e2 = np.cross(f0, e1)
    w_lid = 1.0 / np.sqrt(max(len(Pl), 1) / LID_OBSERVATIONS)

    def unpack(z):
        f = unit_vector(f0 + z[3] * e1 + z[4] * e2)
        return z[:3], f, (radius if fixed_radius else radius + z[5])

    def res(z):
        c, f, r = unpack(z)
        scale = r / ANATOMY_RADIUS_MM
        out = [] if fixed_radius else [z[5] / RADIUS_SIGMA_MM]
        for corner, (fm, fs), (am, as_) in ((M, MEDIAL_CORNER_FWD, MEDIAL_CORNER_AXIS),
                                            (Lc, LATERAL_CORNER_FWD, LATERAL_CORNER_AXIS)):
            w = corner - c
            a = w @ f
            out += [(a - fm * scale) / fs, (np.linalg.norm(w - a * f) - am * scale) / as_]
        d = np.linalg.norm(Pl - c, axis=1) - r
        out += list(w_lid * (d - MARGIN_OFF[0]) / MARGIN_OFF[1])
        sig = np.sin(np.radians(GAZE_SIGMA_DEG))
        out += [(f @ e1) / sig, (f @ e2) / sig]
        return np.asarray(out)

    c0 = 0.5 * (M + Lc) - (radius * 0.7) * f0
    sol = least_squares(res, np.concatenate([c0, [0.0, 0.0, 0.0]]),
                        x_scale=np.array([1, 1, 1, 0.1, 0.1, 0.5]))
    c, f, r = unpack(sol.x)
    d = np.linalg.norm(Pl - c, axis=1) - r - MARGIN_OFF[0]
    return c, f, float(r), float(np.sqrt(np.mean(d ** 2))) if len(d) else 0.0


def fit_texture(mesh: EyeMesh, mesh_arrays, texture, hint, side, st: PlacementSettings, source,
                fixed_radius=None, n_outline=96):
    """Eye opening from the colour texture (coarse scans): the fissure's outline from canthus to
    canthus (:mod:`pipeline.placement.fissure`, seen along the head's forward axis), the eye
    placed behind it by the anatomy (:func:`place_from_fissure`, radius: the prior or
    ``fixed_radius``)."""
    from pipeline.placement import fissure as fs

    V, F = mesh.V, mesh.F
    view = np.array([0.0, 0.0, 1.0])          # the head frame's forward axis
    cmap = fs.eye_colour_map(V, F, mesh_arrays["UV"], mesh_arrays["FUV"], texture, hint, view,
                             radius_mm=st.patch_radius_mm, min_contrast=st.texture_min_contrast)
    if cmap is None:
        raise NoEyeInTexture(source, f"{side} eye: no eyeball surface found near the hint "
                                f"{np.round(hint, 2).tolist()} (geometry and texture)")
    theta, _ = fs.fit_fissure(cmap, 1.0 if side == "left" else -1.0)
    Q = fs.almond_points(theta, n_outline)
    P = fs.lift(V, F, Q, hint, view, cmap.basis)
    lateral = n_outline // 2
    if not np.isfinite(P[[0, lateral]]).all() or np.isnan(P).any(axis=1).mean() > 0.1:
        raise ScanError(source, f"{side} eye: the fissure the texture shows near "
                                f"{np.round(hint, 2).tolist()} runs off the scan surface")
    good = np.isfinite(P).all(axis=1)
    P, Q = P[good], Q[good]
    lateral = int(np.flatnonzero(good)[:lateral + 1].size - 1)
    r0 = st.radius_prior_mm if fixed_radius is None else fixed_radius
    c, forward, r0, rms = place_from_fissure(P, lateral, r0, view, fixed_radius=fixed_radius is not None)
    patch = patch_faces(mesh, hint, st.patch_radius_mm)
    front = (meshtopo.face_normals(V, F) @ view) > 0
    region = patch & front & fs.points_in_polygon((mesh.centroids - hint) @ cmap.basis.T, Q)
    if region.sum() < 2:
        raise NoEyeInTexture(source, f"{side} eye: no eyeball surface found near the hint "
                                f"{np.round(hint, 2).tolist()} (geometry and texture)")
    rv = np.unique(F[region])
    dd = np.full(len(V), np.nan)
    pv = np.unique(F[patch])
    dd[pv] = signed_distance(V[pv], c, r0)
    return TextureEyeFit(side=side, center=c, radius=float(r0), forward=forward, residual_rms_mm=rms,
                         n_inliers=int(len(P)), method="texture", region=region,
                         crease_deg=lid_crease_deg(mesh, region, dd), inliers=rv,
                         fissure={"outline": P, "outline_2d": Q, "lateral": lateral, "hint": np.asarray(hint, float),
                                  "view": view, "basis": cmap.basis, "theta": theta})
