"""Masks, depth maps and landmark visibility (render.masks): pipeline/render/seg.py, visibility.py,
pipeline/io/seg_file.py and the render worker's passes (pipeline/blender/seg_passes.py).

Pure parts are tested on constructed arrays. The Blender tests render a few 120 x 80 images of the
small synthetic-head asset (built through the real stages, as in test_render_worker) with specs
from the render stage's own sampling: the apparent pupil landmarks lie on the pupil mask's
boundary within 1 px, the classes and depth are plausible, the image is the same with and without
the passes, a posed lid covers known landmarks and a tight framing pushes landmarks outside.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from pipeline.errors import ScanError
from pipeline.io import seg_file as sf
from pipeline.io.seg_file import read_depth, read_seg, write_depth, write_seg
from pipeline.render import seg as sg
from pipeline.render import visibility as vis

W, H = 120, 80


# ------------------------------------------------------------------------------- pure Python

def test_seg_png_round_trip_with_palette(tmp_path):
    seg = np.arange(7, dtype=np.uint8)[np.arange(W * H).reshape(H, W) % 7]
    write_seg(tmp_path / "a.png", seg)
    with Image.open(tmp_path / "a.png") as im:
        assert im.mode == "P" and im.getpalette()[:21] == sf.palette()[:21]
    np.testing.assert_array_equal(read_seg(tmp_path / "a.png", (W, H)), seg)
    write_seg(tmp_path / "b.png", seg)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    Image.fromarray(seg).save(tmp_path / "grey.png")                       # not indexed
    other = Image.fromarray(seg, "P")
    other.putpalette([255 - v for v in sf.palette()])
    other.save(tmp_path / "pal.png")
    for name, size, words in (("grey.png", None, "indexed"), ("pal.png", None, "palette"),
                              ("a.png", (W, H + 1), "px"), ("none.png", None, "not found")):
        with pytest.raises(ScanError, match=words):
            read_seg(tmp_path / name, size)
    with pytest.raises(ValueError):
        write_seg(tmp_path / "c.png", seg + 7)


def test_depth_exr_round_trip(tmp_path):
    d = np.linspace(150, 250, W * H, dtype=np.float32).reshape(H, W)
    d[0, 0] = np.inf
    write_depth(tmp_path / "d.exr", d)
    np.testing.assert_array_equal(read_depth(tmp_path / "d.exr", (W, H)), d)
    with pytest.raises(ValueError):
        write_depth(tmp_path / "e.exr", np.full((2, 2), np.nan))
    (tmp_path / "bad.exr").write_bytes(b"nope")
    with pytest.raises(ScanError, match="depth EXR"):
        read_depth(tmp_path / "bad.exr")


def test_classes_from_coverage_majority_and_background():
    z = np.zeros((1, 4))
    cov = {sf.SKIN: np.array([[0.6, 0.2, 0.0, 0.3]]), sf.IRIS: np.array([[0.4, 0.7, 0.3, 0.3]]),
           sf.PUPIL: z}
    np.testing.assert_array_equal(sg.classes_from_coverage(cov), [[sf.SKIN, sf.IRIS, sf.BACKGROUND, sf.SKIN]])
    assert sf.classes_text().startswith("0 background, 1 skin, 2 sclera, 3 iris, 4 pupil, 5 eyelashes, 6 caruncle")


def test_depth_from_cycles_z():
    z = np.array([[0.25 + 0.2, 1e10]])
    np.testing.assert_allclose(sg.depth_mm_from_z(z, 0.001, 0.25), [[200.0, np.inf]])


def _scene():
    """Left half skin (lid, 195 mm), right half sclera (200 mm), a pupil disc, lashes in a band."""
    seg = np.full((H, W), sf.SCLERA, np.uint8)
    seg[:, :60] = sf.SKIN
    depth = np.full((H, W), 200.0)
    depth[:, :60] = 195.0
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    seg[(xx - 90) ** 2 + (yy - 40) ** 2 < 10 ** 2] = sf.PUPIL
    seg[:5, 60:] = sf.LASHES
    depth[:5, 60:] = 190.0
    return seg, depth


def test_visibility_rule_on_a_constructed_scene():
    seg, depth = _scene()
    px = np.full((28, 2), [90.0, 40.0])
    dz = np.full(28, 200.0)
    px[0] = [60.0, 40.0]                  # on the skin / sclera seam, at the sclera's depth: visible
    px[1] = [30.0, 40.0]                  # behind the lid skin (5 mm nearer): lid
    px[2] = [-1.0, 40.0]                  # left of the image
    px[3] = [90.0, 2.0]                   # under the lashes
    px[4] = [60.0, 40.0]
    dz[4] = 190.0                         # on the seam but in front of the sclera: skin beside it at 195
    px[20] = [100.0, 40.0]                # on the pupil boundary: visible
    px[21] = [20.0, 40.0]                 # pupil landmark behind the lid
    app = [None] * 8 + [[100.0, 40.0], [20.0, 40.0]] + [None] * 6
    v = vis.landmark_visibility(px, app, dz, seg, depth, mm_per_px=0.25)
    assert v["visible"][0] and v["occlusion"][0] is None
    assert v["occlusion"][1:4] == ["lid", "outside", "lashes"]
    assert v["visible"][4]
    assert v["visible"][20] and v["occlusion"][21] == "lid"
    assert v["occlusion"][12] == "eye"     # an iris landmark amid the pupil: not on its own surface
    assert vis.boundary_distance_px([100.0, 40.0], seg == sf.PUPIL) < 1.0
    assert vis.boundary_distance_px([90.0, 40.0], seg == sf.PUPIL) > 9.0


def test_labels_reader_checks_visibility(tmp_path):
    import json

    from pipeline.io.labels_file import read_label, write_label

    lab = {"index": 0, "image": {"width": W, "height": H}, "gaze": {"eye": "left", "vector_camera": [0, 0, 1],
                                                                     "camera": {"pitch_deg": 0, "yaw_deg": 0}},
           "seed": {"attempts": 1}, "lighting": {"hdri": "a.exr"}, "render": {"skin_detail": "bump"},
           "camera": {"projection": np.zeros((3, 4)).tolist(), "world_to_camera": np.eye(4).tolist()},
           "landmarks": {k: np.zeros((28, n)).tolist() for k, n in (("px", 2), ("camera_mm", 3), ("head_mm", 3))}}
    write_label(tmp_path / "000000.json", lab)
    assert read_label(tmp_path / "000000.json").visible is None            # labels without masks still read
    write_seg(tmp_path / "000000_seg.png", np.zeros((H, W), np.uint8))
    write_depth(tmp_path / "000000_depth.exr", np.full((H, W), np.inf, np.float32))
    vis28 = [True] * 27 + [False]
    good = {**lab, "seg": {"file": "000000_seg.png"}, "depth": {"file": "000000_depth.exr"},
            "landmarks": {**lab["landmarks"], "visible": vis28, "occlusion": [None] * 27 + ["lid"]}}
    write_label(tmp_path / "000000.json", good)
    got = read_label(tmp_path / "000000.json")
    assert got.visible.tolist() == vis28 and got.occlusion[-1] == "lid"
    for bad, words in (({"occlusion": [None] * 28}, "occlusion"), ({"visible": [1] * 28}, "visible"),
                       ({"occlusion": [None] * 27 + ["hair"]}, "occlusion")):
        doc = json.loads(json.dumps(good))
        doc["landmarks"].update(bad)
        write_label(tmp_path / "000000.json", doc)
        with pytest.raises(ScanError, match=words):
            read_label(tmp_path / "000000.json")
    doc = json.loads(json.dumps(good))
    doc["seg"]["file"] = "../x.png"
    write_label(tmp_path / "000000.json", doc)
    with pytest.raises(ScanError, match="seg.file"):
        read_label(tmp_path / "000000.json")


# ------------------------------------------------------------------------------- Blender

@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from test_render_worker import Worker, build_small_synthetic_asset

    from pipeline.render.asset import load_render_asset
    from pipeline.render.settings import RenderSettings

    root = tmp_path_factory.mktemp("masks")
    paths = build_small_synthetic_asset(root)
    asset = load_render_asset(paths["asset"].parent, paths["rig"])
    # partial crops on purpose (the tight framing pushes the canthi out): no framing margin
    s = RenderSettings.from_params({"width": W, "height": H, "samples": 4, "denoise": False, "frame_margin_px": None})
    out = root / "out"
    out.mkdir()
    w = Worker(paths["asset"], paths["rig"] / "rig.npz")
    assert w.ready["ready"] is True, w.ready
    done = {}

    def render(name, index, overrides=None, masks=True, reject=True):
        from pipeline.render import labels as lb
        from pipeline.render import shard as sh
        from pipeline.render.sampling import make_sample

        smp = make_sample(asset, s, index, out / f"{name}.png", overrides, reject=reject)
        spec = smp.spec.to_dict()
        if masks:
            spec.update(seg_png=str(out / f"{name}_seg.png"), depth_exr=str(out / f"{name}_depth.exr"))
        rep = w.send(spec)
        assert rep["ok"] is True, rep
        app = sh.apparent_landmarks(lb.apparent_job(smp, asset.eyes[smp.side], s))["apparent_px"]
        r = {"smp": smp, "reply": rep, "png": out / f"{name}.png", "apparent": app}
        if masks:
            r["seg"] = read_seg(spec["seg_png"], (W, H))
            r["depth"] = read_depth(spec["depth_exr"], (W, H))
            r["vis"] = vis.landmark_visibility(smp.landmarks_px, app, -smp.landmarks_cam[:, 2], r["seg"],
                                               r["depth"], smp.camera["mm_per_px"])
        done[name] = r
        return r

    # 34 mm wide: the synthetic head's opening is ~30 mm corner to corner (issue 14), so a 30 mm
    # frame cut a canthus off
    front = {"polar_deg": 0.0, "azimuth_deg": 0.0, "jitter": np.zeros(2), "ortho_scale_mm": 34.0,
             "gaze_pitch_deg": 0.0, "gaze_yaw_deg": 0.0}
    render("random", 0)
    render("front", 1, front)
    render("front_plain", 1, front, masks=False)            # the same sample without the passes
    # iris_large: with the human iris (issue 14) the lid of this head covers the large iris's top
    render("down", 2, {**front, "gaze_pitch_deg": -25.0, "iris": 1.0}, reject=False)
    render("tight", 3, {**front, "ortho_scale_mm": 12.0})
    yield done
    assert w.close() == 0


@pytest.mark.blender
def test_masks_and_depth_come_from_the_same_render(rendered):
    a, b = rendered["front"], rendered["front_plain"]
    np.testing.assert_array_equal(np.asarray(Image.open(a["png"])), np.asarray(Image.open(b["png"])))
    assert b["reply"]["passes_s"] == 0.0 and a["reply"]["passes_s"] > 0
    for name in ("front", "random"):
        r = rendered[name]
        seg, depth = r["seg"], r["depth"]
        present = set(np.unique(seg).tolist())
        assert {sf.SKIN, sf.SCLERA, sf.IRIS, sf.PUPIL} <= present, (name, present)
        smp = r["smp"]
        dist = smp.camera["distance_mm"]
        fin = seg != sf.BACKGROUND
        assert np.all(np.isfinite(depth[fin]))
        assert dist - 60 < depth[fin].min() and depth[fin].max() < dist + 30       # camera mm, plausible
        # depth at the visible eyelid landmarks = their own camera depth (the eyeball beside the seam)
        for k in range(12):
            if r["vis"]["visible"][k]:
                u, v = np.clip(smp.landmarks_px[k].astype(int), 0, [W - 1, H - 1])
                near = depth[max(0, v - 1):v + 2, max(0, u - 1):u + 2]
                assert np.min(np.abs(near - (-smp.landmarks_cam[k, 2]))) < 1.5, (name, k)
    # the pupil is dark in the image where the mask says pupil
    lum = np.asarray(Image.open(a["png"]).convert("L"), float)
    assert lum[a["seg"] == sf.PUPIL].mean() < 0.5 * lum[a["seg"] == sf.SCLERA].mean()


@pytest.mark.blender
def test_apparent_pupil_landmarks_lie_on_the_pupil_mask_boundary(rendered):
    n = 0
    for name in ("front", "random", "down"):
        r = rendered[name]
        pupil = r["seg"] == sf.PUPIL
        for j in range(8):
            q = r["apparent"][8 + j]
            if q is None or not r["vis"]["visible"][20 + j]:
                continue
            d = vis.boundary_distance_px(q, pupil)
            assert d <= 1.0, (name, j, d)
            n += 1
    assert n >= 16


def _polygon_distance(q, poly) -> float:
    """Distance from point ``q`` to the closed polygon ``poly`` (n, 2)."""
    a = np.asarray(poly, float)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", np.asarray(q) - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0, 1)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - np.asarray(q), axis=1)))


@pytest.mark.blender
def test_visibility_on_a_posed_lid(rendered):
    from pipeline.render.camera import point_in_polygon

    front = rendered["front"]
    assert all(front["vis"]["visible"][:12]), front["vis"]["occlusion"][:12]   # the visible margin
    r = rendered["down"]
    smp, v = r["smp"], r["vis"]
    poly = smp.lid_polygon_px                       # the posed lid opening, projected
    covered = 0
    for k in range(12, 28):
        q = r["apparent"][k - 12]
        if q is None or not (2 <= q[0] < W - 2 and 2 <= q[1] < H - 2):
            continue
        if _polygon_distance(q, poly) < 2.5:                              # too close to the lid margin to call
            continue
        inside = point_in_polygon(q, poly)
        assert v["visible"][k] == inside, (k, q, v["occlusion"][k])
        if not inside:
            assert v["occlusion"][k] == "lid"
            covered += 1
    assert covered >= 1                             # looking down, the upper lid covers the iris top


@pytest.mark.blender
def test_landmarks_outside_the_image(rendered):
    r = rendered["tight"]
    px = r["smp"].landmarks_px
    for k in range(12):
        out = not (0 <= px[k, 0] < W and 0 <= px[k, 1] < H)
        assert (r["vis"]["occlusion"][k] == "outside") == out, k
    assert r["vis"]["occlusion"][0] == "outside" and r["vis"]["occlusion"][6] == "outside"   # both canthi


def test_contact_sheet_shows_the_mask_and_marks_visibility(tmp_path):
    from PIL import Image

    from pipeline.io.seg_file import write_seg
    from pipeline.render.sheet import CAPTION_H, contact_sheet

    w, h, scale = 40, 30, 2
    Image.new("RGB", (w, h), (90, 90, 90)).save(tmp_path / "000000.png")
    seg = np.ones((h, w), np.uint8)                      # skin everywhere
    write_seg(tmp_path / "000000_seg.png", seg)
    px = [[2.0 + (k % 7) * 5, 3.0 + (k // 7) * 6] for k in range(28)]      # 5 px apart
    visible = [k != 3 for k in range(28)]
    label = {"index": 0, "seg": {"file": "000000_seg.png"},
             "gaze": {"eye": "left", "camera": {"pitch_deg": 0.0, "yaw_deg": 0.0}, "vector_camera": [0, 0, 1]},
             "landmarks": {"px": px, "apparent_px": None, "pupil_center_px": [20.0, 15.0],
                           "visible": visible, "occlusion": [None if v else "lid" for v in visible]}}
    W, H = contact_sheet([(tmp_path / "000000.png", label)], tmp_path / "sheet.png", scale=scale)
    sheet = np.asarray(Image.open(tmp_path / "sheet.png").convert("RGB")).astype(int)
    assert W >= 2 * w * scale                            # the mask panel beside the image
    x0 = 4 + w * scale + 4                               # PAD, tile, PAD: the mask panel's left edge
    y0 = 4 + CAPTION_H                                   # PAD + caption
    vis = sheet[y0 + 3 * scale, x0 + 17 * scale]         # landmark 3 at (17, 3) px: occluded, a red cross
    ok = sheet[y0 + 15 * scale, x0 + 7 * scale]          # landmark 15 at (7, 15) px: visible, a white dot
    assert vis[0] > 200 and vis[1] < 80 and ok.min() > 200
