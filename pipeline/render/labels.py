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
#: A pinhole camera's frames: the gaze angles' zero is the optical axis, which passes through
#: the eye only when the camera aims at it (not a webcam aimed between the eyes).
FRAMES_PINHOLE = FRAMES.replace(
    "a gaze straight at the camera is (0, 0)).",
    "a gaze along the optical axis toward the camera is (0, 0); a gaze at a pinhole camera's centre is (0, 0) "
    "only for an eye on its optical axis). Pinhole camera: ``[u, v, 1] ~ camera.intrinsics.K @ diag(1, -1, -1) "
    "@ p_cam``.")


def _angles(v) -> dict:
    v = np.asarray(v, float) / np.linalg.norm(v)
    return {"pitch_deg": math.degrees(math.asin(max(-1.0, min(1.0, v[1])))),
            "yaw_deg": math.degrees(math.atan2(v[0], v[2]))}


def _normalization_forward(smp: sp.Sample, settings: RenderSettings) -> np.ndarray:
    """(3,) the eye's direction from the camera in OpenCV axes, for ETH-XGaze's normalisation.

    Orthographic rays are parallel: the view axis. A pinhole camera looks at the eye along the
    ray to its centre, which ETH-XGaze and MPIIGaze take as the midpoint of the two eye corners
    (our landmarks 0 and 6)."""
    if settings.camera != "pinhole":
        return np.array([0.0, 0.0, 1.0])
    L = np.asarray(smp.landmarks_cam, float)
    return conv.to_opencv(0.5 * (L[0] + L[6]))


#: Worker reply fields that measure time, not the image: kept out of the labels.
TIMING_KEYS = ("render_s", "total_s", "render_cpu_s", "total_cpu_s", "passes_s")


PINHOLE_NOTE = ("pinhole, no distortion: [u, v, 1] ~ K @ p_opencv, p_opencv = opencv.R @ p_head + opencv.t "
                "(x right, y down, z forward) = diag(1, -1, -1) @ p_cam; K in the labels' pixels (centres at +0.5; "
                "K_pixel_centres_at_integers for OpenCV's); the image is the sensor's pixels [x0, x0 + width) x "
                "[y0, y0 + height), x0, y0 = sensor.crop_offset_px, so K = sensor.K with cx - x0, cy - y0")


def camera_block(smp: sp.Sample, settings: RenderSettings) -> dict:
    """The label's ``camera`` block: orthographic (as before the pinhole camera) or pinhole
    (intrinsics, the sensor and crop, OpenCV extrinsics); both give ``projection`` (3, 4), camera
    mm -> homogeneous px, and ``head_to_pixel``."""
    c, camera = smp.camera, smp.spec.camera
    W2C = np.asarray(camera.world_to_camera, float)
    spherical = {"eye": smp.side, "polar_deg": c["polar_deg"], "azimuth_deg": c["azimuth_deg"],
                 "distance_mm": c["distance_mm"], "polar_axis": "the eye's rest forward (0 = frontal view)"}
    if camera.kind == "ortho":
        P = camera.projection(settings.width, settings.height)
        ow, oh = cam.ortho_size(camera.ortho_scale_mm, settings.width, settings.height)
        return {
            "type": "orthographic",
            "ortho_scale_mm": camera.ortho_scale_mm, "image_width_mm": ow, "image_height_mm": oh,
            "mm_per_px": c["mm_per_px"],
            "world_to_camera": W2C.tolist(),
            "projection": P.tolist(),
            "head_to_pixel": (P @ W2C).tolist(),
            "position_head_mm": list(map(float, c["position_mm"])),
            "spherical": spherical,
            "framing_shift_mm": c["jitter_mm"],
        }
    K, Ks = np.asarray(camera.K, float), np.asarray(c["K_sensor"], float)
    P = camera.projection(settings.width, settings.height)
    Rcv, tcv = cam.opencv_extrinsics(W2C)
    f, (w, h) = float(K[0, 0]), (settings.width, settings.height)
    sw, sh = c["sensor_px"]
    return {
        "type": "pinhole",
        "intrinsics": {"K": K.tolist(), "K_pixel_centres_at_integers": cam.opencv_pixel_K(K).tolist(),
                       "width": w, "height": h, "focal_px": f,
                       "principal_point_px": [float(K[0, 2]), float(K[1, 2])],
                       "fov_deg": [math.degrees(2 * math.atan(w / (2 * f))), math.degrees(2 * math.atan(h / (2 * f)))],
                       "distortion": [0.0] * 5, "distortion_model": "none (OpenCV k1, k2, p1, p2, k3 = 0)"},
        "sensor": {"K": Ks.tolist(), "K_pixel_centres_at_integers": cam.opencv_pixel_K(Ks).tolist(),
                   "width": sw, "height": sh, "crop_offset_px": list(c["crop_offset_px"]),
                   "fov_deg": [math.degrees(2 * math.atan(sw / (2 * f))), math.degrees(2 * math.atan(sh / (2 * f)))]},
        "opencv": {"R": Rcv.tolist(), "t": tcv.tolist(),
                   "world_to_camera": np.vstack([np.c_[Rcv, tcv], [0.0, 0.0, 0.0, 1.0]]).tolist()},
        "model": PINHOLE_NOTE,
        "mm_per_px": c["mm_per_px"],
        "mm_per_px_at": "the median depth of the 28 landmarks",
        "world_to_camera": W2C.tolist(),
        "projection": P.tolist(),
        "head_to_pixel": (P @ W2C).tolist(),
        "position_head_mm": list(map(float, c["position_mm"])),
        "aim": {"rule": c["aim"], "point_head_mm": list(map(float, c["aim_point_mm"]))},
        "spherical": spherical,
        "framing_shift_mm": c["jitter_mm"],
    }


