"""The one camera type (pipeline/render/camera.py ``Camera``, issue 34): its wire layout, the label
blocks it reads, and the errors that name what is wrong. Known answers, no asset, no Blender."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.render.camera import Camera, intrinsics, opencv_pixel_K

W2C = [[1.0, 0.0, 0.0, -1.5], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, -100.0], [0.0, 0.0, 0.0, 1.0]]
K = [[500.0, 0.0, 60.0], [0.0, 500.0, 40.0], [0.0, 0.0, 1.0]]


def test_the_wire_layout_is_todays_bytes_and_round_trips():
    ortho, pinhole = Camera(W2C, 32.0), Camera(W2C, K=K)
    # the worker spec's camera, byte for byte (its JSON is part of every job line)
    assert json.dumps(ortho.to_dict()) == (
        '{"world_to_camera": [[1.0, 0.0, 0.0, -1.5], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, -100.0], '
        '[0.0, 0.0, 0.0, 1.0]], "ortho_scale_mm": 32.0}')
    assert json.dumps(pinhole.to_dict()) == (
        '{"type": "pinhole", "world_to_camera": [[1.0, 0.0, 0.0, -1.5], [0.0, 1.0, 0.0, 2.0], '
        '[0.0, 0.0, 1.0, -100.0], [0.0, 0.0, 0.0, 1.0]], "K": [[500.0, 0.0, 60.0], [0.0, 500.0, 40.0], '
        '[0.0, 0.0, 1.0]]}')
    for c in (ortho, pinhole):
        assert Camera.from_dict(json.loads(json.dumps(c.to_dict()))) == c
    assert (ortho.kind, pinhole.kind) == ("ortho", "pinhole")
    # arrays are kept as the lists the wire carries
    assert Camera(np.asarray(W2C), K=intrinsics(500.0, 60.0, 40.0)) == pinhole


def test_a_label_camera_block_is_the_same_camera():
    # the keys pipeline/render/labels.py camera_block writes (abridged: extra keys are ignored)
    ortho_block = {"type": "orthographic", "ortho_scale_mm": 32.0, "image_width_mm": 32.0, "image_height_mm": 21.3,
                   "mm_per_px": 0.27, "world_to_camera": W2C, "projection": [[0.0] * 4] * 3,
                   "spherical": {"eye": "left"}, "framing_shift_mm": [0.0, 0.0]}
    pinhole_block = {"type": "pinhole",
                     "intrinsics": {"K": K, "K_pixel_centres_at_integers": opencv_pixel_K(K).tolist(),
                                    "width": 120, "height": 80, "focal_px": 500.0},
                     "sensor": {"K": [[500.0, 0.0, 660.0], [0.0, 500.0, 400.0], [0.0, 0.0, 1.0]]},
                     "opencv": {"R": np.diag([1.0, -1.0, -1.0]).tolist()}, "world_to_camera": W2C,
                     "mm_per_px": 0.2}
    assert Camera.from_dict(ortho_block) == Camera(W2C, 32.0)
    assert Camera.from_dict(pinhole_block) == Camera(W2C, K=K)
    # the intrinsics K, not the sensor's: the label's pixels project through it
    uv = Camera.from_dict(pinhole_block).project([[10.0, 0.0, -100.0]], 120, 80)
    np.testing.assert_allclose(uv, [[110.0, 40.0]], atol=1e-12)


@pytest.mark.parametrize("make, message", [
    (lambda: Camera(W2C, K=[[500.0, 2.0, 60.0], [0.0, 500.0, 40.0], [0.0, 0.0, 1.0]]),
     "camera.K must be [[f, 0, cx], [0, f, cy], [0, 0, 1]] (square pixels, no skew)"),
    (lambda: Camera(W2C, 32.0, K), "camera needs exactly one of ortho_scale_mm and K, got both"),
    (lambda: Camera(W2C), "camera needs exactly one of ortho_scale_mm and K, got neither"),
    (lambda: Camera(W2C, float("inf")), "camera.ortho_scale_mm must be finite"),
    (lambda: Camera(W2C, K=[[float("nan"), 0.0, 60.0], [0.0, 500.0, 40.0], [0.0, 0.0, 1.0]]),
     "camera.K must be 3 x 3 finite numbers"),
    (lambda: Camera([[1.0, 0.0, 0.0, float("nan")]] + W2C[1:], 32.0), "camera.world_to_camera must be 4 x 4 finite"),
    (lambda: Camera(W2C, -1.0), "camera.ortho_scale_mm must be > 0"),
    (lambda: Camera.from_dict({"type": "pinhole", "world_to_camera": W2C}), "camera: a pinhole camera needs K"),
    (lambda: Camera.from_dict({"type": "orthographic", "world_to_camera": W2C, "K": K}),
     "camera: an orthographic camera has no K"),
    (lambda: Camera.from_dict({"ortho_scale_mm": 32.0}), "camera has no world_to_camera"),
    (lambda: Camera.from_dict({"type": "fisheye", "world_to_camera": W2C}), "camera.type 'fisheye' not in"),
])
def test_a_bad_camera_is_one_error_naming_the_problem(make, message):
    with pytest.raises(ValueError) as e:
        make()
    assert str(e.value).startswith(message) and "\n" not in str(e.value)
