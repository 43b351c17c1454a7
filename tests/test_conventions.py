"""The label's ``conventions`` block (pipeline/render/conventions.py) against transcriptions of each
convention's own code, on known vectors and on labels of the tiny constructed asset.

Transcribed here, written anew from the reading:

* ETH-XGaze, ``xucong-zhang/ETH-XGaze`` ``normalization_example.py``: the gaze's
  ``gaze_theta = np.arcsin((-1) * gaze_norm[1])``, ``gaze_phi = np.arctan2((-1) * gaze_norm[0],
  (-1) * gaze_norm[2])``; the head's ``M = cv2.Rodrigues(head)[0]; Zv = M[:, 2];
  head_2d = [asin(Zv[1]), atan2(Zv[0], Zv[2])]``; ``normalizeData``'s ``hRx = hR[:, 0]``,
  ``down = cross(forward, hRx)``, ``right = cross(down, forward)``, ``R = c_[right, down, forward].T``.
* OpenCV's ``Rodrigues`` (rotation vector -> matrix; OpenCV documentation, calib3d:
  ``R = cos t I + (1 - cos t) r r^T + sin t [r]x``, ``t = |v|``, ``r = v / t``).
* MPIIGaze, ``hysts/pytorch_mpiigaze`` ``tools/preprocess_mpiigaze.py``: ``convert_gaze``
  (``pitch = arcsin(-y)``, ``yaw = arctan2(-x, -z)``), ``convert_pose``
  (``vec = Rodrigues(v)[0][:, 2]``, ``(arcsin(vec[1]), arctan2(vec[0], vec[2]))``).
* GazeML: tests/fixtures/gazeml_unityeyes.py (``swook/GazeML`` ``src/datasources/unityeyes.py`` and
  ``src/util/gaze.py``).
* UnityEyes: ``Quaternion.Euler(x, y, z)`` = ``Ry(y) Rx(x) Rz(z)`` (Unity's documented order:
  z, then x, then y), ``look_vec = Camera.main.transform.worldToLocalMatrix * GetEyeLookVector()``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fixtures import gazeml_unityeyes as gz
from fixtures import make_render_asset
from fixtures.eth_xgaze import eth_normalization_R
from pipeline.render import asset as ra
from pipeline.render import camera as cam
from pipeline.render import conventions as cv
from pipeline.render import labels as lb
from pipeline.render import sampling as sp
from pipeline.render.formats import unityeyes as uef
from pipeline.render.settings import RenderSettings


# ------------------------------------------------------------------------------ transcriptions

def eth_gaze(gaze_norm):
    """ETH-XGaze normalization_example.py: ``gaze_norm_2d``."""
    gaze_theta = np.arcsin((-1) * gaze_norm[1])
    gaze_phi = np.arctan2((-1) * gaze_norm[0], (-1) * gaze_norm[2])
    return np.asarray([gaze_theta, gaze_phi])


def rodrigues(v):
    """OpenCV ``Rodrigues`` of a rotation vector."""
    v = np.asarray(v, float).ravel()
    t = np.linalg.norm(v)
    if t < 1e-15:
        return np.eye(3)
    r = v / t
    K = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return math.cos(t) * np.eye(3) + (1 - math.cos(t)) * np.outer(r, r) + math.sin(t) * K


def eth_head(head):
    """ETH-XGaze normalization_example.py: ``head_2d`` of a rotation vector."""
    M = rodrigues(np.asarray(head).reshape(1, 3))
    Zv = M[:, 2]
    return np.array([math.asin(Zv[1]), math.atan2(Zv[0], Zv[2])])


def mpii_convert_gaze(vector):
    x, y, z = vector
    return np.array([np.arcsin(-y), np.arctan2(-x, -z)])


def mpii_convert_pose(vector):
    vec = rodrigues(vector)[:, 2]
    return np.array([np.arcsin(vec[1]), np.arctan2(vec[0], vec[2])])


def unity_euler(x, y, z):
    """Unity ``Quaternion.Euler(x, y, z)`` as a matrix: ``Ry(y) Rx(x) Rz(z)`` (degrees)."""
    a, b, c = map(math.radians, (x, y, z))
    Rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    Ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    Rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def ours(p_deg, y_deg):
    """Our camera-frame (OpenGL) gaze of pitch / yaw (labels.py: asin(y), atan2(x, z))."""
    p, y = math.radians(p_deg), math.radians(y_deg)
    return np.array([math.cos(p) * math.sin(y), math.sin(p), math.cos(p) * math.cos(y)])


# ------------------------------------------------------------------------------ known vectors

# into the camera, image right, up, and the anatomical limits (25 deg pitch, 35 deg yaw in the eye
# frame) plus the generic preset's 20 deg camera cap
KNOWN = [(0, 0), (0, 30), (30, 0), (-20, -10), (25, 35), (-25, -35), (25, -35), (-45, 55), (45, -55)]


@pytest.mark.parametrize("p, y", KNOWN)
def test_gaze_pitch_agrees_and_yaw_is_negated_in_every_convention(p, y):
    g = ours(p, y)
    want = np.radians([p, -y])
    g_cv = cv.to_opencv(g)
    np.testing.assert_allclose(eth_gaze(g_cv), want, atol=1e-12)
    np.testing.assert_allclose(cv.eth_gaze_pitchyaw(g_cv), eth_gaze(g_cv), atol=1e-12)
    np.testing.assert_allclose(mpii_convert_gaze(g_cv), want, atol=1e-12)
    np.testing.assert_allclose(cv.gazeml_pitchyaw(g), gz.look_vec_gaze(cv.unityeyes_look_vec(g)), atol=1e-12)
    np.testing.assert_allclose(cv.gazeml_pitchyaw(g), want, atol=1e-12)
    # GazeML's own vector of its angles is ours with x toward the image left
    np.testing.assert_allclose(gz.pitch_yaw_vector(want), g * [-1, 1, 1], atol=1e-12)


def test_known_directions():
    np.testing.assert_allclose(cv.eth_gaze_pitchyaw(cv.to_opencv([0, 0, 1])), [0, 0], atol=1e-15)   # into the camera
    np.testing.assert_allclose(cv.unityeyes_look_vec([0, 0, 1]), [0, 0, -1, 0])
    right = cv.eth_gaze_pitchyaw(cv.to_opencv(ours(0, 20)))
    up = cv.eth_gaze_pitchyaw(cv.to_opencv(ours(20, 0)))
    assert right[1] < 0 and abs(right[0]) < 1e-12       # image right: negative ETH-XGaze yaw
    assert up[0] > 0 and abs(up[1]) < 1e-12             # up: positive pitch


def _head_to_camera(position):
    """Our world_to_camera of a camera at ``position`` (head mm) looking at the head origin."""
    return cam.look_at(np.asarray(position, float), [0, 0, 0], [0, 1, 0])


@pytest.mark.parametrize("pos, want_deg", [
    ((0, 0, 600), (0, 0)),                                              # frontal
    ((600 * math.sin(math.radians(30)), 0, 600 * math.cos(math.radians(30))), (0, 30)),   # on the subject's left
    ((0, 600 * math.sin(math.radians(20)), 600 * math.cos(math.radians(20))), (-20, 0)),  # above: face turns down
])
def test_head_pose_against_eth_xgaze_and_mpiigaze(pos, want_deg):
    W2C = _head_to_camera(pos)
    hR = cv.head_rotation_opencv(W2C)
    assert np.linalg.det(hR) == pytest.approx(1.0)
    rv = cv.rotation_vector(hR)
    np.testing.assert_allclose(rodrigues(rv), hR, atol=1e-12)          # OpenCV's Rodrigues inverts it
    np.testing.assert_allclose(eth_head(rv), np.radians(want_deg), atol=1e-12)
    np.testing.assert_allclose(mpii_convert_pose(rv), np.radians(want_deg), atol=1e-12)
    np.testing.assert_allclose(cv.eth_head_pitchyaw(hR), eth_head(rv), atol=1e-12)
    # ETH-XGaze's face model points map into the camera: a point in front of our face (+Z) lies
    # at face-model -z, nearer the camera (smaller OpenCV z) than the head origin
    Fc = hR @ np.array([0, 0, -50.0]) + [0, 0, 600.0]
    assert Fc[2] < 600.0


def test_rotation_vector_round_trips_near_zero_and_pi():
    rng = np.random.default_rng(3)
    for v in list(rng.normal(size=(20, 3))) + [np.array([0.0, 0.0, 1e-14]), np.array([math.pi, 0, 0]),
                                                np.array([0.0, -math.pi + 1e-9, 0.0])]:
        R = rodrigues(v)
        np.testing.assert_allclose(rodrigues(cv.rotation_vector(R)), R, atol=1e-8)


def test_normalization_is_eth_xgazes_and_only_a_roll_for_an_orthographic_camera():
    W2C = cam.look_at(np.array([40.0, 30.0, 500.0]), [0, 0, 0], [0.2, 1, 0])   # rolled camera
    hR = cv.head_rotation_opencv(W2C)
    Rn = cv.eth_normalization(hR)
    np.testing.assert_allclose(Rn, eth_normalization_R(hR, np.array([0.0, 0.0, 600.0])), atol=1e-12)
    np.testing.assert_allclose(Rn[2], [0, 0, 1], atol=1e-12)            # about the view axis only
    hRn = Rn @ hR
    assert abs(hRn[1, 0]) < 1e-12                                        # the head's x axis: no roll left


def test_unityeyes_head_pose_is_unitys_euler_and_mirrors():
    rng = np.random.default_rng(0)
    for _ in range(20):
        pos = rng.normal(size=3) * [100, 100, 30] + [0, 0, 400]
        W2C = cam.look_at(pos, rng.normal(size=3), [0, 1, 0])
        e = cv.unityeyes_head_pose(W2C)
        np.testing.assert_allclose(unity_euler(*e), cv.unity_camera_rotation(W2C), atol=1e-5)
        # the mirror image is a camera seeing the x-mirrored head, its image x flipped
        M = np.diag([-1.0, 1.0, 1.0])
        W2Cm = np.eye(4)
        W2Cm[:3, :3] = M @ np.asarray(W2C)[:3, :3] @ M
        np.testing.assert_allclose(cv.unityeyes_head_pose(W2C, mirror=True), cv.unityeyes_head_pose(W2Cm),
                                   atol=1e-9)
        g = rng.normal(size=3)
        np.testing.assert_allclose(cv.mirror_look_vec(cv.unityeyes_look_vec(g)), cv.unityeyes_look_vec(M @ g))


# ------------------------------------------------------------------------------ labels

@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("conventions"))
    return ra.load_render_asset(made["asset_dir"], made["rig_dir"])


@pytest.mark.parametrize("preset", ["generic", "unityeyes"])
def test_labels_carry_the_conventions(tiny, preset):
    s = RenderSettings.from_params({"preset": preset, "eyes": ["left", "right"]})
    sides = set()
    for i in range(10):
        smp = sp.make_sample(tiny, s, i, "/x.png")
        label = json.loads(json.dumps(lb.make_label(smp, s, "tiny")))
        c = label["conventions"]
        side = label["gaze"]["eye"]
        sides.add(side)
        g = np.asarray(label["gaze"]["vector_camera"])
        p, y = label["gaze"]["camera"]["pitch_deg"], label["gaze"]["camera"]["yaw_deg"]
        want = np.radians([p, -y])
        np.testing.assert_allclose(c["eth_xgaze"]["gaze_pitchyaw_rad"], want, atol=1e-12)
        np.testing.assert_allclose(c["eth_xgaze"]["gaze_pitchyaw_rad"], eth_gaze(c["eth_xgaze"]["gaze_vector_opencv"]),
                                   atol=1e-12)
        np.testing.assert_allclose(c["gazeml"]["gaze_pitchyaw_rad"], want, atol=1e-12)
        rv = c["eth_xgaze"]["head_rotvec_opencv"]
        np.testing.assert_allclose(c["eth_xgaze"]["head_pose_pitchyaw_rad"], eth_head(rv), atol=1e-12)
        R = np.asarray(label["head_pose"]["rotation_head_to_camera"])
        np.testing.assert_allclose(rodrigues(rv), np.diag([1, -1, -1]) @ R @ np.diag([1, -1, -1]), atol=1e-9)
        n = c["eth_xgaze"]["normalized"]
        np.testing.assert_allclose(c["mpiigaze"]["gaze_pitchyaw_rad"], mpii_convert_gaze(n["gaze_vector"]), atol=1e-12)
        np.testing.assert_allclose(c["mpiigaze"]["head_pose_pitchyaw_rad"], mpii_convert_pose(n["head_rotvec"]),
                                   atol=1e-12)
        # the UnityEyes values are those of the export (a right eye mirrored), as GazeML reads them
        doc = uef.unityeyes_document(label, uef.points_job(tiny, smp))
        assert c["unityeyes"]["mirrored"] == (side == "right")
        np.testing.assert_allclose(gz.look_vec_gaze(c["unityeyes"]["look_vec"]),
                                   want * ([1, -1] if side == "right" else [1, 1]), atol=1e-12)
        look = [float(t) for t in doc["eye_details"]["look_vec"].strip("()").split(", ")]
        np.testing.assert_allclose(look, c["unityeyes"]["look_vec"], atol=6e-5)
        pose = [float(t) for t in doc["head_pose"].strip("()").split(", ")]
        np.testing.assert_allclose(pose, c["unityeyes"]["head_pose_deg"], atol=6e-5)
        np.testing.assert_allclose(np.linalg.norm(g), 1.0)
    assert sides == {"left", "right"}
