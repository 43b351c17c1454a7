"""Label formats (pipeline/render/formats/): UnityEyes JSON read by a transcription of
GazeML's loader (tests/fixtures/gazeml_unityeyes.py), 300-W .pts, the ``unityeyes`` preset's framing,
and ``render.label_formats`` validation.

Labels come from the small constructed asset of fixtures.make_render_asset, sampled without
Blender; one Blender test runs the stage with every format on two images.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from fixtures import gazeml_unityeyes as gz
from fixtures import make_render_asset
from pipeline.errors import ScanError
from pipeline.io.labels_file import read_index, read_label
from pipeline.io.pts_file import pts_name, pts_text, read_pts, write_pts
from pipeline.io.unityeyes_file import read_unityeyes, write_unityeyes
from pipeline.render import asset as ra
from pipeline.render import camera as cam
from pipeline.render import formats as lf
from pipeline.render import labels as lb
from pipeline.render import run as rr
from pipeline.render import sampling as sp
from pipeline.render.formats import pts as pts_format
from pipeline.render.formats import unityeyes as uef
from pipeline.render.settings import RenderSettings
from pipeline.settings import SettingsError

ROOT = Path(__file__).resolve().parents[1]
ALL = ["eyerig", "unityeyes", "pts"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("formats"))
    made["asset"] = ra.load_render_asset(made["asset_dir"], made["rig_dir"])
    return made


def _settings(**kw):
    return RenderSettings.from_params({"preset": "unityeyes", "label_formats": ALL, **kw})


def _samples(tiny, s, n):
    """``n`` (sample, label, job) of settings ``s``, labels as stored on disk."""
    out = []
    for i in range(n):
        smp = sp.make_sample(tiny["asset"], s, i, "/x.png")
        label = json.loads(json.dumps(lb.make_label(smp, s, "tiny")))
        out.append((smp, label, lf.format_job(tiny["asset"], smp, s.label_formats)))
    return out


def _stored_doc(tmp_path, label, job, png_size=(8, 8)):
    """The UnityEyes pair written and read back (a stand-in PNG)."""
    png = tmp_path / "img.png"
    Image.new("RGB", png_size, (90, 60, 40)).save(png)
    paths = write_unityeyes(tmp_path / "unityeyes", label["index"], uef.unityeyes_document(label, job["unityeyes"]),
                            png)
    assert [p.name for p in paths] == [f"{label['index']:06d}.jpg", f"{label['index']:06d}.json"]
    return read_unityeyes(paths[1])


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


# ------------------------------------------------------------------------------- settings

def test_unityeyes_preset_and_label_formats_settings():
    s = _settings()
    assert (s.width, s.height, s.eyes, s.center_jitter_mm, s.camera_distance_mm) == (320, 240, ("left",), 0.0, 100.0)
    assert s.iris_distance_px == uef.GAZEML_EYEBALL_RADIUS_PX and s.label_formats == tuple(ALL)
    assert s.hashed()["label_formats"] == ALL                      # a format change re-renders
    d = RenderSettings.from_params({})
    assert d.label_formats == ("eyerig",) and d.iris_distance_px is None
    assert RenderSettings.from_params({"preset": "unityeyes", "width": 640, "height": 480}).width == 640


@pytest.mark.parametrize("formats, message", [
    (["eyerig", "hdf5"], "render.label_formats[1] must be one of 'eyerig', 'coco', 'normalized', 'pts', "
                         "'unityeyes', "
                         "'webdataset' (got 'hdf5')"),
    (["unityeyes"], "render.label_formats must list eyerig"),
    (["eyerig", "pts", "pts"], "each format once"),
    ("eyerig", "render.label_formats must be a list"),
])
def test_bad_label_formats_are_one_line(formats, message):
    with pytest.raises(SettingsError) as ei:
        RenderSettings.from_params({"label_formats": formats})
    assert message in str(ei.value) and "\n" not in str(ei.value)


def test_unityeyes_framing_refuses_a_framing_shift():
    """params.yaml lists center_jitter_mm: 1.0, which would override the preset's 0 and move the
    eyeball off the image centre that GazeML assumes: refused, saying what to do."""
    with pytest.raises(SettingsError) as ei:
        RenderSettings.from_params({"preset": "unityeyes", "center_jitter_mm": 1.0})
    msg = str(ei.value)
    assert "render.center_jitter_mm must be 0 with iris_distance_px" in msg and "\n" not in msg


def test_stage_refuses_an_unknown_label_format_with_one_line(tmp_path):
    params = tmp_path / "p.yaml"
    params.write_text("render:\n  label_formats: [eyerig, hdf5]\n")
    r = subprocess.run([sys.executable, "-m", "stages.render", str(tmp_path / "asset"), str(tmp_path / "rig"),
                        str(tmp_path / "out"), "--params", str(params), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "render.label_formats[1] must be one of" in r.stderr and not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------- conventions

def test_unityeyes_points_strings_and_axes(tiny, tmp_path):
    s = _settings()
    for smp, label, job in _samples(tiny, s, 6):
        ue = _stored_doc(tmp_path, label, job)
        doc = ue.doc
        assert list(doc) == ["interior_margin_2d", "caruncle_2d", "iris_2d", "eye_details", "lighting_details",
                             "eye_region_details", "head_pose"]
        assert (len(ue.interior), len(ue.caruncle), len(ue.iris)) == (16, 7, 32)
        for text in doc["interior_margin_2d"] + doc["caruncle_2d"] + doc["iris_2d"] + [doc["head_pose"]]:
            x, y, z = (t for t in text.strip("()").split(", "))
            assert all(len(t.split(".")[1]) == 4 for t in (x, y, z)), text      # C# "F4"
        # x from the left, y from the BOTTOM: our image-space landmarks, flipped
        H = label["image"]["height"]
        px = np.asarray(label["landmarks"]["px"])

        def ours(P):
            return np.c_[P[:, 0], H - P[:, 1]]

        np.testing.assert_allclose(ue.interior[8, :2], ours(px[[6]])[0], atol=1e-4)   # lateral canthus
        np.testing.assert_allclose(ue.caruncle[6, :2], ours(px[[0]])[0], atol=1e-4)   # medial canthus
        order = [12 + (4 - m) % 8 for m in range(8)]                                  # a left eye
        np.testing.assert_allclose(ue.iris[::4, :2], ours(px[order]), atol=1e-4)
        # the eyeball centre is 10 Unity units (cm) in front of the camera, the iris nearer
        cen = uef.unity_screen([tiny["asset"].eyes[smp.side].center], label)[0]
        np.testing.assert_allclose(cen, [s.width / 2, H / 2, 10.0], atol=1e-9)
        assert np.all(ue.iris[:, 2] < 10.0)
        # left-handed camera axes: look_vec = (gx, gy, -gz, 0) of our (OpenGL) camera-frame gaze
        g = np.asarray(label["gaze"]["vector_camera"])
        np.testing.assert_allclose(ue.look_vec, [g[0], g[1], -g[2], 0.0], atol=6e-5)
        assert ue.look_vec[2] < 0                        # an eye that faces the camera
        assert np.all((ue.head_pose >= 0) & (ue.head_pose < 360))
        blend = label["eye_configuration"]["blend"]
        assert float(doc["eye_details"]["iris_size"]) == pytest.approx(
            1 + 0.1 * (blend["iris_large"] - blend["iris_small"]), abs=2e-6)
        assert float(doc["eye_details"]["pupil_size"]) == pytest.approx(
            blend["pupil_dilate"] - blend["pupil_constrict"], abs=1e-6)
        assert doc["lighting_details"]["skybox_texture"] + ".exr" == label["lighting"]["hdri"]


def test_cast_onto_eyeball():
    c, f = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.6, 0.8])
    p = c + [4.0, 0.0, 0.0] + 20 * f                      # in front, inside the silhouette
    q = uef.cast_onto_eyeball(p, c, 12.0, f)
    assert np.linalg.norm(q - c) == pytest.approx(12.0) and (q - c) @ f > 0
    np.testing.assert_allclose(np.cross(q - p, f), 0, atol=1e-12)
    far = c + [13.0, 0.0, 0.0]                             # beside the eye: left where it is
    np.testing.assert_allclose(uef.cast_onto_eyeball(far, c, 12.0, f), far)


def test_lid_points_follow_unityeyes_topology(tiny):
    """Interior margin point 0 and caruncle 27 / 31 are midpoints cast along the eye's forward
    (UnityEyes' rule), the rest lie on the lid loop; the caruncle takes the medial part."""
    s = _settings()
    a = tiny["asset"]
    eye = a.eyes["left"]
    for smp, label, job in _samples(tiny, s, 4):
        I = np.asarray(job["unityeyes"]["interior_head_mm"])
        C = np.asarray(job["unityeyes"]["caruncle_head_mm"])
        for p, (u, v) in ((I[0], (I[1], I[15])), (C[1], (C[0], C[2])), (C[4], (C[3], C[5]))):
            np.testing.assert_allclose(p, uef.cast_onto_eyeball((u + v) / 2, eye.center, eye.radius, eye.basis[2]))
        np.testing.assert_allclose(C[6], label["landmarks"]["head_mm"][0], atol=1e-5)
        np.testing.assert_allclose(I[8], label["landmarks"]["head_mm"][6], atol=1e-5)
        medial = eye.basis[0] @ (np.asarray(label["landmarks"]["head_mm"][6]) - label["landmarks"]["head_mm"][0])
        depth = (np.r_[I, C] - label["landmarks"]["head_mm"][0]) @ eye.basis[0] / medial
        assert depth[16:].mean() < depth[:16].min()         # the caruncle: medial of the margin
    # the lid loop fallback (a rig without a loop) uses the 12 landmarks
    P = ra.eyelid_points(a, "left", {})
    Il, Cl = uef.lid_points(P, P, 6, eye.center, eye.radius, eye.basis[2])
    np.testing.assert_allclose(Il[8], P[6]) and np.testing.assert_allclose(Cl[6], P[0])


def test_head_pose_is_the_cameras_unity_euler_angles():
    front = cam.look_at([0, 0, 100.0], [0, 0, 0], [0, 1, 0])
    np.testing.assert_allclose(uef.head_pose(front), [0, 180, 0], atol=1e-9)
    t = math.radians(10)
    above = cam.look_at([0, 100 * math.sin(t), 100 * math.cos(t)], [0, 0, 0], [0, 1, 0])
    np.testing.assert_allclose(uef.head_pose(above), [10, 180, 0], atol=1e-9)       # Unity: +x pitches down
    left = cam.look_at([100 * math.sin(t), 0, 100 * math.cos(t)], [0, 0, 0], [0, 1, 0])  # on the subject's left
    np.testing.assert_allclose(uef.head_pose(left), [0, 170, 0], atol=1e-9)         # Unity's -X side
    below = cam.look_at([0, -100 * math.sin(t), 100 * math.cos(t)], [0, 0, 0], [0, 1, 0])
    np.testing.assert_allclose(uef.head_pose(below), [350, 180, 0], atol=1e-9)      # [0, 360)
    assert uef.cs_vec(uef.head_pose(front)) == "(0.0000, 180.0000, 0.0000)"
    assert uef.cs_vec([-1e-7, 2.5, -3.25]) == "(0.0000, 2.5000, -3.2500)"
    assert [uef.cs_float(x) for x in (1.0, 0.9058223, 0.0, -0.25)] == ["1", "0.9058223", "0", "-0.25"]


# ------------------------------------------------------------------------------- GazeML

def _mirror(label, side):
    """(flip, our iris centre px, our gaze) as the UnityEyes export shows them: a right eye mirrored."""
    W = label["image"]["width"]
    flip = side == "right"
    iris = np.asarray(label["landmarks"]["px"])[12:20].mean(axis=0)
    g = np.asarray(label["gaze"]["vector_camera"], float)
    if flip:
        iris, g = np.array([W - iris[0], iris[1]]), g * [-1, 1, 1]
    return flip, iris, g


def _gazeml_errors(label, doc, center):
    """(iris centre px error, gaze deg error, eyeball centre px error, entry) of GazeML's reading
    of ``doc`` against our label (mirrored for a right eye; None when its head-pose filter drops
    the image)."""
    H, W = label["image"]["height"], label["image"]["width"]
    e = gz.read_entry(doc, H, W)
    if e is None:
        return None
    flip, ours, g = _mirror(label, label["gaze"]["eye"])
    iris = float(np.linalg.norm(e["iris_centre"] - ours))
    gaze = _angle_deg(gz.gaze_to_camera(e["gaze"]), g)
    x, y, _ = uef.unity_screen([center], label, flip)[0]
    cen = float(np.linalg.norm(e["eyeball_centre"] - [x, H - y]))
    return iris, gaze, cen, e


def _crop_box(e):
    """GazeML's crop in the full image: the (60 x 36) eye image's corners through its inverse transform."""
    A, b = e["transform"][:2, :2], e["transform"][:2, 2]
    P = np.array([np.linalg.solve(A, np.array([x, y]) - b) for x, y in ((0, 0), (60, 0), (60, 36), (0, 36))])
    return P.min(axis=0), P.max(axis=0)


@pytest.mark.parametrize("side", ["left", "right"])
def test_gazeml_loader_recovers_our_iris_centre_and_gaze(tiny, side):
    s = _settings(eyes=[side], n_images=24)
    kept = 0
    for smp, label, job in _samples(tiny, s, 24):
        doc = json.loads(json.dumps(uef.unityeyes_document(label, job["unityeyes"])))
        r = _gazeml_errors(label, doc, tiny["asset"].eyes[side].center)
        if r is None:           # GazeML's |head pitch|, |yaw| <= 20 filter (this eye turns 5 deg out)
            continue
        kept += 1
        iris, gaze, cen, e = r
        assert iris <= 1.0 and gaze <= 1.0 and cen <= 1e-9, (iris, gaze, cen)
        assert iris < 0.02 and gaze < 0.01                  # only the strings' 4 decimals differ
        flip, _, _ = _mirror(label, side)
        pc = np.asarray(label["landmarks"]["pupil_center_px"])
        np.testing.assert_allclose([s.width - pc[0], pc[1]] if flip else pc, e["iris_centre"], atol=0.02)
        # its 18 eye-image landmarks are ours through its crop transform (a right eye mirrored, its
        # caruncle on the image left as a left eye's)
        px = np.asarray(label["landmarks"]["px"])
        if flip:
            px = np.c_[s.width - px[:, 0], px[:, 1]]
        order = [12 + (4 - m) % 8 if side == "left" else 12 + m for m in range(8)]
        ours = np.c_[px[order], np.ones(8)] @ e["transform"].T
        np.testing.assert_allclose(e["landmarks"][8:16], ours[:, :2], atol=0.01)
        assert px[0, 0] < px[6, 0]                         # medial canthus left of the lateral one
        assert e["radius"] == pytest.approx(gz.ORIGINAL_EYEBALL_RADIUS * 60 / e["eye_width"])
        lo, hi = _crop_box(e)
        assert np.all(lo >= 0) and np.all(hi <= [s.width, s.height])
    assert kept >= 16


@pytest.mark.parametrize("preset", ["generic", "targeted"])
def test_presets_that_gazeml_cannot_read_refuse_unityeyes_with_one_line(preset):
    with pytest.raises(SettingsError) as ei:
        RenderSettings.from_params({"preset": preset, "label_formats": ALL})
    msg = str(ei.value)
    assert "\n" not in msg and f"preset {preset} frames ortho_scale_mm 30-36 at 120 x 80 px" in msg
    assert "use preset unityeyes, or set iris_distance_px: 71.7593, center_jitter_mm: 0" in msg
    with pytest.raises(SettingsError, match="preset unityeyes frames iris_distance_px 50"):
        RenderSettings.from_params({"preset": "unityeyes", "iris_distance_px": 50, "label_formats": ALL})


def test_why_generic_framing_is_refused(tiny):
    """The generic framing (eye off-centre by the shift, 30-36 mm across 120 px) breaks the loader's
    assumptions: its iris centre lands pixels away from ours and its crop is wider than the image."""
    s = RenderSettings.from_params({"preset": "generic", "eyes": ["left"]})
    worst, wide = 0.0, 0
    for i in range(8):
        smp = sp.make_sample(tiny["asset"], s, i, "/x.png")
        label = json.loads(json.dumps(lb.make_label(smp, s, "tiny")))
        r = _gazeml_errors(label, uef.unityeyes_document(label, uef.points_job(tiny["asset"], smp)),
                           tiny["asset"].eyes["left"].center)
        if r is not None:
            worst = max(worst, r[0])
            assert r[1] < 0.01                              # the gaze still agrees
            lo, hi = _crop_box(r[3])
            outside = bool(np.any(lo < 0) or np.any(hi > [s.width, s.height]))
            wide += outside
            if outside:                                     # what the writer refuses, one line
                with pytest.raises(ScanError, match=f"image {i}: label format unityeyes needs GazeML's crop"):
                    uef.job(tiny["asset"], smp)
            else:
                uef.job(tiny["asset"], smp)
    assert worst > 5.0 and wide >= 1


def test_an_image_too_small_for_gazemls_crop_is_drawn_again_or_refused(tiny):
    """The sampler never hands the writer a sample whose GazeML crop leaves the image (the format's
    ``accepts`` rule: it draws again, or says in one line that no attempt served); the writer
    itself still refuses one in one line."""
    s = _settings(width=200, height=150)
    smp = sp.make_sample(tiny["asset"], s, 0, "/x.png", reject=False)
    assert not uef.accepts(tiny["asset"], smp)
    with pytest.raises(ScanError) as ei:
        lf.format_job(tiny["asset"], smp, s.label_formats)
    msg = str(ei.value)
    assert "\n" not in msg and "image 0: label format unityeyes needs GazeML's crop (1.5 eye widths" in msg
    assert "inside the 200 x 150 image; use preset unityeyes" in msg
    with pytest.raises(sp.RejectionError) as ei:
        sp.make_sample(tiny["asset"], s, 0, "/x.png")
    assert "\n" not in str(ei.value) and f"a label format's own rule in {s.max_attempts})" in str(ei.value)
    assert str(ei.value).endswith("the eye, canthus to canthus, is too wide for a label format's crop at this framing")


@pytest.mark.parametrize("params", [
    {"preset": "unityeyes", "eyes": ["left", "right"]},
    # the generic ranges in GazeML's framing, set by hand
    {"preset": "generic", "eyes": ["left", "right"], "iris_distance_px": 71.7593, "center_jitter_mm": 0,
     "width": 512, "height": 384},
], ids=["unityeyes", "generic_in_gazeml_framing"])
def test_unityeyes_round_trip_through_files_and_gazeml(tiny, tmp_path, params):
    """Written (JPEG mirrored for a right eye), read back, read by GazeML's loader: its crop lies in
    the image, its iris centre and gaze are ours (mirrored) within 0.02 px and 0.01 deg."""
    s = RenderSettings.from_params({**params, "label_formats": ALL})
    png = tmp_path / "img.png"
    pattern = np.zeros((s.height, s.width, 3), np.uint8)
    pattern[:, : s.width // 4] = 255                          # bright on the left only
    Image.fromarray(pattern).save(png)
    sides, kept = set(), 0
    for smp, label, job in _samples(tiny, s, 16):
        side = label["gaze"]["eye"]
        sides.add(side)
        paths = uef.write(tmp_path, label["index"], label, job["unityeyes"], png)
        ue = read_unityeyes(paths[1])
        with Image.open(paths[0]) as im:
            assert im.size == (s.width, s.height)
            grey = np.asarray(im.convert("L"), float)
        bright_left = grey[:, : s.width // 8].mean() > grey[:, -s.width // 8:].mean()
        assert bright_left == (side == "left")                 # a right eye's JPEG is mirrored
        assert label["conventions"]["unityeyes"]["mirrored"] == (side == "right")
        r = _gazeml_errors(label, ue.doc, tiny["asset"].eyes[side].center)
        if r is None:
            continue
        kept += 1
        iris, gaze, cen, e = r
        assert iris < 0.02 and gaze < 0.01 and cen < 1e-9, (iris, gaze, cen)
        lo, hi = _crop_box(e)
        assert np.all(lo >= 0) and np.all(hi <= [s.width, s.height]), (lo, hi)
        # the caruncle (medial) on the image left, as in UnityEyes' left eyes
        assert ue.caruncle[:, 0].mean() < ue.interior[8, 0]
    assert sides == {"left", "right"} and kept >= 8


# ------------------------------------------------------------------------------- 300-W and files

def test_pts_files_hold_the_28_landmarks_one_based(tiny, tmp_path):
    s = _settings()
    for smp, label, job in _samples(tiny, s, 3):
        p = tmp_path / pts_name(label["index"])
        write_pts(p, pts_format.pts_points(label))
        lines = p.read_text().splitlines()
        assert lines[:3] == ["version: 1", "n_points:  28", "{"] and lines[-1] == "}" and len(lines) == 32
        np.testing.assert_allclose(read_pts(p) - 0.5, label["landmarks"]["px"], atol=1e-6)
    bad = tmp_path / "bad.pts"
    for text, msg in ((pts_text(np.zeros((3, 2))).replace("n_points:  3", "n_points:  4"), "n_points is 4"),
                      ("version: 2\n{\n}\n", "not a version 1 .pts"),
                      (pts_text(np.zeros((2, 2))).replace("0.000000 0.000000\n}", "1 2 3\n}"), "two numbers")):
        bad.write_text(text)
        with pytest.raises(ScanError, match=msg):
            read_pts(bad)


def test_unityeyes_reader_refuses_bad_documents(tiny, tmp_path):
    s = _settings()
    _, label, job = _samples(tiny, s, 1)[0]
    doc = uef.unityeyes_document(label, job["unityeyes"])
    p = tmp_path / "000000.json"
    for key, value, msg in (("iris_2d", doc["iris_2d"][:31], "iris_2d must hold 32 points"),
                            ("head_pose", "(1, 2)", "head_pose must be a string"),
                            ("caruncle_2d", ["(1; 2; 3)"] * 7, r"caruncle_2d\[0\] must be a string")):
        p.write_text(json.dumps({**doc, key: value}))
        with pytest.raises(ScanError, match=msg):
            read_unityeyes(p)


def test_stale_and_unfinished_format_files_are_removed(tmp_path):
    out = tmp_path / "out"
    (out / uef.UNITYEYES_DIR).mkdir(parents=True)
    for i in range(3):
        for name in (f"{i:06d}.png", f"{i:06d}.json", f"{i:06d}.pts", f"unityeyes/{i:06d}.json",
                     f"unityeyes/{i:06d}.jpg"):
            (out / name).write_text("x")
    (out / "000002.json").unlink()                            # image 2 unfinished
    (out / "config.json").write_text(json.dumps({"config_hash": "a"}))
    rr.prepare_out(out, "a", 3)
    left = sorted(str(p.relative_to(out)) for p in out.rglob("0*"))
    assert left == sorted(f"{d}{i:06d}.{e}" for i in range(2) for d, e in
                          (("", "png"), ("", "json"), ("", "pts"), ("unityeyes/", "json"), ("unityeyes/", "jpg")))
    rr.prepare_out(out, "b", 3)                               # another config: all stale
    assert not list(out.rglob("0*"))


# ------------------------------------------------------------------------------- Blender

@pytest.mark.blender
def test_stage_writes_every_format_and_gazeml_reads_it(tiny, tmp_path):
    import yaml

    out = tmp_path / "renders" / "tiny"
    params = tmp_path / "p.yaml"
    params.write_text(yaml.safe_dump({"render": {
        "preset": "unityeyes", "label_formats": ALL, "n_images": 5, "samples": 1, "denoise": False,
        "eyes": ["left", "right"],
        "workers": 1, "shard_size": 2,
        "progress": False, "connect_timeout_s": 3}}))
    r = subprocess.run([sys.executable, "-m", "stages.render", str(tiny["asset_dir"]), str(tiny["rig_dir"]),
                        str(out), "--metrics", str(tmp_path / "m.json"), "--params", str(params), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert [x["index"] for x in read_index(out / "index.jsonl")] == [0, 1, 2, 3, 4]
    kept, sides = 0, set()
    for i in range(5):
        label = read_label(out / f"{i:06d}.json").doc
        side = label["gaze"]["eye"]
        sides.add(side)
        np.testing.assert_allclose(read_pts(out / f"{i:06d}.pts") - 0.5, label["landmarks"]["px"], atol=1e-6)
        ue = read_unityeyes(out / "unityeyes" / f"{i:06d}.json")
        with Image.open(out / "unityeyes" / f"{i:06d}.jpg") as im:
            assert im.format == "JPEG" and im.size == (320, 240)
            grey = np.asarray(im.convert("L"), float)
        with Image.open(out / f"{i:06d}.png") as im:
            png = np.asarray(im.convert("L"), float)
        want = png[:, ::-1] if side == "right" else png               # a right eye mirrored
        assert np.abs(grey - want).mean() < 3 < np.abs(grey - want[:, ::-1]).mean()
        r = _gazeml_errors(label, ue.doc, tiny["asset"].eyes[side].center)
        if r is not None:
            kept += 1
            assert r[0] < 0.02 and r[1] < 0.01
            # the label's conventions block says what GazeML reads from the (mirrored) file
            gml = np.asarray(label["conventions"]["gazeml"]["gaze_pitchyaw_rad"]) * ([1, -1] if side == "right" else 1)
            np.testing.assert_allclose(r[3]["gaze"], gml, atol=2e-4)
            lo, hi = _crop_box(r[3])
            assert np.all(lo >= 0) and np.all(hi <= [320, 240])
        c = label["conventions"]["eth_xgaze"]["gaze_pitchyaw_rad"]
        ang = label["gaze"]["camera"]
        np.testing.assert_allclose(np.degrees(c), [ang["pitch_deg"], -ang["yaw_deg"]], atol=1e-9)
        assert grey.std() > 2
    assert kept >= 1 and sides == {"left", "right"}           # images 0-3 right eyes, 4 a left eye
