"""Lids that ride on the cornea as the eye turns in yaw (pipeline/rig/yaw_shapes.py): the rule,
the shapes' known answer, the landmark curves and the rig stage's check.

The meshes are the rig tests' constructed eye regions: a margin ring on a 12 mm parametric
eyeball whose upper lid lies on the cornea, skin rings round it.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.eyeball.geometry import EyeballParams
from pipeline.rig import yaw_shapes as ys
from pipeline.rig.lid_shapes import build_lid_shapes
from pipeline.rig.lids import evaluate_shapes
from fixtures.rig import two_eye_region


def test_the_rule_turns_each_eye_by_its_own_yaw_toward_the_nose_or_away():
    # e_x points to the subject's left: the left eye looks in at negative yaw, the right at positive
    w = ys.yaw_weights({"left": -35.0, "right": 17.5}, pitch_deg=0.0)
    on = {k: v for k, v in w.items() if v}
    assert on == {"lids_look_in_left_level_y35": 1.0, "lids_look_in_right_level_y14": 0.5,
                  "lids_look_in_right_level_y21": 0.5}
    assert len(w) == len(ys.yaw_channels("left")) + len(ys.yaw_channels("right"))
    # bilinear: pitch between two knots, yaw between two knots, the weights sum to 1 per eye
    w = ys.yaw_weights({"left": 24.5}, pitch_deg=-18.75)
    on = {k: v for k, v in w.items() if v}
    assert on == pytest.approx({"lids_look_out_left_down25_y21": 0.25, "lids_look_out_left_down25_y28": 0.25,
                                "lids_look_out_left_down12p5_y21": 0.25, "lids_look_out_left_down12p5_y28": 0.25})
    # clamped to the grid; zero yaw moves nothing
    w = ys.yaw_weights({"left": 70.0, "right": -7.0}, pitch_deg=40.0)
    assert w["lids_look_out_left_up25_y35"] == 1.0 and w["lids_look_out_right_up25_y7"] == 1.0
    assert sum(w.values()) == pytest.approx(2.0)
    assert not any(ys.yaw_weights({"left": 0.0}, 10.0).values())
    with pytest.raises(ValueError, match="finite"):
        ys.yaw_weights({"left": float("nan")})
    with pytest.raises(ValueError, match="max_yaw_deg"):
        ys.yaw_weights({"left": 1.0}, max_yaw_deg=0.0)


def _region():
    V, F, eyes = two_eye_region(radius=12.0, profile=EyeballParams(), upper_deg=12.0, lower_deg=10.0,
                                half_width_deg=40.0)
    # the margin lies on the cornea somewhere (off the sphere by more than 0.3 mm): a yaw moves
    # the bulge under it
    assert max((np.linalg.norm(V[e.loop] - e.center, axis=1) - e.radius).max() for e in eyes) > 0.3
    return V, F, eyes


def test_at_every_grid_pose_the_margin_keeps_its_clearance_off_the_turned_eye():
    """Known answer: at each pose of the grid, the pitch channels at its pitch plus its one yaw
    channel put every margin vertex exactly as far off the eye turned by that pose as the pitch
    alone puts it off the eye looking along that pitch; the lids without the yaw channels sink up
    to ~1 mm into it at 35 deg."""
    from pipeline.rig.lids import lid_weights

    V, F, eyes = _region()
    lid = build_lid_shapes(V, F, eyes).shapes
    shapes = ys.build_yaw_shapes(V, eyes, 3.0, lid, 25.0)
    assert [s.name for s in shapes] == [n for e in eyes for n in ys.yaw_channels(e.side)]
    by = {s.name: s for s in shapes}
    for e in eyes:
        for p in ys.PITCH_KNOTS_DEG:
            P0 = evaluate_shapes(V, lid, lid_weights(p, 25.0))
            c = ys.surface_distance(e, P0[e.loop], ys.yaw_gaze(e, p, 0.0))
            for y in (-35.0, -14.0, 7.0, 35.0):
                w = {k: v for k, v in ys.yaw_weights({e.side: y}, p).items() if v}
                assert len(w) == 1 and list(w.values()) == [1.0]
                P = evaluate_shapes(V, lid + [by[list(w)[0]]], {**lid_weights(p, 25.0), **w})
                g = ys.yaw_gaze(e, p, y)
                assert np.abs(ys.surface_distance(e, P[e.loop], g) - c).max() < 1e-9
                if abs(y) == 35.0:
                    assert ys.surface_distance(e, P0[e.loop], g).min() < -0.3


def test_no_lid_sinks_into_the_turned_eye_at_any_pitch_and_yaw():
    """With the pitch rig: the margin stays on the eye at every pitch x yaw checked, between the
    grid's poses too, within 0.1 mm (the pitch sweep's bound) both ways; without the yaw channels
    the cornea cuts through the lids; nothing folds."""
    V, F, eyes = _region()
    lid = build_lid_shapes(V, F, eyes).shapes
    yaw = ys.build_yaw_shapes(V, eyes, 3.0, lid, 25.0)
    yaw, rounds, damped, sweep = ys.settle_yaw_folds(V, F, eyes, lid, yaw, 25.0)
    assert sweep["flipped_faces"] == 0
    assert rounds == 0 and damped == 0
    pitches, yaws = np.arange(-25.0, 25.1, 5.0), np.arange(-35.0, 35.1, 2.5)
    res = ys.yaw_sweep(V, F, eyes, lid + yaw, pitches, yaws, 25.0)
    assert res["max_penetration_mm"] <= 0.1 and res["max_sink_mm"] <= 0.1 and res["max_gap_mm"] <= 0.1
    assert res["flipped_faces"] == 0
    bare = ys.yaw_sweep(V, F, eyes, lid, pitches, yaws, 25.0)
    assert bare["max_penetration_mm"] > 0.3
    # yaw 0 is the pitch rig itself
    for p in (-25.0, 0.0, 25.0):
        w = {"lids_up": max(p, 0) / 25, "lids_down": max(-p, 0) / 25}
        assert np.array_equal(evaluate_shapes(V, lid + yaw, {**w, **ys.yaw_weights({"left": 0.0, "right": 0.0}, p)}),
                              evaluate_shapes(V, lid, w))


def test_a_sphere_gets_no_yaw_channels():
    V, F, eyes = two_eye_region(radius=12.0, upper_deg=12.0, lower_deg=10.0, half_width_deg=40.0)
    assert ys.build_yaw_shapes(V, eyes, 3.0) == []


def test_the_landmark_curve_moves_as_the_mesh_edge_it_lies_on():
    V, F, eyes = _region()
    shapes = ys.build_yaw_shapes(V, eyes, 3.0)
    e = eyes[0]
    edge = np.stack([e.loop, np.roll(e.loop, -1)], axis=1)[:12]
    t = np.linspace(0.1, 0.9, 12)
    curve = ys.curve_shapes(shapes, e.side, edge, t)
    assert [s.name for s in curve] == ys.yaw_channels(e.side)
    for cs in curve[::7]:
        ms = next(s for s in shapes if s.name == cs.name)
        for w in (0.3, 1.0):
            P = evaluate_shapes(V, [ms], {ms.name: w})
            L = (1 - t)[:, None] * P[edge[:, 0]] + t[:, None] * P[edge[:, 1]]
            L0 = (1 - t)[:, None] * V[edge[:, 0]] + t[:, None] * V[edge[:, 1]]
            assert np.abs(evaluate_shapes(L0, [cs], {cs.name: w}) - L).max() < 1e-12
