"""Pinhole cameras (issue 24, Cameras): intrinsics from the settings, the label's camera block,
re-projection of the landmarks, the webcam crop's K, refused settings, the refraction of pinhole
rays, and Blender's perspective camera against the labels.

The asset is the render tests' tiny fixture (fixtures.make_render_asset: a flat skin grid with the
eyeballs poking through it). Blender renders a few 64 x 48 images at 4 samples.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fixtures import make_render_asset
from pipeline.eyeball.geometry import EyeballParams
from pipeline.render import asset as ra
from pipeline.render import camera as cam
from pipeline.render import labels as lb
from pipeline.render import refraction as rf
from pipeline.render import sampling as sp
from pipeline.render.camera import Camera, quat_to_matrix
from pipeline.render.settings import PINHOLE_KEYS, PRESETS, RenderSettings
from pipeline.render.spec import RenderSpec

#: A frontal view with everything random pinned (sampling's override keys).
FRONT = {"polar_deg": 0.0, "azimuth_deg": 0.0, "jitter": np.zeros(2), "gaze_pitch_deg": 0.0, "gaze_yaw_deg": 0.0,
         "principal_shift_px": np.zeros(2), "crop_shift_px": np.zeros(2)}


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("pinhole"))
    return ra.load_render_asset(made["asset_dir"], made["rig_dir"])


def _settings(**kw) -> RenderSettings:
    return RenderSettings.from_params(kw)


def _labels(asset, s, n=6):
    for i in range(n):
        smp = sp.make_sample(asset, s, i, "/tmp/000000.png")
        yield smp, lb.make_label(smp, s, "tiny")


# ------------------------------------------------------------------------------- projection

def test_projection_known_answers():
    K = cam.intrinsics(500.0, 60.0, 40.0)
    np.testing.assert_array_equal(K, [[500, 0, 60], [0, 500, 40], [0, 0, 1]])
    # OpenGL camera frame: on the axis -> principal point; +x right, +y up (image v down)
    P = np.array([[0.0, 0.0, -100.0], [10.0, 0.0, -100.0], [0.0, 10.0, -200.0]])
    pinhole = Camera(np.eye(4).tolist(), K=K)
    uv = pinhole.project(P, 120, 80)
    np.testing.assert_allclose(uv, [[60, 40], [110, 40], [60, 15]], atol=1e-12)
    # the same through OpenCV's axes and a label-style camera description
    R, t = cam.opencv_extrinsics(np.eye(4))
    np.testing.assert_array_equal(R, np.diag([1.0, -1.0, -1.0]))
    Xc = P @ R.T + t
    np.testing.assert_allclose((Xc @ K.T)[:, :2] / Xc[:, 2:], uv, atol=1e-12)
    label_block = {"type": "pinhole", "world_to_camera": np.eye(4).tolist(), "intrinsics": {"K": K.tolist()}}
    np.testing.assert_allclose(Camera.from_dict(label_block).project(P, 120, 80), uv)
    np.testing.assert_allclose(pinhole.projection(120, 80), [[500, 0, -60, 0], [0, -500, -40, 0], [0, 0, -1, 0]])
    # OpenCV's pixel convention: centres at integers
    np.testing.assert_array_equal(cam.opencv_pixel_K(K)[:2, 2], [59.5, 39.5])
    # an orthographic camera goes to the orthographic projection, bit for bit
    Q = np.random.default_rng(0).normal(size=(5, 3)) * 10
    assert np.array_equal(Camera(np.eye(4).tolist(), 32.0).project(Q, 120, 80), cam.project(Q, 32.0, 120, 80))


def test_pixel_rays_project_back_to_their_pixels():
    px = np.array([[0.0, 0.0], [60.0, 40.0], [119.5, 3.25], [17.0, 79.0]])
    for c in (Camera(np.eye(4).tolist(), K=cam.intrinsics(90.0, 70.0, 30.0)), Camera(np.eye(4).tolist(), 32.0)):
        O, D = c.pixel_rays(px, 120, 80)
        np.testing.assert_allclose(np.linalg.norm(D, axis=1), 1.0)
        assert np.all(D[:, 2] < 0)                                            # forward = -z
        for t in (5.0, 250.0):
            np.testing.assert_allclose(c.project(O + t * D, 120, 80), px, atol=1e-9)


def test_crop_intrinsics_are_the_sensor_K_shifted():
    Ks = cam.intrinsics(1000.0, 640.0, 360.0)
    Kc = cam.crop_intrinsics(Ks, (600, 340))
    np.testing.assert_array_equal(Kc, [[1000, 0, 40], [0, 1000, 20], [0, 0, 1]])
    P = np.array([[3.0, -2.0, -500.0], [-20.0, 7.0, -650.0]])
    np.testing.assert_allclose(cam.project_pinhole(P, Kc) + [600, 340], cam.project_pinhole(P, Ks), atol=1e-9)


# ------------------------------------------------------------------------------- settings and labels

def test_K_comes_from_the_settings(asset):
    s = _settings(preset="near_eye")
    for smp, lab in _labels(asset, s):
        K = np.asarray(lab["camera"]["intrinsics"]["K"])
        assert K[0, 0] == K[1, 1] == 343.1 and K[0, 1] == 0 and list(K[2]) == [0, 0, 1]
        assert abs(K[0, 2] - 160) <= 8 and abs(K[1, 2] - 120) <= 8                # principal_jitter_px 8
        assert 33.5 <= lab["camera"]["spherical"]["distance_mm"] <= 73.5      # 20-60 mm before the cornea
        assert lab["camera"]["sensor"]["crop_offset_px"] == [0, 0]
        np.testing.assert_array_equal(lab["camera"]["sensor"]["K"], K)
        assert lab["camera"]["intrinsics"]["distortion"] == [0.0] * 5
        # the camera stands distance_mm from the eyeball centre along the spherical direction
        eye = asset.eyes[smp.side]
        d = np.linalg.norm(np.asarray(lab["camera"]["position_head_mm"]) - eye.center)
        assert d == pytest.approx(lab["camera"]["spherical"]["distance_mm"], abs=1e-9)
    fixed = _settings(camera="pinhole", focal_px=200.0, principal_point_px=[50.0, 30.0], camera_distance_mm=50.0)
    smp = sp.make_sample(asset, fixed, 0, "/tmp/000000.png")
    np.testing.assert_array_equal(smp.camera["K"], [[200, 0, 50], [0, 200, 30], [0, 0, 1]])
    np.testing.assert_array_equal(smp.spec.camera.K, smp.camera["K"])
    w = _settings(preset="webcam")
    for smp, lab in _labels(asset, w):
        f = lab["camera"]["intrinsics"]["focal_px"]
        assert 950 <= f <= 1150 and 400 <= lab["camera"]["spherical"]["distance_mm"] <= 700
        Ks = np.asarray(lab["camera"]["sensor"]["K"])
        assert abs(Ks[0, 2] - 640) <= 10 and abs(Ks[1, 2] - 360) <= 10
        assert 58 < lab["camera"]["sensor"]["fov_deg"][0] < 68.1                   # a laptop webcam's


@pytest.mark.parametrize("preset", ["near_eye", "webcam"])
def test_pinhole_landmarks_reproject_within_0_01_px(asset, preset):
    s = _settings(preset=preset)
    for smp, lab in _labels(asset, s):
        c = lab["camera"]
        px = np.asarray(lab["landmarks"]["px"])
        assert lb.check_label(lab) < 0.01
        # K and the camera-frame landmarks (OpenGL axes -> OpenCV's)
        C = np.asarray(lab["landmarks"]["camera_mm"]) @ cam.GL_TO_CV
        uv = (C @ np.asarray(c["intrinsics"]["K"]).T)
        assert np.abs(uv[:, :2] / uv[:, 2:] - px).max() < 0.01
        # OpenCV's R|t and K (cv2.projectPoints without distortion, transcribed) from head mm
        X = np.asarray(lab["landmarks"]["head_mm"]) @ np.asarray(c["opencv"]["R"]).T + c["opencv"]["t"]
        assert np.all(X[:, 2] > 0)                                              # in front: z forward
        Kc = np.asarray(c["intrinsics"]["K_pixel_centres_at_integers"])
        uv = X[:, :2] / X[:, 2:] * [Kc[0, 0], Kc[1, 1]] + Kc[:2, 2]
        assert np.abs(uv + 0.5 - px).max() < 0.01
        # the same through head_to_pixel
        Hp = np.c_[lab["landmarks"]["head_mm"], np.ones(28)] @ np.asarray(c["head_to_pixel"]).T
        assert np.abs(Hp[:, :2] / Hp[:, 2:] - px).max() < 0.01
        # the label's own camera block, read as a Camera, projects to the label's px
        assert np.abs(Camera.from_dict(c).project(lab["landmarks"]["camera_mm"], s.width, s.height) - px).max() < 1e-9
        # the OpenCV extrinsics are the OpenGL ones with y and z flipped
        W = np.asarray(c["world_to_camera"])
        np.testing.assert_allclose(np.asarray(c["opencv"]["world_to_camera"]), np.diag([1, -1, -1, 1]) @ W)


def test_webcam_crop_K_relation(asset):
    s = _settings(preset="webcam")
    for smp, lab in _labels(asset, s, 8):
        c = lab["camera"]
        K, Ks = np.asarray(c["intrinsics"]["K"]), np.asarray(c["sensor"]["K"])
        x0, y0 = c["sensor"]["crop_offset_px"]
        assert isinstance(x0, int) and isinstance(y0, int)
        assert 0 <= x0 <= 1280 - 80 and 0 <= y0 <= 720 - 48
        np.testing.assert_array_equal(K, cam.crop_intrinsics(Ks, (x0, y0)))
        # in the sensor image the landmarks lie at the crop's px + the offset
        full = cam.project_pinhole(lab["landmarks"]["camera_mm"], Ks)
        np.testing.assert_allclose(full, np.asarray(lab["landmarks"]["px"]) + [x0, y0], atol=1e-9)
        # the crop is centred on the eyeball centre up to crop_jitter_px (4) and rounding
        e = cam.project_pinhole(cam.to_camera(asset.eyes[smp.side].center[None], c["world_to_camera"]), K)[0]
        assert np.all(np.abs(e - [40, 24]) <= 4.5), e
        # the camera aims between the eyes: the eye is well off the sensor's principal point
        mid = 0.5 * (asset.eyes["left"].center + asset.eyes["right"].center)
        np.testing.assert_allclose(c["aim"]["point_head_mm"], mid, atol=1.5)       # centre_jitter_mm 1
        assert np.linalg.norm(e + [x0, y0] - Ks[:2, 2]) > 20


@pytest.mark.parametrize("preset", ["near_eye", "webcam"])
def test_eye_contact_looks_at_the_camera_centre(asset, preset):
    """Gaze offsets 0: the imaged eye looks at the pinhole camera's centre, off the optical axis
    or not (the webcam aims between the eyes: its eye-contact gaze is not (0, 0) in camera angles)."""
    s = _settings(preset=preset)
    for i in range(4):
        smp = sp.make_sample(asset, s, i, "/tmp/000000.png", {"gaze_offset_deg": [0.0, 0.0]})
        lab = lb.make_label(smp, s, "tiny")
        if lab["gaze"]["clipped"]:
            continue
        e = cam.to_camera(asset.eyes[smp.side].center[None], lab["camera"]["world_to_camera"])[0]
        np.testing.assert_allclose(lab["gaze"]["vector_camera"], -e / np.linalg.norm(e), atol=1e-9)
        off_axis = math.degrees(math.acos(-e[2] / np.linalg.norm(e)))
        assert abs(math.hypot(lab["gaze"]["camera"]["pitch_deg"], lab["gaze"]["camera"]["yaw_deg"])
                   - off_axis) < 0.05
        if preset == "webcam":
            assert off_axis > 2.0                                     # 31.5 mm off the axis at <= 700 mm
        assert "optical axis" in lab["frames"]


def test_spec_round_trips_and_checks_K(asset):
    smp = sp.make_sample(asset, _settings(preset="near_eye"), 2, "/tmp/000002.png")
    d = json.loads(smp.spec.to_json())
    assert d["camera"]["type"] == "pinhole" and "ortho_scale_mm" not in d["camera"]
    assert RenderSpec.from_json(smp.spec.to_json()) == smp.spec
    ortho = sp.make_sample(asset, _settings(), 2, "/tmp/000002.png")
    assert set(json.loads(ortho.spec.to_json())["camera"]) == {"world_to_camera", "ortho_scale_mm"}
    for change, message in ((lambda c: c["K"][1].__setitem__(1, 300.0), "camera.K must be [[f, 0, cx]"),
                            (lambda c: c["K"][0].__setitem__(0, -1.0), "camera.K focal length must be > 0"),
                            (lambda c: c.update(K=[[1, 2]]), "camera.K must be 3 x 3"),
                            (lambda c: c.update(ortho_scale_mm=30.0), "camera: a pinhole camera has no ortho_scale_mm"),
                            (lambda c: c.update(type="fisheye"), "camera.type 'fisheye' not in")):
        bad = json.loads(smp.spec.to_json())
        change(bad["camera"])
        with pytest.raises(ValueError) as e:
            RenderSpec.from_dict(bad)
        assert str(e.value).startswith(message) and "\n" not in str(e.value)


@pytest.mark.parametrize("params, message", [
    ({"camera": "pinhole", "focal_px": 0}, "render.focal_px must be > 0"),
    ({"camera": "pinhole", "focal_px": [-5, 300]}, "render.focal_px every value must be > 0"),
    ({"camera": "pinhole"}, "render.focal_px must be set with camera: pinhole"),
    ({"preset": "near_eye", "camera_distance_mm": [10.0, 60.0]}, "render.camera_distance_mm must be >= 15 mm"),
    ({"preset": "near_eye", "camera_distance_mm": [60.0, 30.0]}, "render.camera_distance_mm must be in increasing"),
    ({"preset": "near_eye", "principal_point_px": [330.0, 120.0]}, "render.principal_point_px [330, 120] +- "
                                                                   "principal_jitter_px 8 must lie inside"),
    ({"preset": "near_eye", "principal_point_px": [5.0, 120.0]}, "render.principal_point_px [5, 120]"),
    ({"preset": "webcam", "principal_jitter_px": 400.0}, "render.principal_point_px [640, 360] +- principal_jitter_px 400"),
    ({"preset": "webcam", "sensor_px": [50, 720]}, "render.sensor_px must be at least the image size"),
    ({"preset": "near_eye", "crop_jitter_px": 2.0}, "render.crop_jitter_px needs sensor_px"),
    ({"preset": "near_eye", "iris_distance_px": 70.0}, "render.iris_distance_px needs camera: ortho"),
    ({"preset": "near_eye", "label_formats": ["eyerig", "unityeyes"]}, "render.label_formats unityeyes needs camera"),
    ({"focal_px": 300.0}, "render.focal_px is a pinhole setting: it needs camera: pinhole"),
    ({"camera_distance_mm": [100.0, 200.0]}, "render.camera_distance_mm must be one value with camera: ortho"),
    ({"camera": "fisheye"}, "render.camera must be one of 'ortho', 'pinhole'"),
])
def test_bad_pinhole_settings_are_one_line(params, message):
    with pytest.raises(ValueError) as e:
        RenderSettings.from_params(params)
    assert str(e.value).startswith(f"params.yaml: {message}") and "\n" not in str(e.value), str(e.value)


def test_orthographic_settings_hash_as_before():
    """The pinhole keys stay out of an orthographic render's config hash (its folder is not stale)."""
    s = _settings()
    assert not set(PINHOLE_KEYS) & set(s.hashed())
    assert s.hashed()["camera_distance_mm"] == 200.0
    p = _settings(preset="near_eye")
    assert set(PINHOLE_KEYS) <= set(p.hashed()) and p.hashed()["camera_distance_mm"] == [33.5, 73.5]
    for name in ("near_eye", "webcam"):
        assert PRESETS[name]["camera"] == "pinhole"


