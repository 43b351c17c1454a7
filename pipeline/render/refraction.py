"""Apparent (refracted) image positions of points seen through the cornea.

The iris and pupil landmarks are points of the Inner mesh, behind the refractive cornea
(n = 1.376). The camera sees them where the camera ray that, refracted once at the outer eye
surface, passes through the point meets the image -- not at their straight projection: the
cornea magnifies the iris by roughly 10-30 % depending on the view.

:func:`apparent_projection` finds, for each point ``P``, that ray by Gauss-Newton iteration
(finite-difference Jacobian) starting from the straight projection: for an orthographic camera
the camera-plane position ``(x, y)`` of the parallel ray, for a pinhole camera the point
``(x, y, z_P)`` at ``P``'s own depth that the ray from the camera centre passes through. The outer surface is the eyeball asset's own analytic profile
(:func:`pipeline.eyeball.geometry.outer_radial`: eyeball sphere and corneal sphere joined by
the smooth maximum, a surface of revolution about the eye's forward axis), in the eye's model
space (mm of the parametric eye, before the scan's scale), intersected by marching + bisection;
the normal is the profile's gradient. The Blender mesh is a tessellation of the same profile,
so the two agree to the tessellation error (well below a pixel at 120 x 80). Points not
reachable through the cornea (ray misses the eye, total internal reflection, no convergence)
get NaN.
"""

from __future__ import annotations

import numpy as np

from pipeline.eyeball.geometry import EyeballParams, outer_radial

CORNEA_IOR = 1.376


def _surface_f(P, params: EyeballParams):
    """Signed distance-like function: |p| - R(theta(p)) (< 0 inside the eye)."""
    r = np.linalg.norm(P, axis=-1)
    th = np.arccos(np.clip(P[..., 2] / np.maximum(r, 1e-12), -1.0, 1.0))
    return r - outer_radial(th, params)


def _normal(S, params: EyeballParams, h: float = 1e-5):
    g = np.stack([(_surface_f(S + h * e, params) - _surface_f(S - h * e, params)) / (2 * h)
                  for e in np.eye(3)], axis=-1)
    return g / np.linalg.norm(g, axis=-1, keepdims=True)


def _hit(O, d, params: EyeballParams, n_march: int = 48, n_bisect: int = 32):
    """First intersection of rays ``O + tau d``, tau >= 0 (model space, unit d), with the outer surface."""
    R = params.apex + 0.5
    b = np.einsum("ij,ij->i", O, d)
    c = np.einsum("ij,ij->i", O, O) - R * R
    disc = b * b - c
    ok = disc > 0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    # a pinhole camera's centre may lie inside the bounding sphere: never march behind it
    t0, t1 = np.maximum(-b - sq, 0.0), -b + sq
    ts = t0[:, None] + (t1 - t0)[:, None] * np.linspace(0.0, 1.0, n_march)[None]
    F = _surface_f(O[:, None] + ts[..., None] * d[:, None], params)
    neg = F < 0
    first = np.argmax(neg, axis=1)
    ok &= neg.any(axis=1) & (first > 0)
    k = np.maximum(first, 1)
    lo = ts[np.arange(len(O)), k - 1]
    hi = ts[np.arange(len(O)), k]
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        inside = _surface_f(O + mid[:, None] * d, params) < 0
        hi = np.where(inside, mid, hi)
        lo = np.where(inside, lo, mid)
    S = O + hi[:, None] * d
    return S, ok


def _refract(d, n, eta):
    cos_i = -np.einsum("ij,ij->i", d, n)
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    ok = k >= 0
    t = eta * d + (eta * cos_i - np.sqrt(np.where(ok, k, 0.0)))[:, None] * n
    return t / np.linalg.norm(t, axis=1, keepdims=True), ok


