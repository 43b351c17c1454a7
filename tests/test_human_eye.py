"""The asset's eye: the paper's human eyeball anchored at the scan's limbus (human_eye)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.eyeball.geometry import EyeballParams, placed_params
from pipeline.placement import human_eye
from pipeline.remove_eyeballs.remove_eyeballs import remove_eyeballs
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings
from fixtures.eye_heads import make_head


def test_limbus_depth_of_the_papers_eye():
    """Known answer: spheres r1 12 and r2 8 with the apex at 13.5 (corneal centre at 5.5) meet
    at z = (144 + 5.5^2 - 64) / 11 = 10.0227 mm, radius sqrt(144 - z^2)."""
    p = EyeballParams()
    z = (144.0 + 5.5 ** 2 - 64.0) / 11.0
    assert human_eye.limbus_depth(p) == pytest.approx(z, abs=1e-12)
    assert human_eye.limbus_radius(p) == pytest.approx(math.sqrt(144.0 - z * z), abs=1e-12)
    # a larger globe keeps the cornea's mm (placed_params): its limbus lies deeper, off a flatter cap
    big = placed_params(p, 16.0)
    assert human_eye.limbus_depth(big) > 13.0
    c = human_eye.anchor_center([1.0, 2.0, 3.0], [0.0, 0.0, 2.0], p)
    assert np.allclose(c, [1.0, 2.0, 3.0 - z])


def test_asset_radius_modes():
    fitted = {"left": (15.0, 0.45), "right": (15.0, 0.45)}
    assert human_eye.asset_radius("human", fitted, 12.0) == {"left": (12.0, 0.0), "right": (12.0, 0.0)}
    assert human_eye.asset_radius("fitted", {"left": (14.0, 0.3), "right": (15.0, None)}) == \
        {"left": (14.0, 0.3), "right": (15.0, 0.0)}
    # the population (11.7 +- 0.45) and two eyes of 15 +- 0.45: the precision-weighted mean
    pop = human_eye.asset_radius("population", fitted)
    assert pop["left"] == pop["right"]
    assert pop["left"][0] == pytest.approx((11.7 + 15.0 + 15.0) / 3.0)
    assert pop["left"][1] == pytest.approx(0.45 / math.sqrt(3.0))
    # no evidence (texture placements): the population itself
    assert human_eye.asset_radius("population", {"left": (12.0, None), "right": (13.0, np.inf)})["left"] \
        == pytest.approx((11.7, 0.45))
    with pytest.raises(ValueError, match="eye_size"):
        human_eye.asset_radius("huge", fitted)


def _almond(cx=0.0, z=11.0, a=13.5, b=4.75, n=64):
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.column_stack([cx + a * np.cos(t), b * np.sin(t), np.full(n, z)])


def test_iris_in_opening_centred_and_in_a_corner():
    L = _almond()
    mid = human_eye.iris_in_opening(L, [0.0, 0.0, 10.0], [0.0, 0.0, 1.0], 5.85)
    assert mid["center_inside"] and 0.6 < mid["visible_share"] < 0.9
    assert mid["offset_mm"] == pytest.approx(0.0, abs=1e-9)
    assert mid["opening_half_width_mm"] == pytest.approx(13.5)
    # turned 57 deg toward a corner: the iris centre leaves the opening
    corner = human_eye.iris_in_opening(L, [15.0, -2.0, 6.0], [0.0, 0.0, 1.0], 5.85)
    assert not corner["center_inside"] and corner["visible_share"] < 0.2


def _scan_eye(lc, axis, loop, prior_axis=None, sigma=(0.2, 0.5)):
    return {"limbus_center": np.asarray(lc, float), "axis": np.asarray(axis, float), "limbus_radius": 6.6,
            "sigma_limbus_mm": sigma[0], "sigma_axis_deg": sigma[1], "source": "geometry",
            "radius": 15.0, "sigma_radius": 0.5, "loop_points": loop, "prior_axis": prior_axis}


def test_asset_eyes_anchor_one_size_and_fall_back_on_a_hidden_iris():
    L = _almond()
    turned = np.array([math.sin(math.radians(57.0)), 0.0, math.cos(math.radians(57.0))])
    scan = {"left": _scan_eye([0.0, 0.0, 10.0], [0.0, 0.0, 1.0], L),
            "right": _scan_eye([14.0, -1.0, 7.0], turned, L, prior_axis=[0.0, 0.1, 1.0])}
    out = human_eye.asset_eyes(scan, eye_size="human", eyeball=EyeballParams())
    d = human_eye.limbus_depth(EyeballParams())
    left, right = out["left"], out["right"]
    assert left["radius"] == right["radius"] == 12.0
    assert np.allclose(left["center"], [0.0, 0.0, 10.0 - d])
    assert left["doubts"] == [] and left["limbus"]["source"] == "geometry"
    # sigma of the centre: the limbus's and the axis's lever over the limbus depth
    assert left["uncertainty"]["center_mm"] == pytest.approx(math.hypot(0.2, d * math.radians(0.5)))
    # the iris turned into the corner: placed from the opening, along the prior's axis, doubted
    assert right["limbus"]["source"] == "opening" and len(right["doubts"]) == 1
    assert "lid opening at rest" in right["doubts"][0]
    assert np.allclose(right["forward"], np.array([0.0, 0.1, 1.0]) / np.linalg.norm([0.0, 0.1, 1.0]))
    assert right["iris"]["center_inside"] and right["iris"]["visible_share"] > 0.5
    assert right["uncertainty"]["limbus_mm"] == human_eye.OPENING_SIGMA_MM
    # an eye whose limbus the scan shows loosely is published with a doubt
    loose = human_eye.asset_eyes({**scan, "right": _scan_eye([0.0, 0.0, 10.0], [0, 0, 1], L, sigma=(0.9, 1.0))},
                                 eye_size="human", eyeball=EyeballParams())
    assert any("limbus centre +-0.90 mm" in x for x in loose["right"]["doubts"])


def test_a_mostly_hidden_iris_on_an_unsure_axis_falls_back_to_the_opening():
    """An iris 40 % inside the opening is a look up when the scan is sure of the axis, and an eye
    the scan could not turn when it is not (the half-blinked head's eye, 34 deg off at +-17 deg)."""
    L = _almond()
    up = np.array([0.0, math.sin(math.radians(30.0)), math.cos(math.radians(30.0))])
    lc = [0.0, 5.2, 9.0]
    iris = human_eye.iris_in_opening(L, lc, up, 5.85)
    assert 0.05 < iris["visible_share"] < human_eye.UNSURE_HIDDEN_SHARE
    assert iris["offset_mm"] < iris["opening_half_width_mm"]
    sure = human_eye.asset_eyes({"left": _scan_eye(lc, up, L, sigma=(0.3, 1.5)),
                                 "right": _scan_eye(lc, up, L, prior_axis=[0, 0, 1], sigma=(0.3, 6.0))},
                                eye_size="human", eyeball=EyeballParams())
    assert sure["left"]["limbus"]["source"] == "geometry" and sure["left"]["doubts"] == []
    assert np.allclose(sure["left"]["forward"], up)
    unsure = sure["right"]
    assert unsure["limbus"]["source"] == "opening" and np.allclose(unsure["forward"], [0, 0, 1])
    assert "axis +-6.0 deg" in unsure["doubts"][0] and unsure["iris"]["visible_share"] > 0.5
    # at the doubt level itself the axis is sure enough to believe the look
    assert not human_eye.iris_hidden(iris, 0.05, 2.0, 2.0)
    assert human_eye.iris_hidden(iris, 0.05, 2.01, 2.0)
    # a sure axis on a limbus the scan is unsure of (id303_down's right eye: +-0.84 mm, +-1.5 deg,
    # turned 47 deg off) believes no look either
    assert not human_eye.iris_hidden(iris, 0.05, 1.5, 2.0, 0.5, 0.5)
    assert human_eye.iris_hidden(iris, 0.05, 1.5, 2.0, 0.51, 0.5)
    loose = human_eye.asset_eyes({"left": _scan_eye(lc, up, L, prior_axis=[0, 0, 1], sigma=(0.84, 1.5)),
                                  "right": _scan_eye(lc, up, L, sigma=(0.3, 1.5))},
                                 eye_size="human", eyeball=EyeballParams())
    assert loose["left"]["limbus"]["source"] == "opening" and "limbus +-0.84 mm" in loose["left"]["doubts"][0]
    assert loose["right"]["limbus"]["source"] == "geometry"
    # the iris plane's normal is not the optical axis: that joins the stated sigma, not the test of
    # how sure the fit is of where the iris lies (the look stays believed)
    read = human_eye.asset_eyes({"left": {**_scan_eye(lc, up, L, sigma=(0.3, 1.5)), "axis_model_sigma_deg": 2.3},
                                 "right": _scan_eye(lc, up, L, sigma=(0.3, 1.5))},
                                eye_size="human", eyeball=EyeballParams())
    assert read["left"]["limbus"]["source"] == "geometry" and np.allclose(read["left"]["forward"], up)
    assert read["left"]["uncertainty"]["axis_deg"] == pytest.approx(math.hypot(1.5, 2.3))
    assert read["right"]["uncertainty"]["axis_deg"] == pytest.approx(1.5)


def test_an_axis_off_the_eyes_front_falls_back_to_the_opening():
    """An axis over eye surface that dips below its sides is believed only where the scan shows
    no front of an eye elsewhere and the iris is not in the opening's outer reach (the eyes
    published 37-50 deg off at +-3-4 deg dipped 0.57-1.10 mm)."""
    L = _almond()
    turned = np.array([math.sin(math.radians(25.0)), 0.0, math.cos(math.radians(25.0))])
    lc = [0.65 * 13.5, 0.0, 8.5]
    iris = human_eye.iris_in_opening(L, lc, turned, 5.85)
    assert iris["visible_share"] >= human_eye.UNSURE_HIDDEN_SHARE
    assert iris["offset_mm"] > human_eye.CORNER_OFFSET_SHARE * iris["opening_half_width_mm"]
    assert not human_eye.iris_hidden(iris, 0.05, 1.5, 2.0, 0.3, 0.5)
    dip = -human_eye.CORNER_DIP_MM
    # in the outer reach: a dip of CORNER_DIP_MM is still an eye's front, a hair more is not
    assert not human_eye.axis_off_front(iris, dip)
    assert human_eye.axis_off_front(iris, dip - 0.01)
    assert not human_eye.axis_off_front(iris, None) and not human_eye.axis_off_front(iris, float("nan"))
    # near the centre: a dip is a recessed iris unless the scan shows a front elsewhere
    near = human_eye.iris_in_opening(L, [0.3 * 13.5, 0.0, 9.5], turned, 5.85)
    assert not human_eye.axis_off_front(near, -1.0)
    assert not human_eye.axis_off_front(near, -1.0, human_eye.FRONT_SHOWS_MM - 0.01)
    assert human_eye.axis_off_front(near, -1.0, human_eye.FRONT_SHOWS_MM)
    assert not human_eye.axis_off_front(near, dip, 1.0)
    eye = lambda st, front=None: {**_scan_eye(lc, turned, L, prior_axis=[0, 0, 1], sigma=(0.3, 1.5)),
                                  "axis_standoff_mm": st, "front_elsewhere_mm": front}
    out = human_eye.asset_eyes({"left": eye(0.4), "right": eye(-0.9, 0.6)}, eye_size="human",
                               eyeball=EyeballParams())
    assert out["left"]["limbus"]["source"] == "geometry" and np.allclose(out["left"]["forward"], turned)
    right = out["right"]
    assert right["limbus"]["source"] == "opening" and np.allclose(right["forward"], [0, 0, 1])
    assert "0.90 mm below its sides" in right["doubts"][0] and "+0.60 mm elsewhere" in right["doubts"][0]
    assert right["uncertainty"]["axis_deg"] == human_eye.OPENING_AXIS_SIGMA_DEG


def test_front_elsewhere_finds_the_bulge_the_axis_misses():
    """Known answer: a 12 mm sclera with a 1 mm cap raised within 15 deg of a gaze 35 deg to the
    side. Along a forward axis the surface stands flush (no front there); the search finds the
    cap's 1 mm standoff in a direction whose 12 deg inner cone lies mostly on the cap (a front,
    not a gaze), and none on a bare sphere."""
    from pipeline.placement import checks

    rng = np.random.default_rng(3)
    u = rng.normal(size=(6000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    g = np.array([math.sin(math.radians(35.0)), 0.0, math.cos(math.radians(35.0))])
    u = u[u[:, 2] > math.cos(math.radians(70.0))]
    lift = np.where(u @ g > math.cos(math.radians(15.0)), 1.0, 0.0)
    P = u * (12.0 + lift)[:, None]
    lim = checks.CheckLimits()
    assert checks.cornea_standoff(P, np.zeros(3), 12.0, np.array([0.0, 0.0, 1.0]), lim) == pytest.approx(0.0, abs=1e-9)
    best, at = checks.front_elsewhere(P, np.zeros(3), 12.0, np.array([0.0, 0.0, 1.0]), lim)
    assert best == pytest.approx(1.0, abs=1e-9)
    assert math.degrees(math.acos(float(at @ g))) <= 12.0
    flat, _ = checks.front_elsewhere(u * 12.0, np.zeros(3), 12.0, np.array([0.0, 0.0, 1.0]), lim)
    assert abs(flat) < 1e-9


@pytest.mark.slow
def test_a_12mm_eye_is_placed_within_0_2mm_and_1deg():
    """The height-field head carries the paper's eye (r1 12, cornea 8, apex 13.5) at (+-30, 0, 0)
    looking along +Z: the asset's eye lands on it."""
    mesh, hints, gt = make_head(0.5, seed=1, noise=0.02)
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings())
    for s in ("left", "right"):
        e = res.eyes[s].to_doc()
        assert e["radius"] == 12.0 and e["eye_size"] == "human"
        assert np.linalg.norm(np.array(e["center"]) - gt[s]["center"]) <= 0.2, (s, e["center"])
        assert np.degrees(np.arccos(min(1.0, e["forward"][2]))) <= 1.0
        assert e["limbus"]["source"] == "geometry" and e["iris_at_rest"]["center_inside"]


def test_spheres_that_disagree_widen_the_sigma_of_the_eyes_the_geometry_places():
    """A pair whose fitted radii disagree past radii_agree's limit (n907_wide_right: 13.3 and
    20.5 mm, its right eye 23 deg off at a stated 3.6 deg) has one sphere in a wrong basin: each
    geometry eye joins 0.3 mm and 2 deg per mm of disagreement to its sigmas, in quadrature; an
    eye placed otherwise keeps its own; the placement itself does not move."""
    L = _almond()
    scan = {"left": _scan_eye([0.0, 0.0, 10.0], [0.0, 0.0, 1.0], L, sigma=(0.4, 1.5)),
            "right": _scan_eye([0.0, 0.0, 10.0], [0.0, 0.0, 1.0], L, sigma=(0.4, 1.5))}
    agree = human_eye.asset_eyes(scan, eye_size="human", eyeball=EyeballParams())
    apart = human_eye.asset_eyes(scan, eye_size="human", eyeball=EyeballParams(), pair_disagree_mm=7.0)
    u, w = agree["left"]["uncertainty"], apart["left"]["uncertainty"]
    assert (u["limbus_mm"], u["axis_deg"]) == (0.4, 1.5)
    assert w["limbus_mm"] == pytest.approx(math.hypot(0.4, human_eye.PAIR_LIMBUS_MM_PER_MM * 7.0))
    assert w["axis_deg"] == pytest.approx(math.hypot(1.5, human_eye.PAIR_AXIS_DEG_PER_MM * 7.0))
    assert w["axis_deg"] > 14.0 and w["center_mm"] > u["center_mm"]
    assert np.allclose(apart["left"]["center"], agree["left"]["center"])
    assert np.allclose(apart["left"]["forward"], agree["left"]["forward"])
    assert any("little evidence" in d for d in apart["left"]["doubts"])
    # an eye not placed by the geometry (its opening, a fill, a texture) keeps its own sigma
    opening = human_eye.asset_eyes({**scan, "right": {**scan["right"], "source": "opening"}},
                                   eye_size="human", eyeball=EyeballParams(), pair_disagree_mm=7.0)
    assert opening["right"]["uncertainty"]["limbus_mm"] == 0.4


@pytest.mark.slow
def test_unequal_scan_spheres_give_one_human_size_or_the_fitted_ones():
    mesh, hints, gt = make_head(0.5, seed=3, noise=0.02, radii=(12.0, 14.0))
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings())
    assert res.eyes["left"].radius == res.eyes["right"].radius == 12.0
    fitted = remove_eyeballs(mesh, hints, RemoveEyeballsSettings(eye_size="fitted"))
    for s in ("left", "right"):
        e = fitted.eyes[s].to_doc()
        assert e["radius"] == pytest.approx(e["scan_sphere"]["radius"], abs=1e-5)
        assert abs(e["radius"] - gt[s]["radius"]) <= 0.5


def test_an_eye_placed_from_its_opening_is_set_back_until_its_lids_may_rest_on_it():
    """An almond margin 11 mm in front of a 12 mm eye's centre whose limbus the opening put
    10.5 mm in front of it: the lids lie inside that eye deeper than ``loop_on_eye`` allows, so
    it is set back along its axis by the smallest step at which they do not, and the shift
    joins its sigmas and a doubt."""
    from pipeline.placement import checks as eye_checks
    from pipeline.placement.place import SEAT_STEP_MM, loop_on_asset_eye, seat_behind_loop

    L = _almond(z=11.0, a=11.0, b=4.0)
    lim = eye_checks.limits_for(0.5)
    eye = {"center": np.array([0.0, 0.0, 0.5]), "radius": 12.0, "forward": np.array([0.0, 0.0, 1.0]),
           "limbus": {"center": np.array([0.0, 0.0, 10.52])},
           "uncertainty": {"limbus_mm": 4.0, "center_mm": 5.0}, "doubts": []}
    before = loop_on_asset_eye(L, eye, EyeballParams(), lim, 32)["value"]
    assert before > lim.max_loop_off_mm + 0.2
    shift = seat_behind_loop(eye, L, EyeballParams(), lim, 32)
    assert 0.0 < loop_on_asset_eye(L, eye, EyeballParams(), lim, 32)["value"] <= lim.max_loop_off_mm
    short = dict(eye, center=eye["center"] + SEAT_STEP_MM * eye["forward"])
    assert loop_on_asset_eye(L, short, EyeballParams(), lim, 32)["value"] > lim.max_loop_off_mm
    assert np.allclose(eye["center"], [0.0, 0.0, 0.5 - shift])
    assert np.allclose(eye["limbus"]["center"], [0.0, 0.0, 10.52 - shift])
    assert eye["uncertainty"]["limbus_mm"] == pytest.approx(math.hypot(4.0, shift))
    assert f"set back {shift:.2f} mm" in eye["doubts"][0]
    # an eye its lids may rest on stays where it is
    assert seat_behind_loop(eye, L, EyeballParams(), lim, 32) == 0.0 and len(eye["doubts"]) == 1
    # a loop round the globe's middle, 6 mm from its axis, lies inside it however far it is set
    # back (up to SEAT_MAX_MM): the eye stays as placed and loop_on_eye says so
    deep = dict(eye, center=np.zeros(3), doubts=[])
    ring = _almond(z=0.5, a=6.0, b=6.0)
    assert seat_behind_loop(deep, ring, EyeballParams(), lim, 32) == 0.0
    assert np.allclose(deep["center"], 0.0) and deep["doubts"] == []
    assert loop_on_asset_eye(ring, deep, EyeballParams(), lim, 32)["value"] > lim.max_loop_off_mm


def test_two_eyes_turned_apart_in_elevation_widen_both_sigmas():
    """A person's two eyes turn up and down together (the truths of 277 unseen heads within
    6 deg): a pair the geometry placed 12 deg apart in elevation (fresh51's 200k wink: its
    closed left eye 34 deg off at a stated 7.5 deg) has one eye turned, and either may be it:
    both join the difference to their axis sigma and the limbus's swing about the centre to
    their limbus sigma, in quadrature, and say so; the eyes themselves do not move. 7 deg
    apart, both looking 20 deg up together, or a partner placed from its opening changes
    nothing."""
    L = _almond()

    def down(deg):
        a = math.radians(deg)
        return [0.0, -math.sin(a), math.cos(a)]

    def pair(left_deg, right_deg):
        scan = {"left": _scan_eye([0.0, 0.0, 10.0], down(left_deg), L, sigma=(0.4, 1.5)),
                "right": _scan_eye([0.0, 0.0, 10.0], down(right_deg), L, sigma=(0.4, 1.5))}
        return human_eye.asset_eyes(scan, eye_size="human", eyeball=EyeballParams())

    assert human_eye.elevation_difference_deg(down(12.0), down(0.0)) == pytest.approx(12.0)
    assert human_eye.elevation_difference_deg(down(-20.0), down(-20.0)) == pytest.approx(0.0, abs=1e-9)
    apart, near, up = pair(12.0, 0.0), pair(7.0, 0.0), pair(-20.0, -20.0)
    d = human_eye.limbus_depth(EyeballParams())
    for s in ("left", "right"):
        u = apart[s]["uncertainty"]
        assert u["axis_deg"] == pytest.approx(math.hypot(1.5, 12.0))
        assert u["limbus_mm"] == pytest.approx(math.hypot(0.4, d * math.sin(math.radians(12.0))))
        assert u["center_mm"] > near[s]["uncertainty"]["center_mm"]
        assert any("differ in elevation by 12.0 deg" in x for x in apart[s]["doubts"])
        for quiet in (near, up):
            assert (quiet[s]["uncertainty"]["limbus_mm"], quiet[s]["uncertainty"]["axis_deg"]) == (0.4, 1.5)
            assert not any("elevation" in x for x in quiet[s]["doubts"])
    assert np.allclose(apart["left"]["forward"], down(12.0)) and np.allclose(apart["right"]["forward"], down(0.0))
    assert human_eye.ELEVATION_PAIR_DEG == 8.0
    # an eye placed from its opening looks along the eye region's forward: no reading of its gaze
    scan = {"left": _scan_eye([0.0, 0.0, 10.0], down(12.0), L, sigma=(0.4, 1.5)),
            "right": {**_scan_eye([0.0, 0.0, 10.0], down(0.0), L, sigma=(0.4, 1.5)), "source": "opening"}}
    one = human_eye.asset_eyes(scan, eye_size="human", eyeball=EyeballParams())
    assert one["left"]["uncertainty"]["axis_deg"] == 1.5 and not any("elevation" in x for x in one["left"]["doubts"])