# ------------------------------------------------------------------------------- refraction

def _iris_case(asset, s, overrides, index=0):
    smp = sp.make_sample(asset, s, index, "/tmp/000000.png", overrides)
    eye = asset.eyes[smp.side]
    A = eye.model_to_head(quat_to_matrix(smp.spec.eye_rotation[smp.side]))
    return smp, A, EyeballParams.from_dict(eye.eyeball_params), eye.cornea_ior


def test_pinhole_rays_through_the_cornea(asset):
    s = _settings(preset="near_eye")
    smp, A, params, ior = _iris_case(asset, s, {"gaze_pitch_deg": 6.0, "gaze_yaw_deg": -9.0, "distance_mm": 30.0},
                                     index=1)
    W, K = smp.camera["world_to_camera"], smp.camera["K"]
    pts = smp.landmarks_head[12:28]
    # no refraction (n = 1): the ray from the camera centre through the point itself
    straight = rf.apparent_points_camera(pts, W, A, params, ior=1.0, pinhole=True)
    np.testing.assert_allclose(cam.project_pinhole(straight, K), smp.landmarks_px[12:28], atol=1e-4)
    # the cornea magnifies the pupil seen from 30 mm: the apparent ring is larger than the straight
    # one. (Part of the iris rim is hidden behind the limbus this close, at this angle: null, as
    # documented, not a guess; a brute-force scan of the rays leaves >= 0.2 mm between them and it)
    app = cam.project_pinhole(rf.apparent_points_camera(pts, W, A, params, ior=ior, pinhole=True), K)
    assert np.all(np.isfinite(app[8:])) and np.isfinite(app[:8, 0]).sum() >= 4

    def radius(q):
        return float(np.mean(np.linalg.norm(q - q.mean(0), axis=1)))

    assert 1.05 < radius(app[8:]) / radius(smp.landmarks_px[20:28]) < 1.6
    # a far pinhole camera sees what the orthographic camera sees: 100 m away, the same image width
    far = _settings(camera="pinhole", focal_px=120.0 * 1e5 / 33.0, camera_distance_mm=1e5, center_jitter_mm=0.0)
    ortho = _settings(ortho_scale_mm=[33.0, 33.0], camera_distance_mm=1e5, center_jitter_mm=0.0, frame_margin_px=None)
    o = {"polar_deg": 12.0, "azimuth_deg": 40.0, "gaze_pitch_deg": 6.0, "gaze_yaw_deg": -9.0,
         "principal_shift_px": np.zeros(2)}
    pf, Af, params, ior = _iris_case(asset, far, o)
    po, Ao, _, _ = _iris_case(asset, ortho, o)
    np.testing.assert_allclose(pf.camera["world_to_camera"], po.camera["world_to_camera"], atol=1e-9)
    a_far = cam.project_pinhole(rf.apparent_points_camera(pf.landmarks_head[12:28], pf.camera["world_to_camera"],
                                                          Af, params, ior, pinhole=True), pf.camera["K"])
    a_ortho = cam.project(rf.apparent_points_camera(po.landmarks_head[12:28], po.camera["world_to_camera"],
                                                    Ao, params, ior), 33.0, 120, 80)
    assert np.abs(a_far - a_ortho).max() < 0.01


