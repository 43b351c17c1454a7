"""benchmarks.bench_band's summary counts bands, not heads, against issue 30's 20 deg."""

from benchmarks.bench_band import summary


def _row(head, left, right, rigs=True, flipped=0):
    return {"head": head, "rigs": rigs, "refused": None if rigs else "rig: a fold",
            "bands": {"left": {"min_angle_deg": left, "flipped_faces": flipped, "flipped_at_ring_spoke": []},
                      "right": {"min_angle_deg": right, "flipped_faces": 0, "flipped_at_ring_spoke": []}}}


def test_summary_counts_each_eye_band_and_names_the_thin_ones():
    s = summary([_row("a", 30.0, 19.9), _row("b", 25.0, 5.0, rigs=False, flipped=2), _row("c", 20.0, 31.0)])
    assert (s["heads"], s["rig"], s["bands"]) == (3, 2, 6)
    assert s["bands_under_20_deg"] == 2 and s["bands_with_a_flipped_face"] == 1
    assert s["smallest_angle_deg"] == 5.0 and s["median_band_smallest_deg"] == 22.5
    assert s["under_20"] == ["a right 19.9", "b right 5.0"]


def test_summary_of_no_heads_has_no_angles():
    s = summary([])
    assert s["bands"] == 0 and s["smallest_angle_deg"] is None and s["under_20"] == []
