"""``ingest/scan.json`` (pipeline/io/scan_file.py): what ingest writes is what the reader gives
back, and a record without usable eye hints is refused in one line naming the file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.errors import ScanError
from pipeline.io.scan_file import read_scan_record, write_scan_record

SCAN = {"name": "james", "source_sha256": "ab" * 32, "licence": "CC0",
        "eyes": {"left": {"hint": [32.0, 35.0, 80.0]}, "right": {"hint": [-32.0, 35.0, 80.0]}},
        "texture": "texture.png", "units_in": "cm", "up_axis_in": "+Y", "forward_axis_in": "+Z"}


def test_round_trip_keeps_every_key_and_types_the_ones_stages_use(tmp_path):
    write_scan_record(tmp_path / "scan.json", SCAN, "raw_scans/james")
    r = read_scan_record(tmp_path)                   # the ingest folder works as well as the file
    assert r.path == tmp_path / "scan.json" and r.name == "james" and r.folder == "raw_scans/james"
    assert r.source_sha256 == "ab" * 32 and r.licence == "CC0"
    np.testing.assert_array_equal(r.hints["left"], [32.0, 35.0, 80.0])
    assert r.hints["right"].dtype == np.float64 and r.hints["right"].shape == (3,)
    assert r.doc == {**SCAN, "folder": "raw_scans/james"}        # unknown keys carried as stored


def test_a_hand_written_record_needs_only_the_hints(tmp_path):
    (tmp_path / "scan.json").write_text(json.dumps({"eyes": SCAN["eyes"]}))
    r = read_scan_record(tmp_path / "scan.json")
    assert r.name is None and r.folder is None and r.source_sha256 == "" and r.licence == ""


@pytest.mark.parametrize("doc,message", [
    ({"name": "x"}, "has no valid eye hints (KeyError)"),
    ({"eyes": {"left": {"hint": [1, 2]}, "right": {"hint": [1, 2, 3]}}}, "has no valid eye hints (ValueError)"),
    ({"eyes": {"left": {"hint": [1, 2, float("nan")]}, "right": {"hint": [1, 2, 3]}}}, "eye hints are not finite"),
    ([1, 2], "is not a scan.json (not a mapping)"),
])
def test_bad_records_are_one_line(tmp_path, doc, message):
    (tmp_path / "scan.json").write_text(json.dumps(doc))
    with pytest.raises(ScanError) as e:
        read_scan_record(tmp_path / "scan.json")
    assert str(e.value) == f"{tmp_path / 'scan.json'}: {message}"


def test_missing_record_names_the_file(tmp_path):
    with pytest.raises(ScanError, match="scan.json: not found"):
        read_scan_record(tmp_path / "scan.json")