def test_apparent_job_of_a_pinhole_label(asset):
    from pipeline.render.shard import apparent_landmarks

    s = _settings(preset="webcam")
    smp = sp.make_sample(asset, s, 0, "/tmp/000000.png")
    job = lb.apparent_job(smp, asset.eyes[smp.side], s)
    assert job["type"] == "pinhole" and "ortho_scale_mm" not in job
    px = apparent_landmarks(job)["apparent_px"]
    assert sum(q is not None for q in px) >= 12
    got = np.array([q for q in px if q is not None])
    assert np.all((got > -5) & (got < [85, 53]))                   # about the eye in the 80 x 48 crop


# ------------------------------------------------------------------------------- Blender

def test_blender_lens_values():
    from pipeline.blender.render_worker import PINHOLE_SENSOR_MM, pinhole_lens

    centred = pinhole_lens(cam.intrinsics(300.0, 60.0, 40.0), 120, 80)
    assert centred == {"lens": 300.0 * PINHOLE_SENSOR_MM / 120, "shift_x": 0.0, "shift_y": 0.0}
    # shifts in units of the image width (sensor fit HORIZONTAL), x toward the view's right, y up
    off = pinhole_lens(cam.intrinsics(300.0, 0.0, 0.0), 120, 80)
    assert (off["shift_x"], off["shift_y"]) == (0.5, -40.0 / 120)
    with pytest.raises(ValueError, match="too short for a 120 px wide image"):
        pinhole_lens(cam.intrinsics(2.0, 60.0, 40.0), 120, 80)


