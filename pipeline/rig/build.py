"""The rig stage's work: eyelid blend shapes, landmark curves and the pitch sweep for one scan.

``build_rig`` takes the snapped mesh and its eyes and returns the arrays of ``rig.npz``, the
``rig.json`` document and the metrics (:class:`RigBuild`); the method is in ``lid_shapes`` (the
shapes), ``sweep`` (the pitch sweep) and ``landmarks``. A sweep that flips a face refuses the scan;
a lid that notches the opening seen from the front (toothed, spiked or split: :func:`lid_notches`)
is a warning.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import ScanError
from pipeline.eyeball.geometry import EyeballParams, placed_params
from pipeline.geometry.opening import JAGGED_LID_MM, opening_notch
from pipeline.rig import landmarks as lmk
from pipeline.rig import lids
from pipeline.rig.eye_frame import eye_frames
from pipeline.rig.folds import describe_folds, fold_report, relax_folds
from pipeline.rig.lid_shapes import build_lid_shapes
from pipeline.rig.sweep import sweep_check
from pipeline.rig import yaw_shapes as yaw
from pipeline.rig import textures as tex
from pipeline.results import StageResult


@dataclass
class RigBuild:
    """What the rig stage writes: ``arrays`` (rig.npz), ``doc`` (rig.json) and ``result`` (its
    metrics and timings); ``warnings``, one line each, for the stage to print."""

    arrays: dict
    doc: dict
    result: StageResult
    warnings: list = field(default_factory=list)


#: The head frame's forward (+Z out of the face, DESIGN.md): the view the lids are judged from.
HEAD_FORWARD = np.array([0.0, 0.0, 1.0])


def lid_notches(V, F, eyes, shapes, max_pitch_deg: float) -> dict:
    """side -> the deepest notch (mm) in what the posed lids leave open of that eye, seen from
    the head's front at rest and looking up by ``max_pitch_deg`` (the lids open widest;
    :func:`pipeline.geometry.opening.opening_notch`). Looking down the lids nearly meet and
    the slit between them is not convex: not judged there."""
    out = {e.side: 0.0 for e in eyes}
    for pitch in (0.0, max_pitch_deg):
        P = lids.evaluate_shapes(V, shapes, lids.lid_weights(pitch, max_pitch_deg))
        for e in eyes:
            out[e.side] = max(out[e.side], opening_notch(P, F, e.loop, HEAD_FORWARD)[1])
    return out


def _model_corneas(eyes):
    """Cornea sphere of the parametric eyeball placed in each fitted eye (for a metric)."""
    out = {}
    for e in eyes:
        p = placed_params(e.profile or EyeballParams(), e.radius)
        out[e.side] = (e.center + e.forward * p.cornea_center_z, p.r2)
    return out


def build_rig(mesh: Mapping, placed_eyes: dict, params, mesh_path="mesh.npz",
              eyes_path="eyes.json", profile=None) -> RigBuild:
    """Everything the rig stage computes (:class:`RigBuild`) from the snapped mesh and its eyes
    (side -> :class:`pipeline.io.eyes_file.Eye`, the snap stage's eyes.json).

    ``params``: a :class:`pipeline.rig.lids.RigSettings` or its raw ``rig:`` mapping.
    ``profile``: EyeballParams of the parametric eye the margin was snapped to (None = sphere).
    """
    st = params if isinstance(params, lids.RigSettings) else lids.RigSettings.from_params(params)
    lp = st.lid_params()
    eyes = eye_frames(placed_eyes, mesh, eyes_source=str(eyes_path), mesh_source=str(mesh_path),
                      max_rest_gap_mm=st.max_rest_gap_mm,
                      profile=profile)
    V = np.asarray(mesh["V"], np.float64)
    F = np.asarray(mesh["F"], np.int64)
    step = st.sweep_step_deg
    pitches = np.unique(np.concatenate([np.arange(-lp.max_pitch_deg, lp.max_pitch_deg + 1e-9, step),
                                        [-lp.max_pitch_deg, 0.0, lp.max_pitch_deg]]))
    t0 = time.perf_counter()
    rig = build_lid_shapes(V, F, eyes, lp)
    # a sliver the retopology left can still turn over under the smooth lid field: smooth the
    # skin's motion around it (the sweep below still refuses any fold that remains)
    rig.shapes, relax_rounds, relaxed = relax_folds(V, F, rig.shapes, eyes, pitches, lp.max_pitch_deg)
    # the lids ride on the cornea as the eye turns in yaw (per eye, a grid of pitch x yaw poses)
    yshapes = yaw.build_yaw_shapes(V, eyes, lp.surface_follow_mm, rig.shapes, lp.max_pitch_deg)
    yshapes, yaw_rounds, yaw_damped, ysweep = yaw.settle_yaw_folds(V, F, eyes, rig.shapes, yshapes,
                                                                   lp.max_pitch_deg) if yshapes else ([], 0, 0, {})
    t_build = time.perf_counter() - t0

    arrays = lids.shapes_to_arrays(rig.shapes + yshapes)
    down = rig.shape(lids.SHAPE_DOWN)
    arrays["lids_down.texture_mask"] = tex.motion_mask(len(V), down.point_indices, down.offsets)
    eyes_doc, lm_doc = {}, {}
    for e in eyes:
        lm = lmk.eyelid_landmarks(V, e)
        lshapes = lmk.landmark_shapes(lm, e, rig) + yaw.curve_shapes(yshapes, e.side, lm.edge, lm.t)
        pre = f"landmarks.{e.side}."
        arrays[pre + "points"] = lm.points
        arrays[pre + "edge"] = lm.edge
        arrays[pre + "t"] = lm.t
        arrays.update(lids.shapes_to_arrays(lshapes, prefix=pre))
        arrays[f"loop_{e.side}"] = e.loop
        eyes_doc[e.side] = {
            "surface": "sphere" if e.profile is None else
                       {"parametric_eye": {k: getattr(placed_params(e.profile, e.radius), k)
                                           for k in ("r1", "r2", "apex", "seam_blend_mm")}},
            "joint": f"eye_{e.side}",
            "center": e.center, "radius": e.radius, "forward": e.forward,
            "pitch_axis": e.axis,
            "lateral_index": e.lateral_index, "loop_length": len(e.loop),
            "doubts": list(placed_eyes[e.side].doubts),   # carried from remove_eyeballs (and a jagged lid's, below)
        }
        lm_doc[e.side] = {"eyelid_loop_position": lm.loop_position, "eyelid_edges": lm.edge}

    t0 = time.perf_counter()
    sweep = sweep_check(V, F, eyes, rig.shapes, pitches, lp.max_pitch_deg,
                        corneas=_model_corneas(eyes), fork=True)
    t_sweep = time.perf_counter() - t0
    if sweep["flipped_faces"]:
        # a face that turns over while the eye moves is a visible fold in every render; say where
        # (eye, lid, band ring, head-frame position, pitch), so the fold can be found
        rep = fold_report(V, F, eyes, rig.shapes, pitches, lp.max_pitch_deg)
        where = "" if rep is None else f": {describe_folds(rep)}"
        raise ScanError(mesh_path, f"the eyelid sweep over pitch +-{lp.max_pitch_deg:g} deg flips "
                                   f"{sweep['flipped_faces']} faces (a fold in the lids){where}; "
                                   f"the eye fit or the eyelid loop is wrong, or the scan itself folds there")

    # a toothed, spiked or split lid shows in every render, yet folds nothing: say so
    notches = lid_notches(V, F, eyes, rig.shapes, lp.max_pitch_deg)
    # ... and the asset carries it as a doubt (its customData, the render's warnings, the dataset's
    # info), beside remove_eyeballs' own
    warnings = []
    for side, n in sorted(notches.items()):
        eyes_doc[side]["lid_notch_mm"] = round(float(n), 3)
        if n > JAGGED_LID_MM:
            doubt = (f"the lids leave a notch of {n:.1f} mm in the opening seen from the front "
                     f"(over {JAGGED_LID_MM:g} mm: a toothed, spiked or split lid the renders show)")
            eyes_doc[side]["doubts"].append(doubt)
            warnings.append(f"{side} eye: {doubt}")

    # margin motion at the extremes (mean vertical displacement per lid, mm)
    motion = {}
    for name in (lids.SHAPE_UP, lids.SHAPE_DOWN):
        P = lids.evaluate_shapes(V, rig.shapes, {name: 1.0})
        for e in eyes:
            dy = (P[e.loop] - V[e.loop]) @ e.basis()[1]
            li = e.lateral_index
            motion[f"{name}_{e.side}_upper_mean_dy_mm"] = float(dy[1:li].mean())
            motion[f"{name}_{e.side}_lower_mean_dy_mm"] = float(dy[li + 1:].mean())

    doc = {
        "weight_rule": lids.weight_rule(lp.max_pitch_deg),
        **({"yaw_rule": yaw.yaw_rule()} if yshapes else {}),
        "shapes": [{"name": s.name, "n_points": int(len(s.point_indices)),
                    "inbetweens": [{"name": n, "weight": float(w)} for n, w in
                                   zip(s.inbetween_names(), s.inbetween_weights)],
                    "max_offset_mm": float(np.linalg.norm(s.offsets, axis=1).max(initial=0.0))}
                   for s in rig.shapes + yshapes],
        "n_segments": rig.n_segments,
        "eyes": eyes_doc,
        "landmarks": {
            "per_eye": lmk.N_PER_EYE,
            "eyelid": {"count": lmk.N_EYELID, "order": lmk.EYELID_ORDER,
                       "curve": "closed curve through the 12 points, in order; carries the same "
                                "shapes and inbetweens as the mesh", **lm_doc},
            **lmk.eyeball_landmark_doc(),
        },
        "smoothed_down_variant": {
            "mask": "lids_down.texture_mask (n,) per-vertex weight in [0, 1] (rig.npz)",
            "rule": "texture_down = mix(texture, gaussian_blur(texture, sigma_mm), "
                    "w_lids_down * mask), for the colour and the displacement map",
            "sigma_mm": st.down_smoothing_sigma_mm,
            "functions": "pipeline.rig.textures.rasterize_vertex_scalar, texels_per_mm, "
                         "smoothed_variant",
        },
        "params": {k: getattr(lp, k) for k in lp.__dataclass_fields__},
        "npz_layout": {
            "shape_names": "(s,) str: lids_up, lids_down, then for each eye with a corneal bulge "
                           "lids_look_<in|out>_<side>_<pitch knot>_y<yaw knot> (yaw_rule)",
            "<shape>.point_indices": "(k,) int64 mesh vertex indices",
            "<shape>.offsets": "(k,3) float64 mm at weight 1",
            "<shape>.inbetween_weights": "(j,) float64 in (0,1)",
            "<shape>.inbetween_offsets": "(j,k,3) float64 mm, same point_indices",
            "landmarks.<side>.points": "(12,3) float64 rest eyelid landmarks",
            "landmarks.<side>.edge": "(12,2) int64 margin edge of each landmark",
            "landmarks.<side>.t": "(12,) float64 position on the edge",
            "landmarks.<side>.shape_names / .<shape>.*": "landmark-curve shapes, same layout, "
                                                          "point_indices 0..11",
            "loop_<side>": "(L,) int64 eyelid margin loop (medial canthus first, upper lid first)",
            "lids_down.texture_mask": "(n,) float64 per-vertex mask of the smoothed down variant",
        },
    }
    metrics = {
        "n_vertices": int(len(V)), "n_faces": int(len(F)),
        "n_segments": rig.n_segments, "interpolation_error_mm": rig.predicted_sag_mm,
        **{f"{s.name}_n_points": int(len(s.point_indices)) for s in rig.shapes},
        "sweep_step_deg": step,
        "fold_relax_rounds": int(relax_rounds), "fold_relaxed_vertices": int(relaxed),
        **{f"sweep_{k}": v for k, v in sweep.items()},
        **{f"yaw_sweep_{k}": (list(v) if isinstance(v, tuple) else v) for k, v in ysweep.items()},
        "yaw_fold_rounds": int(yaw_rounds), "yaw_damped_vertices": int(yaw_damped),
        # one summary, not one key per yaw channel (rig.json lists each channel's points)
        "yaw_channels": len(yshapes),
        "yaw_n_points_max": max((int(len(s.point_indices)) for s in yshapes), default=0),
        **motion,
        **{f"lid_notch_{side}_mm": round(float(n), 3) for side, n in sorted(notches.items())},
        "jagged_lids": len(warnings),
    }
    return RigBuild(arrays, doc, StageResult(metrics, {"build_s": round(t_build, 4),
                                                       "sweep_s": round(t_sweep, 4)}), warnings)
