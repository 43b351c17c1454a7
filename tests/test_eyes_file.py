"""eyes.json: one writer, one validating reader (pipeline.io.eyes_file); the eyeball's params
read from its USD (pipeline.usd.eyeball.read_eyeball_params)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.errors import ScanError
from pipeline.io.eyes_file import SCHEMA, lateral_canthus_index, read_eyes, write_eyes


def _entry(side, n=12):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    sign = 1.0 if side == "left" else -1.0
    pts = np.column_stack([sign * 30 + 10 * np.cos(t) * -sign, 4 * np.sin(t), np.full(n, 9.0)])
    return {"center": [sign * 30, 0, 0], "radius": 12.0, "forward": [0, 0, 2.0],
            "loop_indices": list(range(n) if side == "left" else range(n, 2 * n)),
            "loop_points": pts.tolist(), "lateral_canthus_index": n // 2, "placement": "surface",
            "checks": {"inside": {"value": 0.0, "limit": 2.0, "ok": True}}}


def test_round_trip_keeps_every_key(tmp_path):
    eyes = {s: _entry(s) for s in ("left", "right")}
    write_eyes(tmp_path / "eyes.json", eyes)
    assert json.loads((tmp_path / "eyes.json").read_text())["schema"] == SCHEMA
    rec = read_eyes(tmp_path / "eyes.json", n_vertices=24)
    assert rec["left"].radius == 12.0 and np.allclose(rec["left"].unit_forward, [0, 0, 1])
    assert rec["right"].loop_indices.dtype == np.int64 and rec["right"].lateral_canthus_index == 6
    assert rec["left"].to_doc() == {**eyes["left"], "doubts": []}   # every key carried
    assert rec["left"].extra["checks"] == eyes["left"]["checks"]
    # the Eye is what is written: written, read and written again, the same bytes
    write_eyes(tmp_path / "again.json", rec)
    write_eyes(tmp_path / "third.json", read_eyes(tmp_path / "again.json"))
    assert (tmp_path / "third.json").read_bytes() == (tmp_path / "again.json").read_bytes()


def test_lateral_canthus_is_the_most_lateral_loop_point():
    for side in ("left", "right"):
        e = _entry(side)
        assert lateral_canthus_index(np.array(e["loop_points"]), np.array(e["center"]),
                                     np.array(e["forward"]), side) == 6


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("schema"), "has schema None, this eyerig reads schema 1"),
    (lambda d: d.pop("right"), "has no 'right' eye"),
    (lambda d: d["left"].pop("forward"), "left eye: no forward"),
    (lambda d: d["left"].update(center=[0, "x", 0]), "left eye: center, radius and forward must be numbers"),
    (lambda d: d["left"].update(radius=float("nan")), "left eye: non-finite centre, radius or forward"),
    (lambda d: d["left"].update(radius=120.0), "left eye: radius 120 mm is not in (0, 100)"),
    (lambda d: d["left"].update(forward=[0, 0, 0]), "left eye: forward is the zero vector"),
    (lambda d: d["left"].update(loop_indices=[1, 2, 3]), "left eye: loop_indices must be at least 8"),
    (lambda d: d["left"].update(loop_indices=[0] * 12), "left eye: loop_indices repeat a vertex"),
    (lambda d: d["right"].update(loop_indices=list(range(20, 32))), "right eye: loop_indices outside the mesh's 24"),
    (lambda d: d["left"].update(lateral_canthus_index=0), "left eye: lateral_canthus_index must be a position"),
    (lambda d: d["right"].update(doubts="too narrow"), "right eye: doubts must be a list of sentences"),
    (lambda d: d["right"].update(doubts=[""]), "right eye: doubts must be a list of sentences"),
])
def test_bad_entries_are_one_line_naming_the_file(tmp_path, edit, message):
    doc = {"schema": SCHEMA, **{s: _entry(s) for s in ("left", "right")}}
    edit(doc)
    path = tmp_path / "eyes.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ScanError) as exc:
        read_eyes(path, n_vertices=24)
    assert str(exc.value).startswith(f"{path}: {message}"), str(exc.value)
    assert "\n" not in str(exc.value)


def test_not_json_and_missing(tmp_path):
    (tmp_path / "eyes.json").write_text("{not json")
    with pytest.raises(ScanError, match="is not valid JSON"):
        read_eyes(tmp_path / "eyes.json")
    with pytest.raises(ScanError, match="not found"):
        read_eyes(tmp_path / "none.json")


def test_eyeball_params_from_the_usd_custom_data(tmp_path):
    from pipeline.usd.eyeball import read_eyeball_params

    usda = tmp_path / "eyeball.usda"
    usda.write_text('#usda 1.0\n(\n defaultPrim = "E"\n)\ndef Xform "E" (\n customData = {\n'
                    ' dictionary eyerig = {\n dictionary params = {\n double apex = 14.0\n'
                    ' double r1 = 12.5\n double r2 = 8\n }\n }\n }\n)\n{\n}\n')
    p = read_eyeball_params(tmp_path)
    assert (p.r1, p.r2, p.apex) == (12.5, 8.0, 14.0)
    usda.write_text('#usda 1.0\n(\n defaultPrim = "E"\n)\ndef Xform "E"\n{\n}\n')
    with pytest.raises(ScanError, match="has no eyerig params"):
        read_eyeball_params(tmp_path)
    usda.write_text("not usd at all")
    with pytest.raises(ScanError, match="cannot be opened as USD"):
        read_eyeball_params(tmp_path)
    usda.unlink()
    with pytest.raises(ScanError, match="not found"):
        read_eyeball_params(tmp_path)


def test_write_refuses_what_read_would_refuse(tmp_path):
    good = {"center": [0, 0, 0], "radius": 12.0, "forward": [0, 0, 1]}
    bad = {**good, "loop_indices": list(range(10)), "lateral_canthus_index": 0}
    with pytest.raises(ScanError, match=r"eyes\.json: left eye: lateral_canthus_index must be a position"):
        write_eyes(tmp_path / "eyes.json", {"left": bad, "right": good})
    assert not (tmp_path / "eyes.json").exists()


def test_doubts_read_back(tmp_path):
    doc = {s: _entry(s) for s in ("left", "right")}
    doc["left"]["doubts"] = ["opening 18.0 mm wide where the texture's fissure is 31.5 mm"]
    write_eyes(tmp_path / "eyes.json", doc)
    eyes = read_eyes(tmp_path / "eyes.json", n_vertices=24)
    assert eyes["left"].doubts == doc["left"]["doubts"] and eyes["right"].doubts == []
