"""A scanline rasteriser of triangles: which points of a grid the triangles cover.

Each triangle crossing a row covers one exact x-interval of it (:func:`row_spans`); a row's
intervals are merged (sorted, running maximum; gaps below ``tol``, rounding between triangles
sharing an edge, are closed: :func:`merged_spans`), and a grid point is covered when a merged
interval of its row holds it (:func:`covered_points`). The render's frame test
(:mod:`pipeline.render.coverage`) and the rig's look at what the lids leave open
(:mod:`pipeline.geometry.opening`) both rasterise with it. Units are the caller's (pixels there,
mm here); ``tol`` is in the same units.
"""

from __future__ import annotations

import numpy as np

#: Gaps between a row's intervals up to this are closed (rounding between triangles sharing an edge).
GAP_TOL_PX = 0.01


def row_spans(tri_px, ys):
    """Where each row crosses each triangle.

    Parameters
    ----------
    tri_px : (T, 3, 2) float  triangle corners in pixels (u right, v down)
    ys : (R,) float           row positions, ascending and evenly spaced

    Returns
    -------
    rows (P,) int64, lo (P,) float, hi (P,) float: row ``rows[k]`` is covered on
    ``[lo[k], hi[k]]`` by one triangle (one entry per crossing triangle and row).
    """
    T = np.asarray(tri_px, np.float64).reshape(-1, 3, 2)
    ys = np.asarray(ys, np.float64)
    if len(T) == 0 or len(ys) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    y0 = ys[0]
    step = ys[1] - ys[0] if len(ys) > 1 else 1.0
    v = T[:, :, 1]
    kmin = np.maximum(np.ceil((v.min(1) - y0) / step - 1e-9), 0).astype(np.int64)
    kmax = np.minimum(np.floor((v.max(1) - y0) / step + 1e-9), len(ys) - 1).astype(np.int64)
    n = np.maximum(kmax - kmin + 1, 0)
    tri = np.repeat(np.arange(len(T)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    rows = kmin[tri] + (np.arange(len(tri)) - first)
    y = ys[rows]
    lo = np.full(len(tri), np.inf)
    hi = np.full(len(tri), -np.inf)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        pa, pb = T[tri, a], T[tri, b]
        ya, yb = pa[:, 1], pb[:, 1]
        lo_y, hi_y = np.minimum(ya, yb), np.maximum(ya, yb)
        dy = yb - ya
        ok = (lo_y <= y) & (y <= hi_y) & (dy != 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = pa[:, 0] + (y - ya) / dy * (pb[:, 0] - pa[:, 0])
        x = np.where(ok, x, np.nan)
        lo = np.fmin(lo, x)
        hi = np.fmax(hi, x)
        flat = (dy == 0) & (ya == y)          # an edge lying on the row: both ends
        lo = np.where(flat, np.fmin(lo, np.minimum(pa[:, 0], pb[:, 0])), lo)
        hi = np.where(flat, np.fmax(hi, np.maximum(pa[:, 0], pb[:, 0])), hi)
    keep = np.isfinite(lo) & np.isfinite(hi)
    return rows[keep], lo[keep], hi[keep]


def merged_spans(rows, lo, hi, x0: float, x1: float, tol: float = GAP_TOL_PX):
    """The union of each row's intervals, clipped to ``[x0, x1]``.

    Parameters
    ----------
    rows (P,) int, lo (P,), hi (P,)   from :func:`row_spans`
    x0, x1 : float                    the region's x range
    tol : float                       gaps up to this are closed

    Returns
    -------
    rows (M,) int64, lo (M,), hi (M,): disjoint merged intervals, sorted by row then x.
    """
    rows = np.asarray(rows, np.int64)
    lo = np.clip(np.asarray(lo, np.float64), x0, x1) - x0
    hi = np.clip(np.asarray(hi, np.float64), x0, x1) - x0
    if len(rows) == 0:
        return rows, lo, hi
    big = 2.0 * (x1 - x0) + 4.0 * tol + 1.0          # rows apart on one axis: r * big + x
    order = np.lexsort((lo, rows))
    rows, lo, hi = rows[order], lo[order], hi[order]
    klo, khi = rows * big + lo, rows * big + hi
    run = np.maximum.accumulate(khi)
    new = np.ones(len(rows), bool)
    new[1:] = (rows[1:] != rows[:-1]) | (klo[1:] > run[:-1] + tol)
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], len(rows)) - 1
    r = rows[starts]
    return r, klo[starts] - r * big + x0, run[ends] - r * big + x0


def covered_points(tri_px, xs, ys, tol: float = GAP_TOL_PX) -> np.ndarray:
    """(len(ys), len(xs)) bool: which grid points ``(xs[j], ys[i])`` the triangles cover
    (``ys`` ascending, evenly spaced; ``xs`` ascending)."""
    xs, ys = np.asarray(xs, np.float64), np.asarray(ys, np.float64)
    x0, x1 = float(xs[0]) - 1.0, float(xs[-1]) + 1.0
    r, lo, hi = merged_spans(*row_spans(tri_px, ys), x0, x1, tol)
    if len(r) == 0:                      # no triangle crosses a row
        return np.zeros((len(ys), len(xs)), bool)
    big = 2.0 * (x1 - x0) + 1.0
    klo = r * big + (lo - x0)
    khi = r * big + (hi - x0)
    key = np.arange(len(ys))[:, None] * big + (xs[None, :] - x0)
    i = np.searchsorted(klo, key.ravel(), side="right") - 1
    ok = i >= 0
    ic = np.clip(i, 0, None)
    hit = ok & (r[ic] == np.repeat(np.arange(len(ys)), len(xs))) & (khi[ic] >= key.ravel() - 1e-12)
    return hit.reshape(len(ys), len(xs))
