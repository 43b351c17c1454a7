"""Stage ``render``: sampling, labels, pupil-in-lid rule, resumable sharded rendering.

The asset is built in a fixture (fixtures.make_render_asset) from the small constructed scan of
fixtures.make_inputs (a flat skin grid with the eyeballs poking through it), with 16-vertex lid
loops and eyelid landmark edges added to its rig.npz. Pure-Python parts are tested directly;
Blender renders only a few tiny images (24 x 16 px, 1 sample).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from fixtures import EYES, make_render_asset
from pipeline.errors import ScanError
from pipeline.render.camera import quat_to_matrix
from pipeline.io.labels_file import read_index, read_label
from pipeline.io.rig_file import read_rig, write_rig
from pipeline.render import asset as ra
from pipeline.render import labels as lb
from pipeline.render import run as rr
from pipeline.render import camera as cam
from pipeline.render.settings import RenderSettings
from pipeline.render import sampling as sp
from pipeline.render.coverage import sample_uncovered
from pipeline.rig import lids
from stages._common import read_stage_metrics

ROOT = Path(__file__).resolve().parents[1]
TINY = {"width": 24, "height": 16, "frame_margin_px": None, "samples": 1, "denoise": False, "workers": 1, "shard_size": 2,
        "progress": False, "connect_timeout_s": 3}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("render"))
    return {**made, "asset": ra.load_render_asset(made["asset_dir"], made["rig_dir"])}


def _settings(**kw):
    return RenderSettings.from_dict({**{k: v for k, v in TINY.items()
                                           if k in RenderSettings.__dataclass_fields__}, **kw})


def _params(root: Path, name: str, **kw) -> Path:
    import yaml

    p = root / name
    p.write_text(yaml.safe_dump({"render": {**TINY, **kw}}))
    return p


def _stage_cmd(tiny, out, params, *extra):
    return [sys.executable, "-m", "stages.render", str(tiny["asset_dir"]), str(tiny["rig_dir"]), str(out),
            "--metrics", str(out.parent / (out.name + ".metrics.json")), "--params", str(params),
            "--no-progress", *extra]


# ------------------------------------------------------------------------------- pure Python

def test_asset_reader_matches_the_fixture(tiny):
    from pipeline.eyeball.geometry import EyeballParams

    a = tiny["asset"]
    for side, e in EYES.items():
        eye = a.eyes[side]
        np.testing.assert_allclose(eye.center, e["center"], atol=1e-9)
        np.testing.assert_allclose(eye.forward, np.asarray(e["forward"]) / np.linalg.norm(e["forward"]), atol=1e-9)
        # at rest the eyelid landmarks are the stored rig points (mesh edges lerped, float32 mesh)
        np.testing.assert_allclose(ra.eyelid_points(a, side, {}), a.rig_arrays[f"landmarks.{side}.points"],
                                   atol=1e-5)
        # posing a subset (with repeated vertices, as edges share them) = posing the whole mesh
        E = eye.lm_edge.ravel()
        for w in ({"lids_up": 0.4}, {"lids_down": 1.0}):
            np.testing.assert_allclose(ra.posed_skin(a, w, E), ra.posed_skin(a, w)[E], atol=1e-12)
        # the iris landmarks lie on a circle about the eye's forward axis, the model's iris radius in
        # mm whatever the fitted eyeball radius (the eye is placed, not scaled)
        iris = ra.inner_points(eye, {}, np.eye(3), eye.iris)
        rel = iris - eye.center
        axial = rel @ eye.forward
        assert np.ptp(axial) < 1e-4
        rad = np.linalg.norm(rel - np.outer(axial, eye.forward), axis=1)
        assert np.ptp(rad) < 1e-4 and rad.mean() == pytest.approx(EyeballParams().iris_radius, rel=1e-3)


def test_projection_of_stored_3d_landmarks_reproduces_stored_2d(tiny):
    s = _settings(n_images=8)
    for i in range(8):
        smp = sp.make_sample(tiny["asset"], s, i, "/tmp/x.png")
        lab = json.loads(json.dumps(lb.make_label(smp, s, "tiny")))       # as stored on disk
        assert lb.check_label(lab) < 0.01
        # the composite head -> pixel matrix gives the same pixels from the head-frame landmarks
        Hm = np.asarray(lab["camera"]["head_to_pixel"])
        P = np.asarray(lab["landmarks"]["head_mm"])
        uv = np.concatenate([P, np.ones((28, 1))], 1) @ Hm.T
        np.testing.assert_allclose(uv[:, :2], lab["landmarks"]["px"], atol=0.01)
        # and the camera frame is the head frame moved by the stored rigid transform
        W = np.asarray(lab["camera"]["world_to_camera"])
        np.testing.assert_allclose(W[:3, :3] @ W[:3, :3].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(P @ W[:3, :3].T + W[:3, 3], lab["landmarks"]["camera_mm"], atol=1e-9)


EYE_FIELDS = ("center_head_mm", "center_camera_mm", "center_px", "radius_mm", "center_to_iris_plane_mm")


@pytest.mark.parametrize("preset", ["generic", "near_eye", "webcam"])
def test_every_label_gives_each_eyes_centre_radius_and_iris_plane(tiny, preset):
    """Both eyes of every label: the rotation centre (the gaze origin) in head mm, camera mm and
    pixels, the radius and the centre-to-iris-plane distance, read from the asset; the pixels are
    the label's own camera matrices applied to the centre (orthographic and pinhole)."""
    a = tiny["asset"]
    s = RenderSettings.from_params({"preset": preset, "n_images": 6})          # the preset's own image size
    for i in range(6):
        smp = sp.make_sample(a, s, i, "/tmp/x.png")
        lab = json.loads(json.dumps(lb.make_label(smp, s, "tiny")))       # as stored on disk
        cam_block = lab["camera"]
        assert cam_block["type"] == ("orthographic" if preset == "generic" else "pinhole")
        W, P, H = (np.asarray(cam_block[k]) for k in ("world_to_camera", "projection", "head_to_pixel"))
        for side in ("left", "right"):
            e = lab["eyes"][side]
            assert all(k in e for k in EYE_FIELDS), e.keys()
            c = np.asarray(e["center_head_mm"])
            np.testing.assert_allclose(c, EYES[side]["center"], atol=1e-9)          # the asset's joint
            assert e["radius_mm"] == a.eyes[side].radius == EYES[side]["radius"]    # the asset's radius
            np.testing.assert_allclose(W[:3, :3] @ c + W[:3, 3], e["center_camera_mm"], atol=1e-9)
            for M, X in ((P, e["center_camera_mm"]), (H, c)):
                uv = M @ np.r_[X, 1.0]
                np.testing.assert_allclose(uv[:2] / uv[2], e["center_px"], atol=1e-9)
        # the imaged eye's iris landmarks lie on the iris plane, that far along the gaze from the centre
        e = lab["eyes"][lab["gaze"]["eye"]]
        rel = np.asarray(lab["landmarks"]["head_mm"])[12:20] - e["center_head_mm"]
        np.testing.assert_allclose(rel @ lab["gaze"]["vector_head"], e["center_to_iris_plane_mm"], atol=1e-5)
    # the label reader checks them
    from pipeline.io.labels_file import _eye_geometry
    bad = json.loads(json.dumps(lab))
    bad["eyes"]["left"]["center_px"] = [1.0]
    with pytest.raises(ScanError, match="eyes.left.center_px"):
        _eye_geometry(bad, "x.json")


