"""rig.json + rig.npz: one writer, one validating reader (pipeline.io.rig_file)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.errors import ScanError
from pipeline.io.eyes_file import Eye
from pipeline.io.rig_file import SCHEMA, read_rig, read_rig_arrays, write_rig
from pipeline.rig import lids

N = 40          # vertices of the (notional) mesh the rig deforms


def _shape(name, idx, dy):
    k = len(idx)
    off = np.tile([0.0, dy, 0.0], (k, 1))
    return lids.BlendShape(name=name, point_indices=np.asarray(idx, np.int64), offsets=off,
                           inbetween_weights=np.array([0.5]), inbetween_offsets=0.4 * off[None])


def _arrays():
    arrays = lids.shapes_to_arrays([_shape(lids.SHAPE_UP, range(10, 20), 1.0),
                                    _shape(lids.SHAPE_DOWN, range(10, 20), -1.0)])
    for side in ("left", "right"):
        pre = f"landmarks.{side}."
        arrays[pre + "points"] = np.arange(36, dtype=np.float64).reshape(12, 3)
        arrays.update(lids.shapes_to_arrays([_shape(lids.SHAPE_UP, range(12), 1.0)], prefix=pre))
        arrays[pre + "edge"] = np.stack([np.arange(12), np.arange(1, 13)], 1).astype(np.int64)
        arrays[pre + "t"] = np.full(12, 0.25)
        arrays[f"loop_{side}"] = np.arange(20, 36, dtype=np.int64)
    return arrays


def _doc():
    eye = {"center": [30.0, 0.0, 70.0], "radius": 12.5, "forward": [0.0, 0.0, 1.0], "joint": "eye_left",
           "surface": {"parametric_eye": {"r1": 12.0, "r2": 8.0}}}
    return {"weight_rule": lids.weight_rule(25.0), "eyes": {"left": eye, "right": dict(eye, surface="sphere")},
            "shapes": [], "note": "kept"}


def test_round_trip(tmp_path):
    arrays, doc = _arrays(), _doc()
    write_rig(tmp_path, arrays, doc)
    assert json.loads((tmp_path / "rig.json").read_text())["schema"] == SCHEMA
    rig = read_rig(tmp_path, n_vertices=N)
    assert rig.max_pitch_deg == 25.0 and rig.doc["note"] == "kept"
    assert rig.eyes["left"].model_radius == 12.0 and rig.eyes["right"].model_radius is None
    # rig.json's eyes are the one eye type, read as an eyes.json entry is (rig's keys in extra)
    assert all(isinstance(e, Eye) and e.side == s for s, e in rig.eyes.items())
    assert rig.eyes["left"].extra["joint"] == "eye_left" and rig.eyes["left"].radius == 12.5
    np.testing.assert_array_equal(rig.eyes["left"].center, [30.0, 0.0, 70.0])
    assert [s.name for s in rig.npz.shapes] == [lids.SHAPE_UP, lids.SHAPE_DOWN]
    assert set(rig.npz.arrays) == set(arrays)
    for k, v in arrays.items():
        np.testing.assert_array_equal(rig.npz.arrays[k], v)
    pts, shapes = rig.npz.curves["right"]
    assert pts.shape == (12, 3) and [s.name for s in shapes] == [lids.SHAPE_UP]
    # the same product read from either file's path; rewritten from what was read: same bytes
    assert read_rig(tmp_path / "rig.npz").eyes.keys() == read_rig(tmp_path / "rig.json").eyes.keys()
    again = tmp_path / "again"
    again.mkdir()
    write_rig(again, rig.npz.arrays, rig.doc)
    for name in ("rig.json", "rig.npz"):
        assert (again / name).read_bytes() == (tmp_path / name).read_bytes()


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("schema"), r"rig\.json: has schema None, this eyerig reads schema 1 \(rebuild it with the rig stage\)"),
    (lambda d: d.update(schema=2), r"rig\.json: has schema 2"),
    (lambda d: d.pop("weight_rule"), r"rig\.json: has no weight_rule\.max_pitch_deg"),
    (lambda d: d["weight_rule"].update(max_pitch_deg="25"), r"weight_rule\.max_pitch_deg must be a number \(got str\)"),
    (lambda d: d["eyes"].pop("right"), r"rig\.json: has no eyes\.right"),
    (lambda d: d["eyes"]["left"].update(center=[1.0, 2.0]), r"eyes\.left\.center must be a \(3,\) array of numbers"),
    (lambda d: d["eyes"]["left"].update(radius=-1.0), r"eyes\.left\.radius must be in \(0, 100\] \(got -1\)"),
    (lambda d: d["eyes"]["left"].update(radius=True), r"eyes\.left\.radius must be a number \(got bool\)"),
    (lambda d: d["eyes"]["right"].update(forward=[0, 0, 0]), r"eyes\.right\.forward is the zero vector"),
    (lambda d: d["eyes"]["left"].update(surface="cube"), r"eyes\.left\.surface must be \"sphere\""),
])
def test_bad_rig_json_is_one_line_naming_it(tmp_path, edit, message):
    doc = {"schema": SCHEMA, **_doc()}
    edit(doc)
    write_rig(tmp_path, _arrays(), {})
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    with pytest.raises(ScanError, match=message) as ei:
        read_rig(tmp_path)
    assert ei.value.path == str(tmp_path / "rig.json") and "\n" not in str(ei.value)


def _drop(k):
    return lambda a: a.pop(k)


@pytest.mark.parametrize("edit,message", [
    (_drop("shape_names"), r"rig\.npz: missing lid shape array 'shape_names'"),
    (_drop("lids_down.offsets"), r"missing lid shape array 'lids_down\.offsets'"),
    (lambda a: a.update({"lids_up.offsets": np.zeros((10, 2))}),
     r"lids_up\.offsets must be a \(10, 3\) array of numbers \(got shape \(10, 2\) of float64\)"),
    (lambda a: a.update({"lids_up.offsets": np.full((10, 3), np.nan)}), r"lids_up\.offsets has non-finite values"),
    (lambda a: a.update({"lids_up.point_indices": np.arange(10) + 0.5}),
     r"lids_up\.point_indices must be a \(n,\) array of integers"),
    (lambda a: a.update({"lids_up.point_indices": np.arange(35, 45)}),
     r"shape lids_up indexes vertices outside the mesh \(40 vertices\)"),
    (lambda a: a.update({"lids_up.inbetween_weights": np.array([1.5])}),
     r"lids_up\.inbetween_weights must increase inside \(0, 1\)"),
    (_drop("landmarks.left.points"), r"no eyelid landmarks for the left eye \(landmarks\.left\.points\)"),
    (_drop("landmarks.right.shape_names"), r"missing landmarks\.right shape array 'landmarks\.right\.shape_names'"),
    (lambda a: a.update({"shape_names": np.array([1, 2])}), r"shape_names must be a \(n,\) array of names"),
    (lambda a: a.update({"landmarks.left.edge": np.zeros((11, 2), np.int64)}),
     r"landmarks\.left\.edge must be a \(12, 2\) array of integers \(got shape \(11, 2\) of int64\)"),
    (_drop("landmarks.left.t"), r"landmarks\.left\.t must be a \(12,\) array of numbers"),
    (lambda a: a.update({"loop_right": np.array([1, 2], np.int64)}), r"loop_right must be at least 3 vertex indices"),
    (lambda a: a.update({"loop_right": np.arange(38, 44)}), r"loop_right indexes vertices outside the mesh"),
])
def test_bad_rig_npz_is_one_line_naming_it(tmp_path, edit, message):
    arrays = _arrays()
    edit(arrays)
    write_rig(tmp_path, arrays, _doc())
    with pytest.raises(ScanError, match=message) as ei:
        read_rig(tmp_path, n_vertices=N)
    assert ei.value.path == str(tmp_path / "rig.npz") and "\n" not in str(ei.value)


def test_missing_or_garbage_files(tmp_path):
    with pytest.raises(ScanError, match=r"rig\.json: not found"):
        read_rig(tmp_path)
    (tmp_path / "rig.json").write_text("{not json")
    with pytest.raises(ScanError, match=r"rig\.json: is not valid JSON \(JSONDecodeError\)"):
        read_rig(tmp_path)
    (tmp_path / "rig.json").write_text("[1, 2]")
    with pytest.raises(ScanError, match=r"rig\.json: is not a rig\.json \(not a mapping\)"):
        read_rig(tmp_path)
    with pytest.raises(ScanError, match=r"rig\.npz: not found"):
        read_rig_arrays(tmp_path)
    (tmp_path / "rig.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ScanError, match=r"rig\.npz: cannot be read as a rig \.npz"):
        read_rig_arrays(tmp_path / "rig.npz")