@pytest.fixture(scope="module")
def rendered(asset, tmp_path_factory):
    """A few 64 x 48 pinhole renders of the tiny asset with their masks (one Blender worker)."""
    from pipeline.io.seg_file import read_depth, read_seg
    from pipeline.render import shard as sh

    out = tmp_path_factory.mktemp("pinhole_renders")
    bp = sh.BlenderProcess(asset.usda, asset.rig_npz, threads=2)
    done = {}

    def render(name, s, overrides):
        smp = sp.make_sample(asset, s, 0, out / f"{name}.png", overrides, reject=False)
        spec = dict(smp.spec.to_dict(), seg_png=str(out / f"{name}_seg.png"),
                    depth_exr=str(out / f"{name}_depth.exr"), lashes=False)
        rep = bp.render(spec, timeout_s=300)
        assert rep["ok"], rep
        app = sh.apparent_landmarks(lb.apparent_job(smp, asset.eyes[smp.side], s))["apparent_px"]
        done[name] = {"smp": smp, "reply": rep, "s": s, "apparent": app, "files": spec,
                      "label": lb.make_label(smp, s, "tiny", rep),
                      "seg": read_seg(spec["seg_png"], (s.width, s.height)),
                      "depth": read_depth(spec["depth_exr"], (s.width, s.height))}

    # an orthographic image first, and again after the pinhole ones: the camera goes back
    ortho = _settings(samples=4, denoise=False, width=64, height=48)
    render("ortho_first", ortho, {**FRONT, "ortho_scale_mm": 30.0})
    base = {"samples": 4, "denoise": False, "camera": "pinhole"}
    # near: off-axis eye (aim shifted 3 mm), the principal point far off the centre, gaze away
    render("near", _settings(**base, width=64, height=48, focal_px=64.0, camera_distance_mm=40.0,
                             principal_point_px=[20.0, 30.0]),
           {**FRONT, "polar_deg": 15.0, "azimuth_deg": 60.0, "jitter": np.array([3.0, -2.0]),
            "gaze_pitch_deg": 8.0, "gaze_yaw_deg": -10.0})
    # a webcam-like crop of a 768 x 576 sensor, aimed between the eyes
    render("crop", _settings(**base, width=64, height=48, focal_px=640.0, camera_distance_mm=400.0,
                             sensor_px=[768, 576], camera_aim="between_eyes"), FRONT)
    # the same camera, its whole 128 x 96 sensor, and a 64 x 48 crop of that sensor
    sensor = dict(base, focal_px=96.0, camera_distance_mm=40.0, principal_point_px=[64.0, 48.0])
    render("sensor", _settings(**sensor, width=128, height=96), FRONT)
    render("sensor_crop", _settings(**sensor, width=64, height=48, sensor_px=[128, 96]),
           {**FRONT, "crop_shift_px": np.array([9.0, -5.0])})
    render("ortho_again", ortho, {**FRONT, "ortho_scale_mm": 30.0})
    yield done
    bp.close()