def make_label(smp: sp.Sample, settings: RenderSettings, scan: str, reply: dict | None = None) -> dict:
    """The label dict of one image (``reply`` = the worker's reply, adds the render facts)."""
    spec = smp.spec
    W2C = np.asarray(smp.camera["world_to_camera"], float)
    R = W2C[:3, :3]
    view = -R[2]                               # camera viewing direction in the head frame
    g = smp.gaze[smp.side]
    g_cam = R @ g["vector_head"]
    eyes = {}
    for sd, gd in smp.gaze.items():
        eyes[sd] = {"rotation_wxyz": gd["rotation_wxyz"], "gaze_head": list(map(float, gd["vector_head"])),
                    "pitch_eye_deg": gd["pitch_eye_deg"], "yaw_eye_deg": gd["yaw_eye_deg"],
                    "clipped": gd["clipped"], **smp.eye_geometry[sd]}
    lm_h = smp.landmarks_head
    label = {
        "index": smp.index,
        "scan": scan,
        "image": {"file": sp.png_name(smp.index), "width": settings.width, "height": settings.height,
                  "pixels": "origin top-left, pixel centres at +0.5"},
        "frames": FRAMES_PINHOLE if smp.spec.camera.kind == "pinhole" else FRAMES,
        "seed": {"seed": settings.seed, "index": smp.index, "attempts": smp.attempts,
                 "rng": "numpy.random.default_rng([seed, index, attempt]), attempt = attempts - 1"},
        "preset": settings.preset,
        "camera": camera_block(smp, settings),
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
        "conventions": conv.conventions(W2C, g_cam, mirror_unityeyes=smp.side == "right",
                                        forward_cv=_normalization_forward(smp, settings)),
        "eyes": eyes,
        "eyelids": {"pitch_deg": smp.lid_pitch_deg, "weights": spec.lid_weights,
                    "rule": "pipeline.rig.lids.lid_weights(mean lid pitch of both eyes); "
                            "lids_look_<in|out>_<side>_*: pipeline.rig.yaw_shapes.yaw_weights(each eye's yaw, that pitch)"},
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
    # the camera in its wire layout, which apparent_landmarks reads back with Camera.from_dict
    return {"points_head": smp.landmarks_head[12:28].tolist(), **smp.spec.camera.to_dict(),
            "model_to_head": eye.model_to_head(R).tolist(), "eyeball_params": dict(eye.eyeball_params),
            "ior": eye.cornea_ior,
            "width": settings.width, "height": settings.height, "order": APPARENT_ORDER}


def check_label(label: dict) -> float:
    """Re-project the stored 3D camera landmarks with the stored camera; max pixel error."""
    P = np.asarray(label["camera"]["projection"], float)
    C = np.asarray(label["landmarks"]["camera_mm"], float)
    H = np.concatenate([C, np.ones((len(C), 1))], 1) @ P.T
    uv = H[:, :2] / H[:, 2:]
    return float(np.abs(uv - np.asarray(label["landmarks"]["px"], float)).max())
