"""pipeline/placement/lid_fissure.py: the depth of a lid fissure across an opening, known answers
on height fields: a Gaussian groove, a globe's bulge, a tilted face, a coarse grid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.placement.lid_fissure import OPEN_BELOW_MM, fissure_depth, fissure_depth_ring


def _surface(z, step=0.5, half=24.0, tilt_deg=0.0):
    """A height field ``z(x, y)`` (mm, +Z forward) as a triangle mesh on a ``step`` grid, turned
    by ``tilt_deg`` about the head's x axis (a face looking up); (V, F)."""
    g = np.arange(-half, half + step / 2, step)
    X, Y = np.meshgrid(g, g)
    V = np.column_stack([X.ravel(), Y.ravel(), z(X, Y).ravel()])
    n = len(g)
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    F = np.concatenate([np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])])
    t = math.radians(tilt_deg)
    R = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(t), -math.sin(t)], [0.0, math.sin(t), math.cos(t)]])
    return V @ R.T, F


def _groove(depth, sigma=1.0):
    """Two lids meeting in a horizontal fissure: a Gaussian valley along x, ``depth`` deep."""
    return lambda X, Y: -depth * np.exp(-Y ** 2 / (2 * sigma ** 2))


def _globe(X, Y, r=12.0, stand=3.0):
    """The front of a 12 mm globe standing ``stand`` mm out of a flat face: one smooth hump."""
    return np.maximum(np.sqrt(np.maximum(r ** 2 - X ** 2 - Y ** 2, 0.0)) - (r - stand), 0.0)


@pytest.mark.parametrize("depth", [0.3, 0.6, 1.2])
def test_a_fissure_reads_as_its_depth_after_the_1mm_smoothing(depth):
    """A Gaussian groove of sigma 1 mm, smoothed by the 1 mm Gaussian, is one of sigma sqrt(2) mm
    and 1/sqrt(2) of the depth; the 6 mm closing fills it up to its height 3 mm off the middle."""
    V, F = _surface(_groove(depth))
    got = fissure_depth(V, F, [0.0, 0.0, -depth])
    assert got == pytest.approx(depth / math.sqrt(2.0) * (1.0 - math.exp(-3.0 ** 2 / 4.0)), rel=0.03)
    assert fissure_depth_ring(V, F, [0.0, 0.0, -depth]) == pytest.approx(got, rel=0.05)


def test_a_bulging_globe_and_a_flat_face_show_no_fissure():
    V, F = _surface(_globe)
    assert fissure_depth_ring(V, F, [0.0, 0.0, 3.0]) < 0.01 < OPEN_BELOW_MM
    V, F = _surface(lambda X, Y: 0.0 * X)
    assert fissure_depth_ring(V, F, [0.0, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-9)


def test_a_valley_wider_than_a_fissure_is_not_one():
    """A 6 mm closing fills valleys narrower than 6 mm only: the bowl of an open eye recessed
    between wide lids (sigma 4 mm) reads far shallower than its 1 mm depth."""
    V, F = _surface(_groove(1.0, sigma=4.0))
    assert fissure_depth(V, F, [0.0, 0.0, -1.0]) < 0.25


def test_the_depth_is_taken_across_the_face_however_it_is_turned_and_meshed():
    """The frame follows the surface's mean normal: the fissure of a face looking 20 deg up
    reads the same; and a 1.2 mm grid (a 150k-face head) as the 0.5 mm one."""
    V, F = _surface(_groove(0.6))
    flat = fissure_depth(V, F, [0.0, 0.0, -0.6])
    Vt, Ft = _surface(_groove(0.6), tilt_deg=20.0)
    c = np.array([0.0, 0.6 * math.sin(math.radians(20.0)), -0.6 * math.cos(math.radians(20.0))])
    assert fissure_depth(Vt, Ft, c) == pytest.approx(flat, rel=0.05)
    Vc, Fc = _surface(_groove(0.6), step=1.2)
    assert fissure_depth(Vc, Fc, [0.0, 0.0, -0.6]) == pytest.approx(flat, rel=0.1)
