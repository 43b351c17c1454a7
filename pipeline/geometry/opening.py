"""What the lids leave open of an eye, seen along one direction, and how jagged its outline is.

Seen from the head's front, the part of the lid loop's polygon that no skin triangle covers is
the opening a render shows. An almond fissure is near convex; a lid spiked, toothed or split
where the band meets the margin cuts notches into it. :func:`opening_notch` rasterises the skin
orthographically (:mod:`pipeline.geometry.raster`), takes the largest uncovered part of the
polygon and measures it (:func:`region_shape`): its solidity (area over its convex hull's) and
its deepest notch, the greatest distance of a hull point outside it from the hull's border. A
notch deeper than :data:`JAGGED_LID_MM` is a jagged lid (the rig stage warns of it; the
benchmark ``bench_see_through`` counts it over the held-out assets).
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.geometry.raster import covered_points

# a notch this deep (mm) in what the lids leave open, seen from the front, is a jagged lid: 3-4
# pixels of a default render. The 96 held-out eyes (benchmarks/results/lid_shape.json): median
# 0.5 mm; the lid flaps the previews show (id309_squint_up, id304_in) 2.0-2.1, the toothed lower
# lids id302_up had before snap faded its choices 2.1; a clean almond 0.0-0.5 (synthetic_head)
JAGGED_LID_MM = 1.0


def inside_polygon_grid(xs, ys, poly) -> np.ndarray:
    """(len(ys), len(xs)) bool: which grid points ``(xs[j], ys[i])`` lie inside the closed polygon
    ``poly`` (m, 2), by the even-odd rule row by row (a point is inside when an odd number of the
    polygon's edges cross its row to its left)."""
    xs, ys = np.asarray(xs, np.float64), np.asarray(ys, np.float64)
    a = np.asarray(poly, np.float64)
    b = np.roll(a, -1, axis=0)
    y = ys[:, None]
    straddle = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[None, :, 0] + (y - a[None, :, 1]) / (b[None, :, 1] - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0])
    xc = np.sort(np.where(straddle, xc, np.inf), axis=1)
    left = np.stack([np.searchsorted(row, xs, side="right") for row in xc])
    return (left % 2) == 1


def convex_hull(P) -> np.ndarray:
    """(h, 2) the convex hull of the points ``P`` (n, 2), counter-clockwise, without collinear
    points (Andrew's monotone chain; fewer than 3 distinct points: those points)."""
    pts = [tuple(p) for p in np.unique(np.asarray(P, np.float64), axis=0)]
    if len(pts) < 3:
        return np.asarray(pts, np.float64).reshape(-1, 2)

    def chain(seq):
        out = []
        for x, y in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (y - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (x - out[-2][0])) <= 0:
                out.pop()
            out.append((x, y))
        return out

    return np.asarray(chain(pts)[:-1] + chain(pts[::-1])[:-1], np.float64)


def polygon_notch(P) -> float:
    """The deepest notch (units of ``P``) of the closed polygon ``P`` (n, 2): the greatest
    distance of a vertex inside the polygon's convex hull from the hull's border (0 for a convex
    polygon; fewer than 3 distinct points: 0)."""
    P = np.asarray(P, np.float64)
    H = convex_hull(P)
    if len(H) < 3:
        return 0.0
    # every vertex lies in the hull, so its distance to the hull's border is how deep inside it is
    return float(closed_polyline_distance(P, H).max())


def largest_component(mask: np.ndarray) -> np.ndarray:
    """The largest 4-connected part of the bool image ``mask`` (all False when it is empty)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ids = -np.ones(mask.shape, np.int64)
    ids[mask] = np.arange(int(mask.sum()))
    if not mask.any():
        return mask.copy()
    right = mask[:, :-1] & mask[:, 1:]
    down = mask[:-1, :] & mask[1:, :]
    a = np.concatenate([ids[:, :-1][right], ids[:-1, :][down]])
    b = np.concatenate([ids[:, 1:][right], ids[1:, :][down]])
    n = int(mask.sum())
    _, lab = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    out = np.zeros_like(mask)
    out[mask] = lab == np.argmax(np.bincount(lab))
    return out


def region_shape(region: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> tuple[float, float]:
    """(solidity, concavity) of the bool image ``region`` (rows ``ys``, columns ``xs``, evenly
    spaced): its area over its convex hull's, and the depth of its deepest concavity, the
    greatest distance from the hull's border of a hull point outside the region (units of
    ``xs``). A convex region gives (1, 0) up to a pixel; a notch cut into it, its depth."""
    region = np.asarray(region, bool)
    if len(xs) < 2 or len(ys) < 2:
        return 0.0, 0.0
    gx, gy = np.meshgrid(xs, ys)
    # the hull of the region is its border's: the points without all four neighbours inside
    pad = np.pad(region, 1)
    inner = pad[1:-1, 1:-1] & pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:]
    edge = region & ~inner
    H = convex_hull(np.column_stack([gx[edge], gy[edge]]))
    area = 0.5 * abs(float(np.dot(H[:, 0], np.roll(H[:, 1], -1)) - np.dot(H[:, 1], np.roll(H[:, 0], -1)))) if len(H) >= 3 else 0.0
    if area <= 0.0:
        return 0.0, 0.0
    dx, dy = float(xs[1] - xs[0]), float(ys[1] - ys[0])
    in_hull = inside_polygon_grid(xs, ys, H)
    gap = np.column_stack([gx[in_hull & ~region], gy[in_hull & ~region]])
    depth = float(closed_polyline_distance(gap, H).max()) if len(gap) else 0.0
    return float(region.sum()) * dx * dy / area, depth


def opening_notch(V, F, loop, towards, up=(0.0, 1.0, 0.0), step_mm: float = 0.1) -> tuple[float, float]:
    """(solidity, deepest notch in mm) of what the skin ``(V, F)`` leaves open of the polygon of
    the lid loop ``loop`` (L,) vertex ids, seen orthographically along ``-towards`` (unit (3,),
    from the eye toward the viewer) with ``up`` upward: the largest part of the polygon that no
    triangle covers, on a grid ``step_mm`` apart (:func:`region_shape`). (0, 0) when nothing of
    the polygon is open."""
    w = np.asarray(towards, np.float64)
    w = w / np.linalg.norm(w)
    u = np.cross(np.asarray(up, np.float64), w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    V = np.asarray(V, np.float64)
    uv = np.column_stack([V @ u, V @ v])
    poly = uv[np.asarray(loop, np.int64)]
    (x0, y0), (x1, y1) = poly.min(axis=0), poly.max(axis=0)
    xs = np.arange(x0, x1 + step_mm, step_mm)
    ys = np.arange(y0, y1 + step_mm, step_mm)
    if len(xs) < 3 or len(ys) < 3:         # a loop smaller than the grid: nothing to judge
        return 0.0, 0.0
    T = uv[np.asarray(F, np.int64)]
    # only triangles over the polygon's box can cover a point of it
    near = (T[:, :, 0].max(1) >= x0) & (T[:, :, 0].min(1) <= x1) & (T[:, :, 1].max(1) >= y0) & (T[:, :, 1].min(1) <= y1)
    # gaps under a hundredth of the grid step closed (rounding between triangles sharing an edge)
    open_ = inside_polygon_grid(xs, ys, poly) & ~covered_points(T[near], xs, ys, tol=0.01 * step_mm)
    if not open_.any():
        return 0.0, 0.0
    return region_shape(largest_component(open_), xs, ys)
