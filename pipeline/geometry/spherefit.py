"""Sphere fitting: robust geometric (with a radius prior), and spheres through oriented points.

All functions work on point arrays in millimetres and return plain tuples/arrays.
"""

from __future__ import annotations

import numpy as np


def sphere_from_normals(p1, n1, p2, n2):
    """Sphere through two points whose unit normals point away from the centre (None if parallel).

    The centre is the midpoint of the closest points of the lines ``p - t n``; the radius the
    mean of the two distances ``t`` (both must be positive).

    Returns
    -------
    (center (3,), radius) or None
    """
    w = p1 - p2
    b = n1 @ n2
    den = 1.0 - b * b
    if den < 1e-4:
        return None
    d, e = n1 @ w, n2 @ w
    t1 = (d - b * e) / den
    t2 = (b * d - e) / den
    if t1 <= 0 or t2 <= 0:
        return None
    c = 0.5 * ((p1 - t1 * n1) + (p2 - t2 * n2))
    return c, float(0.5 * (np.linalg.norm(p1 - c) + np.linalg.norm(p2 - c)))


def signed_distance(P, center, radius):
    """Signed distance of points to a sphere (positive outside), (n,) float64."""
    return np.linalg.norm(np.asarray(P, dtype=np.float64) - center, axis=1) - radius


def radius_sigma(P, center, radius):
    """Standard error of a sphere fit's radius (Gauss-Newton covariance, robust residual scale).

    Parameters
    ----------
    P : (n, 3) float64
        The points the sphere was fitted to (n >= 5).
    center : (3,) float64
    radius : float

    Returns
    -------
    float
        ``sqrt(cov[r, r])`` with ``cov = s^2 (J^T J)^-1`` and ``s`` = 1.4826 MAD of the residuals;
        ``inf`` when the points do not determine the radius.
    """
    P = np.asarray(P, dtype=np.float64)
    if len(P) < 5:
        return float("inf")
    w = P - center
    nw = np.linalg.norm(w, axis=1)
    d = nw - radius
    J = np.column_stack([-w / np.maximum(nw, 1e-12)[:, None], -np.ones(len(P))])
    s = max(1.4826 * float(np.median(np.abs(d - np.median(d)))), 1e-6)
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float("inf")
    return float(s * np.sqrt(max(cov[3, 3], 0.0)))


def refine_sphere(P, center, radius, *, scale=0.1, radius_prior=None, radius_sigma=None,
                  fixed_radius=None, center_prior_sigma=None, inside_points=None, inside_margin=0.2):
    """Robust geometric sphere fit (soft-L1 loss), optionally with a Gaussian radius prior.

    Parameters
    ----------
    P : (n, 3) float64
        Points.
    center : (3,) float64
        Start centre.
    radius : float
        Start radius.
    scale : float
        Residual scale of the robust loss, mm (residuals well above it count ~linearly).
    radius_prior, radius_sigma : float, optional
        Adds the residual ``(r - radius_prior) / radius_sigma`` (in units of ``scale``).
    fixed_radius : float, optional
        Fit the centre only, with this radius.
    center_prior_sigma : float, optional
        With ``fixed_radius``: adds ``(c - center) / center_prior_sigma`` (keeps an
        ill-posed fit to a small patch near its start).
    inside_points : (k, 3) float64, optional
        Points that must not lie inside the sphere: one-sided residuals
        ``min(0, |q - c| - r + inside_margin) / scale`` (a surface that wraps the sphere, e.g.
        the rest of the eye region around a fitted sclera patch).
    inside_margin : float

    Returns
    -------
    center : (3,) float64
    radius : float
    """
    from scipy.optimize import least_squares

    P = np.asarray(P, dtype=np.float64)
    Q = None if inside_points is None else np.asarray(inside_points, dtype=np.float64)

    def inside(x, r):
        return np.minimum(np.linalg.norm(Q - x[:3], axis=1) - r + inside_margin, 0.0) / scale

    if fixed_radius is not None:
        c0 = np.asarray(center, float)

        def fun(x):
            d = (np.linalg.norm(P - x[:3], axis=1) - fixed_radius) / scale
            if Q is not None:
                d = np.append(d, inside(x, fixed_radius))
            if center_prior_sigma is not None:
                d = np.append(d, (x[:3] - c0) / center_prior_sigma)
            return d
        res = least_squares(fun, np.asarray(center, float), loss="soft_l1", f_scale=1.0)
        return res.x[:3], float(fixed_radius)

    use_prior = radius_prior is not None and radius_sigma is not None

    def fun(x):
        d = (np.linalg.norm(P - x[:3], axis=1) - x[3]) / scale
        if Q is not None:
            d = np.append(d, inside(x, x[3]))
        if use_prior:
            d = np.append(d, (x[3] - radius_prior) / radius_sigma)
        return d

    x0 = np.append(np.asarray(center, float), float(radius))
    res = least_squares(fun, x0, loss="soft_l1", f_scale=1.0)
    return res.x[:3], float(res.x[3])
