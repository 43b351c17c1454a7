"""Per-image label JSON (DESIGN.md "Render output") built from a posed sample.

Frames: head frame (mm, +Y up, +Z out of the face, +X subject's left); camera frame
(OpenGL/Blender: the camera looks down -Z, +Y up in the image, +X right, mm,
``p_cam = world_to_camera @ [p_head, 1]``); image pixels (origin top-left, pixel centres at
+0.5, ``[u, v, 1] ~ projection @ [p_cam, 1]``). Angles in degrees: pitch positive = up, yaw
positive = toward the subject's left (head frame) / toward image right (camera frame, where
``yaw = atan2(x, z)`` of the camera-frame vector; a gaze straight at the camera is (0, 0)).
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from pipeline.render import camera as cam
from pipeline.render import conventions as conv
from pipeline.render.settings import RenderSettings
from pipeline.render import sampling as sp
from pipeline.render.asset import ring_radius
from pipeline.rig.landmarks import EYELID_ORDER

LANDMARK_ORDER = ("28 landmarks of the imaged eye: 0-11 eyelid (" + EYELID_ORDER + "); 12-19 iris "
                  "boundary, 20-27 pupil boundary (eyeball asset order: azimuth 45 deg * k from the "
                  "eye's +X, counter-clockwise seen from the front)")
FRAMES = __doc__.split("\n\n")[1].replace("\n", " ")


def _angles(v) -> dict:
    v = np.asarray(v, float) / np.linalg.norm(v)
    return {"pitch_deg": math.degrees(math.asin(max(-1.0, min(1.0, v[1])))),
            "yaw_deg": math.degrees(math.atan2(v[0], v[2]))}


#: Worker reply fields that measure time, not the image: kept out of the labels.
TIMING_KEYS = ("render_s", "total_s", "render_cpu_s", "total_cpu_s", "passes_s")


def make_label(smp: sp.Sample, settings: RenderSettings, scan: str, reply: dict | None = None) -> dict:
    """The label dict of one image (``reply`` = the worker's reply, adds the render facts)."""
    spec = smp.spec
    W2C = np.asarray(smp.camera["world_to_camera"], float)
    R = W2C[:3, :3]
    P = cam.projection_matrix(smp.camera["ortho_scale_mm"], settings.width, settings.height)
    ow, oh = cam.ortho_size(smp.camera["ortho_scale_mm"], settings.width, settings.height)
    view = -R[2]                               # camera viewing direction in the head frame
    g = smp.gaze[smp.side]
    g_cam = R @ g["vector_head"]
    eyes = {}
    for sd, gd in smp.gaze.items():
        eyes[sd] = {"rotation_wxyz": gd["rotation_wxyz"], "gaze_head": list(map(float, gd["vector_head"])),
                    "pitch_eye_deg": gd["pitch_eye_deg"], "yaw_eye_deg": gd["yaw_eye_deg"],
                    "clipped": gd["clipped"]}
    lm_h = smp.landmarks_head
    label = {
        "index": smp.index,
        "scan": scan,
        "image": {"file": sp.png_name(smp.index), "width": settings.width, "height": settings.height,
                  "pixels": "origin top-left, pixel centres at +0.5"},
        "frames": FRAMES,
        "seed": {"seed": settings.seed, "index": smp.index, "attempts": smp.attempts,
                 "rng": "numpy.random.default_rng([seed, index, attempt]), attempt = attempts - 1"},
        "preset": settings.preset,
        "camera": {
            "type": "orthographic",
            "ortho_scale_mm": smp.camera["ortho_scale_mm"], "image_width_mm": ow, "image_height_mm": oh,
            "mm_per_px": smp.camera["mm_per_px"],
            "world_to_camera": W2C.tolist(),
            "projection": P.tolist(),
            "head_to_pixel": (P @ W2C).tolist(),
            "position_head_mm": list(map(float, smp.camera["position_mm"])),
            "spherical": {"eye": smp.side, "polar_deg": smp.camera["polar_deg"],
                          "azimuth_deg": smp.camera["azimuth_deg"],
                          "distance_mm": smp.camera["distance_mm"],
                          "polar_axis": "the eye's rest forward (0 = frontal view)"},
            "framing_shift_mm": smp.camera["jitter_mm"],
        },
        "head_pose": {"rotation_head_to_camera": R.tolist(),
                      "camera_direction_head": list(map(float, -view)),
                      **{f"camera_{k}": v for k, v in _angles(-view).items()},
                      "note": "head pose relative to the camera: head-frame direction from the head "
                              "toward the camera and the head-to-camera rotation (no roll)"},
        "gaze": {"eye": smp.side,
                 "vector_head": list(map(float, g["vector_head"])),
                 "vector_camera": list(map(float, g_cam)),
                 "head": _angles(g["vector_head"]),
                 "camera": _angles(g_cam),
                 "eye_frame": {"pitch_deg": g["pitch_eye_deg"], "yaw_deg": g["yaw_eye_deg"]},
                 "eye_contact_eye_frame_deg": smp.camera["eye_contact_eye_deg"],
                 "offset_from_eye_contact_deg": smp.camera["gaze_offset_deg"],
                 "clipped": g["clipped"],
                 "limits_deg": {"pitch": settings.max_pitch_deg, "yaw": settings.max_yaw_deg},
                 "rotation_rule": "Listing's law from the rest forward: minimal rotation forward -> gaze"},
        # the same gaze and head pose as ETH-XGaze, MPIIGaze, GazeML and UnityEyes write them
        "conventions": conv.conventions(W2C, g_cam, mirror_unityeyes=smp.side == "right"),
        "eyes": eyes,
        "eyelids": {"pitch_deg": smp.lid_pitch_deg, "weights": spec.lid_weights,
                    "rule": "pipeline.rig.lids.lid_weights(mean lid pitch of both eyes)"},
        "landmarks": {"order": LANDMARK_ORDER, "eye": smp.side,
                      "px": smp.landmarks_px.tolist(),
                      "camera_mm": smp.landmarks_cam.tolist(),
                      "head_mm": lm_h.tolist(),
                      "pupil_center_px": list(map(float, smp.pupil_center_px))},
        "eye_configuration": {"iris_color": spec.eyeball.iris_color,
                              "sclera_tint": spec.eyeball.sclera_tint,
                              "veins": spec.eyeball.veins,
                              "blend": spec.eyeball.blend,
                              "pupil_radius_mm": ring_radius(lm_h[20:28]),
                              "iris_radius_mm": ring_radius(lm_h[12:20])},
        "lighting": asdict(spec.lighting),
        "render": {"engine": "cycles", "samples": spec.quality.samples, "denoise": spec.quality.denoise,
                   "cycles_seed": spec.quality.cycles_seed, "skin_detail": spec.quality.skin_detail},
    }
    if reply is not None:
        label["landmark_check_mm"] = reply.get("landmark_check_mm")
        for k, v in reply.items():      # timings stay out of labels (identical inputs, identical bytes)
            if k not in ("index", "ok", "rss_mib", "landmark_check_mm", "error") and k not in TIMING_KEYS:
                label["render"].setdefault(k, v)
    return label


APPARENT_ORDER = ("16 points: the iris (8) and pupil (8) landmarks, in the order of landmarks 12-27, where the "
                  "camera sees them through the cornea (single refraction at the eyeball asset's analytic outer "
                  "surface, n = cornea_ior; occlusion ignored; null = not seen through the cornea); "
                  "pipeline/render/refraction.py")


def apparent_job(smp: sp.Sample, eye, settings: RenderSettings) -> dict:
    """What :func:`pipeline.render.shard.apparent_landmarks` needs (computed while Blender renders)."""
    from pipeline.render.camera import quat_to_matrix

    R = quat_to_matrix(smp.spec.eye_rotation[smp.side])
    return {"points_head": smp.landmarks_head[12:28].tolist(),
            "world_to_camera": np.asarray(smp.camera["world_to_camera"]).tolist(),
            "model_to_head": eye.model_to_head(R).tolist(), "eyeball_params": dict(eye.eyeball_params),
            "ior": eye.cornea_ior, "ortho_scale_mm": smp.camera["ortho_scale_mm"],
            "width": settings.width, "height": settings.height, "order": APPARENT_ORDER}


def check_label(label: dict) -> float:
    """Re-project the stored 3D camera landmarks with the stored camera; max pixel error."""
    P = np.asarray(label["camera"]["projection"], float)
    C = np.asarray(label["landmarks"]["camera_mm"], float)
    H = np.concatenate([C, np.ones((len(C), 1))], 1) @ P.T
    uv = H[:, :2] / H[:, 2:]
    return float(np.abs(uv - np.asarray(label["landmarks"]["px"], float)).max())
