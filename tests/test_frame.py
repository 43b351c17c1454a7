"""Units and axes -> head frame (mm): round trips, handedness, and ingest invariance."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fixtures import head_mesh, write_ply, write_sidecar
from pipeline.errors import ScanError
from pipeline.geometry.frame import (UNITS_TO_MM, axis_vector, check_eye_layout, check_float32, check_head_size,
                                     from_head_frame, scan_to_head_rotation, to_head_frame)
from pipeline.ingest.ingest import IngestSettings, ingest_scan

AXES = ["+X", "-X", "+Y", "-Y", "+Z", "-Z"]
PAIRS = [(u, f) for u, f in itertools.product(AXES, AXES) if u[1] != f[1]]


def test_24_conventions_are_proper_rotations():
    assert len(PAIRS) == 24
    mats = set()
    for up, fwd in PAIRS:
        R = scan_to_head_rotation(up, fwd)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=0)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_array_equal(R @ axis_vector(up), [0, 1, 0])    # up -> +Y
        np.testing.assert_array_equal(R @ axis_vector(fwd), [0, 0, 1])   # forward -> +Z
        mats.add(R.tobytes())
    assert len(mats) == 24  # all distinct: every proper axis-aligned rotation


@pytest.mark.parametrize("up,fwd", [("+Y", "+Y"), ("+Z", "-Z"), ("-X", "+X")])
def test_parallel_axes_refused(up, fwd):
    with pytest.raises(ValueError, match="parallel"):
        scan_to_head_rotation(up, fwd)


def test_known_conventions():
    p = np.array([1.0, 2.0, 3.0])
    # head frame itself (glTF/USD Y-up): identity
    np.testing.assert_array_equal(to_head_frame(p, "mm", "+Y", "+Z"), p)
    # Blender-style Z-up, character facing -Y: subject's left stays +X
    np.testing.assert_array_equal(to_head_frame(p, "mm", "+Z", "-Y"), [1.0, 3.0, -2.0])
    # a scan stored upside down and facing backwards (-Y up, -Z forward): a half turn about X
    np.testing.assert_array_equal(to_head_frame(p, "mm", "-Y", "-Z"), [1.0, -2.0, -3.0])
    # units only
    np.testing.assert_array_equal(to_head_frame(p, "cm", "+Y", "+Z"), 10 * p)
    np.testing.assert_array_equal(to_head_frame(p, "m", "+Y", "+Z"), 1000 * p)


@pytest.mark.parametrize("units", ["mm", "cm", "m"])
@pytest.mark.parametrize("up,fwd", PAIRS)
def test_round_trip_and_invariance(units, up, fwd):
    rng = np.random.default_rng(0)
    P = rng.normal(0, 100, (50, 3))                       # head-frame mm
    stored = from_head_frame(P, units, up, fwd)           # how a scan in this convention stores them
    np.testing.assert_allclose(to_head_frame(stored, units, up, fwd), P, rtol=0, atol=1e-10)
    # the stored "up" coordinate is the head-frame height, in the scan's units
    i, s = "XYZ".index(up[1]), (1 if up[0] == "+" else -1)
    np.testing.assert_allclose(s * stored[:, i] * UNITS_TO_MM[units], P[:, 1], atol=1e-10)
    # distances scale with the units only
    d_head = np.linalg.norm(P[0] - P[1])
    assert np.linalg.norm(stored[0] - stored[1]) * UNITS_TO_MM[units] == pytest.approx(d_head)


@pytest.mark.parametrize("units,up,fwd", [("mm", "+Y", "+Z"), ("cm", "+Z", "-Y"), ("m", "-X", "+Y"),
                                          ("mm", "-Y", "-Z"), ("cm", "+X", "-Z"), ("m", "-Z", "+X")])
def test_ingest_result_independent_of_storage(tmp_path, units, up, fwd):
    """The same head stored in six conventions ingests to the same head-frame mesh and hints."""
    V, F, hints = head_mesh(3)
    folder = tmp_path / "s"
    folder.mkdir()
    stored = from_head_frame(V, units, up, fwd)
    # write as float32 PLY like a scanner would; the reference is the float32-rounded stored data
    write_ply(folder / "scan.ply", stored, F)
    write_sidecar(folder, {k: from_head_frame(h, units, up, fwd) for k, h in hints.items()},
                  units=units, up=up, forward=fwd)
    res = ingest_scan(folder, IngestSettings())
    expect = to_head_frame(stored.astype(np.float32).astype(np.float64), units, up, fwd)
    np.testing.assert_allclose(res.mesh["V"], expect, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.mesh["V"], V, atol=1e-4 * UNITS_TO_MM[units])
    np.testing.assert_array_equal(res.mesh["F"], F)
    np.testing.assert_allclose(res.scan["eyes"]["left"]["hint"], hints["left"], atol=1e-9)
    assert res.metrics["flipped_winding"] is False
    assert (res.scan["units_in"], res.scan["up_axis_in"], res.scan["forward_axis_in"]) == (units, up, fwd)


def test_head_size_suggests_units():
    V = np.array([[0, 0, 0], [0.2, 0.25, 0.18]])          # a 0.2 m head declared in mm
    with pytest.raises(ScanError, match="units is probably m"):
        check_head_size(V, "mm", "scan.ply")
    with pytest.raises(ScanError, match="units is probably mm"):
        check_head_size(np.array([[0, 0, 0], [200.0, 0, 0]]) * 1000, "m", "scan.ply")
    np.testing.assert_allclose(check_head_size(np.array([[0, 0, 0], [150, 220, 180.0]]), "mm", "x"), [150, 220, 180])


def test_head_size_fragment_not_units():
    """A scanner's trim that left an 11.5 mm fragment is not a head in cm: the hints, 64 mm apart
    in the declared units, say the units are right (the fourteenth fresh set's n2003_trim_tight)."""
    V = np.array([[0, 0, 0], [11.5, 6.0, 4.0]])
    hints = {"left": [32.0, 35, 80], "right": [-32.0, 35, 80]}
    with pytest.raises(ScanError, match="64 mm apart in the same units, so the units are right and the mesh "
                                        "holds only a fragment of a head") as e:
        check_head_size(V, "mm", "scan.ply", hints=hints)
    assert "probably" not in str(e.value)
    with pytest.raises(ScanError, match="more than a head"):                   # a body scan, 1.8 m
        check_head_size(np.array([[0, 0, 0], [500, 1800, 300.0]]), "mm", "scan.ply", hints=hints)
    with pytest.raises(ScanError, match="units is probably cm"):               # hints as far off as the mesh
        check_head_size(V, "mm", "scan.ply", hints={"left": [3.2, 3.5, 8], "right": [-3.2, 3.5, 8]})


def test_float32_check():
    assert check_float32(np.array([[1e5, 0, 0]]), "x") < 0.01
    with pytest.raises(ScanError, match="float32"):
        check_float32(np.array([[2e5, 0, 0]]), "x")


def test_eye_layout():
    assert check_eye_layout([31, 35, 80], [-31, 35, 80], "s") == pytest.approx(62)
    with pytest.raises(ScanError, match="subject's right"):
        check_eye_layout([-31, 35, 80], [31, 35, 80], "s")
    with pytest.raises(ScanError, match="side by side"):
        check_eye_layout([0, 35, 80], [0, 35, 20], "s")
    with pytest.raises(ScanError, match="apart"):
        check_eye_layout([0.031, 0, 0], [-0.031, 0, 0], "s")
