"""The lid blend shapes (pipeline/rig/lid_shapes.py) on constructed sealed eye regions: which way and how
far the lids move, the canthus taper, the skin falloff, following the turning cornea."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures.rig import PITCHES_1DEG, two_eye_region
from pipeline.errors import ScanError
from pipeline.io.eyes_file import Eye
from pipeline.eyeball.geometry import EyeballParams
from pipeline.rig import lids
from pipeline.rig.eye_frame import EyeFrame, eye_frames, rotate_about_axis
from pipeline.rig.lid_shapes import (build_lid_shapes, canthus_taper, follow_surface, limit_margin_shear,
                                     mesh_edges, smootherstep_falloff)
from pipeline.rig.sweep import lid_opening, sweep_check


def test_lids_move_the_right_way(region):
    V, F, eyes, rig = region
    p = lids.LidParams()
    for e in eyes:
        ey = e.basis()[1]
        li = e.lateral_index
        top, bottom = e.loop[li // 2], e.loop[li + (len(e.loop) - li) // 2]
        up = lids.evaluate_shapes(V, rig.shapes, {"lids_up": 1.0}) - V
        dn = lids.evaluate_shapes(V, rig.shapes, {"lids_down": 1.0}) - V
        assert up[top] @ ey > 1.0 and up[bottom] @ ey > 0.0
        assert up[top] @ ey > 1.3 * (up[bottom] @ ey)          # lower lid moves less
        assert dn[top] @ ey < -2.0 and dn[bottom] @ ey < 0.0
        assert -(dn[top] @ ey) > 1.5 * -(dn[bottom] @ ey)
        # the canthi move only by the floor share of the lids' mean gain (0 with no floor)
        for k, floor in ((e.loop[0], p.canthus_floor), (e.loop[li], p.lateral_canthus_floor)):
            for d, g in ((up, p.gain_upper_up + p.gain_lower_up), (dn, p.gain_upper_down + p.gain_lower_down)):
                arc = np.linalg.norm(V[k] - e.center) * np.radians(25.0) * floor * g / 2
                assert np.linalg.norm(d[k]) <= arc + 1e-9
    still = build_lid_shapes(V, F, eyes, lids.LidParams(canthus_floor=0.0, lateral_canthus_floor=0.0))
    for e in eyes:
        for name in ("lids_up", "lids_down"):
            d = lids.evaluate_shapes(V, still.shapes, {name: 1.0}) - V
            assert np.abs(d[[e.loop[0], e.loop[e.lateral_index]]]).max() < 1e-12


def test_mid_lid_margin_turns_by_the_stated_gain(region):
    """Between the canthus ramps each lid's margin turns about the pitch axis by exactly its gain
    times the pitch (the default rule: ICT-FaceKit's visible lid, see compare_ict_lids)."""
    V, F, eyes, rig = region
    p = lids.LidParams()
    for e in eyes:
        li, u = e.lateral_index, rig.fields[e.side].loop_u
        plateau = (u > p.canthus_width + 1e-6) & (u < 1.0 - p.lateral_canthus_width - 1e-6)
        for lid, idx, gains in (("upper", np.arange(1, li), (p.gain_upper_up, p.gain_upper_down)),
                                ("lower", np.arange(li + 1, len(e.loop)),
                                 (p.gain_lower_up, p.gain_lower_down))):
            k = e.loop[idx[plateau[idx]]]
            assert len(k) >= 3, lid
            for name, pitch, g in (("lids_up", 25.0, gains[0]), ("lids_down", -25.0, gains[1])):
                P = lids.evaluate_shapes(V, rig.shapes, {name: 1.0})
                B = e.basis()
                a0 = np.arctan2((V[k] - e.center) @ B[1], (V[k] - e.center) @ B[2])
                a1 = np.arctan2((P[k] - e.center) @ B[1], (P[k] - e.center) @ B[2])
                np.testing.assert_allclose(np.degrees(a1 - a0), g * pitch, atol=1e-6)


def test_both_lids_share_the_canthus_gain(region):
    """Next to each canthus the upper and lower lid turn by nearly the same angle (they ramp from
    one corner gain, the floor share of their mean), so the corner faces do not shear. The taper
    exactly, with the shear limit off (it only lowers gains: test_margin_shear_is_limited)."""
    V, F, eyes, _ = region
    p = lids.LidParams(max_margin_shear=0.0)
    rig = build_lid_shapes(V, F, eyes, p)
    for e in eyes:
        f, li = rig.fields[e.side], e.lateral_index
        th = f.theta_down[e.loop]
        mean = 0.5 * (p.gain_upper_down + p.gain_lower_down)
        np.testing.assert_allclose(th[[0, li]], -np.radians(p.max_pitch_deg) * mean
                                   * np.array([p.canthus_floor, p.lateral_canthus_floor]), rtol=1e-9)
        # every margin point: the corner gain plus the ramp's share of its lid's difference
        ramp = canthus_taper(f.loop_u, p.canthus_width, p.canthus_exponent, p.lateral_canthus_width)
        ramp[[0, li]] = 0.0
        gain = np.full(len(e.loop), p.gain_lower_down)
        gain[1:li] = p.gain_upper_down
        u = f.loop_u
        medial = u <= p.canthus_width / (p.canthus_width + p.lateral_canthus_width)
        medial[[0, li]] = [True, False]
        c = np.where(medial, p.canthus_floor, p.lateral_canthus_floor) * mean
        np.testing.assert_allclose(th, -np.radians(p.max_pitch_deg) * (c + (gain - c) * ramp),
                                   atol=1e-12)


def _margin_shear(V, P, e, theta):
    """Per loop segment: how far its end moves beyond turning rigidly with its start, per mm."""
    L, Ln = e.loop, np.roll(e.loop, -1)
    rigid = rotate_about_axis(V[Ln] - V[L] + e.center, e.center, e.axis, theta[L]) - e.center
    return np.linalg.norm((P[Ln] - P[L]) - rigid, axis=1) / np.linalg.norm(V[Ln] - V[L], axis=1)


@pytest.mark.parametrize("max_shear", [0.5, 0.2])
def test_margin_shear_is_limited(region, max_shear):
    """Neighbouring margin points part by at most max_margin_shear per mm in the full poses, and
    the limit only lowers the taper's gains, where they climb too fast next to the canthi."""
    V, F, eyes, _ = region
    free = build_lid_shapes(V, F, eyes, lids.LidParams(max_margin_shear=0.0))
    rig = build_lid_shapes(V, F, eyes, lids.LidParams(max_margin_shear=max_shear))
    for e in eyes:
        f0, f = free.fields[e.side], rig.fields[e.side]
        for name, key in (("lids_up", "theta_up"), ("lids_down", "theta_down")):
            P0 = lids.evaluate_shapes(V, free.shapes, {name: 1.0})
            P = lids.evaluate_shapes(V, rig.shapes, {name: 1.0})
            th0, th = getattr(f0, key)[e.loop], getattr(f, key)[e.loop]
            assert np.all(np.abs(th) <= np.abs(th0) + 1e-12)
            assert _margin_shear(V, P, e, getattr(f, key)).max() <= max_shear * (1 + 1e-6)
            if _margin_shear(V, P0, e, getattr(f0, key)).max() > max_shear:
                assert np.any(np.abs(th) < np.abs(th0) - 1e-6)
        if max_shear >= lids.LidParams().max_margin_shear:
            # the default leaves the plateau between the canthus ramps as the taper made it
            mid = (f.loop_u > 0.45) & (f.loop_u < 0.55)
            np.testing.assert_allclose(f.theta_down[e.loop][mid], f0.theta_down[e.loop][mid], atol=1e-12)


def test_limit_margin_shear_known_answer():
    """A step in the gains along a straight loop becomes a ramp of the allowed slope, from the
    low side: the largest gains under the original ones with the Lipschitz bound."""
    P = np.stack([np.arange(10.0), np.zeros(10), np.zeros(10)], axis=1)   # 1 mm apart (closed: 9 mm back)
    g = np.where(np.arange(10) < 5, 0.0, 1.0)
    pmax, rho, k = 0.5, 10.0, 0.5                       # slope: k * d / (rho * pmax) = 0.1 per mm
    out = limit_margin_shear(P, g, pmax, rho, k)
    np.testing.assert_allclose(out, [0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.4, 0.5], atol=1e-12)
    assert np.all(limit_margin_shear(P, np.full(10, 0.3), pmax, rho, k) == 0.3)


def test_falloff_support_and_smoothness(region):
    V, F, eyes, rig = region
    p = lids.LidParams()
    edges = mesh_edges(F)
    elen = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    for s in rig.shapes:
        full = np.zeros_like(V)
        full[s.point_indices] = s.offsets
        moved = np.linalg.norm(full, axis=1) > 0
        D = np.min([rig.fields[e.side].distance for e in eyes], axis=0)
        # nothing moves beyond the largest falloff radius (the params' radius, widened by at
        # most max_support_scale where the skin would fold); everything moved is within it
        support = max(rig.fields[e.side].support_mm for e in eyes)
        assert max(p.upper_falloff_mm, p.lower_falloff_mm) <= support
        assert support <= p.max_support_scale * max(p.upper_falloff_mm, p.lower_falloff_mm) + 1e-9
        assert np.all(D[moved] < support)
        assert not moved[D >= support].any()
        # the rim fades out: vertices near the end of the support barely move
        S = np.max([rig.fields[e.side].falloff for e in eyes], axis=0)
        rim = (S > 0) & (S < 0.01)
        assert rim.any() and np.linalg.norm(full[rim], axis=1).max() < 0.1
        # continuity: offsets change at most by a fraction of the edge length (no step)
        jump = np.linalg.norm(full[edges[:, 0]] - full[edges[:, 1]], axis=1)
        assert np.max(jump / elen) < 0.9
        # offsets are a rotation about the eye centre: distance to the centre is preserved
        for e in eyes:
            side = np.linalg.norm(V - e.center, axis=1) < 40
            for w in (1.0,):
                P = V + w * full
                np.testing.assert_allclose(np.linalg.norm(P[side] - e.center, axis=1),
                                           np.linalg.norm(V[side] - e.center, axis=1), atol=1e-9)


def test_smootherstep_is_c1_at_both_ends():
    assert smootherstep_falloff(0.0) == 1.0 and smootherstep_falloff(1.0) == 0.0
    h = 1e-4
    assert abs(smootherstep_falloff(h) - 1.0) < 1e-9
    assert abs(smootherstep_falloff(1 - h)) < 1e-9
    assert smootherstep_falloff(-3.0) == 1.0 and smootherstep_falloff(7.0) == 0.0
    t = np.linspace(0, 1, 101)
    assert np.all(np.diff(smootherstep_falloff(t)) <= 0)


def test_degenerate_triangles_do_not_break_the_rig():
    V, F, eyes = two_eye_region()
    F2 = np.concatenate([F, [[0, 0, 1], [5, 5, 5]]])
    rig = build_lid_shapes(V, F2, eyes)
    res = sweep_check(V, F2, eyes, rig.shapes, [-25.0, -10.0, 0.0, 10.0, 25.0])
    assert res["flipped_faces"] == 0 and res["max_penetration_mm"] <= 0.1
    with pytest.raises(ScanError, match="no 'left' eye"):
        eye_frames({}, {"V": V, "F": F})


def test_upper_lid_never_crosses_lower_lid_even_with_extreme_gains():
    V, F, eyes = two_eye_region(upper_deg=7.0, lower_deg=5.0)
    # only the lids' guard is tested, with the hand-set taper and falloff of the rule before the
    # ICT fit: the skin keeps the margin's gains (no rise) and the canthi stay still (no floor:
    # the guard does not limit the canthi's own share; with the fitted canthus taper these
    # extreme gains fold the corners of so narrow an opening)
    extreme = dict(gain_upper_down=1.0, gain_lower_down=0.0, gain_upper_up=0.0, gain_lower_up=1.0,
                   upper_rise_mm=0.0, lower_rise_mm=0.0, canthus_floor=0.0, lateral_canthus_floor=0.0,
                   canthus_width=0.35,
                   lateral_canthus_width=0.35, canthus_exponent=1.0, upper_falloff_mm=12.0,
                   lower_falloff_mm=8.0)
    unguarded = build_lid_shapes(V, F, eyes, lids.LidParams(**extreme, min_opening_fraction=-50))
    res = sweep_check(V, F, eyes, unguarded.shapes, [-25.0, 25.0])
    assert res["min_opening_mm"] < 0                     # the lids would cross
    rig = build_lid_shapes(V, F, eyes, lids.LidParams(**extreme))
    res = sweep_check(V, F, eyes, rig.shapes, PITCHES_1DEG)
    assert res["min_opening_mm"] > 0 and res["flipped_faces"] == 0
    assert res["max_penetration_mm"] <= 0.1
    # at every vertical line at least ~20 % of the rest opening remains
    for e in eyes:
        rest = lid_opening(V, e)
        for p in (-25.0, 25.0):
            op = lid_opening(lids.evaluate_shapes(V, rig.shapes, lids.lid_weights(p)), e)
            ok = np.isfinite(op) & np.isfinite(rest)
            assert np.all(op[ok] >= 0.2 * rest[ok] - 0.05)


@pytest.mark.parametrize("radius", [12.0, 15.4])
def test_margin_rides_the_corneal_bulge(radius):
    profile = EyeballParams()
    V, F, eyes = two_eye_region(radius=radius, profile=profile, upper_deg=12.0, lower_deg=10.0,
                                half_width_deg=40.0)
    # the margin really lies on the cornea somewhere (off the sphere by > 0.5 mm)
    off = max((np.linalg.norm(V[e.loop] - e.center, axis=1) - e.radius).max() for e in eyes)
    assert off > 0.5
    rig = build_lid_shapes(V, F, eyes)
    res = sweep_check(V, F, eyes, rig.shapes, PITCHES_1DEG)
    assert res["rest_max_abs_mm"] < 1e-6
    assert res["max_gap_mm"] <= 0.1 and res["max_penetration_mm"] <= 0.1
    assert res["flipped_faces"] == 0 and res["min_opening_mm"] > 0
    assert res["min_skin_clearance_mm"] >= -lids.LidParams().max_chord_sag_mm
    # the sphere-only rig would let the cornea cut through the lids
    sphere_eyes = [EyeFrame(e.side, e.center, e.radius, e.forward, e.loop, e.lateral_index)
                   for e in eyes]
    plain = build_lid_shapes(V, F, sphere_eyes)
    bad = sweep_check(V, F, eyes, plain.shapes, PITCHES_1DEG)
    assert max(bad["max_gap_mm"], bad["max_penetration_mm"]) > 0.3
    # and the stage validates the margin against the same surface
    frames = eye_frames({e.side: Eye(e.side, e.center, e.radius, e.forward) for e in eyes},
                        {"V": V, "F": F, "loop_left": eyes[0].loop,
                         "loop_right": eyes[1].loop}, profile=profile)
    assert all(f.profile is profile for f in frames)
    with pytest.raises(ScanError, match="off the eyeball sphere"):
        eye_frames({e.side: Eye(e.side, e.center, e.radius, e.forward) for e in eyes},
                   {"V": V, "F": F, "loop_left": eyes[0].loop, "loop_right": eyes[1].loop})


def test_skin_on_the_eye_rides_the_turning_cornea():
    """Thin lid skin (0.3 mm over the eye) near a margin on the cornea: the corneal bulge turns
    with the eye by the full pitch, the skin by less, so the bulge slides under the skin. The
    rig pushes the skin out by the clearance it would lose (pipeline.rig.lid_shapes.follow_surface):
    no skin vertex sinks into the eye at any pitch (the margin-only correction sank it by
    0.016 mm here and flipped 2 faces; 0.46 mm on the james scan). The upper margin sits 16 deg
    up, on the cornea of the eye placed at 15.4 mm (its cornea 8 mm, limbus ~23 deg off the
    axis). At 12 deg the skin beside the medial canthus of this coarse ring mesh folds at -25 deg
    with the placed eye (4 faces; not with the eye scaled uniformly to 15.4 mm, the model before
    issue 14): the tapered margin there turns less than the skin above it."""
    V, F, eyes = two_eye_region(radius=15.4, profile=EyeballParams(), upper_deg=16.0,
                                lower_deg=10.0, half_width_deg=40.0, rise_mm=0.3)
    off = max((np.linalg.norm(V[e.loop] - e.center, axis=1) - e.radius).max() for e in eyes)
    assert off > 0.5                                          # the margin lies on the cornea
    rig = build_lid_shapes(V, F, eyes)
    res = sweep_check(V, F, eyes, rig.shapes, PITCHES_1DEG)
    assert res["rest_min_skin_clearance_mm"] == pytest.approx(0.3)
    assert res["min_skin_clearance_mm"] > 0.2
    assert res["flipped_faces"] == 0 and res["min_opening_mm"] > 0
    assert res["max_gap_mm"] <= 0.1 and res["max_penetration_mm"] <= 0.1


def test_follow_surface_restores_clearance_and_fades_out():
    profile = EyeballParams()
    eye = EyeFrame("left", np.zeros(3), 12.0, np.array([0.0, 0, 1]), np.arange(8), 4,
                   profile)
    bulge = float(eye.surface_radius(np.array([[0.0, 0, 1]]))[0]) - 12.0    # 1.5 mm
    H = max(2.0, 1.25 * bulge)
    # points over the lower cornea edge, at rest clearances 0 .. beyond H
    c0 = np.array([0.0, 0.05, 0.3, 1.0, 1.5, H, H + 1.0])
    d = np.array([0.0, -np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])
    V = (eye.surface_radius(d[None])[0] + c0)[:, None] * d
    rest = eye.surface_distance(V, 0.0)
    np.testing.assert_allclose(rest, c0, atol=1e-9)
    # the eye looks down 25 deg, the skin stays put: the cornea slides under it
    sunk = eye.surface_distance(V, -25.0)
    assert sunk.min() < -0.4
    P = follow_surface(V, eye, -25.0, rest, 2.0)
    after = eye.surface_distance(P, -25.0)
    assert after[0] == pytest.approx(0.0, abs=1e-9)          # on the eye: kept on it exactly
    assert (after >= -1e-9).all()                             # nothing ends up inside
    np.testing.assert_allclose(P[-2:], V[-2:], atol=1e-12)    # H or more off: untouched
    # moved only along the rays from the centre
    np.testing.assert_allclose(np.cross(P, V), 0.0, atol=1e-9)
    # a sphere needs no push
    sphere = EyeFrame("left", np.zeros(3), 12.0, np.array([0.0, 0, 1]), np.arange(8), 4)
    np.testing.assert_array_equal(follow_surface(V, sphere, -25.0, rest, 2.0), V)


def test_support_widens_where_the_skin_would_fold():
    """A large eye (skin far from the pitch axis), a strong upper-lid gain and a short falloff:
    the skin above the rising lid would be squeezed past zero thickness (faces flip) with the
    params' radius; the support is widened just enough that no face flips at any pitch."""
    V, F, eyes = two_eye_region(radius=15.0, rise_mm=0.3, d_psi=3.0)
    case = dict(gain_upper_up=1.0, upper_falloff_mm=7.0, lower_falloff_mm=8.0, upper_rise_mm=0.0,
                lower_rise_mm=0.0)
    tight = lids.LidParams(**case, max_support_scale=1.0)
    res = sweep_check(V, F, eyes, build_lid_shapes(V, F, eyes, tight).shapes, PITCHES_1DEG)
    assert res["flipped_faces"] > 0                          # the failure the widening prevents
    p = lids.LidParams(**case)
    rig = build_lid_shapes(V, F, eyes, p)
    res = sweep_check(V, F, eyes, rig.shapes, PITCHES_1DEG)
    assert res["flipped_faces"] == 0
    assert res["max_gap_mm"] <= 0.1 and res["max_penetration_mm"] <= 0.1
    for f in rig.fields.values():
        assert 8.0 < f.support_mm <= p.max_support_scale * 8.0 + 1e-9
    # unchanged where nothing folds: the default region keeps the params' radius
    V, F, eyes = two_eye_region()
    fields = build_lid_shapes(V, F, eyes).fields
    p = lids.LidParams()
    assert all(f.support_mm == pytest.approx(max(p.upper_falloff_mm, p.lower_falloff_mm))
               for f in fields.values())


def test_relax_folds_smooths_a_fold_away():
    """A shape that carries one vertex of a flat grid across its neighbours' edges (a fold) is
    smoothed until nothing flips; motion away from the fold is left as it was, and a shape
    without a fold comes back unchanged."""
    from pipeline.rig.folds import flipped_faces, relax_folds

    n = 9
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    F = np.array([f for i in range(n - 1) for j in range(n - 1) for f in
                  ([i * n + j, i * n + j + 1, (i + 1) * n + j + 1],
                   [i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j])], dtype=np.int64)
    smooth = np.stack([0.3 * V[:, 1], np.zeros(n * n), np.zeros(n * n)], axis=1)   # a shear: folds nothing
    spike = smooth.copy()
    c = 4 * n + 4
    spike[c] += [1.6, 0.0, 0.0]                 # the centre vertex jumps past its right neighbour
    idx = np.arange(n * n)
    down = lids.BlendShape("lids_down", idx, spike)
    up = lids.BlendShape("lids_up", idx, smooth)
    pitches = np.linspace(-25, 25, 11)
    assert len(flipped_faces(V, F, [up, down], pitches, 25.0)) > 0
    shapes, rounds, relaxed = relax_folds(V, F, [up, down], [], pitches, 25.0)
    assert rounds >= 1 and relaxed > 0
    assert len(flipped_faces(V, F, shapes, pitches, 25.0)) == 0
    new_down = np.zeros_like(V)
    new_down[shapes[1].point_indices] = shapes[1].offsets
    far = np.flatnonzero(np.max(np.abs(V - V[c]), axis=1) > 3)
    np.testing.assert_allclose(new_down[far], spike[far], atol=1e-12)
    new_up = np.zeros_like(V)
    new_up[shapes[0].point_indices] = shapes[0].offsets
    np.testing.assert_allclose(new_up[far], smooth[far], atol=1e-12)
    same, rounds, relaxed = relax_folds(V, F, [up], [], pitches, 25.0)
    assert rounds == 0 and relaxed == 0 and same[0] is up
