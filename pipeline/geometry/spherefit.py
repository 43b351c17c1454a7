"""Sphere fitting: algebraic, robust geometric (with a radius prior) and RANSAC.

All functions work on point arrays in millimetres and return plain tuples/arrays.
"""

from __future__ import annotations

import numpy as np


def fit_sphere_algebraic(P, w=None):
    """Least-squares algebraic (Kasa) sphere fit.

    Parameters
    ----------
    P : (n, 3) float64
        Points, n >= 4 and not coplanar.
    w : (n,) float64, optional
        Non-negative weights.

    Returns
    -------
    center : (3,) float64
    radius : float
    """
    P = np.asarray(P, dtype=np.float64)
    mu = P.mean(axis=0)
    Q = P - mu
    A = np.column_stack([2.0 * Q, np.ones(len(Q))])
    b = (Q * Q).sum(axis=1)
    if w is not None:
        sw = np.sqrt(np.asarray(w, dtype=np.float64))
        A, b = A * sw[:, None], b * sw
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    return c + mu, float(np.sqrt(max(r2, 0.0)))


def sphere_through_4(P4):
    """Sphere through four points (None when they are (nearly) coplanar).

    Parameters
    ----------
    P4 : (4, 3) float64

    Returns
    -------
    (center (3,), radius) or None
    """
    A = 2.0 * (P4[1:] - P4[0])
    b = (P4[1:] ** 2).sum(1) - (P4[0] ** 2).sum()
    det = np.linalg.det(A)
    scale = np.abs(A).max() ** 3 + 1e-300
    if abs(det) < 1e-9 * scale:
        return None
    c = np.linalg.solve(A, b)
    return c, float(np.linalg.norm(P4[0] - c))


def signed_distance(P, center, radius):
    """Signed distance of points to a sphere (positive outside), (n,) float64."""
    return np.linalg.norm(np.asarray(P, dtype=np.float64) - center, axis=1) - radius


def refine_sphere(P, center, radius, *, scale=0.1, radius_prior=None, radius_sigma=None,
                  fixed_radius=None, center_prior_sigma=None):
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

    Returns
    -------
    center : (3,) float64
    radius : float
    """
    from scipy.optimize import least_squares

    P = np.asarray(P, dtype=np.float64)
    if fixed_radius is not None:
        c0 = np.asarray(center, float)

        def fun(x):
            d = (np.linalg.norm(P - x[:3], axis=1) - fixed_radius) / scale
            if center_prior_sigma is not None:
                d = np.append(d, (x[:3] - c0) / center_prior_sigma)
            return d
        res = least_squares(fun, np.asarray(center, float), loss="soft_l1", f_scale=1.0)
        return res.x[:3], float(fixed_radius)

    use_prior = radius_prior is not None and radius_sigma is not None

    def fun(x):
        d = (np.linalg.norm(P - x[:3], axis=1) - x[3]) / scale
        if use_prior:
            d = np.append(d, (x[3] - radius_prior) / radius_sigma)
        return d

    x0 = np.append(np.asarray(center, float), float(radius))
    res = least_squares(fun, x0, loss="soft_l1", f_scale=1.0)
    return res.x[:3], float(res.x[3])


def ransac_sphere(P, score, *, rng, n_iter=1500, sample_from=None, r_range=(10.0, 18.0),
                  accept=None):
    """RANSAC over 4-point spheres.

    Parameters
    ----------
    P : (n, 3) float64
        Points to draw samples from when ``sample_from`` is None.
    score : callable
        ``score(center, radius) -> float``; the best-scoring plausible sphere wins.
    rng : numpy.random.Generator
    n_iter : int
    sample_from : (k,) int64, optional
        Indices of ``P`` to draw samples from.
    r_range : (float, float)
        Plausible radii; others are skipped.
    accept : callable, optional
        ``accept(center, radius) -> bool``: further plausibility test.

    Returns
    -------
    (center (3,), radius, score) or None when no plausible sphere was found.
    """
    P = np.asarray(P, dtype=np.float64)
    idx = np.arange(len(P)) if sample_from is None else np.asarray(sample_from)
    if len(idx) < 4:
        return None
    best = None
    samples = rng.integers(0, len(idx), size=(n_iter, 4))
    for s in samples:
        if len(set(s.tolist())) < 4:
            continue
        sph = sphere_through_4(P[idx[s]])
        if sph is None:
            continue
        c, r = sph
        if not (r_range[0] <= r <= r_range[1]):
            continue
        if accept is not None and not accept(c, r):
            continue
        sc = score(c, r)
        if best is None or sc > best[2]:
            best = (c, r, sc)
    return best
