"""What GazeML's UnityEyes loader computes from one UnityEyes JSON: a transcription for the tests.

GazeML (github.com/swook/GazeML) trains its eye-landmark network on UnityEyes images through
``src/datasources/unityeyes.py``, ``UnityEyes.preprocess_entry``, with the angle helpers of
``src/util/gaze.py``. This module redoes, step by step and in the same order, what that method
computes from the JSON and the image size, so a test can feed it our ``unityeyes/NNNNNN.json``
and compare what GazeML would train on with our own labels. Written anew from the reading, not
copied; each step names the GazeML variable it stands for. Left out: the image warping, blurring
and noise (pixels only) and the heatmaps (drawn at the landmarks computed here). The random
augmentation values (rotation, scale, translation) are arguments, 0 by default (no
augmentation), instead of draws. GazeML parses each string with Python's ``eval``; here
``ast.literal_eval``, which reads the same tuple literals and nothing else.

1. ``process_coords``: each point string -> ``(x, ih - y, z)``: UnityEyes' y counts from the
   image bottom, GazeML's from the top.
2. Head pose filter: ``head_pose`` = (pitch, yaw, roll) degrees; pitch > 180 -> pitch - 360;
   yaw -> yaw - 180; the entry is dropped (None) when ``|pitch| > 20`` or ``|yaw| > 20``.
3. Crop: ``left_corner`` = mean of the 7 caruncle points, ``right_corner`` = interior margin
   point 8; ``eye_width = 1.5 * |left_corner.x - right_corner.x|``; ``eye_middle`` = centre of
   the interior margin's bounding box. The transform to the (oh, ow) eye image is
   ``recentre @ scale @ rotate @ translate``: translate by minus the image centre (where GazeML
   assumes the eyeball centre), rotate (augmentation), scale by ``ow / eye_width * (1 + s)``, then
   move by ``(iw/2 - eye_middle.x + eye_width / (2 (1 + s)), ih/2 - eye_middle.y + oh / ow *
   eye_width / (2 (1 + s)))`` plus the translation noise.
4. ``radius``: the fixed ``original_eyeball_radius = 71.7593`` px times the scale.
5. Gaze: ``look_vec`` = the first 3 numbers of ``eye_details.look_vec`` with x negated;
   ``original_gaze`` = (arcsin(y), arctan2(x, z)) of it normalised; the trained ``gaze`` is the same
   of the rotated vector, with the yaw folded: ``pi - yaw`` when yaw > 0, ``-(pi + yaw)`` when < 0.
6. ``iris_centre`` = image centre + 71.7593 * (-cos(pitch) sin(yaw), -sin(pitch)) of
   ``original_gaze``; the 18 landmarks = interior margin [::2] (8), iris [::4] (8), iris centre,
   image centre (the eyeball centre), through the crop transform.
"""

from __future__ import annotations

import ast
import math

import numpy as np

ORIGINAL_EYEBALL_RADIUS = 71.7593


def _points(strings, ih: float) -> np.ndarray:
    """Step 1: (n, 3) points with y measured from the top."""
    out = []
    for text in strings:
        x, y, z = ast.literal_eval(text)
        out.append((x, ih - y, z))
    return np.array(out, float)


def pitch_yaw(v) -> np.ndarray:
    """``util.gaze.vector_to_pitchyaw`` of one vector: (arcsin(y), arctan2(x, z)) of v / |v|."""
    v = np.asarray(v, float).ravel()
    v = v / np.linalg.norm(v)
    return np.array([math.asin(v[1]), math.atan2(v[0], v[2])])


def pitch_yaw_vector(py) -> np.ndarray:
    """``util.gaze.pitchyaw_to_vector`` of one (pitch, yaw): (cos p sin y, sin p, cos p cos y)."""
    p, y = float(py[0]), float(py[1])
    return np.array([math.cos(p) * math.sin(y), math.sin(p), math.cos(p) * math.cos(y)])


