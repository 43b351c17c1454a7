"""Gaze and head pose in the conventions of the field: ETH-XGaze, MPIIGaze, GazeML, UnityEyes.

Ours (pipeline/render/labels.py): the camera frame is OpenGL's (x right, y up, z toward the
viewer); a gaze vector points from the eye outwards; ``pitch = asin(y)``, ``yaw = atan2(x, z)``
in degrees, so a gaze into the camera is (0, 0), up is +pitch and toward the image right is
+yaw. The head frame: x the subject's left, y up, z out of the face. ``R`` (the label's
``head_pose.rotation_head_to_camera``) takes head vectors to camera vectors.

Each convention below is written from its authors' code:

* **ETH-XGaze** (Zhang et al., ECCV 2020; ``xucong-zhang/ETH-XGaze``, ``normalization_example.py``):
  vectors in OpenCV camera axes (x right, y down, z forward, away from the camera): ours are
  ``(x, -y, -z)``. The gaze vector is target minus eye (outwards, as ours);
  ``gaze_theta = arcsin(-g[1])``, ``gaze_phi = arctan2(-g[0], -g[2])`` (radians), so a gaze into
  the camera is (0, 0), up is +pitch and toward the image right is **-yaw**. Head pose:
  ``hR = Rodrigues(hr)`` maps face-model points into the camera (``Fc = hR @ face_model + ht``);
  ``Zv = hR[:, 2]``, ``head = (asin(Zv[1]), atan2(Zv[0], Zv[2]))``. A frontal face is (0, 0), so
  the face model's axes are x the subject's left, y down, z into the head: ours rotated 180 deg
  about x, ``hR = C @ R @ C`` with ``C = diag(1, -1, -1)``. The data are normalised
  (``normalizeData``): the camera turned to look at the eye (``forward``), its x axis
  toward the head's x axis (``down = forward x hR[:, 0]``, ``right = down x forward``,
  ``Rn = [right, down, forward]``), then ``g_n = Rn @ g``, ``hR_n = Rn @ hR``.
* **MPIIGaze / MPIIFaceGaze** (Zhang et al., CVPR 2015 / TPAMI 2017): the same normalisation and
  the same formulas, as ``hysts/pytorch_mpiigaze`` ``tools/preprocess_mpiigaze.py`` writes them:
  ``convert_gaze``: ``pitch = arcsin(-y)``, ``yaw = arctan2(-x, -z)`` of the normalised gaze;
  ``convert_pose``: ``v = Rodrigues(pose)[:, 2]``, ``(arcsin(v[1]), arctan2(v[0], v[2]))``.
* **GazeML** (Park et al., ETRA 2018; ``swook/GazeML``): its UnityEyes loader
  (``src/datasources/unityeyes.py``) negates ``look_vec``'s x, takes ``util.gaze.vector_to_pitchyaw``
  (``(arcsin(y), arctan2(x, z))``) and folds the yaw (``pi - yaw`` when > 0, ``-(pi + yaw)`` when
  < 0): ``(asin(gy), atan2(-gx, gz))`` of our camera-frame gaze. Equal to ETH-XGaze's.
* **UnityEyes** (Wood et al., ETRA 2016): ``look_vec`` = the gaze in Unity's left-handed camera
  axes (x right, y up, z forward), ``(gx, gy, -gz, 0)`` of ours; ``head_pose`` = the camera's
  Unity ``eulerAngles`` (degrees, [0, 360), ``R = Ry Rx Rz``) in the head's Unity world (ours
  with x mirrored); pipeline/render/formats/unityeyes.py. UnityEyes renders left eyes only: the
  export mirrors a right eye's image, and :func:`mirror_look_vec` / :func:`mirror_head_pose`
  give its mirrored values.

So every one of them has our pitch and **minus our yaw**, up to the normalisation's roll.
"""

from __future__ import annotations

import math

import numpy as np

#: OpenGL camera axes -> OpenCV camera axes (and our head frame -> ETH-XGaze's face model frame).
GL_TO_CV = np.diag([1.0, -1.0, -1.0])
#: Our head frame -> Unity's world (x mirrored: Unity's +X is the subject's right).
HEAD_TO_UNITY = np.diag([-1.0, 1.0, 1.0])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float).reshape(3)
    return v / np.linalg.norm(v)


