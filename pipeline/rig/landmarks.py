"""Eye-region landmarks (SynthesEyes paper, section 4.3): 28 per eye.

* 12 eyelid landmarks per eye on the eyelid margin (the skin/eyeball seam), at
  even arc length along each lid. Order (:data:`EYELID_ORDER`):
  0 = medial (inner) canthus, 1..5 = along the upper lid from medial to lateral,
  6 = lateral (outer) canthus, 7..11 = along the lower lid from lateral back to
  medial. 0 and 6 are the true corners, the two ends of the opening's loop (vertex 0 and the
  lateral canthus of ``loop_<side>``): where the lids meet, the medial one past the caruncle.
  Near them the loop may stand off the eyeball (pipeline/geometry/corners.py); the landmarks
  stay on the loop, so they follow the lids there too. The upper lid (loop from medial to lateral canthus) is split into six
  equal-length arcs, and so is the lower lid.
  Each landmark is a point on one margin edge ``(a, b, t)``: ``(1 - t) V[a] + t V[b]``.
  The landmarks form a separate closed curve that carries the same blend shapes
  (and inbetweens) as the lids: its offsets are the lid rotation of the margin,
  interpolated along the edge, so the curve follows the seam in every pose.
* 8 iris and 8 pupil landmarks are vertices of the eyeball asset (they follow
  the pupil/iris blend shapes there); this module only records that they come
  from the eyeball asset (:data:`EYEBALL_LANDMARKS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.rig.eye_frame import EyeFrame, rotate_about_axis
from pipeline.rig.lid_shapes import LidRig
from pipeline.rig.lids import MAX_PITCH_DEG, BlendShape, evaluate_shapes, lid_weights, shapes_from_arrays

N_EYELID = 12
N_IRIS = 8
N_PUPIL = 8
N_PER_EYE = N_EYELID + N_IRIS + N_PUPIL

EYELID_ORDER = ("0: medial (inner) canthus; 1-5: upper lid, medial to lateral, at 1/6..5/6 of its "
                "arc length; 6: lateral (outer) canthus; 7-11: lower lid, lateral to medial, at "
                "1/6..5/6 of its arc length")

EYEBALL_LANDMARKS = {
    "iris": {"count": N_IRIS, "source": "eyeball asset vertices (iris boundary), follow the iris "
                                        "size blend shape"},
    "pupil": {"count": N_PUPIL, "source": "eyeball asset vertices (pupil boundary), follow the pupil "
                                          "dilation blend shape"},
}


def eyeball_landmark_doc() -> dict:
    """Where the iris and pupil landmarks come from (for rig.json / the asset metadata).

    They are inner-mesh vertices of the eyeball asset
    (``pipeline.eyeball.geometry.landmark_indices(resolution)``); their indices depend
    on the eyeball asset's resolution, so they are read from that asset, not stored here.
    """
    doc = {k: dict(v) for k, v in EYEBALL_LANDMARKS.items()}
    try:
        from pipeline.eyeball import geometry as eg
        n, direction = int(eg.N_LANDMARKS), str(eg.LANDMARK_DIRECTION)
        eg.landmark_indices  # noqa: B018 -- the API named below
    except (ImportError, AttributeError, TypeError, ValueError):
        return doc
    for k in doc:
        doc[k].update({"api": "pipeline.eyeball.geometry.landmark_indices(resolution)"
                              f"['{k}'] (inner mesh vertex indices)",
                       "asset_attribute": f"rigged_assets/eyeball/eyeball.usda </Eyeball/Inner> "
                                          f"eyerig:landmarks:{k}",
                       "order": f"azimuth {360 // n} deg * k from the eye's +X, {direction}"})
    return doc


@dataclass
class EyelidLandmarks:
    """The 12 eyelid landmarks of one eye.

    Attributes
    ----------
    side : str
    edge : (12, 2) int64
        Mesh vertex pair of the margin edge each landmark lies on.
    t : (12,) float64
        Position along the edge, 0 at ``edge[:, 0]``.
    points : (12, 3) float64
        Rest positions, mm.
    loop_position : (12,) float64
        Fractional position along the loop (index of ``edge[:, 0]`` in the loop + ``t``).
    """

    side: str
    edge: np.ndarray
    t: np.ndarray
    points: np.ndarray
    loop_position: np.ndarray


def _points_at_arclength(P, fractions):
    """Edge index and parameter of points at arc-length fractions along an open polyline."""
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    if total <= 0:
        raise ValueError("degenerate lid polyline (zero length)")
    target = np.asarray(fractions, float) * total
    k = np.clip(np.searchsorted(cum, target, side="right") - 1, 0, len(seg) - 1)
    t = np.where(seg[k] > 0, (target - cum[k]) / np.where(seg[k] > 0, seg[k], 1.0), 0.0)
    return k, np.clip(t, 0.0, 1.0)


def eyelid_landmarks(V, eye: EyeFrame) -> EyelidLandmarks:
    """The 12 eyelid landmarks of one eye at even arc length along each lid.

    Parameters
    ----------
    V : (n, 3) float64
        Rest mesh points.
    eye : EyeFrame
        Its ``loop`` starts at the medial canthus and runs over the upper lid;
        ``lateral_index`` is the lateral canthus.

    Returns
    -------
    EyelidLandmarks
    """
    V = np.asarray(V, float)
    loop = np.asarray(eye.loop, np.int64)
    L, li = len(loop), int(eye.lateral_index)
    if not (0 < li < L - 1):
        raise ValueError(f"lateral canthus index {li} must lie strictly inside the loop of {L}")
    upper_idx = np.arange(0, li + 1)                       # medial .. lateral
    lower_idx = np.concatenate([np.arange(li, L), [0]])    # lateral .. medial (closing)
    fr = np.arange(1, 6) / 6.0
    ku, tu = _points_at_arclength(V[loop[upper_idx]], fr)
    kl, tl = _points_at_arclength(V[loop[lower_idx]], fr)
    a_pos = np.concatenate([[0], upper_idx[ku], [li], lower_idx[kl]])
    b_pos = np.concatenate([[1], upper_idx[ku + 1], [li + 1], lower_idx[kl + 1]]) % L
    t = np.concatenate([[0.0], tu, [0.0], tl])
    edge = np.stack([loop[a_pos], loop[b_pos]], axis=1)
    pts = (1.0 - t)[:, None] * V[edge[:, 0]] + t[:, None] * V[edge[:, 1]]
    return EyelidLandmarks(side=eye.side, edge=edge, t=t, points=pts,
                           loop_position=a_pos.astype(float) + t)


def landmark_shapes(lm: EyelidLandmarks, eye: EyeFrame, rig: LidRig) -> list[BlendShape]:
    """Blend shapes of the landmark curve: the same channels and inbetweens as the lids.

    Each landmark rotates about the eye's pitch axis by the lid angle of its edge
    (interpolated with ``t``), sampled at the same weights as the mesh shapes.

    Returns
    -------
    list of BlendShape
        Point indices 0..11 into the landmark curve.
    """
    field = rig.fields[eye.side]
    out = []
    n = rig.n_segments
    for s in rig.shapes:
        theta_all = field.theta_up if s.name == "lids_up" else field.theta_down
        th = (1.0 - lm.t) * theta_all[lm.edge[:, 0]] + lm.t * theta_all[lm.edge[:, 1]]
        poses = np.stack([rotate_about_axis(lm.points, eye.center, eye.axis, th * j / n) - lm.points
                          for j in range(1, n + 1)])
        out.append(BlendShape(name=s.name, point_indices=np.arange(len(lm.points), dtype=np.int64),
                              offsets=poses[-1], inbetween_weights=s.inbetween_weights.copy(),
                              inbetween_offsets=poses[:-1]))
    return out


def posed_eyelid_landmarks(rig_arrays, side: str, pitch_deg: float,
                           max_pitch_deg: float = MAX_PITCH_DEG) -> np.ndarray:
    """The 12 eyelid landmarks of one eye posed for an eyeball pitch (for render labels).

    Parameters
    ----------
    rig_arrays : mapping
        The arrays of rig.npz (dict or open ``np.load`` file).
    side : {"left", "right"}
    pitch_deg : float
        Eyeball pitch, degrees, up positive (the same value that drives the lid shapes).
    max_pitch_deg : float
        From rig.json ``weight_rule.max_pitch_deg``.

    Returns
    -------
    (12, 3) float64
        Head-frame positions, mm, in :data:`EYELID_ORDER`.
    """
    pre = f"landmarks.{side}."
    points = np.asarray(rig_arrays[pre + "points"], np.float64)
    shapes = shapes_from_arrays(rig_arrays, prefix=pre)
    return evaluate_shapes(points, shapes, lid_weights(pitch_deg, max_pitch_deg))
