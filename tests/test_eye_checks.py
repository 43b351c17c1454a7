"""eye_checks: the anatomical self-checks of a fitted eye, on exact geometry."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.placement import checks as eye_checks
from pipeline.placement.checks import CheckLimits, check_eye, check_pair, failed, inside_area


def _sphere_patch(center, radius, max_deg, n=40):
    """A spherical cap (triangulated) of half-angle ``max_deg`` around +Z."""
    th = np.radians(np.linspace(0.0, max_deg, n))
    ph = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = center + radius * np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    V = V.reshape(-1, 3)
    idx = np.arange(n * 2 * n).reshape(n, 2 * n)
    a, b = idx[:-1], np.roll(idx, -1, axis=1)[:-1]
    c, d = np.roll(idx, -1, axis=1)[1:], idx[1:]
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return V, F


def _loop(center, radius, deg=55.0, k=48):
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    th = np.radians(deg)
    return center + radius * np.column_stack([np.sin(th) * np.cos(t), 0.4 * np.sin(th) * np.sin(t),
                                              np.sqrt(1 - (np.sin(th) * np.cos(t)) ** 2
                                                      - (0.4 * np.sin(th) * np.sin(t)) ** 2)])


C, R, FWD = np.zeros(3), 12.0, np.array([0.0, 0.0, 1.0])


def test_the_true_sphere_passes_every_check():
    V, F = _sphere_patch(C, R + 0.1, 70.0)        # scanned surface just outside the eye
    ch = check_eye(V, F, C, R, FWD, _loop(C, R), CheckLimits())
    assert failed(ch) == []
    assert ch["inside"]["value"] == 0.0
    assert ch["loop_on_sphere"]["value"] == pytest.approx(0.0, abs=1e-9)
    assert 0.5 < ch["opening_fits"]["value"] < 1.0


def test_a_sphere_too_large_has_the_head_inside():
    """The fitted sphere is 1.5 mm too large: the whole cap lies 1.5 mm inside, far beyond the
    noise; the inside area is the cap's area outside the corneal cone."""
    V, F = _sphere_patch(C, R, 60.0, n=60)
    lim = CheckLimits()
    area = inside_area(V, F, C, R + 1.5, FWD, V.mean(axis=0), lim)
    cap = lambda deg: 2 * np.pi * R ** 2 * (1 - np.cos(np.radians(deg)))  # noqa: E731
    assert area == pytest.approx(cap(60.0) - cap(lim.cornea_cone_deg), rel=0.05)
    ch = check_eye(V, F, C, R + 1.5, FWD, _loop(C, R), lim)
    assert "inside" in failed(ch) and "loop_on_sphere" in failed(ch)


def test_a_recessed_iris_disc_inside_the_cone_is_tolerated():
    V, F = _sphere_patch(C, R, 30.0)
    V = V.copy()
    V[:, 2] = np.minimum(V[:, 2], R - 1.2)            # a flat disc 1.2 mm under the apex
    assert inside_area(V, F, C, R, FWD, np.array([0, 0, R]), CheckLimits()) == 0.0
    V[:, 2] = np.minimum(V[:, 2], R - 2.5)            # deeper than any iris: counted
    assert inside_area(V, F, C, R, FWD, np.array([0, 0, R]), CheckLimits()) > 1.0


def test_noise_sets_the_tolerated_depth():
    V, F = _sphere_patch(C, R - 0.4, 60.0)
    lim = CheckLimits()
    assert inside_area(V, F, C, R, FWD, V.mean(axis=0), lim, rms=0.0) > 10.0
    assert inside_area(V, F, C, R, FWD, V.mean(axis=0), lim, rms=0.12) == 0.0   # 4 x 0.12 > 0.4


@pytest.mark.parametrize("radius,ok", [(9.0, False), (10.0, True), (21.0, True), (21.5, False)])
def test_radius_range(radius, ok):
    V, F = _sphere_patch(C, radius, 60.0)
    ch = check_eye(V, F, C, radius, FWD, _loop(C, radius), CheckLimits())
    assert ch["radius_in_range"]["ok"] is ok


def test_an_opening_wider_than_the_eye_fails():
    L = _loop(C, R, deg=55.0) * np.array([1.6, 1.0, 1.0])
    V, F = _sphere_patch(C, R, 60.0)
    ch = check_eye(V, F, C, R, FWD, L, CheckLimits())
    assert not ch["opening_fits"]["ok"]


def test_a_notched_opening_is_not_convex():
    """An almond loop fills its hull; the same loop with a tongue pushed into it from the upper
    lid (scanned eyeball left on the lid) does not."""
    L = _loop(C, R)
    ch = check_eye(*_sphere_patch(C, R, 60.0), C, R, FWD, L, CheckLimits())
    assert ch["opening_convex"]["value"] > 0.97 and ch["opening_convex"]["ok"]
    t = np.linspace(0, 2 * np.pi, len(L), endpoint=False)
    tongue = np.exp(-((t - np.pi / 2) / 0.35) ** 2)          # around the top of the loop
    N = L.copy()
    N[:, 1] -= 1.6 * tongue * (L[:, 1] - C[1])               # pulled down to below the centre
    N = C + R * (N - C) / np.linalg.norm(N - C, axis=1)[:, None]
    ch = check_eye(*_sphere_patch(C, R, 60.0), C, R, FWD, N, CheckLimits())
    assert not ch["opening_convex"]["ok"] and ch["opening_convex"]["value"] < 0.85


