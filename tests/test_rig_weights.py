"""The pitch-to-weight rule of the lid blend shapes and its shape-key expansion (pipeline/rig/lids.py)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.rig import lids
from pipeline.rig.eye_frame import EyeFrame, rotate_about_axis


def test_weight_rule_extremes_and_clamping():
    assert lids.lid_weights(0.0) == {"lids_up": 0.0, "lids_down": 0.0}
    assert lids.lid_weights(25.0) == {"lids_up": 1.0, "lids_down": 0.0}
    assert lids.lid_weights(-25.0) == {"lids_up": 0.0, "lids_down": 1.0}
    assert lids.lid_weights(12.5)["lids_up"] == pytest.approx(0.5)
    assert lids.lid_weights(40.0) == {"lids_up": 1.0, "lids_down": 0.0}
    assert lids.lid_weights(-90.0) == {"lids_up": 0.0, "lids_down": 1.0}
    assert lids.lid_weights(10.0, max_pitch_deg=20.0)["lids_up"] == pytest.approx(0.5)
    for p in np.linspace(-30, 30, 61):
        w = lids.lid_weights(p)
        assert 0.0 <= w["lids_up"] <= 1.0 and 0.0 <= w["lids_down"] <= 1.0
        assert w["lids_up"] * w["lids_down"] == 0.0
    with pytest.raises(ValueError, match="pitch must be finite, got nan"):
        lids.lid_weights(float("nan"))
    with pytest.raises(ValueError, match="max_pitch_deg must be positive, got 0.0"):
        lids.lid_weights(10.0, max_pitch_deg=0.0)


def test_flat_shape_keys_reproduce_inbetween_evaluation(region):
    V, F, eyes, rig = region
    assert rig.n_segments >= 2  # 25 deg on a 12 mm eye needs inbetweens
    for p in (-25.0, -17.3, -8.0, 0.0, 3.0, 12.5, 24.9, 25.0):
        flat = lids.flat_shape_weights(rig.shapes, lids.lid_weights(p))
        P = V.copy()
        for s in rig.shapes:
            poses = list(s.inbetween_offsets) + [s.offsets]
            for name, off in zip(s.inbetween_names() + [s.name], poses):
                P[s.point_indices] += flat[name] * off
        np.testing.assert_allclose(P, lids.evaluate_shapes(V, rig.shapes, lids.lid_weights(p)),
                                   atol=1e-12)
    # hat weights: exactly one pose at the sample weights
    s = rig.shape("lids_up")
    for j, w in enumerate(s.inbetween_weights):
        sub = lids.subshape_weights(s, w)
        assert sub[j] == pytest.approx(1.0) and sub.sum() == pytest.approx(1.0)


def test_pitch_from_gaze_matches_eye_rotation():
    f = np.array([0.1366, 0.0117, 0.9906])
    f /= np.linalg.norm(f)
    eye = EyeFrame("left", np.zeros(3), 15.0, f, np.arange(8), 4)
    for p in (-25.0, -7.0, 0.0, 13.0, 25.0):
        g = rotate_about_axis(f[None], np.zeros(3), eye.axis, np.radians(p))[0]
        assert lids.pitch_from_gaze(g, f) == pytest.approx(p, abs=1e-9)
    # pure yaw does not change the pitch
    yaw = np.radians(20.0)
    g = np.array([np.sin(yaw), 0.0, np.cos(yaw)])
    assert lids.pitch_from_gaze(g, [0, 0, 1]) == pytest.approx(0.0, abs=1e-12)