def test_the_iris_plane_distance_is_the_eyeballs_geometry(tiny):
    """Centre to iris plane = the Inner mesh's planar front, z = sqrt((r1 - gap)^2 - r_iris^2) in the
    asset's eyeball (its own r1, not a fixed 12 mm), moved by the iris blend shapes' offsets (linear
    in their weights), within 1e-6 mm; the same at every eye rotation."""
    from pipeline.eyeball.geometry import EyeballParams, shape_targets

    for side in ("left", "right"):
        eye = tiny["asset"].eyes[side]
        p = EyeballParams.from_dict(eye.eyeball_params)
        assert p.r1 == EYES[side]["radius"]
        z = lambda r: np.sqrt(p.inner_radius ** 2 - r ** 2)                        # noqa: E731
        z_large, z_small = (z(shape_targets(p)[k][1]) for k in ("iris_large", "iris_small"))
        scale = np.linalg.norm(eye.bind[2, :3])
        for blend in ({}, {"iris_large": 0.7}, {"iris_small": 1.0, "pupil_dilate": 0.5}, {"pupil_constrict": 1.0}):
            want = z(p.iris_radius) + blend.get("iris_large", 0.0) * (z_large - z(p.iris_radius)) \
                + blend.get("iris_small", 0.0) * (z_small - z(p.iris_radius))
            assert abs(ra.iris_plane_distance(eye, blend) - scale * want) < 1e-6, (side, blend)
        # rotated about the centre, the iris ring keeps its plane's distance along the rotated forward
        R = quat_to_matrix([0.95, 0.2, -0.2, 0.1] / np.linalg.norm([0.95, 0.2, -0.2, 0.1]))
        ring = ra.inner_points(eye, {}, R, eye.iris) - eye.center
        np.testing.assert_allclose(ring @ (R @ eye.forward), ra.iris_plane_distance(eye, {}), atol=1e-6)


