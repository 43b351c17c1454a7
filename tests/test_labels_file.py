"""Render labels and index.jsonl: one writer, one validating reader (pipeline.io.labels_file)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.errors import ScanError
from pipeline.io.labels_file import (SCHEMA, index_line, index_row, label_name, read_index, read_label,
                                     write_label)


def _label(i=3):
    """The fields a consumer relies on, shaped as pipeline.render.labels.make_label writes them."""
    rng = np.random.default_rng(i)
    return {"index": i, "scan": "tiny", "image": {"file": f"{i:06d}.png", "width": 120, "height": 80},
            "seed": {"seed": 0, "index": i, "attempts": 2},
            "camera": {"ortho_scale_mm": 32.0, "world_to_camera": np.eye(4).tolist(),
                       "projection": np.hstack([np.eye(3), np.zeros((3, 1))]).tolist()},
            "gaze": {"eye": "left", "vector_camera": [0.0, 0.0, 1.0],
                     "camera": {"pitch_deg": 1.5, "yaw_deg": -2.0}},
            "landmarks": {"px": rng.random((28, 2)).tolist(), "camera_mm": rng.random((28, 3)).tolist(),
                          "head_mm": rng.random((28, 3)).tolist(), "apparent_px": [None] * 16},
            "lighting": {"hdri": "forest.exr", "strength": 1.0},
            "render": {"skin_detail": "bump", "samples": 12},
            "landmark_check_mm": 2e-5}


def test_label_round_trip(tmp_path):
    path = tmp_path / label_name(3)
    assert path.name == "000003.json"
    write_label(path, _label())
    doc = json.loads(path.read_text())
    assert list(doc)[:2] == ["schema", "index"] and doc["schema"] == SCHEMA
    lab = read_label(path)
    assert (lab.index, lab.width, lab.height, lab.eye) == (3, 120, 80, "left")
    assert lab.px.shape == (28, 2) and lab.camera_mm.shape == (28, 3) and lab.head_mm.shape == (28, 3)
    assert lab.projection.shape == (3, 4) and lab.world_to_camera.shape == (4, 4)
    assert lab.doc == {"schema": SCHEMA, **_label()}                # every key carried
    write_label(tmp_path / "again.json", {k: v for k, v in lab.doc.items() if k != "schema"})
    assert (tmp_path / "again.json").read_bytes() == path.read_bytes()


def test_index_round_trip(tmp_path):
    for i in range(3):
        write_label(tmp_path / label_name(i), _label(i))
    with open(tmp_path / "index.jsonl", "w") as fh:
        for i in range(3):
            fh.write(index_line(read_label(tmp_path / label_name(i))))
    rows = read_index(tmp_path / "index.jsonl")
    assert [r["index"] for r in rows] == [0, 1, 2]
    assert rows[1] == {"index": 1, "png": "000001.png", "json": "000001.json", "eye": "left",
                       "gaze_camera_deg": [1.5, -2.0], "landmark_check_mm": 2e-5}
    assert rows[2] == index_row(read_label(tmp_path / label_name(2)))


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("schema"), r"has schema None, this eyerig reads schema 1 \(rebuild it with the render stage\)"),
    (lambda d: d.pop("index"), r"000003\.json: has no index"),
    (lambda d: d.update(index="3"), r"index must be an integer \(got str\)"),
    (lambda d: d["image"].update(width=0), r"index, image\.width and image\.height must be >= 0, > 0, > 0"),
    (lambda d: d["gaze"].update(eye="middle"), r"gaze\.eye must be 'left' or 'right' \(got 'middle'\)"),
    (lambda d: d["gaze"]["camera"].pop("yaw_deg"), r"has no gaze\.camera\.yaw_deg"),
    (lambda d: d["camera"].update(projection=np.eye(3).tolist()),
     r"camera\.projection must be a \(3, 4\) array of numbers \(got shape \(3, 3\) of float64\)"),
    (lambda d: d["landmarks"].update(px=d["landmarks"]["px"][:27]), r"landmarks\.px must be a \(28, 2\) array"),
    (lambda d: d["landmarks"]["head_mm"][0].__setitem__(0, None), r"landmarks\.head_mm must be a \(28, 3\) array"),
    (lambda d: d["landmarks"].update(camera_mm="x"), r"landmarks\.camera_mm must be a \(28, 3\) array of numbers \(got str\)"),
    (lambda d: d["seed"].update(attempts=1.0), r"seed\.attempts must be an integer \(got float\)"),
    (lambda d: d["lighting"].pop("hdri"), r"has no lighting\.hdri"),
    (lambda d: d["render"].pop("skin_detail"), r"has no render\.skin_detail"),
    (lambda d: d.update(landmark_check_mm="small"), r"landmark_check_mm must be a number \(got str\)"),
])
def test_bad_label_is_one_line_naming_it(tmp_path, edit, message):
    doc = {"schema": SCHEMA, **_label()}
    edit(doc)
    path = tmp_path / "000003.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ScanError, match=message) as ei:
        read_label(path)
    assert ei.value.path == str(path) and "\n" not in str(ei.value)


@pytest.mark.parametrize("lines,message", [
    (['{"index": 0, "png": "a.png", "json": "a.json", "eye": "left"}', "{oops"], r"line 2 is not valid JSON"),
    (["[0]"], r"line 1 is not a mapping"),
    (['{"index": -1, "png": "a", "json": "b", "eye": "left"}'], r"line 1: index must be an integer >= 0 \(got -1\)"),
    (['{"index": 0, "png": "a", "json": "b", "eye": "left"}'] * 2, r"line 2: index 0 is listed twice"),
    (['{"index": 0, "json": "b", "eye": "left"}'], r"line 1: png must be a file name \(got None\)"),
    (['{"index": 0, "png": "a", "json": "b", "eye": "up"}'], r"line 1: eye must be 'left' or 'right' \(got 'up'\)"),
])
def test_bad_index_is_one_line_naming_it(tmp_path, lines, message):
    path = tmp_path / "index.jsonl"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ScanError, match=message) as ei:
        read_index(path)
    assert ei.value.path == str(path)
    with pytest.raises(ScanError, match=r"nothing\.jsonl: not found"):
        read_index(tmp_path / "nothing.jsonl")