def apparent_projection(points_head, world_to_camera, model_to_head, params: EyeballParams,
                        ior: float = CORNEA_IOR, tol_mm: float = 1e-6, max_iter: int = 20,
                        pinhole: bool = False):
    """Camera-frame (x, y) mm where the camera sees ``points_head`` through the cornea.

    Orthographic (default): the camera ray is the line along the view axis through camera-plane
    point ``(x, y)``. Pinhole (``pinhole=True``): the ray from the camera centre (the origin of
    the camera frame) through camera-frame point ``(x, y, z_P)``, ``z_P`` the point's own
    camera-frame depth; its pixel is that point's pinhole projection (:func:`apparent_points_camera`).

    Parameters
    ----------
    points_head : (n, 3) float64     points inside the eye (head frame, mm)
    world_to_camera : (4, 4)         head -> camera (OpenGL: the camera looks down -Z)
    model_to_head : (4, 4)           column-vector affine of the posed eye's model space
                                     (uniform scale * rotation, translation)
    params : EyeballParams           the eyeball asset's geometry (model mm)
    ior : float                      cornea refractive index
    pinhole : bool                   rays from the camera centre instead of parallel rays

    Returns
    -------
    (n, 2) float64 camera-frame coordinates (NaN where not seen through the cornea).
    """
    P = np.asarray(points_head, float)
    W = np.asarray(world_to_camera, float)
    A = np.asarray(model_to_head, float)
    Ainv = np.linalg.inv(A)
    Rc = W[:3, :3]
    cam_pos = -Rc.T @ W[:3, 3]
    xc, yc, zc = Rc
    d_head = -zc
    P_m = P @ Ainv[:3, :3].T + Ainv[:3, 3]
    d_m = Ainv[:3, :3] @ d_head
    d_m /= np.linalg.norm(d_m)
    ex = Ainv[:3, :3] @ xc
    ex /= np.linalg.norm(ex)
    ey = np.cross(d_m, ex)
    eta = 1.0 / float(ior)
    # far start: 4 eye sizes before the point along the ray (orthographic: depth is free)
    back = 4.0 * (params.apex + 1.0)
    cam = P @ Rc.T + W[:3, 3]

    def parallel_rays(xy, P_m):
        O_h = cam_pos + xy[:, :1] * xc + xy[:, 1:] * yc
        O_m = O_h @ Ainv[:3, :3].T + Ainv[:3, 3]
        O_m = O_m + ((P_m - O_m) @ d_m - back)[:, None] * d_m     # slide the origin near the eye
        S, ok = _hit(O_m, np.broadcast_to(d_m, O_m.shape).copy(), params)
        n = _normal(S, params)
        t, ok2 = _refract(np.broadcast_to(d_m, O_m.shape), n, eta)
        w = P_m - S
        r = w - np.einsum("ij,ij->i", w, t)[:, None] * t
        return np.stack([r @ ex, r @ ey], 1), ok & ok2

    z3 = np.tile(cam[:, 2], 3)
    O_pin = Ainv[:3, :3] @ cam_pos + Ainv[:3, 3]

    def central_rays(xy, P_m):
        Q = cam_pos + xy[:, :1] * xc + xy[:, 1:] * yc + z3[:len(xy), None] * zc
        d = (Q - cam_pos) @ Ainv[:3, :3].T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        S, ok = _hit(np.broadcast_to(O_pin, d.shape).copy(), d, params)
        t, ok2 = _refract(d, _normal(S, params), eta)
        w = P_m - S
        r = w - np.einsum("ij,ij->i", w, t)[:, None] * t
        return np.stack([r @ ex, r @ ey], 1), ok & ok2

    residual = central_rays if pinhole else parallel_rays

    xy = cam[:, :2].copy()
    n_p = len(P)
    good = np.ones(n_p, bool)
    h = 1e-4
    P_m3 = np.tile(P_m, (3, 1))
    for _ in range(max_iter):
        # the residual at xy and at its two finite-difference steps in one call (rows are
        # independent: the same values as three calls, for a third of the numpy overhead)
        r3, ok3 = residual(np.concatenate([xy, xy + [h, 0.0], xy + [0.0, h]]), P_m3)
        r, ok = r3[:n_p], ok3[:n_p]
        good &= ok
        if np.all(np.abs(r[good]) < tol_mm):
            break
        J = np.empty((n_p, 2, 2))
        for j in range(2):
            J[:, :, j] = (r3[(j + 1) * n_p:(j + 2) * n_p] - r) / h
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        good &= np.abs(det) > 1e-12
        detg = np.where(good, det, 1.0)
        step = np.stack([(J[:, 1, 1] * r[:, 0] - J[:, 0, 1] * r[:, 1]) / detg,
                         (-J[:, 1, 0] * r[:, 0] + J[:, 0, 0] * r[:, 1]) / detg], 1)
        xy = xy - np.where(good[:, None], np.clip(step, -2.0, 2.0), 0.0)
    r, ok = residual(xy, P_m)
    good &= ok & np.all(np.abs(r) < 1e-4, axis=1)
    xy[~good] = np.nan
    return xy


def apparent_points_camera(points_head, world_to_camera, model_to_head, params: EyeballParams,
                           ior: float = CORNEA_IOR, pinhole: bool = False) -> np.ndarray:
    """(n, 3) camera-frame mm points on the rays along which the camera sees ``points_head``
    through the cornea (NaN rows where not seen): orthographic ``(x, y, 0)``, pinhole
    ``(x, y, z_P)``; project them with :meth:`pipeline.render.camera.Camera.project`."""
    xy = apparent_projection(points_head, world_to_camera, model_to_head, params, ior, pinhole=pinhole)
    if not pinhole:
        return np.c_[xy, np.zeros(len(xy))]
    W = np.asarray(world_to_camera, float)
    z = np.asarray(points_head, float) @ W[2, :3] + W[2, 3]
    return np.c_[xy, z]
