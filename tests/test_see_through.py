"""tests/fixtures/see_through.py (what benchmarks/bench_see_through.py measures) on exact geometry."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tests.fixtures.see_through import cornea_cap, view_direction

PARAMS = {"r1": 12.0, "r2": 8.0, "apex": 13.5}


def _eye(scale=1.0):
    return SimpleNamespace(center=np.array([30.0, 30.0, 80.0]), basis=np.eye(3), radius=12.0 * scale,
                           eyeball_params=PARAMS, forward=np.array([0.0, 0.0, 1.0]))


@pytest.mark.parametrize("pitch", [-25.0, 0.0, 25.0])
@pytest.mark.parametrize("scale", [1.0, 11.7 / 12.0])
def test_the_cap_lies_on_the_cornea_outside_the_globe_and_turns_with_the_gaze(pitch, scale):
    eye = _eye(scale)
    T = cornea_cap(eye, pitch)
    P = T.reshape(-1, 3)
    k = scale
    n = np.array([0.0, math.sin(math.radians(pitch)), math.cos(math.radians(pitch))])
    cc = eye.center + k * (PARAMS["apex"] - PARAMS["r2"]) * n
    # every vertex on the corneal sphere, none inside the globe; the rim on the globe itself
    assert np.allclose(np.linalg.norm(P - cc, axis=1), k * PARAMS["r2"], atol=1e-9)
    d = np.linalg.norm(P - eye.center, axis=1)
    assert d.min() == pytest.approx(eye.radius, abs=1e-9)
    # the apex, 13.5 mm (scaled) in front of the centre along the turned gaze
    assert np.max(P @ n - eye.center @ n) == pytest.approx(k * PARAMS["apex"], abs=1e-9)


def test_view_directions_are_unit_and_front_is_the_head_forward():
    assert np.allclose(view_direction(0.0, 0.0), [0.0, 0.0, 1.0])
    for yaw, pitch in ((35.0, 0.0), (-35.0, 0.0), (0.0, 20.0), (0.0, -20.0)):
        v = view_direction(yaw, pitch)
        assert np.linalg.norm(v) == pytest.approx(1.0)
        assert math.degrees(math.acos(v[2])) == pytest.approx(abs(yaw) + abs(pitch))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from pipeline.render import asset as ra
    from tests.fixtures.assets import make_render_asset

    made = make_render_asset(tmp_path_factory.mktemp("see_through"))
    return ra.load_render_asset(made["asset_dir"], made["rig_dir"])


def test_an_opening_the_eye_does_not_fill_is_seen_through_by_its_uncovered_area(tiny):
    """The tiny asset's skin left out: a globe whose silhouette covers its square 16-vertex loop
    (20 mm wide, corners up to 15.9 mm from the eye's centre) leaves nothing; the asset's own
    12.5 mm globe leaves the corners; a 0.5 mm one leaves the loop's area less its own disc and
    the contact strip (front view, orthographic)."""
    from dataclasses import replace

    from tests.fixtures.see_through import CONTACT_MM, opening_uncovered

    bare = replace(tiny, skin_faces=np.zeros((0, 3), np.int64))
    front = view_direction(0.0, 0.0)
    big = replace(bare, eyes={**bare.eyes, "left": replace(bare.eyes["left"], radius=17.0)})
    assert opening_uncovered(big, "left", 0.0, front) == 0.0
    assert opening_uncovered(bare, "left", 0.0, front) > 5.0
    small = replace(bare, eyes={**bare.eyes, "left": replace(bare.eyes["left"], radius=0.5)})
    # the square less its CONTACT_MM strip along the loop (the contact line of a resting margin)
    side = np.ptp(tiny.skin_rest[tiny.eyes["left"].loop][:, :2], axis=0)
    assert side == pytest.approx([20.0, 20.0])
    inner = (20.0 - 2 * CONTACT_MM) ** 2
    assert opening_uncovered(small, "left", 0.0, front) == pytest.approx(inner - math.pi * 0.25, rel=0.02)
    # the skin across the tiny asset's openings covers them whatever the eye
    assert opening_uncovered(replace(tiny, eyes=small.eyes), "left", 0.0, front) == 0.0


def test_the_true_iris_is_hidden_where_skin_lies_in_front_of_it_and_only_there(tiny):
    """The tiny asset's skin is the plane z = 86 mm, open over a 20 mm square round each eye. A
    true iris behind that plane beside the opening is all hidden, the same disc 100 mm in front
    of the face none of it, and a true iris at the asset's own limbus as much as the asset's
    own; with the skin left out, none of any."""
    from dataclasses import replace

    from tests.fixtures.see_through import iris_hidden_share, truth_iris_hidden_share

    eye = tiny.eyes["left"]
    limbus = eye.center + 10.0 / 12.0 * eye.radius * eye.forward
    at = lambda c: {"limbus": {"center_mm": list(c)}, "gaze_direction": eye.forward.tolist()}   # noqa: E731
    beside = np.array([72.0, 0.5, 80.0])              # 20 mm past the opening's edge, 6 mm deep
    assert truth_iris_hidden_share(tiny, "left", at(beside)) == 1.0
    assert truth_iris_hidden_share(tiny, "left", at(beside + [0.0, 0.0, 100.0])) == 0.0
    own = iris_hidden_share(tiny, "left")
    assert own < 0.5
    assert truth_iris_hidden_share(tiny, "left", at(limbus)) == pytest.approx(own, abs=0.12)
    bare = replace(tiny, skin_faces=np.zeros((0, 3), np.int64))
    assert truth_iris_hidden_share(bare, "left", at(beside)) == 0.0 == iris_hidden_share(bare, "left")


def test_a_skin_triangle_poking_into_an_opening_is_a_notch_of_its_depth(tiny):
    """The tiny asset's skin is a flat 5 mm grid over its 20 mm square loops; with the faces inside
    each square cut away, what the lids leave open is the square (convex, no notch); one grid
    triangle left standing on the middle of the upper edge pokes 5 mm into it: a 5 mm notch."""
    from dataclasses import replace

    from tests.fixtures.see_through import JAGGED_MM, SHAPE_PITCHES, opening_shape

    for side in ("left", "right"):
        ring = tiny.skin_rest[tiny.eyes[side].loop]
        lo, hi = ring[:, :2].min(axis=0), ring[:, :2].max(axis=0)
        cen = tiny.skin_rest[tiny.skin_faces].mean(axis=1)[:, :2]
        inside = np.all((cen > lo) & (cen < hi), axis=1)
        opened = replace(tiny, skin_faces=tiny.skin_faces[~inside])
        for pitch in SHAPE_PITCHES:
            solidity, notch = opening_shape(opened, side, pitch)
            assert solidity > 0.98 and notch < 0.1
        # a triangle inside with two corners on the middle of the upper edge
        V = tiny.skin_rest[tiny.skin_faces][:, :, :2]
        on_top = (np.isclose(V[:, :, 1], hi[1]).sum(axis=1) == 2) & (np.abs(V[:, :, 0].mean(axis=1) - (lo[0] + hi[0]) / 2) < 3.0)
        keep = np.flatnonzero(inside & on_top)[:1]
        assert len(keep) == 1
        jag = replace(tiny, skin_faces=np.concatenate([tiny.skin_faces[~inside], tiny.skin_faces[keep]]))
        solidity, notch = opening_shape(jag, side, 0.0)
        assert notch == pytest.approx(5.0, abs=0.1) and notch > JAGGED_MM and solidity < 0.99
