"""fixtures.truth: a scan folder's true eye corners (what bench_proportions compares the canthus
landmarks with) and the iris diameter through the 8 iris landmarks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixtures.truth import iris_diameter, truth_corners

HEAD_FRAME = "units: mm\nup_axis: \"+Y\"\nforward_axis: \"+Z\"\n"


def _margin(points, medial, lateral):
    return {"points_mm": points, "medial_canthus_index": medial, "lateral_canthus_index": lateral}


def test_ground_truth_corners_are_the_indexed_margin_points(tmp_path):
    (tmp_path / "scan.yaml").write_text(HEAD_FRAME)
    left = [[20.0, 0, 0], [30.0, 4, 1], [45.0, 0, -5], [30.0, -4, 1]]
    right = [[-45.0, 0, -5], [-30.0, 4, 1], [-20.0, 0, 0], [-30.0, -4, 1]]
    doc = {"eyes": {"left": {"eyelid_margin": _margin(left, 0, 2)},
                    "right": {"eyelid_margin": _margin(right, 2, 0)}}}
    (tmp_path / "ground_truth.json").write_text(json.dumps(doc))
    c = truth_corners(tmp_path)
    assert c["left"]["medial"].tolist() == [20.0, 0, 0] and c["left"]["lateral"].tolist() == [45.0, 0, -5]
    assert c["right"]["medial"].tolist() == [-20.0, 0, 0] and c["right"]["lateral"].tolist() == [-45.0, 0, -5]


def test_annotation_corners_are_the_points_nearest_and_farthest_from_the_midline(tmp_path):
    # menpo's groups: reye is the subject's left (+X) eye; the midline here is x = -10
    L = np.zeros((68, 3))
    L[17:23] = [[-40.0, 0, -8], [-32, 3, 0], [-24, 3, 0], [-16, 0, 1], [-24, -3, 0], [-32, -3, 0]]
    L[23:29] = [[-4.0, 0, 1], [4, 3, 0], [12, 3, 0], [20, 0, -8], [12, -3, 0], [4, -3, 0]]
    np.save(tmp_path / "x_landmarks68.npy", L)
    (tmp_path / "x_landmarks68_groups.json").write_text(
        json.dumps({"leye": list(range(17, 23)), "reye": list(range(23, 29))}))
    (tmp_path / "scan.yaml").write_text(HEAD_FRAME)
    c = truth_corners(tmp_path)
    assert c["left"]["medial"].tolist() == [-4.0, 0, 1] and c["left"]["lateral"].tolist() == [20, 0, -8]
    assert c["right"]["medial"].tolist() == [-16, 0, 1] and c["right"]["lateral"].tolist() == [-40, 0, -8]


def test_no_truth_outside_the_head_frame(tmp_path):
    # the truth is in scan coordinates: a scan in cm (or turned) is not compared
    (tmp_path / "scan.yaml").write_text("units: cm\nup_axis: \"+Y\"\nforward_axis: \"+Z\"\n")
    (tmp_path / "ground_truth.json").write_text(json.dumps({"eyes": {}}))
    assert truth_corners(tmp_path) is None
    (tmp_path / "scan.yaml").write_text(HEAD_FRAME)
    (tmp_path / "ground_truth.json").unlink()
    assert truth_corners(tmp_path) is None


def test_iris_diameter_is_the_major_axis_of_a_tilted_circle():
    k = np.arange(8) * np.pi / 4
    circle = np.stack([5.85 * np.cos(k), 5.85 * np.sin(k)], 1)
    tilted = circle * [np.cos(np.radians(40)), 1.0]     # seen 40 deg off its axis
    assert iris_diameter(tilted) == pytest.approx(11.7, abs=1e-9)


def test_james_annotated_corners(extra_scan):
    # the widths quoted in docs/known-gaps.md (eye proportions on the real scans)
    c = truth_corners(extra_scan("james"))
    width = {s: float(np.linalg.norm(c[s]["medial"] - c[s]["lateral"])) for s in ("left", "right")}
    assert width["left"] == pytest.approx(31.30, abs=0.01)
    assert width["right"] == pytest.approx(28.53, abs=0.01)
    assert c["left"]["medial"][0] < c["left"]["lateral"][0]
    assert c["right"]["medial"][0] > c["right"]["lateral"][0]
