"""Unseen scan-like heads (scanify, about 100k faces): each eye is right or says it is not sure.

Issue 21's fast cases, one per way a head nobody tuned on has gone wrong (the full variety is
``benchmarks/bench_unseen_scans.py``): ICT-FaceKit heads looking down, squinting and wide, an
opening the scanner filled with flat triangles, hints moved 5 mm, and a full blink. An open eye
is either right (centre and radius within 1 mm of the truth, every self-check passing) or the
stage says it is not sure of it: published with a doubt on that eye and a ``warning:`` line
naming the scan folder and the eye, or the scan refused in one line that does not call it
simply closed. A published eye names the cues that carried it and states an uncertainty. The
blink is refused as closed with one line naming the scan folder and nothing written, or, where
the stage cannot tell (this head at 100k faces), its eyes are published doubted.
(Issue 21's target, every open eye within 1 mm, is the benchmark's figure, not met: see
docs/remove_eyeballs.md.) Identity seeds come from the benchmark's dev set (never the held-out
one). Needs ``EYERIG_EXTRA_SCANS`` (ICT-FaceKit and ``../tools/scanify`` beside it); skips
cleanly without. Each scan is made once per test session (about a minute each).

The benchmark's instrument (``tests/fixtures/unseen/metrics.py``) is checked here too, fast, on
an eye whose answers are known.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, extra_scans_dir
from fixtures.truth import truth_limbus
from pipeline.io.eyes_file import read_eyes

FACES = 100_000


def _cases():
    from fixtures.unseen.cases import _filled, _sc

    return {c["name"]: c for c in (
        _sc("t_id42_down", "expression", 42, faces=FACES, expr=["eyeLookDown"]),
        _sc("t_id86_squint", "expression", 86, faces=FACES, expr=["eyeSquint"]),
        _sc("t_id93_wide", "expression", 93, faces=FACES, expr=["eyeWide"]),
        _filled("t_filled_id44", 44, faces=FACES),
        _sc("t_id31_hint5", "hint_5mm", 31, faces=FACES, hint_offset=5.0, seed=7),
        {**_sc("t_id41_blink", "blink", 41, faces=FACES, expr=["eyeBlink=1"]), "expect": "closed"},
    )}


OPEN = ["t_id42_down", "t_id86_squint", "t_id93_wide", "t_filled_id44", "t_id31_hint5"]


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """``scans(name)`` -> the scan folder of that case, made on first use in this module."""
    base = extra_scans_dir()
    if base is None:
        pytest.skip("EYERIG_EXTRA_SCANS is not set")
    tool, ict = base.parent / "tools" / "scanify" / "scanify.py", base / "ict_facekit"
    if not tool.is_file() or not (ict / "ict_shape_modes.npz").is_file():
        pytest.skip(f"scanify or ICT-FaceKit not found beside {base}")
    from fixtures.unseen.cases import generate

    work, cases = tmp_path_factory.mktemp("unseen"), _cases()
    return lambda name: generate(cases[name], work, tool, ict)


def _run(*args):
    return subprocess.run([sys.executable, "-m", *map(str, args), "--params", str(ROOT / "params.yaml")],
                          cwd=ROOT, capture_output=True, text=True)


def _place(scan: Path, build: Path):
    r = _run("stages.ingest", scan, build / "ingest")
    assert r.returncode == 0, r.stderr
    return _run("stages.remove_eyeballs", build / "ingest", build / "remove_eyeballs")


@pytest.mark.slow
@pytest.mark.parametrize("name", OPEN)
def test_open_eyes_are_right_or_not_sure(scans, tmp_path, name):
    scan = scans(name)
    r = _place(scan, tmp_path)
    lines = r.stderr.strip().splitlines()
    if r.returncode == 2:
        assert len(lines) == 1 and lines[0].startswith(f"error: {scan}: "), lines
        assert "Traceback" not in r.stderr and not (tmp_path / "remove_eyeballs").exists()
        assert "too little of the eyeball shows" in lines[0] or "not sure" in lines[0], lines[0]
        return
    assert r.returncode == 0, r.stderr
    eyes = {s: e.to_doc() for s, e in read_eyes(tmp_path / "remove_eyeballs" / "eyes.json").items()}
    truth = json.loads((scan / "ground_truth.json").read_text())["eyes"]
    for side in ("left", "right"):
        e, g = eyes[side], truth[side]
        placement = e.get("placement")
        assert placement and isinstance(placement, list) and all(isinstance(p, str) for p in placement), \
            f"{side}: placement must name the cues that carried the fit, got {placement!r}"
        unc = e.get("uncertainty")
        assert isinstance(unc, dict) and all(np.isfinite(unc.get(k, np.nan)) and unc[k] > 0
                                             for k in ("limbus_mm", "axis_deg")), \
            f"{side}: no stated 1-sigma uncertainty (limbus, axis): {unc!r}"
        lt, gz = truth_limbus(g)
        err = float(np.linalg.norm(np.asarray(e["limbus"]["center"]) - lt))
        ang = float(np.degrees(np.arccos(np.clip(np.dot(e["forward"], gz), -1.0, 1.0))))
        if err <= 1.0 and ang <= 3.0:
            continue
        # not right: it must say so, in eyes.json and on stderr, naming the scan and the eye
        assert e["doubts"], f"{side} limbus {err:.2f} mm, axis {ang:.1f} deg off and not doubted"
        assert any(ln.startswith(f"warning: {scan}: {side} eye: ") for ln in lines), lines


@pytest.mark.slow
def test_blink_is_refused_as_closed_or_never_published_as_sure(scans, tmp_path):
    """A blinked head has no eye to place. Refused as closed (one line naming the folder,
    nothing written) is what issue 21 asks; this head at 100k faces is not (a sphere over the
    closed lids is ringed by the lids' seam and the crease: see docs/known-gaps.md), so the
    stage's own contract is held instead: an eye it publishes is doubted, with a warning line
    naming the scan and the eye."""
    scan = scans("t_id41_blink")
    r = _run("stages.ingest", scan, tmp_path / "ingest")      # either stage may see it closed
    out = tmp_path / "ingest"
    if r.returncode == 0:
        r = _run("stages.remove_eyeballs", tmp_path / "ingest", tmp_path / "remove_eyeballs")
        out = tmp_path / "remove_eyeballs"
    lines = r.stderr.strip().splitlines()
    if r.returncode == 0:
        eyes = read_eyes(out / "eyes.json")
        for side in ("left", "right"):
            assert eyes[side].doubts, f"a blinked head's {side} eye was published without a doubt"
            assert any(ln.startswith(f"warning: {scan}: {side} eye: ") for ln in lines), lines
        return
    assert r.returncode == 2, r.stderr[-500:]
    assert len(lines) == 1 and lines[0].startswith(f"error: {scan}: "), lines
    from fixtures.unseen.metrics import says_closed

    assert says_closed(lines[0]), lines[0]
    assert "Traceback" not in r.stderr and not out.exists()


# ----------------------------------------------------------------------------- the instrument
def _truth_eye(side="left"):
    """A 12 mm eye at the origin looking +Z with an 8 mm cornea, and a 24 x 10 mm elliptic
    opening in front of it (medial corner first, upper lid, lateral corner, lower lid)."""
    sgn = 1.0 if side == "left" else -1.0          # the left eye's lateral side is head +X
    t = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    x, y = -sgn * 12.0 * np.cos(t), 5.0 * np.sin(t)
    z = np.sqrt(np.maximum(12.0 ** 2 - x ** 2 - y ** 2, 0.0))
    return {"eyeball_sphere": {"center_mm": [0.0, 0.0, 0.0], "radius_mm": 12.0},
            "cornea_sphere": {"center_mm": [0.0, 0.0, 5.5], "radius_mm": 8.0},
            "gaze_direction": [0.0, 0.0, 1.0],
            "eyelid_margin": {"points_mm": np.stack([x, y, z], 1).tolist()}}


def test_visible_surface_lies_on_the_true_eye_inside_the_opening():
    from fixtures.unseen.metrics import true_visible_surface

    g = _truth_eye()
    P = true_visible_surface(g, step=0.5)
    r_ball = np.linalg.norm(P, axis=1)
    r_cornea = np.linalg.norm(P - [0, 0, 5.5], axis=1)
    on_ball, on_cornea = np.abs(r_ball - 12.0) < 1e-9, np.abs(r_cornea - 8.0) < 1e-9
    assert (on_ball | on_cornea).all()                      # on the outer envelope ...
    assert (r_ball[on_cornea] >= 12.0 - 1e-9).all() and (r_cornea[on_ball] >= 8.0 - 1e-9).all()
    assert on_ball.any() and on_cornea.any()                 # ... both parts show
    assert ((P[:, 0] / 12.0) ** 2 + (P[:, 1] / 5.0) ** 2 <= 1.0 + 1e-9).all()   # inside the opening
    assert abs(len(P) * 0.25 - np.pi * 12.0 * 5.0) < 0.05 * np.pi * 60.0         # and all of it


def test_placement_figures_against_a_known_eye():
    from fixtures.unseen.metrics import placement_metrics, true_visible_surface

    g = _truth_eye()
    P = true_visible_surface(g, step=0.5)
    e = {"center": [0.3, 0.0, -0.4], "radius": 12.2, "forward": [0, 0, 1], "placement": "surface",
         "uncertainty_mm": {"center": 0.2, "radius": 0.3}, "doubts": []}
    m = placement_metrics(e, g, P, ([0.0, 0.0, 0.0], 12.0, [0.0, 0.0, 1.0]), None)
    assert m["center_error_mm"] == pytest.approx(0.5) and m["radius_error_mm"] == pytest.approx(0.2)
    assert m["placement"] == ["surface"] and m["doubted"] is False
    assert m["within_2sigma"] is False and m["radius_within_2sigma"] is True   # 0.5 > 2 x 0.2
    assert m["visible_rms_mm"] is None                     # no eyeball params: no asset figure
    m = placement_metrics({**e, "uncertainty_mm": None, "placement": ["sclera", "margin"],
                           "doubts": ["little sclera"]}, g, P, (e["center"], 12.2, [0, 0, 1]), None)
    assert m["within_2sigma"] is None and m["placement"] == ["sclera", "margin"] and m["doubted"]
    exact = placement_metrics({**e, "center": [0, 0, 0], "radius": 12.0}, g, P,
                              ([0, 0, 0], 12.0, [0, 0, 1]), None)
    assert exact["visible_rms_sclera_mm"] > 0.5            # the sphere alone misses the cornea


def test_asset_eye_figure_reuses_the_placed_eye():
    """The asset figure measures the eye the usd stage builds: placed_params' eye, here with the
    truth's own cornea, so the truth placed exactly is 0 and a 0.3 mm shift is about 0.3."""
    from fixtures.unseen.metrics import placement_metrics, true_visible_surface
    from pipeline.eyeball.geometry import EyeballParams

    g = _truth_eye()
    P = true_visible_surface(g, step=0.5)
    p = EyeballParams(r1=12.0, r2=8.0, apex=13.5, seam_blend_mm=0.0)
    e = {"center": [0, 0, 0], "radius": 12.0, "forward": [0, 0, 1]}
    assert placement_metrics(e, g, P, ([0, 0, 0], 12.0, [0, 0, 1]), p)["visible_rms_mm"] < 1e-3
    shifted = placement_metrics(e, g, P, ([0, 0, 0.3], 12.0, [0, 0, 1]), p)["visible_rms_mm"]
    assert 0.2 < shifted <= 0.3 + 1e-3


@pytest.mark.parametrize("side", ["left", "right"])
def test_margin_and_canthi_against_a_known_opening(side):
    from fixtures.unseen.metrics import canthus_metrics, margin_metrics, true_canthi

    g = _truth_eye(side)
    M = np.asarray(g["eyelid_margin"]["points_mm"])
    med, lat, ok = true_canthi(g, side)
    assert ok and np.allclose(med, M[0]) and np.allclose(lat, M[24])
    m = margin_metrics(M, g)
    assert m["margin_mean_mm"] < 1e-9 and m["margin_symmetric_mm"] < 1e-9
    # the upper lid there and back: on the truth one way, far from its lower lid the other
    half = margin_metrics(np.vstack([M[:25], M[23:0:-1]]), g)
    assert half["margin_mean_mm"] < 0.05 and half["margin_symmetric_mm"] > 1.0
    L = np.zeros((12, 3))
    L[0], L[6] = M[0] + [0, 0, 1.0], M[24]
    c = canthus_metrics(L, g, side)
    assert c["canthus_medial_mm"] == pytest.approx(1.0) and c["canthus_lateral_mm"] < 1e-9
    assert c["canthus_medial_in_view_mm"] < 1e-9        # 1 mm in front: the same corner in view
    L[6] = M[24] + [0, 0.5, 2.0]
    c = canthus_metrics(L, g, side)
    assert c["canthus_lateral_mm"] == pytest.approx(np.hypot(0.5, 2.0), abs=1e-4)
    assert c["canthus_lateral_in_view_mm"] == pytest.approx(0.5)


def test_a_case_marked_not_ideal_scans_icts_own_eyeball():
    # the non_ideal_eye family was scanned with --ideal-eyes for its first two weeks: what a case
    # says of its eye must be what scanify is asked for
    from fixtures.unseen.cases import ALL_CASES

    scanned = [c for c in ALL_CASES if c["kind"] in ("scanify", "filled")]
    not_ideal = [c for c in scanned if c.get("ideal", True) is False]
    assert {c["name"] for c in not_ideal} >= {"id39_icteye", "id40_icteye_up", "id329_icteye", "id330_icteye_down"}
    assert all("--ideal-eyes" not in c["args"] for c in not_ideal)
    assert all("--ideal-eyes" in c["args"] for c in scanned if c.get("ideal", True))
    assert all(c.get("ideal", True) is False for c in scanned if c["family"] == "non_ideal_eye")


def test_eye_holes_drop_a_bow_tie_left_between_two_removed_eye_vertices():
    """On a 12 x 12 grid, removing the faces round two eye vertices two apart on a diagonal
    leaves the skin vertex between them a bow-tie (two wedges of faces meeting only there): its
    faces go too, and the two holes become one simple rim round all three."""
    from fixtures.unseen.cases import eye_holes
    from pipeline.geometry import meshtopo

    n = 12
    xs, ys = np.meshgrid(np.arange(n), np.arange(n))
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], 1).astype(float)
    F = np.array([f for i in range(n - 1) for j in range(n - 1)
                  for a in [i * n + j] for f in ((a, a + 1, a + n + 1), (a, a + n + 1, a + n))])
    labels = np.zeros(n * n, np.uint8)
    labels[[4 * n + 4, 6 * n + 6]] = 1
    V2, F2, L2, rims = eye_holes(V, F, labels)
    assert len(rims) == 1
    centre = np.flatnonzero((V2[:, :2] == [5.0, 5.0]).all(axis=1))
    assert len(centre) == 1 and not np.isin(F2, centre).any()
    assert len(meshtopo.boundary_loops(F2)) == 2         # the rim and the grid's own edge


