"""The bake product: one writer, one validating reader (pipeline.io.bake_file)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from pipeline.io.exr import write_exr
from pipeline.errors import ScanError
from pipeline.io.bake_file import SCHEMA, read_bake, read_displacement, write_bake

RES = 32


def _write(folder, color=True):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2]])
    d = np.linspace(-0.3, 0.5, RES * RES).reshape(RES, RES)
    mask = np.zeros((RES, RES), bool)
    mask[4:20, 4:20] = True
    col = np.full((RES, RES, 3), 90, np.uint8) if color else None
    write_bake(folder, {"V": V, "F": F, "UV": V[:, :2], "FUV": F}, d, mask, col, resolution=RES,
               falloff_mm=2.0, colour_source="scan texture" if color else None)
    return d, mask


def test_round_trip(tmp_path):
    d, mask = _write(tmp_path)
    assert json.loads((tmp_path / "bake.json").read_text())["schema"] == SCHEMA
    maps = read_bake(tmp_path)
    assert maps.resolution == RES and maps.doc["color"]["source"] == "scan texture"
    assert maps.displacement == tmp_path / "displacement.exr" and maps.color == tmp_path / "color.png"
    got = read_displacement(maps.displacement)
    np.testing.assert_array_equal(got, d.astype(np.float32))
    prev = np.asarray(Image.open(maps.preview)).astype(np.float64)
    back = maps.preview_offset + maps.preview_scale * prev
    assert np.abs(back[mask] - d[mask]).max() <= maps.preview_scale        # 16-bit preview of the mask's range
    assert np.all(np.asarray(Image.open(maps.color)) == 90)
    # no colour: a flat grey map, and the document says so
    other = tmp_path / "grey"
    other.mkdir()
    _write(other, color=False)
    grey = read_bake(other)
    assert grey.doc["color"]["source"] == "none (flat grey)"
    assert np.all(np.asarray(Image.open(grey.color)) == 200)


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("schema"), r"bake\.json: has schema None, this eyerig reads schema 1 \(rebuild it with the bake stage\)"),
    (lambda d: d.update(resolution="2048"), r"bake\.json: resolution must be an integer \(got str\)"),
    (lambda d: d.update(resolution=0), r"bake\.json: resolution must be > 0 \(got 0\)"),
    (lambda d: d["displacement"].update(units="cm"), r"bake\.json: displacement\.units must be \"mm\""),
    (lambda d: d["preview"].pop("value_mm = offset + scale * pixel"),
     r"bake\.json: has no preview\.value_mm = offset \+ scale \* pixel\.scale"),
    (lambda d: d["preview"]["value_mm = offset + scale * pixel"].update(scale=0.0),
     r"preview\.value_mm = offset \+ scale \* pixel\.scale must be > 0 \(got 0\)"),
    (lambda d: d["color"].update(file="../color.png"),
     r"bake\.json: color\.file must be a file name in the same folder \(got '\.\./color\.png'\)"),
    (lambda d: d["displacement"].pop("file"), r"bake\.json: has no displacement\.file"),
])
def test_bad_bake_json_is_one_line_naming_it(tmp_path, edit, message):
    _write(tmp_path)
    doc = json.loads((tmp_path / "bake.json").read_text())
    edit(doc)
    (tmp_path / "bake.json").write_text(json.dumps(doc))
    with pytest.raises(ScanError, match=message) as ei:
        read_bake(tmp_path)
    assert ei.value.path == str(tmp_path / "bake.json") and "\n" not in str(ei.value)


def test_missing_files_and_bad_maps(tmp_path):
    with pytest.raises(ScanError, match=r"bake\.json: not found"):
        read_bake(tmp_path)
    _write(tmp_path)
    (tmp_path / "color.png").unlink()
    with pytest.raises(ScanError, match=r"color\.png: not found \(named by bake\.json color\.file\)"):
        read_bake(tmp_path)
    with pytest.raises(ScanError, match=r"nope\.exr: not found"):
        read_displacement(tmp_path / "nope.exr")
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    with pytest.raises(ScanError, match=r"bad\.exr: cannot read displacement map"):
        read_displacement(tmp_path / "bad.exr")
    write_exr(tmp_path / "nan.exr", np.array([[0.0, np.nan], [1.0, 2.0]]))
    with pytest.raises(ScanError, match=r"nan\.exr: displacement map has non-finite texels"):
        read_displacement(tmp_path / "nan.exr")
    with pytest.raises(ScanError, match=r"nan\.exr: cannot read displacement map .*no channel 'Z'"):
        read_displacement(tmp_path / "nan.exr", channel="Z")
