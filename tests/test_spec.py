"""RenderSpec (pipeline/render/spec.py): the sampler's spec is what the worker reads back, and a
bad value is refused once, when the spec is read, naming its key."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixtures import make_render_asset
from pipeline.render import sampling as sp
from pipeline.render.asset import load_render_asset
from pipeline.render.settings import RenderSettings
from pipeline.render.spec import RenderSpec


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("spec"))
    asset = load_render_asset(made["asset_dir"], made["rig_dir"])
    return sp.make_sample(asset, RenderSettings(), 3, "/tmp/000003.png").spec


def test_the_wire_layout_round_trips(spec):
    back = RenderSpec.from_json(spec.to_json())
    assert back == spec
    d = json.loads(spec.to_json())
    assert d["samples"] == spec.quality.samples and d["lighting"]["hdri"] == spec.lighting.hdri
    assert "seg_png" not in d and "cycles" not in d           # optional keys only when set
    masked = spec.with_masks("/tmp/a_seg.png", "/tmp/a_depth.exr").with_overrides(cycles={"x": 1}, samples=2)
    d = masked.to_dict()
    assert (d["seg_png"], d["cycles"], d["samples"]) == ("/tmp/a_seg.png", {"x": 1}, 2)
    assert RenderSpec.from_dict(d) == masked


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("camera"), "spec has no 'camera'"),
    (lambda d: d["eyeball"].update(iris_color="purple"), "eyeball.iris_color 'purple' not in"),
    (lambda d: d.update(samples=0), "samples 0 out of range"),
    (lambda d: d.update(png="x.png"), "png 'x.png': an absolute path"),
    (lambda d: d.update(skin_detail="fur"), "skin_detail 'fur' not in"),
    (lambda d: d.update(landmarks_head_mm=[[0, 0, 0]]), "landmarks_head_mm must be 28 x 3"),
    (lambda d: d["lid_weights"].update(lids_up=1.5), "lid_weights.lids_up = 1.5 outside [0, 1]"),
    (lambda d: d["eye_rotation"].update(left=[0, 0, 0, 0]), "eye_rotation.left: a non-zero quaternion"),
    (lambda d: d["camera"].update(ortho_scale_mm=float("nan")), "camera.ortho_scale_mm must be finite"),
    (lambda d: d["lighting"].update(strength=0), "lighting.strength must be > 0"),
    (lambda d: d.update(sharpness=2), "unknown spec keys ['sharpness']"),
    (lambda d: d.update(width=9000), "image size 9000x80 out of range"),
])
def test_bad_values_are_one_error_naming_the_key(spec, change, message):
    d = json.loads(spec.to_json())
    change(d)
    with pytest.raises(ValueError) as e:
        RenderSpec.from_dict(d)
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_the_sampler_builds_typed_values(spec):
    assert np.asarray(spec.camera.world_to_camera).shape == (4, 4)
    assert set(spec.eye_rotation) == {"left", "right"} and spec.eye in ("left", "right")
    assert spec.lighting.hdri.endswith(".exr") and spec.quality.overrides == {}