def test_refusals_that_say_closed():
    from fixtures.unseen.metrics import says_closed

    assert says_closed("error: raw_scans/x: left eye looks closed, or too little of the eyeball shows")
    assert says_closed("error: raw_scans/x: both eyes are closed")
    assert not says_closed("error: raw_scans/x: right eye: the cut left a non-simple boundary "
                           "(boundary edges do not form closed loops)")


def test_true_corners_belong_to_the_lids_not_the_turned_eye():
    """An eye turned 30 deg inward (scanify rotates the eyeball, not the lids) keeps its corners."""
    from fixtures.unseen.metrics import true_canthi

    g = _truth_eye("left")
    a = np.radians(-30.0)                       # the left eye turned toward the nose (-X)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    turned = {**g, "gaze_direction": (R @ [0.0, 0.0, 1.0]).tolist()}
    rest = true_canthi(g, "left")
    assert np.allclose(true_canthi(turned, "left", R.tolist())[1], rest[1])
    assert not np.allclose(true_canthi(turned, "left")[1], rest[1])   # what the gaze frame would pick


def _flat_skin_with_eye(side):
    """A 1 mm grid of skin in front of :func:`_truth_eye` (40 x 52 mm, reaching up to a brow so
    that its outer border is no eye hole), 2 mm in front of the eye's corners on the medial half
    and 3 mm on the lateral half, its vertices inside the 24 x 10 mm opening labelled the eyeball
    (1): ``(V, F, labels)``."""
    sgn = 1.0 if side == "left" else -1.0
    x, y = np.meshgrid(np.arange(-20.0, 21.0), np.arange(-12.0, 41.0))
    x, y = x.ravel(), y.ravel()
    V = np.stack([x, y, np.where(sgn * x > 0, 3.0, 2.0)], 1)
    nx = 41
    q = np.array([[i * nx + j, i * nx + j + 1, (i + 1) * nx + j + 1, (i + 1) * nx + j]
                  for i in range(52) for j in range(40)])
    F = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int64)
    labels = np.where((x / 12.0) ** 2 + (y / 5.0) ** 2 < 1.0, 1, 0).astype(np.uint8)
    return V, F, labels


