"""What the lids leave open, seen along one direction (pipeline/geometry/opening.py): known answers
for the polygon and hull helpers, the notch of a region and of a skin triangle poking into a hole."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry.opening import (convex_hull, inside_polygon_grid, largest_component, opening_notch, polygon_notch,
                                       region_shape)


def test_inside_polygon_grid_fills_a_concave_polygon_by_the_even_odd_rule():
    """An L of three 1 mm squares: the grid points inside it and nowhere else (points off the
    edges; the notch's square stays empty)."""
    L = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    xs = ys = np.arange(0.25, 2.0, 0.5)
    got = inside_polygon_grid(xs, ys, L)
    gx, gy = np.meshgrid(xs, ys)
    assert np.array_equal(got, (gx < 1) | (gy < 1))
    assert np.array_equal(inside_polygon_grid(xs, ys, L[::-1]), got)        # either orientation


def test_convex_hull_known_answers():
    """A square's corners with points inside and on its edges: the four corners, counter-clockwise;
    fewer than three distinct points come back as they are."""
    P = np.array([[0, 0], [4, 0], [4, 4], [0, 4], [2, 2], [2, 0], [1, 3], [4, 2]], float)
    H = convex_hull(P)
    assert sorted(map(tuple, H)) == [(0, 0), (0, 4), (4, 0), (4, 4)]
    assert 0.5 * (np.dot(H[:, 0], np.roll(H[:, 1], -1)) - np.dot(H[:, 1], np.roll(H[:, 0], -1))) == 16.0
    assert len(convex_hull(np.array([[1.0, 1.0], [1.0, 1.0], [2.0, 2.0]]))) == 2


def test_largest_component_keeps_the_biggest_4_connected_part():
    m = np.zeros((6, 8), bool)
    m[0:2, 0:2] = True                      # 4 cells
    m[3:6, 3:8] = True                      # 15 cells
    m[2, 2] = True                          # touches the first only diagonally
    got = largest_component(m)
    assert got.sum() == 15 and got[3:6, 3:8].all()
    assert not largest_component(np.zeros((3, 3), bool)).any()


def test_region_shape_reads_a_notch_by_its_depth():
    """Known answers: a 20 x 10 rectangle is convex (solidity 1, no notch); with a 1 mm wide slot
    cut 3 mm into it from its top edge, the notch is 3 mm deep and the solidity 1 - 3 / 200; a
    spike of the border poking in is read the same way, whatever its width."""
    step = 0.05
    xs, ys = np.arange(-12.0, 12.0, step), np.arange(-7.0, 7.0, step)
    gx, gy = np.meshgrid(xs, ys)
    rect = (np.abs(gx) <= 10.0) & (np.abs(gy) <= 5.0)
    solidity, depth = region_shape(rect, xs, ys)
    assert solidity == pytest.approx(1.0, abs=0.01) and depth < step
    slot = rect & ~((np.abs(gx - 2.0) < 0.5) & (gy > 2.0))
    solidity, depth = region_shape(slot, xs, ys)
    assert depth == pytest.approx(3.0, abs=2 * step)
    assert solidity == pytest.approx(1.0 - 3.0 / 200.0, abs=0.01)
    spike = rect & ~((np.abs(gx + 4.0) < 0.1 + 0.2 * (5.0 - gy)) & (gy > 1.0))     # a wedge 4 mm long
    assert region_shape(spike, xs, ys)[1] == pytest.approx(4.0, abs=2 * step)


def _holed_sheet(step=5.0, half=20.0, hole=10.0):
    """A flat sheet z = 0 of ``step`` mm squares over [-half, half]^2 cut in two triangles each, the
    faces inside the square [-hole, hole]^2 removed; the hole's boundary as an ordered loop."""
    n = int(round(2 * half / step)) + 1
    g = np.linspace(-half, half, n)
    X, Y = np.meshgrid(g, g)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(n * n)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    inside = np.all(np.abs(V[F][:, :, :2].mean(axis=1)) < hole, axis=1)
    k = int(round((half - hole) / step))
    ring = ([idx[k, j] for j in range(k, n - k)] + [idx[i, n - k - 1] for i in range(k + 1, n - k)]
            + [idx[n - k - 1, j] for j in range(n - k - 2, k - 1, -1)] + [idx[i, k] for i in range(n - k - 2, k, -1)])
    return V, F, inside, np.array(ring)


def test_a_square_hole_is_open_and_a_triangle_poking_into_it_is_a_notch_of_its_depth():
    V, F, inside, loop = _holed_sheet()
    solidity, notch = opening_notch(V, F[~inside], loop, (0.0, 0.0, 1.0))
    assert solidity == pytest.approx(1.0, abs=0.02) and notch < 0.15
    assert opening_notch(V, F, loop, (0.0, 0.0, 1.0)) == (0.0, 0.0)          # nothing open
    # one triangle inside with an edge on the middle of the hole's top edge: it pokes 5 mm in
    top = np.isclose(V[F][:, :, 1], 10.0).sum(axis=1) == 2
    mid = np.abs(V[F][:, :, 0].mean(axis=1)) < 3.0
    keep = np.flatnonzero(inside & top & mid)[:1]
    solidity, notch = opening_notch(V, np.concatenate([F[~inside], F[keep]]), loop, (0.0, 0.0, 1.0))
    assert notch == pytest.approx(5.0, abs=0.15) and solidity < 0.99
    # the same sheet seen from behind, and in metres: the same notch, scaled
    assert opening_notch(V, np.concatenate([F[~inside], F[keep]]), loop, (0.0, 0.0, -1.0))[1] == pytest.approx(notch, abs=0.15)
    assert opening_notch(V / 1000.0, np.concatenate([F[~inside], F[keep]]), loop, (0.0, 0.0, 1.0),
                         step_mm=1e-4)[1] == pytest.approx(notch / 1000.0, abs=2e-4)


def test_degenerate_openings_read_as_nothing_open():
    """A loop collapsed to a point, one on a line, and one smaller than the grid step: nothing
    open, no error; a finite figure for a loop with a repeated vertex."""
    V, F, inside, loop = _holed_sheet()
    F = F[~inside]
    for P in (np.zeros((4, 3)), np.column_stack([np.linspace(-1, 1, 4), np.zeros(4), np.zeros(4)]),
              0.01 * np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)):
        V2 = np.vstack([V, P])
        assert opening_notch(V2, F, np.arange(len(V), len(V2)), (0.0, 0.0, 1.0)) == (0.0, 0.0)
    solidity, notch = opening_notch(V, F, np.concatenate([loop, loop[:1]]), (0.0, 0.0, 1.0))
    assert solidity == pytest.approx(1.0, abs=0.02) and notch < 0.15


