"""Whether the geometry shows a lid fissure across an eye's opening: the cue that tells an open
eye whose globe bulges past its lids from a closed one, where the search found no eye ringed by
a lid fold (:mod:`pipeline.placement.fissure` is the fissure a colour texture shows).

The search takes an open eye by the lid fold round its exposed surface. An eye with a large
globe seen by a noisy or sparse scan (held-out ``id321_sparse_views``' right eye, both of
``id324_hint5_down``'s, looking down on ICT globes of 15.7-18.2 mm) shows none: its surface
is one smooth hump from lid to lid. A closed eye's lids meet in a fissure, a narrow horizontal
valley between two bulges. So where the search finds no eye, the depth of the narrowest
horizontal valley across the opening says which it is:

1. the scan's front-most surface as a height field on a 0.25 mm grid round the hint, in the
   frame of the surface's mean normal within 15 mm (``up`` the head's +Y made perpendicular);
2. smoothed by a 1 mm Gaussian; valleys up to 6 mm wide along ``up`` filled (a grey closing)
   and the surface subtracted: the depth of every narrow horizontal valley;
3. per vertical line within 5 mm of the centre, the deepest valley within 7 mm above or below;
   the median over the lines;
4. that median at 8 points on a 2.5 mm ring round the hint, and their median (one window can
   miss the fissure or catch a margin's crease; the ring cannot do both).

Measured (``benchmarks/results/placement.md``): the three open eyes above 0.000-0.069 mm, every
blink eye of the held-out and dev heads 0.279-0.932 mm (``id332_blink_dome``'s left the
lowest), the open eyes the search places 0.30-0.82 mm. A high value says nothing (an open eye
recessed behind its margins has creases too: dev ``id42_down``'s left, 0.48 mm, stays refused),
and a low one alone does not say open: a lid laid smooth over the eye, with no crease anywhere
(the tests' closed head; a blink scanned too coarsely to keep its fissure), reads 0 too. So an
eye the search would refuse as closed is placed behind its opening, doubted, only when no
fissure crosses it and the same search still finds an eye surface ringed by a weaker lid fold
(:data:`LOWER_FOLD_DEG`, where the smooth lid rings none). Smoothing 0.7-1.4 mm
and valley widths 4-8 mm keep the two groups apart (at most 0.199 against at least 0.153), and so
does the ring with the hint 2.5 mm further off; at 5 mm further off they nearly meet (0.10
against 0.18). A coarse blink that keeps no fissure but whose lids still ring an eye-sized
surface by 8 deg would be published as open, doubted: no such head was at hand.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LOWER_FOLD_DEG", "OPEN_BELOW_MM", "fissure_depth", "fissure_depth_ring"]

#: below this ring median (mm) no fissure crosses the opening
OPEN_BELOW_MM = 0.18
#: the lid fold (deg) that must still ring an eye surface for an eye with no fissure to count as
#: open: the search finds one round the three open eyes above at 8 deg, none round a lid laid
#: smooth over the eye at 6 deg, nor round ``id331_blink``'s eyes at 8 deg
LOWER_FOLD_DEG = 8.0
RES_MM = 0.25
HALF_MM = 14.0


def _frame(V, F, c, reach=15.0):
    """(3, 3) rows x, up, out: ``out`` the area-weighted mean normal of the faces (facing +Z)
    within ``reach`` of ``c``, ``up`` +Y made perpendicular to it."""
    T = V[F]
    near = np.linalg.norm(T.mean(axis=1) - c, axis=1) < reach
    N = np.cross(T[near, 1] - T[near, 0], T[near, 2] - T[near, 0])
    N = N[N[:, 2] > 0].sum(axis=0)
    n = N / np.linalg.norm(N)
    up = np.array([0.0, 1.0, 0.0]) - n[1] * n
    up /= np.linalg.norm(up)
    return np.stack([np.cross(up, n), up, n])


def _height_field(V, F, c, R, half, res):
    """The front-most surface's height along ``R[2]`` on a grid of ``(x, y)`` round ``c``
    (rows y, columns x), NaN where no face lies."""
    P = (np.asarray(V, float) - c) @ R.T
    T = P[np.asarray(F)]
    lo, hi = T.min(axis=1), T.max(axis=1)
    T = T[(hi[:, 0] > -half) & (lo[:, 0] < half) & (hi[:, 1] > -half) & (lo[:, 1] < half) & (hi[:, 2] > -25.0)]
    n = int(round(2 * half / res)) + 1
    g = np.linspace(-half, half, n)
    Z = np.full((n, n), -np.inf)
    for (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) in T:
        ix0 = max(int(np.ceil((min(x0, x1, x2) + half) / res)), 0)
        ix1 = min(int(np.floor((max(x0, x1, x2) + half) / res)), n - 1)
        iy0 = max(int(np.ceil((min(y0, y1, y2) + half) / res)), 0)
        iy1 = min(int(np.floor((max(y0, y1, y2) + half) / res)), n - 1)
        det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if ix1 < ix0 or iy1 < iy0 or abs(det) < 1e-12:
            continue
        X, Y = np.meshgrid(g[ix0:ix1 + 1], g[iy0:iy1 + 1])
        a = ((y1 - y2) * (X - x2) + (x2 - x1) * (Y - y2)) / det
        b = ((y2 - y0) * (X - x2) + (x0 - x2) * (Y - y2)) / det
        inside = (a >= -1e-9) & (b >= -1e-9) & (1.0 - a - b >= -1e-9)
        sub = Z[iy0:iy1 + 1, ix0:ix1 + 1]
        np.maximum(sub, np.where(inside, a * z0 + b * z1 + (1.0 - a - b) * z2, -np.inf), out=sub)
    Z[~np.isfinite(Z)] = np.nan
    return g, Z


def fissure_depth(V, F, c, smooth_mm=1.0, valley_mm=6.0, half_width_mm=5.0, reach_mm=7.0) -> float:
    """Median over the vertical lines within ``half_width_mm`` of ``c`` of the deepest horizontal
    valley narrower than ``valley_mm`` within ``reach_mm`` above or below (mm; module doc).

    Parameters
    ----------
    V : (n, 3) float, mm, head frame (+Y up, +Z forward)
    F : (m, 3) int
    c : (3,) the centre, mm
    """
    from scipy import ndimage

    c = np.asarray(c, float)
    R = _frame(np.asarray(V, float), np.asarray(F), c)
    g, Z = _height_field(V, F, c, R, HALF_MM, RES_MM)
    ok = np.isfinite(Z)
    s = smooth_mm / RES_MM
    Zs = ndimage.gaussian_filter(np.where(ok, Z, 0.0), s) / np.maximum(ndimage.gaussian_filter(ok * 1.0, s), 1e-6)
    valley = ndimage.grey_closing(Zs, size=(int(valley_mm / RES_MM) | 1, 1)) - Zs
    X, Y = np.meshgrid(g, g)
    window = (np.abs(X) < half_width_mm) & (np.abs(Y) < reach_mm) & ok
    return float(np.median(np.where(window, valley, 0.0).max(axis=0)[np.abs(g) < half_width_mm]))


def fissure_depth_ring(V, F, hint, ring_mm=2.5, n=8) -> float:
    """Median of :func:`fissure_depth` at ``n`` points on a ``ring_mm`` circle round ``hint`` in
    the head's x-y plane (mm)."""
    hint = np.asarray(hint, float)
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return float(np.median([fissure_depth(V, F, hint + ring_mm * np.array([np.cos(t), np.sin(t), 0.0]))
                            for t in a]))
