"""Closest points on the outer surface of a placed parametric eye (the smoothed sphere + cornea
profile of :mod:`pipeline.eyeball.geometry` placed with a fitted radius by
:func:`~pipeline.eyeball.geometry.placed_params`, centred and turned to a forward direction): what
the snap stage moves the eyelid margin onto.
"""

from __future__ import annotations

import numpy as np

from pipeline.eyeball.geometry import EyeballParams, outer_radial, placed_params


_PROFILE_CACHE: dict = {}


def _profile(p: EyeballParams, n: int = 8192):
    key = (p, n)
    if key not in _PROFILE_CACHE:
        th = np.linspace(0, np.pi, n)
        R = outer_radial(th, p)
        if len(_PROFILE_CACHE) >= 4:
            _PROFILE_CACHE.clear()
        _PROFILE_CACHE[key] = np.stack([R * np.sin(th), R * np.cos(th)], 1)
    return _PROFILE_CACHE[key]


def _nearest_profile_index(prof, q2, step: int = 16, chunk: int = 4096):
    """Index of the nearest profile sample: coarse scan (every ``step``-th), then a fine window.

    Exact for the nearest sample as long as the true nearest lies within one
    coarse interval of the nearest coarse sample (always the case for this
    smooth, convex-ish profile at 16 x 8192 sampling). O(n * (n_prof/step + 2 step)).
    """
    n = len(prof)
    coarse = np.arange(0, n, step)
    out = np.empty(len(q2), np.int64)
    win = np.arange(-step, step + 1)
    for s0 in range(0, len(q2), chunk):
        q = q2[s0:s0 + chunk]
        d = ((q[:, None, :] - prof[coarse][None]) ** 2).sum(-1)
        ic = coarse[np.argmin(d, 1)]
        cand = np.clip(ic[:, None] + win[None], 0, n - 1)
        dd = ((q[:, None, :] - prof[cand]) ** 2).sum(-1)
        out[s0:s0 + chunk] = cand[np.arange(len(q)), np.argmin(dd, 1)]
    return out


def outer_surface_closest_point(P, center=(0.0, 0.0, 0.0), forward=(0.0, 0.0, 1.0),
                                radius: float | None = None,
                                params: EyeballParams | None = None):
    """Closest points on the (smoothed) parametric outer surface of a placed eye.

    The eye placed with its sphere of ``radius`` (default ``params.r1``; the cornea keeps its
    size, :func:`~pipeline.eyeball.geometry.placed_params`), centred at ``center`` and looking
    along ``forward``. Accuracy: the profile is sampled at 8192 polar angles and refined on
    segments (error < 1e-5 x radius).

    Parameters
    ----------
    P : (n, 3) float64 query points, mm.
    center : (3,), forward : (3,) (normalised here), radius : float, params : EyeballParams

    Returns
    -------
    Q : (n, 3) float64 closest surface points
    N : (n, 3) float64 unit outward surface normals at Q
    d : (n,) float64 signed distance (positive outside)
    """
    p = params or EyeballParams()
    if radius is not None:
        p = placed_params(p, radius)
    P = np.atleast_2d(np.asarray(P, float))
    c = np.asarray(center, float)
    f = np.asarray(forward, float)
    f = f / np.linalg.norm(f)
    # orthonormal frame (e1, e2, f)
    a = np.array([1.0, 0, 0]) if abs(f[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(a, f)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(f, e1)
    L = P - c
    z = L @ f
    x, y = L @ e1, L @ e2
    rho = np.hypot(x, y)
    prof = _profile(p)
    q2 = np.stack([rho, z], 1)
    i = _nearest_profile_index(prof, q2)
    best = np.full(len(P), np.inf)
    best_pt = np.zeros((len(P), 2))
    best_t = np.zeros((len(P), 2))
    for i0 in (i - 1, i):
        a0 = prof[np.clip(i0, 0, len(prof) - 2)]
        b0 = prof[np.clip(i0, 0, len(prof) - 2) + 1]
        ab = b0 - a0
        t = np.clip(np.einsum("ij,ij->i", q2 - a0, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        pt = a0 + t[:, None] * ab
        dd = np.linalg.norm(q2 - pt, axis=1)
        better = dd < best
        best[better] = dd[better]
        best_pt[better] = pt[better]
        best_t[better] = ab[better]
    # outward normal of the profile: tangent (d rho, d z) rotated; profile runs apex -> back pole
    tan = best_t / np.linalg.norm(best_t, axis=1, keepdims=True)
    n2 = np.stack([-tan[:, 1], tan[:, 0]], 1)   # points away from the axis side (outside)
    inside_r = np.hypot(*q2.T) < np.hypot(*best_pt.T)
    sign = np.where(inside_r, -1.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cph = np.where(rho > 1e-12, x / np.where(rho > 1e-12, rho, 1), 1.0)
        sph = np.where(rho > 1e-12, y / np.where(rho > 1e-12, rho, 1), 0.0)
    radial = cph[:, None] * e1 + sph[:, None] * e2
    Q = c + (best_pt[:, :1] * radial + best_pt[:, 1:] * f)
    N = n2[:, :1] * radial + n2[:, 1:] * f
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    return Q, N, sign * best