def test_covered_points_with_no_triangle_on_any_row_covers_nothing():
    from pipeline.geometry.raster import covered_points

    xs, ys = np.arange(0.0, 5.0, 1.0), np.arange(0.0, 3.0, 1.0)
    assert not covered_points(np.zeros((0, 3, 2)), xs, ys).any()
    above = np.array([[[0.0, 10.0], [4.0, 10.0], [2.0, 12.0]]])      # wholly above the rows
    assert covered_points(above, xs, ys).shape == (3, 5) and not covered_points(above, xs, ys).any()
    assert covered_points(np.array([[[-1.0, -1.0], [9.0, -1.0], [-1.0, 9.0]]]), xs, ys)[0].all()


def test_polygon_notch_known_answers():
    square = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]])
    assert polygon_notch(square) == 0.0
    assert polygon_notch(square[::-1]) == 0.0                    # either winding
    # a V cut 1.5 mm down into the top edge, at its middle
    notched = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [2.0, 2.5], [0.0, 4.0]])
    assert polygon_notch(notched) == pytest.approx(1.5)
    assert polygon_notch(notched * 10.0) == pytest.approx(15.0)   # in the polygon's units
    # collinear or too few points: nothing to judge
    assert polygon_notch(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])) == 0.0
    assert polygon_notch(np.zeros((2, 2))) == 0.0
