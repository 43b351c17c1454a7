"""Framing that keeps the eye (issue 33): in ``generic`` and ``targeted`` every landmark and the
whole iris ring lie at least ``frame_margin_px`` inside the image, on the extremes of each
preset's draws (largest camera polar angle in four azimuths, largest gaze offsets, the
framing shift in each corner, the narrowest scale); only the framing moves.

The small constructed asset of fixtures.make_render_asset, sampled without Blender.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fixtures import make_render_asset
from pipeline.render import asset as ra
from pipeline.render import sampling as sp
from pipeline.render.settings import RenderSettings


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("framing"))
    return ra.load_render_asset(made["asset_dir"], made["rig_dir"])


def _margin(smp, s) -> float:
    """The smallest distance (px) of a landmark or an iris ring point to the image border."""
    P = sp.framing_points(smp.landmarks_cam)
    uv = smp.spec.camera.project(P, s.width, s.height)
    return float(np.min([uv[:, 0], s.width - uv[:, 0], uv[:, 1], s.height - uv[:, 1]]))


def _extremes(s):
    g = s.gaze_offset_max_deg - s.gaze_offset_max_deg % s.gaze_step_deg
    for side, az, dp, dy, jx, jy in itertools.product(s.eyes, (0.0, 90.0, 180.0, 270.0), (-g, g), (-g, g),
                                                      (-1, 1), (-1, 1)):
        yield {"side": side, "polar_deg": s.camera_polar_max_deg, "azimuth_deg": az,
               "gaze_offset_deg": [dp, dy], "jitter": np.array([jx, jy]) * s.center_jitter_mm,
               "ortho_scale_mm": s.ortho_scale_mm[0]}


@pytest.mark.parametrize("preset", ["generic", "targeted"])
def test_the_whole_eye_stays_inside_on_the_presets_extremes(tiny, preset):
    # the fixture's eye opening is 20 mm tall: the narrowest 120 x 80 frame (30 x 20 mm) must widen
    s = RenderSettings.from_params({"preset": preset})
    assert s.frame_margin_px == 3.0
    loose = RenderSettings.from_params({"preset": preset, "frame_margin_px": None})
    moved = 0
    for o in _extremes(s):
        smp = sp.pose_sample(tiny, s, 0, 0, "/x.png", overrides=o)
        raw = sp.pose_sample(tiny, loose, 0, 0, "/x.png", overrides=o)
        assert _margin(smp, s) >= 3.0 - 1e-9
        assert s.ortho_scale_mm[0] <= smp.camera["ortho_scale_mm"] <= s.ortho_scale_mm[1]
        # only the framing moved: camera direction, gaze and eyelids are the draw's own
        np.testing.assert_allclose(np.asarray(smp.camera["world_to_camera"])[:3, :3],
                                   np.asarray(raw.camera["world_to_camera"])[:3, :3], atol=1e-12)
        for sd in smp.gaze:
            np.testing.assert_array_equal(smp.gaze[sd]["vector_head"], raw.gaze[sd]["vector_head"])
        assert smp.spec.lid_weights == raw.spec.lid_weights and smp.spec.eyeball == raw.spec.eyeball
        moved += _margin(raw, loose) < 3.0
    assert moved > 0                    # the extremes did need the framing


def test_sampled_images_keep_the_eye_and_an_unset_margin_keeps_the_draw(tiny):
    s = RenderSettings.from_params({"preset": "generic"})
    for i in range(40):
        smp = sp.make_sample(tiny, s, i, "/x.png", cover=False)
        assert _margin(smp, s) >= 3.0 - 1e-9
    # frame_margin_px: null is the draw as it was (and leaves the config hash as it was)
    loose = RenderSettings.from_params({"preset": "generic", "frame_margin_px": None})
    assert "frame_margin_px" not in loose.hashed() and "frame_margin_px" in s.hashed()
    smp = sp.pose_sample(tiny, loose, 3, 0, "/x.png")
    assert np.array_equal(smp.camera["jitter_mm"], sp.pose_sample(tiny, loose, 3, 0, "/x.png").camera["jitter_mm"])


def test_an_eye_too_wide_for_the_widest_frame_is_drawn_again_then_named(tiny):
    s = RenderSettings.from_params({"preset": "generic", "ortho_scale_mm": [4.0, 5.0], "max_attempts": 3})
    with pytest.raises(sp.FramingError):
        sp.pose_sample(tiny, s, 0, 0, "/x.png")
    with pytest.raises(sp.RejectionError, match="the eye wider than the widest framing in 3"):
        sp.make_sample(tiny, s, 0, "/x.png", cover=False)


def test_the_margin_is_not_used_where_the_framing_is_fixed():
    """A pinhole camera and GazeML's framing (iris_distance_px) keep their own framing, and their
    config hash (pipeline/render/settings.py frames_the_eye)."""
    for params in ({"preset": "webcam", "frame_margin_px": 3.0}, {"preset": "unityeyes", "frame_margin_px": 3.0},
                   {"preset": "generic", "camera": "pinhole", "focal_px": 900.0}):
        s = RenderSettings.from_params(params)
        assert not s.frames_the_eye() and "frame_margin_px" not in s.hashed()
    assert RenderSettings.from_params({"preset": "unityeyes"}).frame_margin_px is None
