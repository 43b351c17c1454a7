"""Eyelid blend shapes driven by eyeball pitch (SynthesEyes paper, section 3.4): the rig's
contract with the stages that use it (usd, render, the Blender previews).

Two blend shapes, ``lids_up`` (eyes pitched up by ``max_pitch_deg``) and
``lids_down`` (pitched down by the same angle), each with inbetweens (UsdSkel
``inbetweens:<name>``). This module holds their settings (:class:`LidParams`,
:class:`RigSettings`), the container (:class:`BlendShape`), its evaluation and its array
layout in rig.npz. How they are built from the sealed mesh and the fitted eyeballs:
:mod:`pipeline.rig.lid_shapes`; the eyes they move: :mod:`pipeline.rig.eye_frame`; the
pitch sweep that checks them: :mod:`pipeline.rig.sweep`.

The pitch-to-weight rule (:func:`lid_weights`, documented in
:data:`WEIGHT_RULE`) is the single function that the renderer and the USD
stage use; it is stored in the asset. For shape-key systems without
inbetweens (Blender shape keys) :func:`flat_shape_weights` expands channel
weights to one weight per stored pose (hat functions), which gives exactly the
same points as the UsdSkel inbetween evaluation (:func:`evaluate_shapes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from pipeline.io.blend_shapes import BlendShape, shapes_from_arrays, shapes_to_arrays  # noqa: F401 (moved to io)
from pipeline.settings import Settings, setting

SHAPE_UP = "lids_up"
SHAPE_DOWN = "lids_down"
MAX_PITCH_DEG = 25.0

#: The pitch-to-weight rule, as stored in the asset (rig.json, USD metadata).
WEIGHT_RULE = {
    "function": "pipeline.rig.lids.lid_weights (pitch from pipeline.rig.lids.pitch_from_gaze)",
    "formula": "w_lids_up = clamp(pitch_deg / max_pitch_deg, 0, 1); "
               "w_lids_down = clamp(-pitch_deg / max_pitch_deg, 0, 1)",
    "pitch_definition": "gaze elevation relative to the rest gaze, degrees, positive = looking up: "
                        "pitch_deg = degrees(asin(g_y) - asin(forward_y)) for the head-frame unit "
                        "gaze g and the eye's rest forward (eyes.<side>.forward); for a pure pitch "
                        "this is the eyeball's rotation about its horizontal axis (through the "
                        "centre, perpendicular to forward and head +Y). Both eyes share one pitch "
                        "(use their mean if they differ).",
    "channels": [SHAPE_UP, SHAPE_DOWN],
    "inbetweens": "UsdSkel semantics: a channel weight w between two stored poses (implicit 0, "
                  "inbetween weights, 1) interpolates their offsets linearly; see "
                  "pipeline.rig.lids.evaluate_shapes / flat_shape_weights",
}


def weight_rule(max_pitch_deg: float = MAX_PITCH_DEG) -> dict:
    """The pitch-to-weight rule as metadata for the asset: :data:`WEIGHT_RULE` plus its parameter."""
    return {**WEIGHT_RULE, "max_pitch_deg": float(max_pitch_deg)}


def pitch_from_gaze(gaze, forward) -> float:
    """Lid-rule pitch of a head-frame gaze direction: its elevation above the rest gaze, degrees.

    ``degrees(asin(g_y) - asin(f_y))`` with ``g``, ``f`` normalised; positive = looking up.

    Parameters
    ----------
    gaze : (3,) float64
        Gaze direction in the head frame.
    forward : (3,) float64
        The eye's rest forward direction (rig.json ``eyes.<side>.forward``).
    """
    g = np.asarray(gaze, dtype=np.float64)
    f = np.asarray(forward, dtype=np.float64)
    g, f = g / np.linalg.norm(g), f / np.linalg.norm(f)
    return math.degrees(math.asin(float(np.clip(g[1], -1, 1))) - math.asin(float(np.clip(f[1], -1, 1))))


def lid_weights(pitch_deg: float, max_pitch_deg: float = MAX_PITCH_DEG) -> dict[str, float]:
    """Blend-shape channel weights for an eyeball pitch: THE pitch-to-weight rule.

    ``w_lids_up = clamp(pitch / max_pitch, 0, 1)``,
    ``w_lids_down = clamp(-pitch / max_pitch, 0, 1)``.

    Parameters
    ----------
    pitch_deg : float
        Eyeball pitch from its rest orientation, degrees, positive = looking up.
    max_pitch_deg : float
        Pitch at which each shape reaches weight 1 (the anatomical limit, 25 deg).

    Returns
    -------
    dict
        ``{"lids_up": w_up, "lids_down": w_down}``, each in [0, 1], at most one non-zero.
    """
    p = float(pitch_deg)
    m = float(max_pitch_deg)
    if not math.isfinite(p):
        raise ValueError(f"pitch must be finite, got {pitch_deg!r}")
    if not (math.isfinite(m) and m > 0):
        raise ValueError(f"max_pitch_deg must be positive, got {max_pitch_deg!r}")
    return {SHAPE_UP: min(max(p / m, 0.0), 1.0), SHAPE_DOWN: min(max(-p / m, 0.0), 1.0)}


@dataclass(frozen=True)
class LidParams(Settings):
    """Settings of the lid shapes (the ``rig:`` block of params.yaml, see :class:`RigSettings`).

    Gains are lid rotation / eyeball rotation at the middle of each lid.
    """

    max_pitch_deg: float = setting(MAX_PITCH_DEG, gt=0, le=90)
    # Lid rotation / eye rotation at mid-lid, the canthus taper and the skin falloff: fitted to
    # ICT-FaceKit's captured eyeLookUp/eyeLookDown (Li et al. 2020, CVPR; weight 1 taken as
    # 25 deg) at its visible lid edge, the innermost vertex ring round its margin loop that is
    # seen from the front (benchmarks/compare_ict_lids.py; the loop itself is the lid's hidden
    # posterior edge). The upper lid follows the eye about 1:1 looking down and half as much
    # looking up (the capture's ring, 1.75 mm off the eye, turns 0.94 / 0.45 of the pitch; our
    # margin lies on the eye, nearer the axis, and needs 1.04 / 0.50 for the same path), the
    # lower lid a third and a quarter; the lateral canthus moves with 0.8 of the lids' mean, the
    # medial one 0.375. The fit keeps the medial ramp >= 0.3 of the lid width: at 0.2 james'
    # coarse medial canthus and the rig tests' opening on the cornea fold looking down.
    gain_upper_up: float = setting(0.50, ge=0, le=2)
    gain_upper_down: float = setting(1.04, ge=0, le=2)
    gain_lower_up: float = setting(0.23, ge=0, le=2)
    gain_lower_down: float = setting(0.33, ge=0, le=2)
    canthus_width: float = setting(0.325, ge=0, le=0.5)         # medial end of the gain taper
    canthus_exponent: float = setting(0.75, gt=0, le=10)
    lateral_canthus_width: float = setting(0.35, ge=0, le=0.5)   # lateral end
    canthus_floor: float = setting(0.375, ge=0, le=1)           # medial canthus: share of the lids' mean gain
    max_margin_shear: float = setting(0.5, ge=0, le=10)         # neighbouring margin points part by at most this per mm in a full pose (0 = off)
    lateral_canthus_floor: float = setting(0.8, ge=0, le=1)     # lateral canthus
    upper_falloff_mm: float = setting(22.0, gt=0, le=100)
    lower_falloff_mm: float = setting(10.0, gt=0, le=100)
    # the lid skin beyond the margin: with a rise distance its gain goes from the margin's to
    # these over rise_mm (pipeline.rig.lid_shapes.lid_angle_field), then fades with the falloff
    # above; rise 0 (default): the skin keeps the margin's gain (what the capture's visible lid
    # does: its skin turns with the margin for 4-6 mm, then falls off)
    skin_gain_upper_up: float = setting(0.50, ge=0, le=2)
    skin_gain_upper_down: float = setting(1.04, ge=0, le=2)
    skin_gain_lower_up: float = setting(0.23, ge=0, le=2)
    skin_gain_lower_down: float = setting(0.33, ge=0, le=2)
    upper_rise_mm: float = setting(0.0, ge=0, le=100)
    lower_rise_mm: float = setting(0.0, ge=0, le=100)
    max_chord_sag_mm: float = setting(0.03, gt=0, le=10)
    max_segments: int = setting(12, ge=1, le=100)
    min_opening_fraction: float = setting(0.2, le=1)   # negative: the guard is off
    surface_follow_mm: float = setting(3.0, ge=0, le=50)   # skin this far off the eyeball no longer follows the cornea
    min_offset_mm: float = setting(1e-6, ge=0, le=1)
    min_area_fraction: float = setting(0.25, ge=0, le=1)   # faces keep this share of their area in the full poses
    max_support_scale: float = setting(2.0, ge=1, le=10)   # ... by widening the falloff radii up to this factor

    @classmethod
    def from_dict(cls, d: dict | None) -> "LidParams":
        """Build from a params dict, ignoring keys that are not lid settings."""
        d = dict(d or {})
        names = set(LidParams.keys())
        return LidParams(**{k: v for k, v in d.items() if k in names})

    def lid_params(self) -> "LidParams":
        """Only the lid-shape settings (what rig.json records)."""
        return LidParams(**{k: getattr(self, k) for k in LidParams.keys()})


@dataclass(frozen=True)
class RigSettings(LidParams):
    """The whole ``rig:`` block: the lid-shape settings plus the stage's checks and outputs."""

    block: ClassVar[str] = "rig"

    max_rest_gap_mm: float = setting(0.5, gt=0, le=10)    # refuse a margin farther than this from its eyeball sphere
    sweep_step_deg: float = setting(0.5, ge=0.05, le=25)   # pitch step of the sweep written to the metrics
    down_smoothing_sigma_mm: float = setting(0.75, ge=0, le=20)  # blur of the down-looking texture variant