def test_projection_convention_of_an_orthographic_camera():
    # image 120 x 80, 30 mm wide: a point 7.5 mm right and 5 mm up of the axis
    uv = cam.project([[7.5, 5.0, -100.0], [0.0, 0.0, -5.0]], 30.0, 120, 80)
    np.testing.assert_allclose(uv, [[90.0, 20.0], [60.0, 40.0]])
    M = cam.look_at([0, 0, 100.0], [0, 0, 0], [0, 1, 0])
    np.testing.assert_allclose(cam.to_camera([[1.0, 2.0, 3.0]], M), [[1.0, 2.0, -97.0]])


def test_pupil_in_lid_rule_constructed_cases(tiny):
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    assert cam.point_in_polygon([5, 5], square) and not cam.point_in_polygon([15, 5], square)
    notch = np.array([[0, 0], [10, 0], [10, 10], [5, 4], [0, 10]], float)      # concave (V notch on top)
    assert cam.point_in_polygon([5, 2], notch) and not cam.point_in_polygon([5, 7], notch)
    # a sample pinned so that the camera grazes the (flat) lid ring from the lateral side (70 deg)
    # while the eye turns 35 deg laterally: the projected pupil centre leaves the foreshortened
    # lid polygon, so every (pinned) attempt is rejected
    a, s = tiny["asset"], _settings(max_attempts=3, camera_polar_max_deg=70.0)
    bad = {"side": "left", "polar_deg": 70.0, "azimuth_deg": 0.0, "gaze_pitch_deg": 0.0,
           "gaze_yaw_deg": 35.0, "jitter": np.zeros(2)}
    smp = sp.make_sample(a, s, 0, "/tmp/x.png", overrides=bad, reject=False)
    assert not cam.point_in_polygon(smp.pupil_center_px, smp.lid_polygon_px)
    with pytest.raises(sp.RejectionError, match="sample 0: pupil outside the eyelid polygon"):
        sp.make_sample(a, s, 0, "/tmp/x.png", overrides=bad)
    good = dict(bad, polar_deg=0.0, gaze_yaw_deg=0.0)
    smp = sp.make_sample(a, s, 0, "/tmp/x.png", overrides=good)
    assert smp.attempts == 1 and cam.point_in_polygon(smp.pupil_center_px, smp.lid_polygon_px)


def test_rejected_attempts_are_redrawn_and_counted(tiny):
    # wide camera range on the tiny asset: some samples need more than one attempt
    s = _settings(camera_polar_max_deg=70.0)
    att = [sp.make_sample(tiny["asset"], s, i, "/tmp/x.png").attempts for i in range(40)]
    assert max(att) > 1
    for i, n in enumerate(att):
        smp = sp.make_sample(tiny["asset"], s, i, "/tmp/x.png")
        assert smp.attempts == n and cam.point_in_polygon(smp.pupil_center_px, smp.lid_polygon_px)
        # the rule holds on the 12 eyelid landmarks of the label itself
        assert cam.point_in_polygon(smp.pupil_center_px, smp.landmarks_px[:12])
        for k in range(n - 1):     # every earlier attempt was rejected (pupil, or background)
            prev = sp.pose_sample(tiny["asset"], s, i, k, "/tmp/x.png")
            assert not sp.pupil_in_lids(prev) or sample_uncovered(tiny["asset"], prev, s.width, s.height) > 0


