"""benchmarks.bench_see_through: the corneal cap it adds to the coverage test, on exact geometry."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.bench_see_through import cornea_cap, view_direction

PARAMS = {"r1": 12.0, "r2": 8.0, "apex": 13.5}


def _eye(scale=1.0):
    return SimpleNamespace(center=np.array([30.0, 30.0, 80.0]), basis=np.eye(3), radius=12.0 * scale,
                           eyeball_params=PARAMS, forward=np.array([0.0, 0.0, 1.0]))


@pytest.mark.parametrize("pitch", [-25.0, 0.0, 25.0])
@pytest.mark.parametrize("scale", [1.0, 11.7 / 12.0])
def test_the_cap_lies_on_the_cornea_outside_the_globe_and_turns_with_the_gaze(pitch, scale):
    eye = _eye(scale)
    T = cornea_cap(eye, pitch)
    P = T.reshape(-1, 3)
    k = scale
    n = np.array([0.0, math.sin(math.radians(pitch)), math.cos(math.radians(pitch))])
    cc = eye.center + k * (PARAMS["apex"] - PARAMS["r2"]) * n
    # every vertex on the corneal sphere, none inside the globe; the rim on the globe itself
    assert np.allclose(np.linalg.norm(P - cc, axis=1), k * PARAMS["r2"], atol=1e-9)
    d = np.linalg.norm(P - eye.center, axis=1)
    assert d.min() == pytest.approx(eye.radius, abs=1e-9)
    # the apex, 13.5 mm (scaled) in front of the centre along the turned gaze
    assert np.max(P @ n - eye.center @ n) == pytest.approx(k * PARAMS["apex"], abs=1e-9)


def test_view_directions_are_unit_and_front_is_the_head_forward():
    assert np.allclose(view_direction(0.0, 0.0), [0.0, 0.0, 1.0])
    for yaw, pitch in ((35.0, 0.0), (-35.0, 0.0), (0.0, 20.0), (0.0, -20.0)):
        v = view_direction(yaw, pitch)
        assert np.linalg.norm(v) == pytest.approx(1.0)
        assert math.degrees(math.acos(v[2])) == pytest.approx(abs(yaw) + abs(pitch))