@pytest.mark.blender
@pytest.mark.slow
def test_blender_landmark_check_holds_for_pinhole(rendered):
    for name, r in rendered.items():
        assert r["reply"]["landmark_check_mm"] < r["s"].landmark_tolerance_mm, name
        # the landmarks Blender measured in its posed scene, projected with the label's camera
        M = np.c_[r["reply"]["landmarks_measured_head_mm"], np.ones(28)] @ np.asarray(
            r["label"]["camera"]["head_to_pixel"]).T
        assert np.abs(M[:, :2] / M[:, 2:] - r["label"]["landmarks"]["px"]).max() < 0.01, name


@pytest.mark.blender
@pytest.mark.slow
def test_blender_pinhole_image_agrees_with_the_label_projection(asset, rendered):
    from pipeline.io.seg_file import PUPIL
    from pipeline.render import visibility as vis

    for name in ("near", "crop", "sensor"):
        r = rendered[name]
        pupil = r["seg"] == PUPIL
        app = np.array([q for q in r["apparent"][8:] if q is not None])
        assert len(app) == 8 and pupil.sum() >= 20, (name, pupil.sum())
        # the pupil landmarks seen through the cornea lie on the rendered pupil's boundary
        d = [vis.boundary_distance_px(q, pupil) for q in app]
        assert max(d) <= 1.0, (name, d)
        ys, xs = np.nonzero(pupil)
        assert np.linalg.norm([xs.mean() + 0.5 - app[:, 0].mean(), ys.mean() + 0.5 - app[:, 1].mean()]) < 1.0, name
        # depth is measured from the pinhole camera itself (no orthographic pull-back): at the
        # corneal apex's pixel, the apex's own depth
        smp = r["smp"]
        e = asset.eyes[smp.side]
        A = e.model_to_head(quat_to_matrix(smp.spec.eye_rotation[smp.side]))
        apex = (A @ [0.0, 0.0, EyeballParams.from_dict(e.eyeball_params).apex, 1.0])[:3]
        ac = cam.to_camera(apex[None], smp.camera["world_to_camera"])
        u, v = cam.project_pinhole(ac, smp.camera["K"])[0]
        assert 0 <= u < r["s"].width and 0 <= v < r["s"].height, name
        assert abs(r["depth"][int(v), int(u)] + ac[0, 2]) < 0.3, (name, r["depth"][int(v), int(u)], -ac[0, 2])