def test_same_seed_same_labels_other_seed_other_labels(tiny):
    a = tiny["asset"]
    dump = lambda s, i: json.dumps(lb.make_label(sp.make_sample(a, s, i, "/x.png"), s, "tiny"))  # noqa: E731
    s0, s1 = _settings(seed=5), _settings(seed=6)
    assert [dump(s0, i) for i in range(4)] == [dump(_settings(seed=5), i) for i in range(4)]
    assert dump(s0, 2) != dump(s1, 2)
    # sample i does not depend on how many images are rendered
    assert dump(_settings(seed=5, n_images=3), 2) == dump(_settings(seed=5, n_images=500), 2)


EXTREMES = [  # (pitch, yaw requested in the eye frame, polar, pupil) -> clipped to +-25 / +-35
    {"gaze_pitch_deg": 40.0, "gaze_yaw_deg": 50.0, "polar_deg": 0.0, "pupil": 1.0, "iris": 1.0},
    {"gaze_pitch_deg": -40.0, "gaze_yaw_deg": -50.0, "polar_deg": 0.0, "pupil": -1.0, "iris": -1.0},
    {"gaze_pitch_deg": 25.0, "gaze_yaw_deg": -35.0, "polar_deg": 20.0, "azimuth_deg": 90.0, "pupil": -1.0},
    {"gaze_pitch_deg": -25.0, "gaze_yaw_deg": 35.0, "polar_deg": 20.0, "azimuth_deg": 270.0, "pupil": 1.0},
]


def _extreme_sample(tiny, k, png="/tmp/x.png"):
    s = _settings()
    ov = dict(EXTREMES[k], side="left", jitter=np.zeros(2))
    return s, sp.make_sample(tiny["asset"], s, 100 + k, png, overrides=ov, reject=False)


def test_extremes_give_finite_clipped_labels(tiny):
    radii = {}
    for k, ex in enumerate(EXTREMES):
        s, smp = _extreme_sample(tiny, k)
        lab = lb.make_label(smp, s, "tiny")
        flat = np.concatenate([np.ravel(lab["landmarks"][key]) for key in ("px", "camera_mm", "head_mm")])
        assert np.all(np.isfinite(flat))
        g = lab["gaze"]["eye_frame"]
        assert abs(g["pitch_deg"]) == pytest.approx(min(abs(ex["gaze_pitch_deg"]), 25.0), abs=1e-9)
        assert abs(g["yaw_deg"]) == pytest.approx(min(abs(ex["gaze_yaw_deg"]), 35.0), abs=1e-9)
        assert lab["gaze"]["clipped"] == (abs(ex["gaze_pitch_deg"]) > 25)
        for side in ("left", "right"):      # the other eye is clipped to its own limits too
            assert abs(lab["eyes"][side]["pitch_eye_deg"]) <= 25 + 1e-9
            assert abs(lab["eyes"][side]["yaw_eye_deg"]) <= 35 + 1e-9
        # Listing's law: the eye rotation takes the rest forward to the gaze, axis perpendicular to it
        eye = tiny["asset"].eyes["left"]
        q = lab["eyes"]["left"]["rotation_wxyz"]
        R = quat_to_matrix(q)
        np.testing.assert_allclose(R @ eye.forward, lab["gaze"]["vector_head"], atol=1e-12)
        assert abs(np.dot(q[1:], eye.forward)) < 1e-12
        w = lab["eyelids"]["weights"]
        assert w == lids.lid_weights(lab["eyelids"]["pitch_deg"])
        if ex["polar_deg"] == 0.0:           # camera at the pole = the eye's rest forward
            np.testing.assert_allclose(lab["head_pose"]["camera_direction_head"], eye.forward, atol=1e-12)
        radii[ex["pupil"]] = lab["eye_configuration"]["pupil_radius_mm"]
    # pupil_dilated_mm / pupil_constricted_mm, not scaled with the fitted eyeball radius
    assert EYES["left"]["radius"] != 12.0
    assert radii[1.0] == pytest.approx(4.0, rel=1e-3)
    assert radii[-1.0] == pytest.approx(1.0, rel=1e-3)