def to_opencv(v_gl) -> np.ndarray:
    """(3,) a vector in OpenGL camera axes -> OpenCV camera axes: ``(x, -y, -z)``."""
    return GL_TO_CV @ np.asarray(v_gl, float).reshape(3)


def eth_gaze_pitchyaw(g_cv) -> np.ndarray:
    """(2,) radians: ETH-XGaze's ``(arcsin(-g[1]), arctan2(-g[0], -g[2]))`` of an OpenCV gaze."""
    g = _unit(g_cv)
    return np.array([math.asin(max(-1.0, min(1.0, -g[1]))), math.atan2(-g[0], -g[2])])


def eth_head_pitchyaw(hR_cv) -> np.ndarray:
    """(2,) radians: ETH-XGaze's head pose ``(asin(Zv[1]), atan2(Zv[0], Zv[2]))``, ``Zv = hR[:, 2]``."""
    z = _unit(np.asarray(hR_cv, float)[:, 2])
    return np.array([math.asin(max(-1.0, min(1.0, z[1]))), math.atan2(z[0], z[2])])


def head_rotation_opencv(R_head_to_gl) -> np.ndarray:
    """(3, 3) ETH-XGaze's ``hR`` (face model -> OpenCV camera) of our head -> OpenGL camera ``R``."""
    return GL_TO_CV @ np.asarray(R_head_to_gl, float)[:3, :3] @ GL_TO_CV


def rotation_vector(R) -> np.ndarray:
    """(3,) OpenCV's ``Rodrigues`` of a rotation matrix: axis times angle (radians, [0, pi])."""
    R = np.asarray(R, float)
    c = max(-1.0, min(1.0, 0.5 * (np.trace(R) - 1.0)))
    a = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if a < 1e-12:
        return 0.5 * w
    if math.pi - a < 1e-6:                    # sin(a) ~ 0: the axis from the symmetric part
        k = int(np.argmax(np.diag(R)))
        axis = (R[:, k] + np.eye(3)[k]) / math.sqrt(2.0 * (1.0 + R[k, k]))
        return a * axis / np.linalg.norm(axis)
    return a * w / (2.0 * math.sin(a))


