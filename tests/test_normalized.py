"""The normalised export (label format ``normalized``, pipeline/render/normalize.py) against
ETH-XGaze's own normalisation: its ``normalizeData`` lines transcribed here (W = K_norm S R K^-1,
``cv2.perspectiveTransform`` of the landmarks), known answers (a gaze at the virtual camera is
(0, 0) and puts the pupil at the crop's principal point), the warped landmarks against the
virtual camera's view of the 3D landmarks, and the files it writes.

Labels of the small constructed asset (fixtures.make_render_asset), sampled without Blender.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from fixtures import make_render_asset
from fixtures.eth_xgaze import eth_normalization_R
from pipeline.io.seg_file import palette
from pipeline.render import asset as ra
from pipeline.render import formats as lf
from pipeline.render import labels as lb
from pipeline.render import normalize as nz
from pipeline.render import sampling as sp
from pipeline.render.formats import normalized as nf
from pipeline.render.settings import RenderSettings


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("normalized"))
    return ra.load_render_asset(made["asset_dir"], made["rig_dir"])


def _label(tiny, s, i, overrides=None):
    smp = sp.make_sample(tiny, s, i, "/x.png", overrides, cover=False)
    return json.loads(json.dumps(lb.make_label(smp, s, "tiny")))              # as stored on disk


def _eth_xgaze_W(label, e_cv, focal_norm, distance_norm, roi):
    """ETH-XGaze's normalizeData (xucong-zhang/data-preprocessing-gaze), its lines in numpy."""
    hR = np.asarray(label["conventions"]["eth_xgaze"]["head_rotation_opencv"])
    cam = np.asarray(label["camera"]["intrinsics"]["K_pixel_centres_at_integers"])
    distance = np.linalg.norm(e_cv)
    z_scale = distance_norm / distance
    cam_norm = np.array([[focal_norm, 0, roi[0] / 2], [0, focal_norm, roi[1] / 2], [0, 0, 1.0]])
    S = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, z_scale]])
    R = eth_normalization_R(hR, e_cv)
    return np.dot(np.dot(cam_norm, S), np.dot(R, np.linalg.inv(cam))), R


def _perspective_transform(px, W):
    P = np.c_[px, np.ones(len(px))] @ W.T
    return P[:, :2] / P[:, 2:]


SETTINGS = [({"preset": "generic"}, "eth_xgaze"), ({"preset": "targeted"}, "mpiigaze"),
            ({"preset": "webcam"}, "eth_xgaze"), ({"preset": "near_eye"}, "mpiigaze")]