def test_eye_contact_gaze_points_at_the_camera(tiny):
    s = _settings(gaze_offset_max_deg=0.0)
    for i in range(6):
        lab = lb.make_label(sp.make_sample(tiny["asset"], s, i, "/x.png"), s, "tiny")
        if not lab["gaze"]["clipped"]:
            assert lab["gaze"]["camera"]["pitch_deg"] == pytest.approx(0.0, abs=1e-9)
            assert lab["gaze"]["camera"]["yaw_deg"] == pytest.approx(0.0, abs=1e-9)


def test_refraction_through_the_cornea(tiny):
    from pipeline.eyeball.geometry import EyeballParams
    from pipeline.render import refraction as rf

    a = tiny["asset"]
    s = _settings()                                  # camera at the pole, eye at rest
    smp = sp.make_sample(a, s, 0, "/x.png", overrides={"side": "left", "polar_deg": 0.0, "gaze_pitch_deg": 0.0,
                                                       "gaze_yaw_deg": 0.0, "jitter": np.zeros(2), "pupil": 0.0,
                                                       "iris": 0.0})
    eye = a.eyes["left"]
    A = eye.model_to_head(np.eye(3))
    p = EyeballParams.from_dict(eye.eyeball_params)
    W = smp.camera["world_to_camera"]
    pts = np.concatenate([smp.landmarks_head[20:28], ra.pupil_center(a, "left", {}, np.eye(3))[None]])
    straight = cam.to_camera(pts, W)[:, :2]
    # no refraction (n = 1): the apparent position is the straight projection
    np.testing.assert_allclose(rf.apparent_projection(pts, W, A, p, ior=1.0), straight, atol=1e-5)
    # the cornea: the pupil centre on the optical axis stays put, the pupil ring looks larger
    # (entrance pupil ~13 % larger than the real pupil for a human eye)
    app = rf.apparent_projection(pts, W, A, p, ior=eye.cornea_ior)
    np.testing.assert_allclose(app[8], straight[8], atol=1e-4)
    mag = np.linalg.norm(app[:8] - app[8], axis=1) / np.linalg.norm(straight[:8] - straight[8], axis=1)
    assert np.all((mag > 1.05) & (mag < 1.3)) and np.ptp(mag) < 1e-3


def test_skin_detail_rule():
    assert sp.choose_skin_detail(0.25, 0.2, 1.2) == "displacement"      # relief >= half a pixel
    assert sp.choose_skin_detail(0.25, 0.08, 1.2) == "bump"             # polygons span > 1 px
    assert sp.choose_skin_detail(2.0, 0.08, 1.2) == "none"              # everything sub-pixel
    assert sp.choose_skin_detail(0.25, 0.0, 1.2) == "none"              # no map


def test_settings_presets_and_validation():
    assert RenderSettings.from_dict({"preset": "targeted"}).camera_polar_max_deg == 5.0
    assert RenderSettings.from_dict({"preset": "targeted", "gaze_step_deg": 2}).gaze_step_deg == 2
    np.testing.assert_array_equal(sp.offset_grid(45, 10), [-40, -30, -20, -10, 0, 10, 20, 30, 40])
    for bad, message in (({"preset": "nope"}, r"render\.preset must be one of generic, near_eye, targeted"),
                         ({"width": 40, "height": 80}, r"render\.width must be >= height"),
                         ({"eyes": ["middle"]}, r"render\.eyes\[0\] must be one of 'left', 'right'"),
                         ({"samples": 0}, r"render\.samples must be >= 1")):
        with pytest.raises(ValueError, match=message):
            RenderSettings.from_dict(bad)