def eth_normalization(hR_cv, forward_cv=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(3, 3) ETH-XGaze's ``R`` of ``normalizeData``: rows right, down, forward.

    ``forward_cv`` is the eye's direction from the camera (OpenCV axes); an orthographic camera
    sees every point along its own z, so the default.
    """
    f = _unit(forward_cv)
    down = _unit(np.cross(f, np.asarray(hR_cv, float)[:, 0]))
    right = _unit(np.cross(down, f))
    return np.stack([right, down, f])


def gazeml_pitchyaw(g_gl) -> np.ndarray:
    """(2,) radians: the gaze GazeML's UnityEyes loader gives for our camera-frame gaze ``g_gl``."""
    g = _unit(g_gl)
    return np.array([math.asin(max(-1.0, min(1.0, g[1]))), math.atan2(-g[0], g[2])])


def unityeyes_look_vec(g_gl) -> np.ndarray:
    """(4,) UnityEyes' ``look_vec``: our camera-frame gaze in Unity's camera axes, w = 0."""
    g = np.asarray(g_gl, float).reshape(3)
    return np.array([g[0], g[1], -g[2], 0.0])


def mirror_look_vec(look) -> np.ndarray:
    """``look_vec`` of the horizontally mirrored image: x negated."""
    out = np.array(look, float)
    out[0] = -out[0]
    return out


def _euler_zxy(Q) -> np.ndarray:
    """Unity's ``eulerAngles`` (x, y, z) of a rotation ``Q = Ry(y) Rx(x) Rz(z)``, degrees in [0, 360)."""
    x = math.degrees(math.asin(max(-1.0, min(1.0, -Q[1, 2]))))
    y = math.degrees(math.atan2(Q[0, 2], Q[2, 2]))
    z = math.degrees(math.atan2(Q[1, 0], Q[1, 1]))
    return np.array([round(a, 4) % 360.0 for a in (x, y, z)])


def unity_camera_rotation(world_to_camera) -> np.ndarray:
    """(3, 3) the camera's rotation in the head's Unity world: columns Unity right, up, forward."""
    R = np.asarray(world_to_camera, float)[:3, :3]          # rows: camera x, y, z (back) in the head
    return HEAD_TO_UNITY @ np.stack([R[0], R[1], -R[2]], axis=1)


def unityeyes_head_pose(world_to_camera, mirror: bool = False) -> np.ndarray:
    """(3,) UnityEyes' ``head_pose``: the camera's Unity ``eulerAngles``, degrees in [0, 360).

    ``mirror``: of the horizontally mirrored image, the camera seeing a mirrored head
    (``M Q M``, M = x mirror: the Euler angles ``(x, -y, -z)``).
    """
    Q = unity_camera_rotation(world_to_camera)
    if mirror:
        Q = HEAD_TO_UNITY @ Q @ HEAD_TO_UNITY
    return _euler_zxy(Q)


def conventions(world_to_camera, gaze_camera, mirror_unityeyes: bool = False, forward_cv=(0.0, 0.0, 1.0)) -> dict:
    """The label's ``conventions`` block: gaze and head pose of one image in each convention.

    Parameters
    ----------
    world_to_camera : (4, 4) or (3, 3)   head mm -> OpenGL camera (the label's camera)
    gaze_camera : (3,)                   the imaged eye's gaze, OpenGL camera axes
    mirror_unityeyes : bool              the UnityEyes export mirrors this image (a right eye)
    forward_cv : (3,)                    the eye's direction from the camera, OpenCV axes
    """
    R = np.asarray(world_to_camera, float)[:3, :3]
    g_cv = to_opencv(gaze_camera)
    hR = head_rotation_opencv(R)
    Rn = eth_normalization(hR, forward_cv)
    g_n, hR_n = Rn @ g_cv, Rn @ hR
    look = unityeyes_look_vec(gaze_camera)
    if mirror_unityeyes:
        look = mirror_look_vec(look)

    def fl(a):
        return [float(x) for x in np.asarray(a, float).ravel()]

    normalized = {"rotation": np.asarray(Rn).tolist(), "gaze_vector": fl(g_n),
                  "gaze_pitchyaw_rad": fl(eth_gaze_pitchyaw(g_n)),
                  "head_rotvec": fl(rotation_vector(hR_n)),
                  "head_pose_pitchyaw_rad": fl(eth_head_pitchyaw(hR_n))}
    return {
        "note": "pitch/yaw as each field computes them; all have our pitch and minus our yaw (ETH-XGaze: "
                "up to the normalisation's roll); formulas in pipeline/render/conventions.py and docs/labels.md",
        "eth_xgaze": {"axes": "OpenCV camera (x right, y down, z forward); face model x subject's left, y down, "
                              "z into the head",
                      "gaze_vector_opencv": fl(g_cv), "gaze_pitchyaw_rad": fl(eth_gaze_pitchyaw(g_cv)),
                      "head_rotation_opencv": hR.tolist(), "head_rotvec_opencv": fl(rotation_vector(hR)),
                      "head_pose_pitchyaw_rad": fl(eth_head_pitchyaw(hR)),
                      "normalized": normalized},
        "mpiigaze": {"gaze_pitchyaw_rad": normalized["gaze_pitchyaw_rad"],
                     "head_pose_pitchyaw_rad": normalized["head_pose_pitchyaw_rad"],
                     "note": "MPIIGaze's normalised (pitch, yaw): the same as eth_xgaze.normalized"},
        "gazeml": {"gaze_pitchyaw_rad": fl(gazeml_pitchyaw(gaze_camera)),
                   "note": "the gaze GazeML's UnityEyes loader gives for this image as rendered (the UnityEyes "
                           "export of a right eye is mirrored: there GazeML's yaw is minus this one)"},
        "unityeyes": {"look_vec": fl(look),
                      "head_pose_deg": fl(unityeyes_head_pose(R, mirror_unityeyes)),
                      "mirrored": bool(mirror_unityeyes),
                      "note": "as the unityeyes/ export writes them (a right eye mirrored into a left eye)"},
    }