def subshape_weights(shape: BlendShape, w: float) -> np.ndarray:
    """Weights of the stored poses (inbetweens..., full) for channel weight ``w``.

    UsdSkel semantics: piecewise-linear between the knots (implicit 0, inbetweens,
    1); outside [0, 1] linear extrapolation of the end segment.

    Returns
    -------
    (j+1,) float64
        One weight per inbetween, then the full shape.
    """
    knots, _ = shape.knots()
    w = float(w)
    if w <= knots[1]:
        seg = 0
    elif w >= knots[-2]:
        seg = len(knots) - 2
    else:
        seg = int(np.searchsorted(knots, w, side="right") - 1)
    a = (w - knots[seg]) / (knots[seg + 1] - knots[seg])
    full = np.zeros(len(knots))
    full[seg] = 1.0 - a
    full[seg + 1] = a
    return full[1:]


def flat_shape_weights(shapes, channel_weights: dict) -> dict[str, float]:
    """Expand channel weights to one weight per stored pose, for shape keys without inbetweens.

    Parameters
    ----------
    shapes : sequence of BlendShape
    channel_weights : dict
        ``{name: w}``, e.g. from :func:`lid_weights`.

    Returns
    -------
    dict
        ``{"<name>_ib1": .., ..., "<name>": ..}`` for every shape; a renderer that
        creates one shape key per stored pose (offsets relative to the rest mesh)
        and sets these values reproduces :func:`evaluate_shapes` exactly.
    """
    out = {}
    for s in shapes:
        sub = subshape_weights(s, channel_weights.get(s.name, 0.0))
        for name, w in zip(s.inbetween_names() + [s.name], sub):
            out[name] = float(w)
    return out


def evaluate_shapes(V, shapes, channel_weights: dict) -> np.ndarray:
    """Posed points: rest ``V`` plus every shape at its channel weight (UsdSkel semantics).

    Parameters
    ----------
    V : (n, 3) float64
    shapes : sequence of BlendShape
    channel_weights : dict

    Returns
    -------
    (n, 3) float64
    """
    P = np.array(V, dtype=np.float64, copy=True)
    for s in shapes:
        w = channel_weights.get(s.name, 0.0)
        if w == 0.0 or len(s.point_indices) == 0:
            continue
        _, offs = s.knots()
        sub = subshape_weights(s, w)
        P[s.point_indices] += np.tensordot(sub, offs[1:], axes=1)
    return P