@pytest.mark.parametrize("centre_height,ok", [(0.0, False), (0.1, False), (-0.3, False),
                                               (0.7, True), (1.5, True), (-1.2, True)])
def test_the_cornea_must_stand_off_the_sphere(centre_height, ok):
    """The eye surface within 12 deg of the gaze stands this far off the sclera sphere (a corneal
    bulge, the iris seen through a flattened cornea, or a recessed iris); its sides lie on it.
    Flush means the sphere took the cornea in."""
    V, F = _sphere_patch(C, R, 60.0, n=60)
    ang = np.degrees(np.arccos(np.clip(V[:, 2] / R, -1, 1)))
    V = C + (R + np.where(ang < 12.0, centre_height, 0.0))[:, None] * V / R
    ch = check_eye(V, F, C, R, FWD, _loop(C, R), CheckLimits(), eye_points=V)
    assert ch["cornea_shows"]["ok"] is ok
    assert ch["cornea_shows"]["value"] == pytest.approx(centre_height, abs=1e-6)
    too_few = V[ang > 30.0]                                  # no centre left: nothing to say
    assert check_eye(V, F, C, R, FWD, _loop(C, R), CheckLimits(),
                     eye_points=too_few)["cornea_shows"] == {"value": None, "limit": [-0.4, 0.15],
                                                             "ok": True}


def test_pair_agreement_and_the_one_line_description():
    ch = check_pair({"left": 12.0, "right": 14.5}, CheckLimits())
    assert failed(ch) == ["radii_agree"]
    assert eye_checks.describe("radii_agree", ch["radii_agree"]) == \
        "the two eyes' radii differ by 2.50 mm (limit 2.0 mm)"
    assert failed(check_pair({"left": 12.0, "right": 13.9}, CheckLimits())) == []


def test_limits_follow_the_scan_resolution():
    """Fine scans keep the base limits; a coarse one (4 mm edges, like the james scan) gets a
    loop and depth tolerance of a fraction of its edge and an area limit of two faces."""
    fine, base = eye_checks.limits_for(0.8), CheckLimits()
    assert (fine.inside_noise_mm, fine.max_inside_area_mm2, fine.max_loop_off_mm) == \
        (base.inside_noise_mm, base.max_inside_area_mm2, base.max_loop_off_mm)
    coarse = eye_checks.limits_for(4.0, (11.0, 17.0))
    assert coarse.max_loop_off_mm == 2.0 and coarse.inside_noise_mm == 1.0
    assert coarse.max_inside_area_mm2 == pytest.approx(2 * 0.433 * 16.0)
    assert coarse.radius_range_mm == (11.0, 17.0)


def test_a_loop_inside_the_eye_fails_loop_on_eye():
    """loop_on_eye (asked of the eye the asset carries once loop_on_sphere failed): a loop on
    the sclera or standing off it passes; one cut 2 mm into the eye (or into its cornea) fails
    with the depth as its value."""
    from pipeline.placement.checks import loop_inside_eye

    cc, rc = C + 5.5 * FWD, 8.0                     # the paper's cornea on a 12 mm eye
    lim = CheckLimits()
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    th = np.radians(40.0)                           # on the sclera, beyond the limbus (33 deg)
    on = C + R * np.column_stack([np.sin(th) * np.cos(t), np.sin(th) * np.sin(t), np.full_like(t, np.cos(th))])
    assert loop_inside_eye(on, C, R, FWD, cc, rc, lim)["value"] == pytest.approx(0.0, abs=1e-9)
    off = C + (on - C) * (R + 1.5) / R              # a margin standing 1.5 mm off
    assert loop_inside_eye(off, C, R, FWD, cc, rc, lim)["ok"]
    inside = C + (on - C) * (R - 2.0) / R
    ch = loop_inside_eye(inside, C, R, FWD, cc, rc, lim)
    assert not ch["ok"] and ch["value"] == pytest.approx(2.0, abs=1e-6) and ch["limit"] == 1.0
    small = _loop(C, R, deg=12.0)                   # a small loop on the sclera sphere lies in the cornea
    depth = rc - np.linalg.norm(small - cc, axis=1)
    ch = loop_inside_eye(small, C, R, FWD, cc, rc, lim)
    assert not ch["ok"] and ch["value"] == pytest.approx(float(np.percentile(depth, 90)), abs=1e-4)
    assert eye_checks.describe("loop_on_eye", ch).startswith("the eyelid loop lies ")
    assert "inside the eye the asset would carry" in eye_checks.describe("loop_on_eye", ch)


def test_a_loop_round_part_of_an_eye_fails_opening_wide():
    """A loop 8 mm across (id311_look_right's right eye: the cut went round the cornea of an eye
    placed in a wrong basin) is no fissure; the true opening (about 20 mm here) passes."""
    V, F = _sphere_patch(C, R + 0.1, 70.0)
    lim = CheckLimits()
    wide = check_eye(V, F, C, R, FWD, _loop(C, R), lim)["opening_wide"]
    assert wide["ok"] and wide["value"] == pytest.approx(2 * R * np.sin(np.radians(55.0)), rel=0.02)
    small = check_eye(V, F, C, R, FWD, _loop(C, R, deg=20.0), lim)["opening_wide"]
    assert not small["ok"] and small["value"] == pytest.approx(2 * R * np.sin(np.radians(20.0)), rel=0.02)
    assert "spans 8.2 mm" in eye_checks.describe("opening_wide", small)
