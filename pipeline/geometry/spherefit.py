"""Sphere fitting: robust geometric (with a radius prior) and RANSAC.

All functions work on point arrays in millimetres and return plain tuples/arrays.
"""

from __future__ import annotations

import numpy as np


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


def ransac_sphere(P, score, *, rng, n_iter=1500, sample_from=None, r_range=(10.0, 18.0),
                  accept=None, refine=None, prescore=None, n_refine=8, normals=None):
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
    refine : callable, optional
        ``refine(center, radius) -> (center, radius)``: local optimisation (LO-RANSAC). The
        ``n_refine`` best samples by ``prescore`` (default ``score``) are refined and then
        ranked by ``score``; a sample and its refinement both compete. With ``prescore`` the
        ``n_refine`` best by ``score`` are refined too.
    prescore : callable, optional
        Score of the sampling phase when ``refine`` is given (e.g. a more lenient one).
    n_refine : int
    normals : ((k, 3), (k, 3)) float64, optional
        Oriented points (e.g. face centroids) and their unit outward normals: ``2 n_iter``
        further hypotheses from pairs of them (``sphere_from_normals``), far likelier to be
        all-inlier than 4-point samples when inliers are few.

    Returns
    -------
    (center (3,), radius, score) or None when no plausible sphere was found.
    """
    P = np.asarray(P, dtype=np.float64)
    idx = np.arange(len(P)) if sample_from is None else np.asarray(sample_from)
    if len(idx) < 4:
        return None
    best = None
    pre = score if (refine is None or prescore is None) else prescore
    cands = []
    samples = rng.integers(0, len(idx), size=(n_iter, 4))
    hyps = [sphere_through_4(P[idx[s]]) if len(set(s.tolist())) == 4 else None for s in samples]
    if normals is not None and len(normals[0]) >= 2:
        Pn, N = (np.asarray(a, dtype=np.float64) for a in normals)
        for a, b in rng.integers(0, len(Pn), size=(2 * n_iter, 2)):
            if a != b:
                hyps.append(sphere_from_normals(Pn[a], N[a], Pn[b], N[b]))
    for sph in hyps:
        if sph is None:
            continue
        c, r = sph
        if not (r_range[0] <= r <= r_range[1]):
            continue
        if accept is not None and not accept(c, r):
            continue
        sc = pre(c, r)
        if refine is not None:
            cands.append((sc, score(c, r) if pre is not score else sc, c, r))
        elif best is None or sc > best[2]:
            best = (c, r, sc)
    if refine is None:
        return best
    order = np.argsort([-t[0] for t in cands], kind="stable")[:n_refine].tolist()
    if pre is not score:  # the best by either score
        order += [i for i in np.argsort([-t[1] for t in cands], kind="stable")[:n_refine].tolist()
                  if i not in order]
    for i in order:
        _, _, c, r = cands[i]
        opts = [(c, r)]
        try:
            c2, r2 = refine(c, r)
            if (np.all(np.isfinite(c2)) and r_range[0] <= r2 <= r_range[1]
                    and (accept is None or accept(c2, r2))):
                opts.append((np.asarray(c2, dtype=np.float64), float(r2)))
        except (ValueError, np.linalg.LinAlgError):
            pass
        for c_, r_ in opts:
            sc = score(c_, r_)
            if best is None or sc > best[2]:
                best = (c_, r_, sc)
    return best
