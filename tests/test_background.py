"""No background in renders: the coverage rasteriser (pipeline/render/coverage.py) and the sampler's
rejection of a camera that sees past the asset (pipeline/render/sampling.py make_sample).

Pure parts on constructed triangles with known answers: a square covering exactly part of an
image, shared edges that must not leave a gap, a thin gap that must be found, the inscribed
silhouettes of a sphere under both projections, the near-plane refusal. The sampler on the
tiny fixture asset (a 190 x 90 mm plane): a framing wider than the plane is redrawn, a framing no
camera can fill is refused with one line naming the asset and the preset. The Blender test
renders a few tiny images per preset the asset can fill and counts class-0 pixels: none.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fixtures import make_render_asset
from pipeline.render import asset as ra
from pipeline.render import coverage as cov
from pipeline.render import sampling as sp
from pipeline.render.camera import project
from pipeline.render.settings import RenderSettings

ROOT = Path(__file__).resolve().parents[1]


def _square(x0, x1, y0, y1):
    """(2, 3, 2) two triangles sharing the diagonal of an axis-aligned rectangle."""
    a, b, c, d = (x0, y0), (x1, y0), (x1, y1), (x0, y1)
    return np.array([[a, b, c], [a, c, d]], float)


# ------------------------------------------------------------------------------- rasteriser

def test_square_covering_part_of_the_image_leaves_the_rest_uncovered():
    # a 20 x 10 image; the square covers x < 8 (and overhangs the other three edges)
    tris = _square(-5.0, 8.0, -5.0, 15.0)
    x0, x1, y0, y1 = cov.frame_region(20, 10, margin_px=0.75)
    rows = np.arange(y0, y1 + 1e-9, 0.5)
    assert cov.uncovered_area(tris, x0, x1, y0, y1, step=0.5) == pytest.approx((x1 - 8.0) * len(rows) * 0.5)
    xs = np.arange(20) + 0.5
    ys = np.arange(10) + 0.5
    hit = cov.covered_points(tris, xs, ys)
    assert hit.shape == (10, 20)
    assert hit[:, xs < 8].all() and not hit[:, xs > 8].any()
    # the whole region covered, and nothing at all
    assert cov.uncovered_area(_square(-1, 21, -1, 11), x0, x1, y0, y1) == 0.0
    assert cov.uncovered_area(np.zeros((0, 3, 2)), x0, x1, y0, y1) == pytest.approx((x1 - x0) * len(rows) * 0.5)


def test_a_mesh_of_shared_edges_has_no_gap_and_a_thin_crack_is_found():
    # a 10 x 10 grid of squares, each as two triangles, over a 12 x 8 frame
    g = np.linspace(-3.0, 15.0, 11)
    h = np.linspace(-3.0, 11.0, 11)
    tris = np.concatenate([_square(g[i], g[i + 1], h[j], h[j + 1]) for i in range(10) for j in range(10)])
    x0, x1, y0, y1 = cov.frame_region(12, 8)
    assert cov.uncovered_area(tris, x0, x1, y0, y1) == 0.0
    # a vertical crack 0.2 px wide: found on every row
    crack = np.concatenate([_square(-3, 6.0, -3, 11), _square(6.2, 15, -3, 11)])
    rows = len(np.arange(y0, y1 + 1e-9, cov.ROW_STEP_PX))
    assert cov.uncovered_area(crack, x0, x1, y0, y1) == pytest.approx(0.2 * rows * cov.ROW_STEP_PX)
    # a triangle pointing into the frame from below leaves the rows above its apex uncovered
    tri = np.array([[[-2.0, 20.0], [14.0, 20.0], [6.0, 4.0]]])
    hit = cov.covered_points(tri, [6.0], np.arange(0.5, 8.0, 0.5))
    assert hit[:, 0].tolist() == [y >= 4.0 for y in np.arange(0.5, 8.0, 0.5)]


def test_sphere_silhouettes_are_inscribed_in_the_true_outline():
    r, n = 12.0, cov.SPHERE_SEGMENTS
    tris = cov.sphere_silhouette([3.0, -2.0, -100.0], r)
    assert tris.shape == (n, 3, 3)
    area = 0.5 * np.abs(np.cross(tris[:, 1, :2] - tris[:, 0, :2], tris[:, 2, :2] - tris[:, 0, :2])).sum()
    assert area == pytest.approx(0.5 * n * r * r * math.sin(2 * math.pi / n))
    assert np.allclose(np.linalg.norm(tris[:, 1, :2] - [3.0, -2.0], axis=1), r)
    # perspective: a sphere on the axis at distance d images as a circle of radius f r / sqrt(d^2 - r^2)
    d, f = 60.0, 500.0
    tris = cov.sphere_silhouette([0.0, 0.0, -d], r, perspective=True)
    P = tris[:, 1]
    uv = f * P[:, :2] / -P[:, 2:]
    assert np.allclose(np.linalg.norm(uv, axis=1), f * r / math.sqrt(d * d - r * r))
    assert np.allclose(np.linalg.norm(P - [0, 0, -d], axis=1), r)           # on the sphere
    assert len(cov.sphere_silhouette([0.0, 0.0, -5.0], r, perspective=True)) == 0   # camera inside


def test_triangles_behind_a_pinhole_are_refused():
    f, W, H = 100.0, 40, 30

    def pinhole(P):
        P = np.asarray(P, float)
        return np.stack([f * P[:, 0] / -P[:, 2] + W / 2, -f * P[:, 1] / -P[:, 2] + H / 2], 1)

    big = np.array([[[-1e3, -1e3, -50.0], [1e3, -1e3, -50.0], [0.0, 1e3, -50.0]]])
    assert cov.frame_uncovered(big, pinhole, W, H, near_mm=1.0) == 0.0
    straddling = big.copy()
    straddling[0, 2, 2] = 10.0                    # one corner behind the camera
    assert cov.frame_uncovered(straddling, pinhole, W, H, near_mm=1.0) > 0


# ------------------------------------------------------------------------------- sampler

@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    made = make_render_asset(tmp_path_factory.mktemp("background"))
    return {**made, "asset": ra.load_render_asset(made["asset_dir"], made["rig_dir"])}


def _settings(**kw):
    return RenderSettings.from_params({"width": 24, "height": 16, "frame_margin_px": None, **kw})


def test_asset_carries_its_skin_triangles(tiny):
    a = tiny["asset"]
    assert a.skin_faces.shape == (2 * 38 * 18, 3) and a.skin_faces.max() < len(a.skin_rest)


def test_a_camera_seeing_past_the_mesh_edge_is_redrawn(tiny):
    a = tiny["asset"]
    # the plane is 190 x 90 mm, the eyes 31-32 mm off centre: frames wider than ~126 mm see past it
    s = _settings(ortho_scale_mm=[30.0, 200.0])
    redrawn = 0
    for i in range(12):
        first = sp.pose_sample(a, s, i, 0, "/x.png")
        smp = sp.make_sample(a, s, i, "/x.png")
        assert cov.sample_uncovered(a, smp, s.width, s.height) == 0.0
        if sp.pupil_in_lids(first) and cov.sample_uncovered(a, first, s.width, s.height) > 0:
            redrawn += 1
            assert smp.attempts > 1 and smp.camera["ortho_scale_mm"] < 130.0
    assert redrawn >= 2
    # the same draws without the rule: the first attempt that passes the pupil test
    loose = sp.make_sample(a, s, 0, "/x.png", reject=False)
    assert loose.attempts == 1


def test_a_framing_no_camera_can_fill_is_refused_in_one_line(tiny):
    s = _settings(ortho_scale_mm=[300.0, 310.0], max_attempts=5)
    with pytest.raises(sp.RejectionError) as e:
        sp.make_sample(tiny["asset"], s, 0, "/x.png")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("tiny, preset generic: sample 0:") and "background" in msg
    # label studies that render nothing may keep only the pupil rule
    assert sp.make_sample(tiny["asset"], s, 0, "/x.png", cover=False).attempts <= 5


def test_visible_part_of_the_tiny_asset_agrees_with_the_rasteriser(tiny):
    """The coverage test sees what the labels see: every landmark of an accepted sample lies in
    a covered part of the frame (the skin or an eyeball silhouette)."""
    a = tiny["asset"]
    s = _settings()
    for i in range(4):
        smp = sp.make_sample(a, s, i, "/x.png")
        tris = cov.scene_triangles(a, smp.spec.lid_weights, smp.camera["world_to_camera"])
        P = project(tris.reshape(-1, 3), smp.camera["ortho_scale_mm"], s.width, s.height).reshape(-1, 3, 2)
        lm = smp.landmarks_px
        inside = (lm[:, 0] > 0) & (lm[:, 0] < s.width) & (lm[:, 1] > 0) & (lm[:, 1] < s.height)
        for u, v in lm[inside]:
            assert cov.covered_points(P, [u], [v])[0, 0]


# ------------------------------------------------------------------------------- Blender

SIZES = {"generic": (48, 32), "targeted": (48, 32), "unityeyes": (128, 96), "near_eye": (320, 240), "webcam": (80, 48)}


@pytest.mark.blender
@pytest.mark.slow
@pytest.mark.parametrize("preset", sorted(SIZES))
def test_rendered_images_have_no_background(tiny, tmp_path, preset):
    import yaml
    from PIL import Image

    out = tmp_path / "renders"
    params = tmp_path / "p.yaml"
    w, h = SIZES[preset]
    params.write_text(yaml.safe_dump({"render": {
        "preset": preset, "n_images": 3, "width": w, "height": h, "samples": 1, "denoise": False,
        "masks": True, "workers": 1, "shard_size": 3, "progress": False, "connect_timeout_s": 3,
        # the tiny asset's eye region is too small for a 3 px margin at 48 x 32: the framing is
        # test_framing's; this test is the background
        "frame_margin_px": None}}))
    r = subprocess.run([sys.executable, "-m", "stages.render", str(tiny["asset_dir"]), str(tiny["rig_dir"]),
                        str(out), "--metrics", str(tmp_path / "m.json"), "--params", str(params), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    segs = sorted(out.glob("*_seg.png"))
    assert len(segs) == 3
    for p in segs:
        seg = np.asarray(Image.open(p))
        assert seg.shape == (h, w) and int((seg == 0).sum()) == 0, p.name
    assert json.loads((tmp_path / "m.json").read_text())["n_images"] == 3