@pytest.mark.parametrize("params, profile", SETTINGS, ids=[p["preset"] for p, _ in SETTINGS])
def test_warped_landmarks_are_the_virtual_cameras_view(tiny, params, profile):
    s = RenderSettings.from_params(params)
    prof = nz.PROFILES[profile]
    for i in range(6):
        label = _label(tiny, s, i)
        for center in ("eyeball", "canthi"):
            n = nz.normalization(label, prof["size_px"], prof["focal_px"], prof["distance_mm"], center)
            doc = nz.normalized_label(label, n)
            want = nz.project_normalized(label["landmarks"]["camera_mm"], n)
            assert np.abs(np.asarray(doc["landmarks"]["px"]) - want).max() < 0.01
            # the eye centre is at the principal point, and R is a rotation
            c = nz.project_normalized(n["center_camera_mm"][None], n)[0]
            np.testing.assert_allclose(c, np.asarray(prof["size_px"]) / 2 + 0.5, atol=1e-9)
            np.testing.assert_allclose(n["R"] @ n["R"].T, np.eye(3), atol=1e-12)
            if label["camera"]["type"] == "pinhole":             # ETH-XGaze's own lines give the same W
                W, R = _eth_xgaze_W(label, n["center_opencv_mm"], prof["focal_px"], prof["distance_mm"],
                                    prof["size_px"])
                np.testing.assert_allclose(n["warp_opencv"], W, rtol=1e-12, atol=1e-9)
                np.testing.assert_allclose(n["R"], R, atol=1e-12)
                cv_px = np.asarray(label["landmarks"]["px"]) - 0.5
                np.testing.assert_allclose(np.asarray(doc["landmarks"]["px"]) - 0.5,
                                           _perspective_transform(cv_px, W), atol=1e-9)
            else:                                                 # a roll about the axis, no scale in z
                np.testing.assert_allclose(n["R"][2], [0.0, 0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("params", [{"preset": "generic"}, {"preset": "webcam"}], ids=["ortho", "pinhole"])
def test_a_gaze_at_the_virtual_camera_is_zero_and_centres_the_pupil(tiny, params):
    s = RenderSettings.from_params(params)
    label = _label(tiny, s, 1)
    n = nz.normalization(label)
    e = np.asarray(n["center_camera_mm"])
    to_cam = np.array([0.0, 0.0, 1.0]) if n["orthographic"] else -e / np.linalg.norm(e)
    label["gaze"]["vector_camera"] = to_cam.tolist()
    doc = nz.normalized_label(label, n)
    np.testing.assert_allclose(doc["gaze"]["pitchyaw_rad"], [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(doc["gaze"]["vector_opencv"], [0.0, 0.0, -1.0], atol=1e-12)
    # a point on that gaze ray (the pupil of such a gaze) lands on the crop's principal point
    p = e + 12.0 * to_cam
    np.testing.assert_allclose(nz.project_normalized(p[None], n)[0], [64.5, 64.5], atol=1e-9)


def test_a_sampled_eye_contact_gaze_reads_zero_in_the_crop(tiny):
    """Eye contact with the orthographic camera (offsets 0, frontal): the normalised gaze is (0, 0)
    and the pupil landmarks ring the crop's centre."""
    s = RenderSettings.from_params({"preset": "generic"})
    label = _label(tiny, s, 0, {"polar_deg": 0.0, "gaze_offset_deg": [0.0, 0.0], "jitter": np.zeros(2)})
    doc = nz.normalized_label(label, nz.normalization(label))
    np.testing.assert_allclose(doc["gaze"]["pitchyaw_rad"], [0.0, 0.0], atol=1e-9)
    pupil = np.asarray(doc["landmarks"]["px"])[20:28].mean(0)
    assert np.abs(pupil - 64.5).max() < 0.05


def test_warp_image_is_opencvs_warp():
    """Identity and a whole-pixel shift give the source's pixels; a half-pixel shift the mean of two."""
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (20, 30, 3), dtype=np.uint8)
    np.testing.assert_array_equal(nz.warp_image(img, np.eye(3), (30, 20)), img)
    T = np.array([[1.0, 0, -2], [0, 1, -3], [0, 0, 1]])
    out = nz.warp_image(img, T, (30, 20))
    np.testing.assert_array_equal(out[:17, :28], img[3:, 2:])
    assert (out[17:] == 0).all()
    half = nz.warp_image(img.astype(float), np.array([[1.0, 0, -0.5], [0, 1, 0], [0, 0, 1]]), (29, 20))
    np.testing.assert_allclose(half[:, :29], np.floor((img[:, :29].astype(float) + img[:, 1:]) / 2 + 0.5), atol=0)
    ids = rng.integers(0, 7, (20, 30)).astype(np.uint8)
    near = nz.warp_image(ids, T, (30, 20), nearest=True, fill=nz.OUTSIDE)
    np.testing.assert_array_equal(near[:17, :28], ids[3:, 2:])
    assert (near[17:] == nz.OUTSIDE).all()


def test_the_format_writes_crop_mask_and_label(tiny, tmp_path):
    s = RenderSettings.from_params({"preset": "generic", "label_formats": ["eyerig", "normalized"],
                                    "normalized_size_px": [60, 36], "normalized_focal_px": 960.0})
    assert s.hashed()["normalized_size_px"] == [60, 36]
    assert "normalized_size_px" not in RenderSettings.from_params({"preset": "generic"}).hashed()
    smp = sp.make_sample(tiny, s, 2, "/x.png", cover=False)
    label = json.loads(json.dumps(lb.make_label(smp, s, "tiny")))
    job = lf.format_job(tiny, smp, s.label_formats, s)
    assert job["normalized"] == {"size_px": [60, 36], "focal_px": 960.0, "distance_mm": 600.0, "center": "eyeball"}
    Image.new("RGB", (s.width, s.height), (200, 100, 50)).save(tmp_path / "000002.png")
    seg = Image.fromarray(np.full((s.height, s.width), 3, np.uint8), mode="P")
    seg.putpalette(palette())
    seg.save(tmp_path / "000002_seg.png")
    paths = nf.write(tmp_path, 2, label, job["normalized"], tmp_path / "000002.png")
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == [
        "normalized/000002.png", "normalized/000002_seg.png", "normalized/000002.json"]
    crop = np.asarray(Image.open(paths[0]))
    assert crop.shape == (36, 60, 3) and (crop[18, 30] == [200, 100, 50]).all()
    m = np.asarray(Image.open(paths[1]))
    assert Image.open(paths[1]).mode == "P" and set(np.unique(m)) <= {3, nz.OUTSIDE} and m[18, 30] == 3
    doc = json.loads(paths[2].read_text())
    W = np.asarray(doc["warp"])
    np.testing.assert_allclose(nz.apply_h(W, label["landmarks"]["px"]), doc["landmarks"]["px"], atol=1e-9)
    # every file of the format is an image file of the folder (a re-plan may remove it)
    assert {p for _, p in lf.image_files(tmp_path)} >= set(paths)