@pytest.mark.parametrize("side", ["left", "right"])
def test_canthus_floor_of_a_known_fill_boundary(side):
    """The fill's boundary runs through (+-12, 0) on the skin 2 mm (medial) and 3 mm (lateral)
    in front of the true corners: no opening along it comes nearer than that."""
    from fixtures.unseen.cases import eye_holes
    from fixtures.unseen.metrics import rim_canthus_floor

    V, F, labels = _flat_skin_with_eye(side)
    V2, _, _, rims = eye_holes(V, F, labels)
    assert len(rims) == 1
    rim = V2[rims[0]]
    assert np.isclose(np.abs(rim[:, 0]).max(), 12.0) and np.isclose(np.abs(rim[:, 1]).max(), 5.0)
    floor = rim_canthus_floor(rim, _truth_eye(side), side)
    # in view, the boundary passes through both corners: only its depth misses them
    assert floor == {"medial": pytest.approx(2.0), "lateral": pytest.approx(3.0),
                     "medial_in_view": pytest.approx(0.0), "lateral_in_view": pytest.approx(0.0)}


def test_canthus_floor_reads_the_unfilled_scan_beside_a_filled_case(tmp_path):
    from fixtures.unseen.cases import _ply_write
    from fixtures.unseen.metrics import canthus_floor

    V, F, labels = _flat_skin_with_eye("left")
    src, folder = tmp_path / "filled_x_src", tmp_path / "filled_x"
    src.mkdir()
    folder.mkdir()
    _ply_write(src / "scan.ply", V, F)
    np.save(src / "scan_labels.npy", labels)
    truth = {"left": _truth_eye("left"), "right": _truth_eye("right")}
    truth["right"]["eyeball_sphere"] = {"center_mm": [60.0, 0.0, 0.0], "radius_mm": 12.0}
    floor = canthus_floor(folder, truth, {})
    assert floor["left"]["medial"] == pytest.approx(2.0) and floor["left"]["lateral"] == pytest.approx(3.0)
    assert canthus_floor(src, truth, {}) is None        # not a filled case: no scan beside it