@pytest.mark.blender
@pytest.mark.slow
def test_blender_crop_is_the_sensor_image_window(rendered):
    """A crop with K = K_sensor shifted by the offset renders the sensor image's window."""
    big, crop = rendered["sensor"], rendered["sensor_crop"]
    x0, y0 = crop["label"]["camera"]["sensor"]["crop_offset_px"]
    assert (x0, y0) != (32, 24)                                   # the crop jitter moved it off the centre
    window = big["seg"][y0:y0 + 48, x0:x0 + 64]
    same = float(np.mean(window == crop["seg"]))
    assert same > 0.97, same
    np.testing.assert_allclose(np.asarray(crop["label"]["landmarks"]["px"]) + [x0, y0],
                               big["label"]["landmarks"]["px"], atol=1e-9)


@pytest.mark.blender
@pytest.mark.slow
def test_blender_orthographic_after_pinhole_is_unchanged(rendered):
    """The worker's camera goes back to orthographic: the same spec gives the same bytes."""
    from pathlib import Path

    a, b = rendered["ortho_first"]["files"], rendered["ortho_again"]["files"]
    for k in ("png", "seg_png", "depth_exr"):
        assert Path(a[k]).read_bytes() == Path(b[k]).read_bytes(), k


@pytest.mark.parametrize("preset", ["near_eye", "webcam"])
def test_eth_normalisation_of_a_pinhole_label_looks_at_the_eye(asset, preset):
    """ETH-XGaze's normalised camera looks at the eye centre (the eye corners' midpoint): the
    forward row of its rotation is the unit ray to that point in OpenCV axes."""
    s = _settings(preset=preset)
    for smp, lab in _labels(asset, s, n=4):
        L = np.asarray(lab["landmarks"]["camera_mm"], float)
        mid = 0.5 * (L[0] + L[6])
        ray = np.array([mid[0], -mid[1], -mid[2]]) / np.linalg.norm(mid)
        Rn = np.asarray(lab["conventions"]["eth_xgaze"]["normalized"]["rotation"], float)
        assert np.allclose(Rn[2], ray, atol=1e-9)
        assert np.allclose(Rn @ Rn.T, np.eye(3), atol=1e-9)
