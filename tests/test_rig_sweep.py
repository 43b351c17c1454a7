"""The rig's pitch sweep (pipeline/rig/sweep.py): the margin stays on the eyeball, nothing flips or crosses,
the cornea's intrusion, and the forked sweep equals the single-process one."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures.rig import PITCHES_1DEG, two_eye_region
from pipeline.rig import lids
from pipeline.rig.eye_frame import EyeFrame
from pipeline.rig.lid_shapes import build_lid_shapes
from pipeline.rig.sweep import cornea_intrusion, lid_opening, sweep_check


@pytest.mark.parametrize("radius", [12.0, 15.4, 17.1])
def test_sweep_keeps_margin_on_eyeball_no_flips_no_crossing(radius):
    V, F, eyes = two_eye_region(radius=radius)
    rig = build_lid_shapes(V, F, eyes)
    res = sweep_check(V, F, eyes, rig.shapes, PITCHES_1DEG)
    assert res["n_pitches"] == 51
    assert res["rest_max_abs_mm"] < 1e-9
    assert res["max_gap_mm"] <= 0.1
    assert res["max_penetration_mm"] <= 0.1
    assert res["max_penetration_mm"] <= lids.LidParams().max_chord_sag_mm + 1e-9
    assert res["flipped_faces"] == 0
    assert res["min_opening_mm"] > 0.5
    assert res["min_skin_clearance_mm"] > 0.0
    assert res["max_skin_sink_mm"] <= lids.LidParams().max_chord_sag_mm + 1e-9


def test_margin_exactly_on_sphere_at_stored_poses(region):
    V, F, eyes, rig = region
    n = rig.n_segments
    for j in range(-n, n + 1):
        P = lids.evaluate_shapes(V, rig.shapes, lids.lid_weights(25.0 * j / n))
        for e in eyes:
            d = np.linalg.norm(P[e.loop] - e.center, axis=1) - e.radius
            assert np.abs(d).max() < 1e-9


def test_without_inbetweens_the_chord_sinks_into_the_eyeball():
    V, F, eyes = two_eye_region(radius=15.4)
    one = build_lid_shapes(V, F, eyes, lids.LidParams(max_segments=1))
    assert one.n_segments == 1
    res = sweep_check(V, F, eyes, one.shapes, np.arange(-25.0, 25.01, 0.5))
    assert res["max_penetration_mm"] > 0.1          # the problem inbetweens fix
    assert res["max_penetration_mm"] == pytest.approx(one.predicted_sag_mm, rel=0.02)
    assert res["max_gap_mm"] < 1e-9                 # chords only ever cut inside the sphere


def test_cornea_intrusion_geometry():
    eye = EyeFrame("left", np.zeros(3), 12.0, np.array([0.0, 0, 1]), np.arange(8), 4)
    cornea_c, cornea_r = np.array([0.0, 0, 5.5]), 8.0            # apex at 13.5 mm
    pts = np.array([[0, 0, 12.0], [0, 12.0, 0], [0, 0, -12.0]])
    got = cornea_intrusion(pts, eye, cornea_c, cornea_r, 0.0)
    np.testing.assert_allclose(got, [1.5, 0.0, 0.0], atol=1e-12)
    # pitched up 90 deg, the apex points along +Y
    got = cornea_intrusion(pts, eye, cornea_c, cornea_r, 90.0)
    np.testing.assert_allclose(got, [0.0, 1.5, 0.0], atol=1e-9)


def _sweep_cases():
    V, F, eyes = two_eye_region(radius=15.4)
    from pipeline.rig.build import _model_corneas
    full = build_lid_shapes(V, F, eyes)
    one = build_lid_shapes(V, F, eyes, lids.LidParams(max_segments=1))
    return {
        "corneas": (V, F, eyes, full.shapes, PITCHES_1DEG, _model_corneas(eyes)),
        "sagging_chords_odd": (V, F, eyes, one.shapes, np.arange(-25.0, 25.01, 0.5), None),
        "two_pitches": (V, F, eyes, one.shapes, [25.0, -25.0], _model_corneas(eyes)),
        "one_pitch": (V, F, eyes, full.shapes, [0.0], _model_corneas(eyes)),
    }


@pytest.mark.parametrize("case", ["corneas", "sagging_chords_odd", "two_pitches", "one_pitch"])
def test_forked_sweep_equals_the_single_process_sweep(case):
    # the first half of the pitches in a child; every measure, the worst pitch and the key order
    # (the metrics file's bytes) must be those of the one-process sweep
    V, F, eyes, shapes, pitches, corneas = _sweep_cases()[case]
    here = sweep_check(V, F, eyes, shapes, pitches, corneas=corneas)
    forked = sweep_check(V, F, eyes, shapes, pitches, corneas=corneas, fork=True)
    assert list(forked.items()) == list(here.items())
    if case == "sagging_chords_odd":
        assert here["max_penetration_mm"] > 0.1 and here["n_pitches"] == 101
        assert here["worst_pitch_deg"] < 0          # found in the child's half of the pitches


def test_forked_sweep_child_failure_is_rerun_here(monkeypatch):
    import os
    from pipeline.rig import sweep as sweep_mod
    V, F, eyes, shapes, pitches, corneas = _sweep_cases()["corneas"]
    here = sweep_check(V, F, eyes, shapes, pitches, corneas=corneas)
    parent, real = os.getpid(), sweep_mod._sweep_pitches

    def child_fails(*args):
        if os.getpid() != parent:
            raise MemoryError("child ran out")
        return real(*args)

    monkeypatch.setattr(sweep_mod, "_sweep_pitches", child_fails)
    forked = sweep_check(V, F, eyes, shapes, pitches, corneas=corneas, fork=True)
    assert list(forked.items()) == list(here.items())


def _lid_opening_loop(P, eye, n_lines=64, margin_frac=0.02):
    """lid_opening as it was, one vertical line at a time (the reference)."""
    B = eye.basis()
    li = int(eye.lateral_index)
    Q = (np.asarray(P)[np.asarray(eye.loop)] - eye.center) @ B[:2].T
    up, lo = Q[: li + 1], np.concatenate([Q[li:], Q[:1]])
    xa, xb = sorted((Q[0, 0], Q[li, 0]))
    xs = np.linspace(xa + margin_frac * (xb - xa), xb - margin_frac * (xb - xa), n_lines)

    def heights(poly, reduce):
        x0, y0, x1, y1 = poly[:-1, 0], poly[:-1, 1], poly[1:, 0], poly[1:, 1]
        res = np.full(len(xs), np.nan)
        for k, s in enumerate(xs):
            hit = ((x0 - s) * (x1 - s) <= 0) & (np.abs(x1 - x0) > 1e-12)
            if hit.any():
                res[k] = reduce(y0[hit] + (s - x0[hit]) / (x1[hit] - x0[hit]) * (y1[hit] - y0[hit]))
        return res

    return heights(up, np.min) - heights(lo, np.max)


def test_lid_opening_equals_the_line_by_line_loop():
    # jagged, crossing and folded-back loops: the same numbers
    rng = np.random.default_rng(5)
    n_crossed = 0
    for trial in range(60):
        n = int(rng.integers(6, 90))
        li = int(rng.integers(2, n - 2))
        t = np.linspace(np.pi, -np.pi, n, endpoint=False)
        P = np.stack([12 * np.cos(t), 5 * np.sin(t) + rng.normal(0, 2, n), rng.normal(0, 1, n)], 1)
        eye = EyeFrame("left", np.array([0.0, 0, -10]), 12.0, np.array([0.0, 0, 1]), np.arange(n), li)
        ref = _lid_opening_loop(P, eye)
        got = lid_opening(P, eye)
        np.testing.assert_array_equal(got, ref)
        n_crossed += int((ref < 0).sum())
    assert n_crossed > 0 and np.isfinite(ref).all()


def test_rest_cornea_intrusion_is_the_worse_eye():
    # it used to keep whichever eye was swept last at pitch 0
    V, F, eyes, shapes, _, corneas = _sweep_cases()["corneas"]
    centre, radius = corneas["right"]          # the fixture is symmetric: bulge one cornea more
    corneas = {**corneas, "right": (centre, radius + 0.3)}
    per_eye = {side: sweep_check(V, F, eyes, shapes, [0.0], corneas={side: c})
               ["rest_cornea_intrusion_mm"] for side, c in corneas.items()}
    both = sweep_check(V, F, eyes, shapes, [0.0], corneas=corneas)["rest_cornea_intrusion_mm"]
    assert len(per_eye) == 2 and per_eye["left"] != per_eye["right"]
    assert both == max(per_eye.values())


def test_fold_report_names_the_eye_lid_ring_and_pitch_of_a_constructed_fold():
    """One vertex of the right eye's lower lid, three edge rings out below loop vertex 36 (the
    lowest of 48), pulled 2.5 times across its inner neighbour by lids_down: the faces around it
    turn over looking down, and the report says so (pipeline/rig/folds.py)."""
    from pipeline.io.blend_shapes import BlendShape
    from pipeline.rig.folds import describe_folds, fold_report

    V, F, eyes = two_eye_region(radius=12.0)
    right = eyes[1]
    n_loop = len(right.loop)
    base = int(right.loop[0])                    # the right eye's ring 0 starts here
    v, u = base + 3 * n_loop + 36, base + 2 * n_loop + 36
    shape = BlendShape(name=lids.SHAPE_DOWN, point_indices=np.array([v]),
                       offsets=2.5 * (V[u] - V[v])[None])
    rest = fold_report(V, F, eyes, [], PITCHES_1DEG, 25.0)
    assert rest is None                          # nothing moves, nothing folds
    rep = fold_report(V, F, eyes, [shape], PITCHES_1DEG, 25.0)
    assert rep is not None and list(rep["per_lid"]) == ["right lower lid"]
    w = rep["worst"]
    assert (w["side"], w["lid"], w["loop_length"]) == ("right", "lower lid", n_loop)
    assert (w["loop_vertex"], w["ring"]) == (36, 2)              # the faces between rings 2 and 3
    # it crosses its inner neighbour at 0.4 of lids_down: pitch -10 deg, and only looking down
    assert w["turn_deg"] > 90.0 and -11.0 <= w["first_pitch_deg"] <= -9.0 and -25.0 <= w["pitch_deg"] < 0.0
    assert rep["first_pitch_deg"] == w["first_pitch_deg"] and rep["faces"] >= 2
    assert np.linalg.norm(np.array(w["position_mm"]) - V[v]) < 3.0 and w["position_mm"][0] < 0
    msg = describe_folds(rep)
    assert msg.startswith("worst on the right eye's lower lid: a face turned ")
    assert f"out from loop vertex {w['loop_vertex']} of {n_loop}" in msg and "mm in the head frame" in msg
    assert f"at pitch {w['pitch_deg']:+g} deg (over from {w['first_pitch_deg']:+g} deg)" in msg


def test_a_crease_unrolling_is_no_fold_and_skin_folding_under_is():
    """pipeline/geometry/meshtopo.turned_over_faces: an eye region facing +z whose crease's
    underside (facing -z) turns 130 degrees to face out as a lid comes down folds nothing; the
    same turn of skin that faced out, now facing in, does; a closed surface (normals summing to
    nothing) is judged by the turn alone."""
    from pipeline.geometry.meshtopo import turned_over_faces

    def turn(n, deg):
        a = np.radians(deg)
        R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
        return n @ R.T

    out = np.tile([0.0, 0.0, 1.0], (20, 1))                        # the region, facing +z
    under = turn(np.array([[0.0, 0.0, 1.0]]), 140.0)               # a crease's underside, facing in
    n0 = np.vstack([out, under])
    unroll = n0.copy()
    unroll[-1] = turn(under, -130.0)[0]                            # turned out again
    assert float(n0[-1] @ unroll[-1]) < 0 and not turned_over_faces(n0, unroll).any()
    fold = n0.copy()
    fold[0] = turn(out[:1], 130.0)[0]                              # skin that faced out, turned in
    assert np.flatnonzero(turned_over_faces(n0, fold)).tolist() == [0]
    assert not turned_over_faces(n0, n0).any()
    closed = np.vstack([out[:10], -out[:10]])                      # no way it faces
    flip = closed.copy()
    flip[12] = -flip[12]
    assert np.flatnonzero(turned_over_faces(closed, flip)).tolist() == [12]
