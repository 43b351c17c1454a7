"""The 12 eyelid landmarks per eye (pipeline/rig/landmarks.py) and the lateral canthus
(pipeline/rig/eye_frame.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fixtures.rig import PITCHES_1DEG, two_eye_region
from pipeline.io.eyes_file import Eye
from pipeline.rig import landmarks as lmk
from pipeline.rig import lids
from pipeline.rig.eye_frame import eye_frames, find_lateral_canthus


def _arclength_positions(P):
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])


def test_eyelid_landmarks_order_and_even_arclength(region):
    V, F, eyes, rig = region
    for e in eyes:
        lm = lmk.eyelid_landmarks(V, e)
        assert lm.points.shape == (12, 3)
        np.testing.assert_allclose(lm.points[0], V[e.loop[0]])
        np.testing.assert_allclose(lm.points[6], V[e.loop[e.lateral_index]])
        li, L = e.lateral_index, len(e.loop)
        upper = V[e.loop[: li + 1]]
        lower = V[np.concatenate([e.loop[li:], e.loop[:1]])]
        for poly, idx in ((upper, range(0, 7)), (lower, list(range(6, 12)) + [0])):
            cum = _arclength_positions(poly)
            s = []
            for k in idx:
                pos = lm.loop_position[k]
                local = pos - (0 if poly is upper else li) if k != 0 or poly is upper else L - li
                i = int(np.floor(local + 1e-12))
                i = min(i, len(poly) - 2)
                s.append(cum[i] + (local - i) * (cum[i + 1] - cum[i]))
            np.testing.assert_allclose(np.diff(s), cum[-1] / 6, rtol=1e-9)
        # upper landmarks are above the lower ones (documented order)
        ey = e.basis()[1]
        assert np.all((lm.points[1:6] - e.center) @ ey > ((lm.points[7:12] - e.center) @ ey)[::-1])
        # lateral landmark is lateral
        ex = e.basis()[0] * (1 if e.side == "left" else -1)
        assert (lm.points[6] - lm.points[0]) @ ex > 0


def test_landmark_curve_follows_the_lid_shapes(region):
    V, F, eyes, rig = region
    for e in eyes:
        lm = lmk.eyelid_landmarks(V, e)
        shapes = lmk.landmark_shapes(lm, e, rig)
        assert [s.name for s in shapes] == ["lids_up", "lids_down"]
        for p in PITCHES_1DEG:
            w = lids.lid_weights(p)
            P = lids.evaluate_shapes(V, rig.shapes, w)
            Q = lids.evaluate_shapes(lm.points, shapes, w)
            on_edge = (1 - lm.t)[:, None] * P[lm.edge[:, 0]] + lm.t[:, None] * P[lm.edge[:, 1]]
            assert np.abs(Q - on_edge).max() < 0.05
            d = np.linalg.norm(Q - e.center, axis=1) - np.linalg.norm(lm.points - e.center, axis=1)
            assert np.abs(d).max() <= lids.LidParams().max_chord_sag_mm + 1e-9


def test_lateral_canthus_detection(region):
    V, F, eyes, rig = region
    for e in eyes:
        assert find_lateral_canthus(V[e.loop], e.center, e.forward, e.side) == e.lateral_index


def test_lateral_canthus_from_dense_loop_points_and_mesh_arrays():
    V, F, eyes = two_eye_region()
    e = eyes[0]
    li = e.lateral_index
    mesh = {"V": V, "F": F, "loop_left": e.loop, "loop_right": eyes[1].loop}
    base = {s.side: Eye(s.side, s.center, s.radius, s.forward) for s in eyes}
    # remove_eyeballs carries its dense loop: 100 points, lateral canthus at 37
    dense = np.zeros((100, 3))
    dense[37] = V[e.loop[li]] + 0.2
    doc = {**base, "left": replace(base["left"], loop_points=dense, loop_indices=np.arange(100),
                                   lateral_canthus_index=37)}
    assert eye_frames(doc, mesh)[0].lateral_index == li
    # an index into another loop (different length, no points) is ignored
    doc = {**base, "left": replace(base["left"], loop_indices=np.arange(100), lateral_canthus_index=37)}
    assert eye_frames(doc, mesh)[0].lateral_index == li
    # an explicit mesh array wins
    assert eye_frames(base, {**mesh, "lateral_index_left": np.array(li - 1)})[0] \
        .lateral_index == li - 1
