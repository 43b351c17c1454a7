"""Corners off the globe (pipeline/geometry/corners.py): the snap's fade toward a canthus that
stands off the eye, the strip that closes the gap, the self-checks and the rig around them.

The meshes are the rig tests' constructed eye regions (a margin ring on a 12 mm eyeball, skin
rings around it) with the medial corner lifted off the globe as a real one is (the caruncle's end
lies 3-7 mm off it).
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.eyeball.geometry import EyeballParams
from pipeline.geometry import corners as cn
from pipeline.geometry import meshtopo
from pipeline.io.eyes_file import Eye
from pipeline.placement import checks as eye_checks
from pipeline.rig.eye_frame import eye_frames
from pipeline.rig.lid_shapes import build_lid_shapes
from pipeline.rig.sweep import sweep_check
from pipeline.snap import snap as sn
from fixtures.rig import two_eye_region

R = 12.0


def lifted_region(lift_mm=4.0, reach=5, lateral_lift_mm=0.0):
    """The rig tests' two-eye region with each medial corner lifted ``lift_mm`` off the globe
    (radially, fading over ``reach`` loop vertices each way and over the skin rings) and, with
    ``lateral_lift_mm``, the lateral corner too. Returns (mesh dict, eyes dict, frames)."""
    V, F, frames = two_eye_region(R)
    V = V.copy()
    n_loop = len(frames[0].loop)
    for e in frames:
        c = e.center
        base = int(e.loop[0])
        for corner, lift in ((0, lift_mm), (e.lateral_index, lateral_lift_mm)):
            if lift <= 0:
                continue
            for k in range(-reach, reach + 1):
                w = 0.5 * (1 + np.cos(np.pi * k / (reach + 1)))
                i = (corner + k) % n_loop
                for ring in range(4):     # the ring and the skin just outside it follow
                    v = base + ring * n_loop + i
                    d = V[v] - c
                    V[v] += lift * w * (1 - ring / 4) * d / np.linalg.norm(d)
    mesh = {"V": V, "F": F, "loop_left": frames[0].loop, "loop_right": frames[1].loop,
            "lateral_index_left": np.array([frames[0].lateral_index]),
            "lateral_index_right": np.array([frames[1].lateral_index])}
    eyes = {e.side: (e.center, e.radius, e.forward) for e in frames}
    return mesh, eyes, frames


@pytest.fixture(scope="module")
def snapped():
    mesh, eyes, frames = lifted_region()
    out, reports, metrics = sn.snap_mesh(mesh, eyes, EyeballParams(), sn.SnapSettings())
    return mesh, eyes, frames, out, metrics


def test_corner_weights_fade_toward_an_off_globe_canthus():
    mesh, eyes, frames = lifted_region()
    e = frames[0]
    P = mesh["V"][e.loop]
    off = np.linalg.norm(P - e.center, axis=1) - R
    runs = cn.corner_weights(P, off, e.lateral_index)
    assert runs.weight[0] == 0.0 and len(runs.lateral) == 0
    # 0 at the canthus, rising along both lids to 1 where the lid meets the eye
    up, down = runs.weight[:8], runs.weight[::-1][:7]
    assert np.all(np.diff(up) >= 0) and np.all(np.diff(np.concatenate([[0.0], down])) >= 0)
    assert up[-1] == 1.0 and down[-1] == 1.0
    assert set(runs.medial.tolist()) == set(np.flatnonzero(runs.weight < 1).tolist())
    # every vertex of a run stands farther off than a lid margin can, or lies within the
    # MIN_RUN_MM of arc from its canthus that every run fades over
    L, li = len(P), e.lateral_index
    arc = np.full(L, np.inf)
    for seq in (np.arange(0, li + 1), np.concatenate([[0], np.arange(L - 1, li - 1, -1)])):
        arc[seq] = np.minimum(arc[seq], np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(np.diff(P[seq], axis=0), axis=1))]))
    member = runs.medial[1:]
    assert np.all((off[member] > cn.MARGIN_OFF_GLOBE_MM) | (arc[member] < cn.MIN_RUN_MM))
    # nothing off the globe: no run, every weight 1
    P0 = frames[1].center + R * (P - e.center) / np.linalg.norm(P - e.center, axis=1)[:, None]
    none = cn.corner_weights(P0, np.zeros(len(P0)), e.lateral_index)
    assert none.on_eye.all() and len(none.medial) == len(none.lateral) == 0


def test_a_run_fades_over_at_least_min_run_mm_beside_a_canthus_just_off_the_globe():
    """A lateral canthus 2.35 mm off the globe beside lid points 2.0 mm off (within a margin's
    reach, so a run measured by distance alone would end at the next point, one edge away, and
    the snap move it its whole way: fresh41's n4702_icteye_cams6 folded there): the weight rises
    from 0 at the canthus over at least MIN_RUN_MM of arc along each lid, monotone, and is 1
    beyond it; the medial canthus, on the globe, has no run."""
    _, _, frames = lifted_region()
    e = frames[0]
    V = two_eye_region(R)[0]
    P = V[e.loop]
    li = e.lateral_index
    off = np.full(len(P), 2.0)
    off[li] = 2.35
    runs = cn.corner_weights(P, off, li)
    assert len(runs.medial) == 0 and runs.weight[li] == 0.0
    for seq in (np.arange(li, -1, -1), np.concatenate([np.arange(li, len(P)), [0]])):
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[seq], axis=0), axis=1))])
        w = runs.weight[seq]
        near = s < cn.MIN_RUN_MM
        assert near.sum() >= 3                              # the loop's edges are shorter than the run
        assert w[near].max() < 1.0 and np.all(np.diff(w[near]) > 0)
        assert w[~near].min() == 1.0
    assert set(runs.lateral.tolist()) == set(np.flatnonzero(runs.weight < 1).tolist())


def test_a_run_never_covers_more_than_its_share_of_a_lid():
    _, _, frames = lifted_region()
    e = frames[0]
    V = two_eye_region(R)[0]
    P = V[e.loop]
    off = np.full(len(P), 5.0)                  # everything far off: a placement error, not corners
    share = 0.2
    runs = cn.corner_weights(P, off, e.lateral_index, max_share=share)
    li = e.lateral_index
    for lid in (np.arange(0, li + 1), np.concatenate([np.arange(li, len(P)), [0]])):
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[lid], axis=0), axis=1))])
        from_corner = np.minimum(s, s[-1] - s)
        assert runs.weight[lid][from_corner >= share * s[-1]].min() == 1.0
        assert runs.weight[lid][from_corner < share * s[-1]].max() < 1.0


def test_snap_leaves_the_canthus_off_the_globe_and_the_lids_on_it(snapped):
    mesh, eyes, frames, out, metrics = snapped
    for e in frames:
        s = e.side
        P0, P1 = mesh["V"][e.loop], out["V"][e.loop]
        w = out[f"loop_snap_{s}"]
        assert np.array_equal(P1[0], P0[0])                       # the canthus keeps its place
        d = sn.EyeballSurface(e.center, R, e.forward, EyeballParams()).signed_distance(P1)
        assert np.abs(d[w >= 1]).max() < 1e-6                     # the lids rest on the eye
        assert d[0] > 3.5 and np.all(d[w < 1] > 0)                # the corner stands off it
        assert metrics[s]["corner_vertices"] == int((w < 1).sum()) > 0
    assert metrics["gap_max_mm"] < 1e-6 and metrics["flipped_faces"] == 0


def test_the_strip_closes_the_corner_manifold_and_inside_the_eye(snapped):
    mesh, eyes, frames, out, metrics = snapped
    V, F = out["V"], out["F"]
    n0, m0 = len(mesh["V"]), len(mesh["F"])
    assert meshtopo.is_edge_manifold(F) and metrics["edge_manifold_closed"]
    # consistently oriented: no directed edge twice
    he = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    assert len(np.unique(he, axis=0)) == len(he)
    for e in frames:
        strip = out[f"corner_strip_{e.side}"]
        assert len(strip) > 0 and strip[:, 0].min() >= n0
        # the inner edge: the last vertex hanging from each loop vertex (the caruncle's mound
        # rows come before it), strip_depth_mm inside the sphere on the ray through its loop vertex
        last = {int(p): int(v) for v, p in strip}
        assert len(last) < len(strip)              # the caruncle has rows between loop and eye
        q = V[list(last.values())]
        depth = R - np.linalg.norm(q - e.center, axis=1)
        np.testing.assert_allclose(depth, sn.SnapSettings().strip_depth_mm, atol=1e-9)
        P = V[list(last)]
        u = (P - e.center) / np.linalg.norm(P - e.center, axis=1)[:, None]
        np.testing.assert_allclose((q - e.center) / np.linalg.norm(q - e.center, axis=1)[:, None], u, atol=1e-12)
        # every other strip vertex stands outside the eye (the mound), hidden by nothing
        mound = np.setdiff1d(strip[:, 0], list(last.values()))
        assert len(mound) and (np.linalg.norm(V[mound] - e.center, axis=1) > R - 0.8).all()
        # the loop edges of the corner are no longer boundary: the opening's boundary there is
        # the strip's inner edge, inside the eye
        bnd = np.unique(meshtopo.boundary_halfedges(F))
        assert not np.isin(e.loop[0], bnd)
    car = out["caruncle_faces"]
    assert len(car) == metrics["caruncle_faces"] > 0 and car.min() >= m0
    # the caruncle: the medial strips' faces up to CARUNCLE_MM along the lids from the canthus
    # (only medial corners were lifted); the strip beyond is the lid's inside
    assert set(car.tolist()) <= set(range(m0, len(F)))
    for e in frames:
        P = V[e.loop]
        arc = np.full(len(P), np.inf)
        for order in (np.arange(len(P)), np.r_[0, np.arange(len(P) - 1, 0, -1)]):
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[order], axis=0), axis=1))])
            arc[order] = np.minimum(arc[order], s)
        pos = {int(v): k for k, v in enumerate(e.loop)}
        mine = [f for f in car if any(int(v) in pos for v in F[f])]
        assert mine
        for f in mine:
            assert max(arc[pos[int(v)]] for v in F[f] if int(v) in pos) <= cn.CARUNCLE_MM + 1e-9


def test_the_caruncle_is_a_mound_that_grows_out_of_the_lids(snapped):
    """Known answer at the medial canthus: its segment to the eye (4 mm off a 12 mm eye, 4.8 mm
    long) gets ``caruncle_rows`` vertices at t = k / (rows + 1) of the way in, raised toward the
    opening by ``caruncle_mound_mm`` sin(pi t) (perpendicular to the segment, in the plane of
    the eye's forward); the colour weight is 0 on the lid margin and every skin vertex and 1
    from 0.4 of the way in at the canthus. With no rows the strip is the flat one."""
    mesh, eyes, frames, out, metrics = snapped
    st = sn.SnapSettings()
    V, w = out["V"], out["caruncle_weight"]
    assert w.shape == (len(V),) and w.min() >= 0 and w.max() <= 1
    assert np.all(w[: len(mesh["V"])] == 0)                   # skin and the lid margin
    for e in frames:
        strip = out[f"corner_strip_{e.side}"]
        col = strip[strip[:, 1] == e.loop[0], 0]              # the canthus's column, loop inward
        assert len(col) == st.caruncle_rows + 1
        p, q = V[e.loop[0]], V[col[-1]]
        u = (q - p) / np.linalg.norm(q - p)
        n = e.forward - (e.forward @ u) * u
        n /= np.linalg.norm(n)
        h = min(st.caruncle_mound_mm, np.linalg.norm(q - p) / 3)
        for k, v in enumerate(col[:-1], start=1):
            t = k / (st.caruncle_rows + 1)
            np.testing.assert_allclose(V[v], p + t * (q - p) + h * np.sin(np.pi * t) * n, atol=1e-9)
        np.testing.assert_allclose(w[col], [cn._smoothstep(k / len(col) / cn.CARUNCLE_RIM_SHARE)
                                            for k in range(1, len(col) + 1)])
        assert w[col[-1]] == 1.0 and w[col[0]] < 1.0
        # the mound's crown stands toward the opening: in front of the flat strip
        assert (V[col[1]] - (p + 0.5 * (q - p))) @ e.forward > 0
    flat_out, _, flat_metrics = sn.snap_mesh(mesh, eyes, EyeballParams(), sn.SnapSettings(caruncle_rows=0))
    for e in frames:
        strip = flat_out[f"corner_strip_{e.side}"]
        assert len(np.unique(strip[:, 1])) == len(strip)      # one inner vertex per loop vertex
    assert flat_metrics["flipped_faces"] == 0 and flat_metrics["edge_manifold_closed"]


def test_nothing_changes_when_every_corner_rests_on_the_eye():
    V, F, frames = two_eye_region(R)
    mesh = {"V": V, "F": F, "loop_left": frames[0].loop, "loop_right": frames[1].loop}
    eyes = {e.side: (e.center, e.radius, e.forward) for e in frames}
    out, _, metrics = sn.snap_mesh(mesh, eyes, EyeballParams(), sn.SnapSettings())
    assert np.array_equal(out["F"], F) and len(out["V"]) == len(V)
    assert len(out["caruncle_faces"]) == 0 and all(len(out[f"corner_strip_{s}"]) == 0 for s in sn.SIDES)
    assert "caruncle_weight" not in out                       # no caruncle, nothing to blend
    assert all(out[f"loop_snap_{s}"].min() == 1.0 for s in sn.SIDES)


def test_strip_carries_texture_coordinates():
    mesh, eyes, _ = lifted_region()
    V, F = mesh["V"], mesh["F"]
    mesh = dict(mesh, UV=V[:, :2] * 0.01, FUV=F.copy())
    out, _, _ = sn.snap_mesh(mesh, eyes, EyeballParams(), sn.SnapSettings())
    assert len(out["FUV"]) == len(out["F"]) and out["FUV"].max() < len(out["UV"])
    for s in sn.SIDES:
        strip = out[f"corner_strip_{s}"]
        new = np.flatnonzero(np.isin(out["F"], strip[:, 0]).any(axis=1))
        for f in new:   # an inner vertex shows the texel of the loop vertex it hangs from
            for k in range(3):
                v = out["F"][f, k]
                if v in strip[:, 0]:
                    p = strip[strip[:, 0] == v, 1][0]
                    np.testing.assert_allclose(out["UV"][out["FUV"][f, k]], mesh["UV"][p])


def test_checks_leave_the_corners_out(snapped):
    mesh, eyes, frames, out, metrics = snapped
    e = frames[0]
    L = mesh["V"][e.loop]
    lim = eye_checks.limits_for(0.5)
    V, F = mesh["V"], mesh["F"]
    plain = eye_checks.check_eye(V, F, e.center, R, e.forward, L, lim)
    corners = eye_checks.check_eye(V, F, e.center, R, e.forward, L, lim, lateral_index=e.lateral_index)
    assert not plain["loop_on_sphere"]["ok"]            # the whole loop: the corner is far off
    assert corners["loop_on_sphere"]["ok"]              # the lids: the lifted ones within a margin's reach
    assert corners["loop_on_sphere"]["corner_vertices"] > 0
    # a lid far off the eye (a wrong sphere) is still seen: it is no corner
    L2 = L.copy()
    mid = e.lateral_index // 2
    L2[mid - 2:mid + 3] += 3.0 * (L2[mid - 2:mid + 3] - e.center) / R
    bad = eye_checks.check_eye(V, F, e.center, R, e.forward, L2, lim, lateral_index=e.lateral_index)
    assert not bad["loop_on_sphere"]["ok"]


def test_rig_turns_the_strip_with_its_corner_and_keeps_it_inside(snapped):
    mesh, eyes, frames, out, metrics = snapped
    doc = {e.side: Eye(e.side, e.center, R, e.forward) for e in frames}
    E = eye_frames(doc, out, profile=EyeballParams())
    assert all(e.strip is not None and (~e.on_eye).sum() > 0 for e in E)
    V, F = out["V"], out["F"]
    rig = build_lid_shapes(V, F, E)
    on_loop = np.zeros(len(V), bool)
    for e in E:
        on_loop[e.loop] = True
    for e in E:
        f = rig.fields[e.side]
        q = e.strip[:, 0]
        # each strip vertex turns by the mean of its neighbours' angles (strip and loop): the
        # loop's angles interpolated harmonically over the strip
        for v in q:
            nb = np.unique(F[(F == v).any(axis=1)])
            nb = nb[(nb != v) & (np.isin(nb, q) | on_loop[nb])]
            for th in (f.theta_up, f.theta_down):
                assert th[v] == pytest.approx(th[nb].mean(), abs=1e-12)
        # the off-globe corner keeps its canthus's gain
        off = ~e.on_eye
        np.testing.assert_allclose(f.theta_down[e.loop[off]], f.theta_down[e.loop[0]])
    # eyelid landmarks 0 and 6 are the loop's ends: the canthi, the medial one off the globe
    from pipeline.rig.landmarks import eyelid_landmarks

    for e in E:
        lm = eyelid_landmarks(V, e)
        np.testing.assert_array_equal(lm.points[0], V[e.loop[0]])
        np.testing.assert_array_equal(lm.points[6], V[e.loop[e.lateral_index]])
        assert np.linalg.norm(lm.points[0] - e.center) - R > 3.5
    res = sweep_check(V, F, E, rig.shapes, np.arange(-25.0, 25.1, 2.5))
    assert res["flipped_faces"] == 0
    assert res["max_gap_mm"] < 0.05 and res["max_penetration_mm"] < 0.05
    assert res["strip_max_mm"] < -0.5                     # the inner edge stays inside the eye
    assert res["min_skin_clearance_mm"] > -0.03


def test_strip_angles_are_the_loops_interpolated_harmonically_over_the_strip():
    """Known answer: a strip path 0 - s0 - s1 - 1 between loop vertices 0 and 1 (angles 0 and 1),
    both also joined to loop vertex 2 (0.5) and both hung from loop vertex 0, turns s0 by 3/8 and
    s1 by 5/8 (each the mean of its neighbours), not 0 and 0: a strip turned with its own loop
    vertex alone sheared the face it shares with the next one (n3002_in_up folded at pitch
    -24 deg). A strip vertex joined to no loop vertex keeps its own loop vertex's angle."""
    from pipeline.rig.lid_shapes import _strip_angles

    loop = np.array([0, 1, 2])
    s0, s1, lone, lone2 = 3, 4, 5, 6
    F = np.array([[0, s0, 2], [s0, s1, 2], [s1, 1, 2], [lone, lone2, 7]])
    theta = np.array([0.0, 1.0, 0.5, 0, 0, 0, 0, 0])
    out = _strip_angles(F, loop, np.array([s0, s1, lone, lone2]), np.array([0, 0, 2, 1]), theta)
    # s0 and s1 also touch loop vertex 2 (0.5): s0 = (0 + s1 + 0.5) / 3, s1 = (s0 + 1 + 0.5) / 3
    np.testing.assert_allclose(out[:2], [3.0 / 8.0, 5.0 / 8.0], atol=1e-12)
    np.testing.assert_allclose(out[2:], [0.5, 1.0], atol=0)


def test_rig_refuses_a_margin_off_the_eye_that_is_no_corner(snapped):
    from pipeline.errors import ScanError

    mesh, eyes, frames, out, metrics = snapped
    doc = {e.side: Eye(e.side, e.center, R, e.forward) for e in frames}
    bad = dict(out)
    bad["V"] = out["V"].copy()
    e = frames[0]
    mid = e.lateral_index // 2
    bad["V"][e.loop[mid]] += 2.0 * (bad["V"][e.loop[mid]] - e.center) / R
    with pytest.raises(ScanError, match="off the eyeball"):
        eye_frames(doc, bad, profile=EyeballParams())
    wrong = dict(out, loop_snap_left=np.ones(3))
    with pytest.raises(ScanError, match="one finite weight per loop vertex"):
        eye_frames(doc, wrong, profile=EyeballParams())


def test_the_mound_keeps_clear_of_the_cornea():
    """Known answers of the clearance rule on a 12 mm sphere: a point 1 mm outside raised 2 mm
    straight toward the centre keeps 0.35 of the raise (it ends 0.3 mm outside); a raise away
    from the eye is kept whole; a point already inside (0.5 mm) raised further in is not raised;
    without a surface the raise is whole."""
    c = np.zeros(3)

    def sd(P):
        return np.linalg.norm(np.asarray(P) - c, axis=1) - R

    flat = np.array([0.0, 0.0, R + 1.0])
    inward, outward = np.array([0.0, 0.0, -2.0]), np.array([0.0, 2.0, 0.0])
    s = cn._keep_clear(flat, inward, sd, 0.3)
    assert abs(s - 0.35) < 1e-3 and sd((flat + s * inward)[None])[0] >= 0.3 - 1e-9
    assert cn._keep_clear(flat, outward, sd, 0.3) == 1.0
    assert cn._keep_clear(np.array([0.0, 0.0, R - 0.5]), inward, sd, 0.3) < 1e-3
    assert cn._keep_clear(flat, inward, None, 0.3) == 1.0


def test_the_corner_benchmark_sees_the_cornea_turn_under_a_strip(snapped):
    """``measure_head`` (tests/fixtures/corners.py, bench_corners') on the lifted region: it counts the strip's vertices and
    the caruncle's mound rows, finds no point of the strip inside the cornea's bulge at rest
    (the medial corners lie 4 mm off the globe, far from the limbus) and finds the cornea in the
    strip with the eye turned 35 deg toward the nose (a strip fixed to the lids: known gap)."""
    from fixtures.corners import measure_head

    mesh, eyes, frames, out, metrics = snapped
    doc = {e.side: Eye(e.side, e.center, R, e.forward) for e in frames}
    m = measure_head(out, doc)
    strips = [out[f"corner_strip_{e.side}"] for e in frames]
    assert m["strip_vertices"] == sum(len(S) for S in strips) > 0
    assert m["mound_vertices"] == sum(len(S) - len(np.unique(S[:, 1])) for S in strips) > 0
    assert m["caruncle_faces"] == len(out["caruncle_faces"])
    assert m["cornea_at_rest_mm"] == 0.0
    assert m["cornea_at_yaw_mm"] > 0.05


def test_a_corner_run_ends_where_the_loop_passes_over_the_cornea():
    """Known answers of ``corner_weights(over_cornea=)`` on the lifted region's loop, every vertex
    standing off: a lid over the cornea rests on it, so a run stops at the first loop vertex over
    the cornea (its weight 1) when the run keeps at least ``MIN_STOPPED_RUN_MM`` from its canthus;
    one the cornea would cut shorter runs on as without it (snapping a lid that near its canthus
    folds it); a canthus over the cornea keeps its whole run."""
    _, _, frames = lifted_region()
    e = frames[0]
    V = two_eye_region(R)[0]
    P = V[e.loop]
    off = np.full(len(P), 5.0)
    li = e.lateral_index
    free = cn.corner_weights(P, off, li)
    up = np.arange(0, li + 1)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[up], axis=0), axis=1))])
    k = int(np.searchsorted(s, cn.MIN_STOPPED_RUN_MM + 0.5))    # a vertex past the 2 mm
    assert free.weight[k] < 1.0                                  # inside the free run
    over = np.zeros(len(P), bool)
    over[k] = True
    cut = cn.corner_weights(P, off, li, over_cornea=over)
    assert cut.weight[k] == 1.0 and cut.weight[k - 1] < 1.0 and k not in cut.medial
    assert np.all(cut.weight[up[k:len(up) // 2]] == 1.0)      # to mid-lid (the lateral run is its own)
    near = np.zeros(len(P), bool)
    near[1] = True                                               # under 2 mm from the canthus
    assert np.array_equal(cn.corner_weights(P, off, li, over_cornea=near).weight, free.weight)
    canthus = np.zeros(len(P), bool)
    canthus[[0, k]] = True                                       # the canthus itself over it
    assert np.array_equal(cn.corner_weights(P, off, li, over_cornea=canthus).weight, free.weight)


def test_the_yaw_channels_move_the_corner_with_the_turning_cornea(snapped):
    """The known gap the test above shows, closed by the rig's yaw channels
    (pipeline/rig/yaw_shapes.py): posed at every pitch and yaw checked, nothing of the corner,
    its strip's caruncle rows or the margin enters the turned eye by more than the pitch sweep's
    0.1 mm, the inner edge stays inside it, and no face turns over; without them the cornea
    enters the rows."""
    from pipeline.rig import yaw_shapes as ys

    mesh, eyes, frames, out, metrics = snapped
    doc = {e.side: Eye(e.side, e.center, R, e.forward) for e in frames}
    E = eye_frames(doc, out, profile=EyeballParams())
    V, F = out["V"], out["F"]
    lid = build_lid_shapes(V, F, E).shapes
    yaw, rounds, damped, sweep = ys.settle_yaw_folds(V, F, E, lid, ys.build_yaw_shapes(V, E, 3.0, lid), 25.0)
    pitches, yaws = np.arange(-25.0, 25.1, 6.25), np.arange(-35.0, 35.1, 3.5)
    res = ys.yaw_sweep(V, F, E, lid + yaw, pitches, yaws, 25.0)
    assert res["flipped_faces"] == 0 and damped == 0
    assert max(res["max_penetration_mm"], res["max_sink_mm"], res["max_strip_sink_mm"]) <= 0.1
    bare = ys.yaw_sweep(V, F, E, lid, pitches, yaws, 25.0)
    assert bare["max_strip_sink_mm"] > 0.3 and bare["max_penetration_mm"] > 0.3
    from pipeline.rig.lids import evaluate_shapes, lid_weights

    for e in E:
        inner = np.fromiter({int(p): int(v) for v, p in e.strip}.values(), np.int64)
        for p in pitches:
            for y in yaws:
                P = evaluate_shapes(V, lid + yaw, {**lid_weights(p), **ys.yaw_weights({e.side: y}, p)})
                assert ys.surface_distance(e, P[inner], ys.yaw_gaze(e, p, y)).max() < -0.5