def look_vec_gaze(look_vec) -> np.ndarray:
    """Step 5 without augmentation: GazeML's trained ``gaze`` (pitch, yaw) of a ``look_vec``
    (its first 3 numbers, x negated, ``vector_to_pitchyaw``, the yaw folded about pi)."""
    look = np.array(look_vec, float)[:3]
    look[0] = -look[0]
    gaze = pitch_yaw(look)
    if gaze[1] > 0.0:
        gaze[1] = math.pi - gaze[1]
    elif gaze[1] < 0.0:
        gaze[1] = -(math.pi + gaze[1])
    return gaze


def read_entry(doc: dict, ih: int, iw: int, eye_image_shape=(36, 60), rotation_deg: float = 0.0,
               scale_noise: float = 0.0, translation=(0.0, 0.0)) -> dict | None:
    """What ``preprocess_entry`` derives from one UnityEyes JSON ``doc`` of an ``ih`` x ``iw``
    image (None: dropped by the head-pose filter). Returns ``gaze`` (2,) radians, ``radius``,
    ``landmarks`` (18, 2) in the eye image, and the full-image ``iris_centre``,
    ``eyeball_centre``, ``transform`` (3, 3), ``eye_width``, ``eye_middle``."""
    oh, ow = eye_image_shape
    cx, cy = 0.5 * iw, 0.5 * ih
    interior = _points(doc["interior_margin_2d"], ih)
    caruncle = _points(doc["caruncle_2d"], ih)
    iris = _points(doc["iris_2d"], ih)

    pitch, yaw, _ = ast.literal_eval(doc["head_pose"])                      # step 2
    if pitch > 180.0:
        pitch -= 360.0
    yaw -= 180.0
    if abs(pitch) > 20 or abs(yaw) > 20:
        return None

    left = caruncle[:, :2].mean(axis=0)                                      # step 3
    right = interior[8, :2]
    eye_width = 1.5 * abs(left[0] - right[0])
    middle = 0.5 * (interior[:, :2].min(axis=0) + interior[:, :2].max(axis=0))
    translate = np.eye(3)
    translate[:2, 2] = [-cx, -cy]
    rotate = np.eye(3)
    if rotation_deg > 0:                  # GazeML rotates only for a positive draw
        a = math.radians(rotation_deg)
        rotate[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    s = 1.0 + scale_noise
    scale = np.diag([ow / eye_width * s] * 3)
    recentre = np.eye(3)
    recentre[0, 2] = iw / 2 - middle[0] + 0.5 * eye_width / s + translation[0]
    recentre[1, 2] = ih / 2 - middle[1] + 0.5 * oh / ow * eye_width / s + translation[1]
    transform = recentre @ scale @ rotate @ translate

    radius = ORIGINAL_EYEBALL_RADIUS * scale[0, 0]                           # step 4

    look = np.array(ast.literal_eval(doc["eye_details"]["look_vec"])[:3], float)   # step 5
    look[0] = -look[0]
    original_gaze = pitch_yaw(look)
    gaze = pitch_yaw(rotate @ look)
    if gaze[1] > 0.0:
        gaze[1] = math.pi - gaze[1]
    elif gaze[1] < 0.0:
        gaze[1] = -(math.pi + gaze[1])

    p0, y0 = original_gaze                                                   # step 6
    iris_centre = np.array([cx + ORIGINAL_EYEBALL_RADIUS * -math.cos(p0) * math.sin(y0),
                            cy + ORIGINAL_EYEBALL_RADIUS * -math.sin(p0)])
    pts = np.concatenate([interior[::2, :2], iris[::4, :2], iris_centre[None], [[cx, cy]]])
    landmarks = (np.c_[pts, np.ones(len(pts))] @ transform.T)[:, :2]
    return {"gaze": gaze, "radius": radius, "landmarks": landmarks, "iris_centre": iris_centre,
            "eyeball_centre": np.array([cx, cy]), "transform": transform, "eye_width": eye_width,
            "eye_middle": middle, "head_pose": (pitch, yaw)}


def gaze_to_camera(gaze) -> np.ndarray:
    """GazeML's (pitch, yaw) as a unit vector in our camera frame (x right, y up, z toward the
    camera): GazeML's vector ``pitch_yaw_vector(gaze)`` has x toward the image left."""
    v = pitch_yaw_vector(gaze)
    return np.array([-v[0], v[1], v[2]])
