"""Cycles contact sheet of the per-scan asset (stage ``preview`` after ``usd``, Blender worker)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from fixtures import make_inputs, params_file, usd_argv
from pipeline.blender.asset_preview import LABEL_H, PAD, TILE_ASPECT, sheet_size, tile_boxes
from stages import preview as preview_stage
from stages import usd as usd_stage
from stages._common import read_stage_metrics, run_stage

pytestmark = pytest.mark.blender
SIZE = 32


@pytest.fixture(scope="module")
def previewed(tmp_path_factory):
    root = tmp_path_factory.mktemp("asset_preview")
    inp = make_inputs(root)
    params = params_file(root, {"usd": {"usdz": False, "preview_px": SIZE, "preview_samples": 2}})
    args = usd_argv(inp)
    args[args.index("--params") + 1] = str(params)
    assert run_stage(usd_stage.main, args) == 0
    inp["png"] = inp["out"].with_name(inp["out"].name + ".preview.png")
    metrics = root / "preview.metrics.json"
    assert run_stage(preview_stage.main, [str(inp["out"]), str(inp["dirs"]["rig"]), str(inp["png"]),
                                          "--metrics", str(metrics), "--params", str(params)]) == 0
    return inp, read_stage_metrics(metrics)


def _tiles(img):
    a = np.asarray(img.convert("RGB"), np.float64)
    return [a[y:y + h, x:x + w] for x, y, w, h in tile_boxes(SIZE)]


def test_sheet_written_with_expected_size_and_content(previewed):
    inp, metrics = previewed
    png = inp["png"]
    assert png.is_file() and not (inp["out"] / "tiny.usdz").exists()
    assert not [p.name for p in png.parent.iterdir() if ".tmp" in p.name]     # written through a sibling
    img = Image.open(png)
    assert img.size == sheet_size(SIZE) == (2 * TILE_ASPECT * SIZE + 3 * PAD, 2 * (SIZE + LABEL_H) + 3 * PAD)
    for t in _tiles(img):
        assert t.mean() > 40                       # lit, not black
        assert t.std() > 5                         # something rendered, not a flat backdrop
    # metrics of the step
    assert metrics["preview_s"] > 0 and metrics["preview_px"] == list(sheet_size(SIZE))
    assert metrics["preview_samples"] == 2


def test_pose_changes_the_picture_and_lids_match_the_rig(previewed):
    inp, metrics = previewed
    up, rest, down, _ = _tiles(Image.open(inp["png"]))
    assert np.abs(up - down).mean() > 0.5          # eyes and lids moved between +25 and -25 deg
    # Blender shape keys (+ inbetween keys from rig.npz) reproduce the UsdSkel inbetween evaluation
    assert metrics["preview_lid_max_error_mm"] < 1e-4
    # both eyes turned by the tile's pitch (positive = looking up), measured at the corneal apex
    meas = metrics["preview_gaze_pitch_deg"]
    for key, pitch in (("+25", 25.0), ("+0", 0.0), ("-25", -25.0)):
        assert sorted(meas[key]) == ["eye_left", "eye_right"]
        for side, got in meas[key].items():
            assert got == pytest.approx(pitch, abs=0.3), (key, side)


def test_tiles_lie_inside_the_sheet_apart():
    W, H = sheet_size(SIZE)
    boxes = tile_boxes(SIZE)
    for x, y, w, h in boxes:
        assert 0 < x and x + w < W and LABEL_H <= y and y + h < H and (w, h) == (TILE_ASPECT * SIZE, SIZE)
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert a[0] + a[2] <= b[0] or b[0] + b[2] <= a[0] or a[1] + a[3] <= b[1] or b[1] + b[3] <= a[1]


def test_render_options_checked(tmp_path, capsys):
    from pipeline.blender.asset_preview import RENDER_OPTIONS, main, render_options

    assert render_options() == RENDER_OPTIONS
    got = render_options({"denoise": "off", "world_map_resolution": "512", "subsurface_method": "RANDOM_WALK"})
    assert got["denoise"] is False and got["world_map_resolution"] == 512
    assert got["subsurface_method"] == "RANDOM_WALK"
    for bad in ({"nope": 1}, {"denoise": "maybe"}, {"tile_size": "big"}):
        with pytest.raises(ValueError):
            render_options(bad)
    out = tmp_path / "x.png"
    assert main([str(tmp_path / "a.usda"), str(tmp_path / "r.npz"), str(out), "--option", "nope=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: unknown render option 'nope'") and not out.exists()