def test_fingerprint_covers_the_referenced_eyeball_and_its_textures(tiny):
    a = tiny["asset"]
    before = a.fingerprint()
    bump = Path(a.usda).parent / "eyeball" / "textures" / "sclera_bump.png"    # the asset's own copy
    data = bump.read_bytes()
    try:
        bump.write_bytes(data + b"changed")
        assert a.fingerprint() != before
    finally:
        bump.write_bytes(data)
    assert a.fingerprint() == before


def test_config_change_removes_stale_images(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    for i in range(3):
        (out / f"{i:06d}.png").write_bytes(b"x")
        (out / f"{i:06d}.json").write_text("{}")
        (out / f"{i:06d}_seg.png").write_bytes(b"x")          # mask and depth map (render.masks)
        (out / f"{i:06d}_depth.exr").write_bytes(b"x")
    (out / "000003.png").write_bytes(b"half")               # unfinished: no JSON
    (out / "000003_seg.png").write_bytes(b"half")
    (out / "config.json").write_text(json.dumps({"config_hash": "a"}))
    rr.prepare_out(out, "a", 2)                               # same config, fewer images
    assert sorted(p.name for p in out.glob("0*")) == sorted(f"{i:06d}{e}" for i in range(2)
                                                             for e in (".json", ".png", "_seg.png", "_depth.exr"))
    info = rr.prepare_out(out, "b", 2)                        # another config: everything stale
    assert info["stale_config"] and not list(out.glob("0*"))


# ------------------------------------------------------------------------------- Blender

@pytest.mark.blender
def test_extreme_images_are_not_black_or_blank(tiny, tmp_path):
    from pipeline.render.shard import BlenderProcess

    bp = BlenderProcess(tiny["asset"].usda, tiny["asset"].rig_npz, threads=2)
    try:
        for k in range(len(EXTREMES)):
            png = tmp_path / f"x{k}.png"
            _, smp = _extreme_sample(tiny, k, str(png))
            spec = dict(smp.spec.to_dict(), width=32, height=24, samples=1, denoise=False)
            reply = bp.render(spec, timeout_s=300)
            assert reply["ok"], reply
            assert reply["landmark_check_mm"] < 0.01
            a = np.asarray(Image.open(png).convert("RGB"), float)
            assert a.shape == (24, 32, 3)
            assert a.mean() > 10 and a.std() > 2, (k, a.mean(), a.std())
    finally:
        bp.close()
    assert bp.proc.returncode == 0


@pytest.mark.blender
def test_resumed_images_are_byte_identical(tiny, tmp_path):
    """An image rendered first in a fresh Blender worker (a resumed run) has the same bytes as
    the same index rendered after others: image, mask, depth map and label."""
    params = _params(tmp_path, "p.yaml", n_images=4)
    whole, resumed = tmp_path / "whole" / "tiny", tmp_path / "resumed" / "tiny"
    for out in (whole, resumed):
        r = subprocess.run(_stage_cmd(tiny, out, params), cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
    for f in list(resumed.glob("00000[12]*")) + [resumed / "index.jsonl"]:
        f.unlink()
    r = subprocess.run(_stage_cmd(tiny, resumed, params), cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert read_stage_metrics(resumed.parent / "tiny.metrics.json")["rendered"] == 2
    files = sorted(p.name for p in whole.glob("0*"))
    assert len(files) == 16 and files == sorted(p.name for p in resumed.glob("0*"))
    assert [f for f in files if (whole / f).read_bytes() != (resumed / f).read_bytes()] == []


@pytest.mark.blender
def test_stage_killed_and_resumed_has_every_index_once(tiny, tmp_path):
    out = tmp_path / "renders" / "tiny"
    params = _params(tmp_path, "p.yaml", n_images=6)
    proc = subprocess.Popen(_stage_cmd(tiny, out, params), cwd=ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.time()
    while time.time() - t0 < 120 and len(list(out.glob("0*.json"))) < 2 and proc.poll() is None:
        time.sleep(0.1)
    assert proc.poll() is None, proc.stderr.read().decode()
    os.killpg(proc.pid, signal.SIGKILL)                       # the job and its dask/Blender children
    proc.wait()
    n_before = len(list(out.glob("0*.json")))
    assert 2 <= n_before < 6 and not (out / "index.jsonl").exists()
    r = subprocess.run(_stage_cmd(tiny, out, params), cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = read_index(out / "index.jsonl")
    assert [x["index"] for x in lines] == list(range(6))
    assert sorted(p.name for p in out.glob("0*")) == sorted(f"{i:06d}{e}" for i in range(6)
                                                             for e in (".png", ".json", "_seg.png", "_depth.exr"))
    m = read_stage_metrics(out.parent / "tiny.metrics.json")
    assert m["skipped_done"] >= n_before and m["rendered"] == 6 - m["skipped_done"]
    assert m["landmark_check_max_mm"] < 0.01
    assert m["shards"] >= 1 and m["blender_starts"] == 1
    for x in lines:
        lab = read_label(out / x["json"])
        assert lab.index == x["index"] and lb.check_label(lab.doc) < 0.01
        a = np.asarray(Image.open(out / x["png"]).convert("RGB"), float)
        assert a.shape == (16, 24, 3) and a.std() > 1
    # the same seed gives the same labels as a fresh sampling (resume did not change them)
    s = _settings(n_images=6)
    fresh = lb.make_label(sp.make_sample(tiny["asset"], s, 3, "/x.png"), s, tiny["asset"].name)
    stored = read_label(out / "000003.json").doc
    extra = {k: stored["landmarks"].pop(k) for k in ("apparent_px", "apparent_order", "visible", "occlusion",
                                                     "visibility_rule")}
    # (the stage runs on pinned numeric kernels, pipeline/kernels.py, and this process on the
    # CPU's own: the same sample to the last few bits, not bit for bit)
    want = json.loads(json.dumps(fresh["landmarks"]))
    assert stored["landmarks"].keys() == want.keys()
    for k, v in want.items():
        if isinstance(v, str):
            assert stored["landmarks"][k] == v, k
        else:
            np.testing.assert_allclose(np.asarray(stored["landmarks"][k], float), np.asarray(v, float),
                                       rtol=1e-12, atol=1e-9, err_msg=k)
    sheet = Image.open(out / "contact_sheet.png")
    assert sheet.size == tuple(m["contact_sheet_px"])
    assert not (out / ".tmp").exists()
    cfg = rr.read_config(out)                                # no absolute path: same bytes anywhere
    assert not os.path.isabs(cfg["asset"]) and (ROOT / cfg["asset"]).resolve() == tiny["asset"].usda.resolve()
    app = extra["apparent_px"]                               # iris/pupil seen through the cornea
    assert len(app) == 16 and sum(q is not None for q in app) >= 8
    # nothing of the killed run is left running
    left = subprocess.run(["pgrep", "-f", f"render_worker {tiny['asset'].usda}"], capture_output=True, text=True)
    assert left.stdout.strip() == ""


@pytest.mark.blender
def test_stage_on_an_existing_dask_cluster(tiny, tmp_path):
    from dask.distributed import LocalCluster

    out = tmp_path / "renders" / "tiny"
    params = _params(tmp_path, "p.yaml", n_images=3, shard_size=1)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        r = subprocess.run(_stage_cmd(tiny, out, params, "--scheduler", cl.scheduler_address), cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    m = read_stage_metrics(out.parent / "tiny.metrics.json")
    assert m["scheduler"] == cl.scheduler_address and m["workers"] == 1 and m["rendered"] == 3
    assert m["shards"] == 3 and m["blender_starts"] == 1      # one Blender per dask worker, kept across tasks
    assert [x["index"] for x in read_index(out / "index.jsonl")] == [0, 1, 2]


@pytest.mark.slow
def test_bad_inputs_exit_2_with_one_line(tiny, tmp_path):
    params = _params(tmp_path, "p.yaml", n_images=2)
    r = subprocess.run(_stage_cmd(tiny, tmp_path / "o1", params)[:3] + [str(tmp_path / "missing")]
                       + _stage_cmd(tiny, tmp_path / "o1", params)[4:], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert r.stderr.startswith("error: ") and "missing" in r.stderr and "not found" in r.stderr
    quick = _params(tmp_path, "quick.yaml", n_images=2, connect_timeout_s=0.5)   # port 9 refuses at once
    r = subprocess.run(_stage_cmd(tiny, tmp_path / "o2", quick, "--scheduler", "tcp://127.0.0.1:9"),
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "tcp://127.0.0.1:9" in r.stderr and "scheduler" in r.stderr
    bad = _params(tmp_path, "bad.yaml", n_images=2, preset="nope")
    r = subprocess.run(_stage_cmd(tiny, tmp_path / "o3", bad), cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "preset" in r.stderr
    neg = _params(tmp_path, "neg.yaml", n_images=2, workers=-1)
    r = subprocess.run(_stage_cmd(tiny, tmp_path / "o4", neg), cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "workers must be >= 0" in r.stderr
    assert not (tmp_path / "o4").exists()
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "broken.usda").write_text("#usda 1.0\ngarbage (((\n")
    with pytest.raises(ScanError, match="could not be opened"):
        ra.load_render_asset(broken, tiny["rig_dir"])
    rig = tmp_path / "rig"
    rig.mkdir()
    write_rig(rig, {"junk": np.zeros(3)}, read_rig(tiny["rig_dir"]).doc)
    with pytest.raises(ScanError, match=r"rig\.npz: missing lid shape array 'shape_names'") as ei:
        ra.load_render_asset(tiny["asset_dir"], rig)
    assert ei.value.path == str(rig / "rig.npz")


def test_sampling_streams_for_any_n_images(tiny, tmp_path, monkeypatch):
    """A million images: the stage samples one window of images before the first shard goes
    out, never all of them (memory stays flat); a billion is refused with one line."""
    s = _settings(n_images=1_000_000)
    calls = []
    real = sp.make_sample
    monkeypatch.setattr(sp, "make_sample", lambda *a, **k: calls.append(a[2]) or real(*a, **k))
    stats = {"sampling_s": 0.0, "shards": 0}
    shards = rr.pending_shards(tiny["asset"], s, tmp_path, iter(range(s.n_images)), 16, stats,
                               tiny["asset_dir"])
    first = next(shards)
    assert calls == list(range(16)) and 1 <= len(first) <= s.shard_size
    assert len({spec.lighting.hdri for spec, _ in first}) == 1
    rest = [next(shards) for _ in range(3)]
    assert len(calls) <= 32 and all(len(x) <= s.shard_size for x in rest)
    huge = _params(tmp_path, "huge.yaml", n_images="1e9")
    r = subprocess.run(_stage_cmd(tiny, tmp_path / "o5", huge), cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "render.n_images must be <= 1000000 (got 1000000000)" in r.stderr
    assert not (tmp_path / "o5").exists()


def test_auto_workers_give_each_blender_two_cores():
    assert [rr.auto_workers(c) for c in (1, 2, 3, 4, 16)] == [1, 1, 1, 2, 8]


@pytest.mark.blender
def test_same_inputs_give_byte_identical_renders(tiny, tmp_path):
    """Two runs of the stage into two folders: every image, label, the index and the contact sheet
    have the same bytes (no time/text chunks in the PNGs, no timings in the labels)."""
    from pipeline.io.png import DROPPED, png_chunks

    params = _params(tmp_path, "p.yaml", n_images=2, sheet_images=2)
    outs = [tmp_path / f"run{k}" / "tiny" for k in (1, 2)]
    for out in outs:
        r = subprocess.run(_stage_cmd(tiny, out, params), cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
    files = [{p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} for out in outs]
    assert sorted(files[0]) == sorted(files[1]) and "000001.png" in files[0] and "index.jsonl" in files[0]
    assert [k for k in files[0] if files[0][k] != files[1][k]] == []
    for name, data in files[0].items():
        if name.endswith(".png"):
            assert not {kind for kind, _, _ in png_chunks(data)} & DROPPED, name
    label = read_label(outs[0] / "000000.json").doc
    assert not {"render_s", "total_s", "render_cpu_s", "total_cpu_s"} & set(label["render"])
