"""Persistent Blender render worker (pipeline/blender/render_worker.py) on a small synthetic head.

The fixture builds a small synthetic-head asset through the real stages (synthetic_head ->
... -> usd, ~10 s at 100k triangles / 256 px maps, in a temp folder; nothing from ``dvc
repro`` is used), starts ONE worker and feeds it hand-made specs (frontal orthographic camera
at an eye, gaze from quaternions, lids from the rig's pitch rule). Expected landmarks are
computed here independently of Blender: eyelid points from the rig's shapes on the snap mesh
(numpy), iris/pupil points from the eyeball USD (pxr) posed by the skeleton's bind transform
and the eye quaternion.
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

from pipeline.blender.lashes import LASH_POINTS, LASHES, lash_curves
from pipeline.blender.render_worker import REPLY_PREFIX, camera_to_head
from pipeline.render.camera import quat_to_matrix
from pipeline.io.rig_file import read_rig
from pipeline.rig import lids

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.blender
W, H = 120, 80

SMALL_PARAMS = {  # edits of params.yaml for a fast chain
    "target_triangles: 350000": "target_triangles: 100000",
    "texture_size: 2048": "texture_size: 256",
    "resolution: 2048 ": "resolution: 256 ",
    "metric_samples: 100000": "metric_samples: 5000",
    "metric_samples: 50000": "metric_samples: 5000",
    "usdz: true": "usdz: false",
    "resolution: high ": "resolution: low ",
    "iris_texture_px: 512": "iris_texture_px: 128",
    "sclera_texture_px: [1024, 512]": "sclera_texture_px: [128, 64]",
}


def build_small_synthetic_asset(root: Path) -> dict:
    """Run the chain synthetic_head -> usd with small parameters under ``root``; returns paths."""
    text = (ROOT / "params.yaml").read_text()
    for a, b in SMALL_PARAMS.items():
        text = text.replace(a, b)
    params = root / "params.yaml"
    params.write_text(text)
    b, ra = root / "build" / "s", root / "rigged_assets"
    steps = [["synthetic_head", root / "raw" / "s"],
             ["eyeball", ra / "eyeball"],
             ["ingest", root / "raw" / "s", b / "ingest"],
             ["remove_eyeballs", b / "ingest", b / "remove_eyeballs"],
             ["retopo", b / "remove_eyeballs", b / "retopo"],
             ["bake", b / "retopo", b / "remove_eyeballs", b / "bake"],
             ["snap", b / "bake", b / "remove_eyeballs", ra / "eyeball", b / "snap"],
             ["rig", b / "snap", b / "rig", "--eyeball", ra / "eyeball"],
             ["usd", b / "snap", b / "bake", b / "rig", b / "ingest", ra / "eyeball", ra / "s"]]
    for i, (stage, *args) in enumerate(steps):
        cmd = [sys.executable, "-m", f"stages.{stage}", *map(str, args),
               "--metrics", str(root / f"m{i}.json"), "--params", str(params)]
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, (stage, r.stderr[-2000:])
    return {"asset": ra / "s" / "s.usda", "rig": b / "rig", "snap": b / "snap"}


class Worker:
    def __init__(self, asset, rig_npz, *extra):
        self.p = subprocess.Popen([sys.executable, "-m", "pipeline.blender.render_worker", str(asset),
                                   str(rig_npz), "--threads", "2", *map(str, extra)], cwd=ROOT, stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.ready = self.read()

    def read(self) -> dict:
        for line in self.p.stdout:
            if line.startswith(REPLY_PREFIX):
                return json.loads(line[len(REPLY_PREFIX):])
        raise AssertionError(f"worker ended (exit {self.p.wait()})")

    def send(self, obj) -> dict:
        self.p.stdin.write((obj if isinstance(obj, str) else json.dumps(obj)) + "\n")
        self.p.stdin.flush()
        return self.read()

    def close(self) -> int:
        self.p.stdin.close()
        return self.p.wait(timeout=60)


def quat(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    h = math.radians(deg) / 2
    return np.array([math.cos(h), *(math.sin(h) * a)])


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


class Scene:
    """Independent (numpy + pxr) model of the asset: posed landmarks, camera matrices."""

    def __init__(self, paths):
        from pxr import Usd, UsdGeom, UsdSkel

        from pipeline.io.meshfile import load_mesh

        self.paths = paths
        rig = read_rig(paths["rig"])
        self.rig, self.shapes, self.eyes = rig.npz.arrays, rig.npz.shapes, rig.eyes
        self.V = load_mesh(paths["snap"] / "mesh.npz")["V"]
        stage = Usd.Stage.Open(str(paths["asset"]))
        self.inner = {}
        for side in ("left", "right"):
            prim = next(p for p in stage.Traverse() if p.GetName() == "Inner"
                        and f"eye_{side}" in str(p.GetPath()))
            # rigid skinning at the rest pose: row vectors, p_head = [p, 1] @ geomBindTransform
            B = np.array(UsdSkel.BindingAPI(prim).GetGeomBindTransformAttr().Get())
            P = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(), float)
            binding = UsdSkel.BindingAPI(prim)
            names = [str(n) for n in binding.GetBlendShapesAttr().Get()]
            targets = binding.GetBlendShapeTargetsRel().GetTargets()
            offs = {}
            for n, t in zip(names, targets):
                bs = UsdSkel.BlendShape(stage.GetPrimAtPath(t))
                off = np.zeros_like(P)
                idx = bs.GetPointIndicesAttr().Get()
                o = np.array(bs.GetOffsetsAttr().Get(), float)
                if idx:
                    off[np.array(idx)] = o
                else:
                    off[:] = o
                offs[n] = off
            ids = {k: np.array(prim.GetAttribute(f"eyerig:landmarks:{k}").Get(), int) for k in ("iris", "pupil")}
            self.inner[side] = (B, P, offs, ids)

    def landmarks(self, side, q, cw, blend) -> np.ndarray:
        """(28, 3) head mm: eyelid (posed mesh lerp), iris, pupil (posed Inner vertices)."""  # noqa: D401
        P = lids.evaluate_shapes(self.V, self.shapes, cw)
        e, t = self.rig[f"landmarks.{side}.edge"], self.rig[f"landmarks.{side}.t"]
        lid = (1 - t)[:, None] * P[e[:, 0]] + t[:, None] * P[e[:, 1]]
        B, Pin, offs, ids = self.inner[side]
        Q = Pin + sum(float(blend.get(k, 0.0)) * o for k, o in offs.items())
        Qh = Q @ B[:3, :3] + B[3, :3]
        c = self.eyes[side].center
        Qh = (Qh - c) @ quat_to_matrix(q).T + c
        return np.concatenate([lid, Qh[ids["iris"]], Qh[ids["pupil"]]])

    def spec(self, index, out_dir, side="left", pitch=0.0, yaw=0.0, cam_yaw=0.0, scale=32.0,
             blend=None, **kw) -> dict:
        e = self.eyes[side]
        c, f = e.center, e.forward
        cy = math.radians(cam_yaw)
        zc = np.array([math.sin(cy), 0.0, math.cos(cy)])
        xc = np.cross([0.0, 1.0, 0.0], zc)
        xc /= np.linalg.norm(xc)
        R = np.stack([xc, np.cross(zc, xc), zc])            # rows: camera axes in the head frame
        o = c + 12.0 * f + 30.0 * zc
        M = np.eye(4)
        M[:3, :3] = R
        M[:3, 3] = -R @ o
        q = qmul(quat([0, 1, 0], yaw), quat([-1, 0, 0], pitch))
        cw = lids.lid_weights(pitch)
        blend = blend or {}
        spec = {"index": index, "png": str(Path(out_dir) / f"{index:06d}.png"), "width": W, "height": H,
                "samples": 4, "denoise": False, "cycles_seed": index, "eye": side,
                "camera": {"world_to_camera": M.tolist(), "ortho_scale_mm": scale},
                "eye_rotation": {"left": q.tolist(), "right": q.tolist()}, "lid_weights": cw,
                "eyeball": {"iris_color": "blue", "sclera_tint": "white", "veins": "clear", "blend": blend},
                "lighting": {"hdri": "forest.exr", "rotation_deg": 0.0, "strength": 1.0},
                "skin_detail": "bump",
                "landmarks_head_mm": self.landmarks(side, q, cw, blend).tolist()}
        spec.update(kw)
        return spec


def project(spec, P):
    """Head mm -> pixel (u, v) with the render design's orthographic rule."""
    M = np.asarray(spec["camera"]["world_to_camera"])
    pc = P @ M[:3, :3].T + M[:3, 3]
    ow = spec["camera"]["ortho_scale_mm"]
    oh = ow * spec["height"] / spec["width"]
    return np.stack([(pc[:, 0] / ow + 0.5) * spec["width"], (0.5 - pc[:, 1] / oh) * spec["height"]], 1)


def luminance(png) -> np.ndarray:
    a = np.asarray(Image.open(png).convert("RGB"), np.float64)
    return a @ [0.2126, 0.7152, 0.0722]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("render_worker")
    paths = build_small_synthetic_asset(root)
    scene = Scene(paths)
    out = root / "renders"
    out.mkdir()
    w = Worker(paths["asset"], paths["rig"] / "rig.npz")
    assert w.ready["ready"] is True, w.ready
    yield scene, w, out
    assert w.close() == 0


EXTREMES = {"rest": {}, "up": {"pitch": 25.0}, "down": {"pitch": -25.0}, "left": {"yaw": 35.0},
            "right": {"yaw": -35.0}, "dilated": {"blend": {"pupil_dilate": 1.0, "iris_small": 1.0}},
            "constricted": {"blend": {"pupil_constrict": 1.0, "iris_large": 1.0}},
            "up_left_right_eye": {"pitch": 25.0, "yaw": 35.0, "side": "right", "cam_yaw": -20.0}}


@pytest.fixture(scope="module")
def extremes(setup):
    scene, w, out = setup
    res = {}
    for i, (name, kw) in enumerate(EXTREMES.items()):
        spec = scene.spec(i, out, **kw)
        res[name] = (spec, w.send(spec))
    return res


def test_extremes_render_lit_images_with_matching_landmarks(extremes):
    for name, (spec, rep) in extremes.items():
        assert rep["ok"] is True and rep["index"] == spec["index"], (name, rep)
        img = Image.open(spec["png"])
        assert img.size == (W, H) and img.mode == "RGB"
        lum = luminance(spec["png"])
        assert lum.mean() > 25 and lum.std() > 8, name          # not black, not blank
        assert rep["landmark_check_mm"] < 0.01, (name, rep["landmark_check_mm"])
        assert rep["render_s"] > 0 and rep["rss_mib"] > 50
        assert not list(Path(spec["png"]).parent.glob(".*tmp*"))   # temp file renamed into place


def test_pupil_is_dark_where_the_labels_put_it(extremes):
    for name, (spec, rep) in extremes.items():
        lum = luminance(spec["png"])
        uv = project(spec, np.asarray(spec["landmarks_head_mm"]))
        pupil = uv[20:].mean(0)
        iris_r = np.linalg.norm(uv[12:20] - uv[12:20].mean(0), axis=1).mean()
        u, v = int(pupil[0]), int(pupil[1])
        assert 0 <= u < W and 0 <= v < H, name
        # 3 x 3 median: at 4 samples undenoised a single pixel can hold a firefly of the
        # cornea's highlight (up to 255 in an otherwise 0-13 pupil); the pupil is ~15 px wide
        centre = np.median(lum[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2])
        # sclera/skin ring well outside the iris
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        ring = [lum[int(np.clip(pupil[1] + 1.6 * iris_r * np.sin(a), 0, H - 1)),
                    int(np.clip(pupil[0] + 1.6 * iris_r * np.cos(a), 0, W - 1))] for a in ang]
        assert centre < 0.5 * np.median(ring), (name, centre, np.median(ring))


def test_gaze_and_lids_move_the_right_way(extremes):
    uv = {n: project(s, np.asarray(s["landmarks_head_mm"])) for n, (s, _) in extremes.items()}
    pupil = {n: p[20:].mean(0) for n, p in uv.items()}
    assert pupil["left"][0] > pupil["rest"][0] + 10        # yaw toward the subject's left = image right
    assert pupil["right"][0] < pupil["rest"][0] - 10
    assert pupil["up"][1] < pupil["rest"][1] - 5           # looking up = image up (v decreases)
    assert pupil["down"][1] > pupil["rest"][1] + 5
    # upper-lid landmark 3 (mid upper lid) rises when looking up, drops when looking down
    assert uv["up"][3, 1] < uv["rest"][3, 1] - 1 and uv["down"][3, 1] > uv["rest"][3, 1] + 1
    # pupil size blend shapes
    r = {n: np.linalg.norm(p[20:] - p[20:].mean(0), axis=1).mean() for n, p in uv.items()}
    assert r["dilated"] > 1.5 * r["rest"] > 1.5 * r["constricted"]
    # the pictures differ where the scene moved
    lum = {n: luminance(s["png"]) for n, (s, _) in extremes.items()}
    assert np.abs(lum["up"] - lum["down"]).mean() > 5


def test_lashes_are_visible_and_follow_the_lid(setup):
    scene, w, out = setup
    a = scene.spec(100, out, samples=8)
    b = scene.spec(101, out, samples=8, lashes=False)
    assert w.send(a)["ok"] and w.send(b)["ok"]
    la, lb = luminance(a["png"]), luminance(b["png"])
    uv = project(a, np.asarray(a["landmarks_head_mm"]))
    top = int(uv[1:6, 1].min())                              # above the upper lid
    assert top > 5
    dark = (lb - la)[:top].mean()
    assert dark > 4, dark                                    # lashes darken the band above the lid
    # lash roots follow the posed margin: compare lash geometry for lids up vs down
    rng = {k: np.random.default_rng(0).random((v["count"], 4)) for k, v in LASHES.items()}
    n_up = LASHES["upper"]["count"]
    loop = scene.rig["loop_left"]
    li = int(np.flatnonzero(loop == scene.rig["landmarks.left.edge"][6, 0])[0])
    f = scene.eyes["left"].forward
    for pitch in (-25.0, 25.0):
        P = lids.evaluate_shapes(scene.V, scene.shapes, lids.lid_weights(pitch))[loop]
        pts, rad = lash_curves(P, li, f, rng)
        roots = pts[::LASH_POINTS]
        d = np.min(np.linalg.norm(roots[:, None] - P[None], axis=2), axis=1)
        assert d.max() < 1.5                                 # every root within 1.5 mm of the posed margin
        assert rad[0] > rad[LASH_POINTS - 1] > 0
        up_tips = pts[LASH_POINTS - 1::LASH_POINTS][:n_up]
        assert np.all(np.linalg.norm(up_tips - roots[:n_up], axis=1) > 2.0)
        assert np.all(up_tips[:, 1] > roots[:n_up, 1])      # upper lashes curl upward (head +Y)


def test_lighting_rotation_and_strength(setup):
    scene, w, out = setup
    base = scene.spec(200, out)
    dim = scene.spec(201, out, lighting={"hdri": "forest.exr", "rotation_deg": 0.0, "strength": 0.5})
    turned = scene.spec(202, out, lighting={"hdri": "forest.exr", "rotation_deg": 180.0, "strength": 1.0})
    for s in (base, dim, turned):
        rep = w.send(s)
        assert rep["ok"] and rep["landmark_check_mm"] < 0.01, rep
    lb, l2, lt = (luminance(s["png"]) for s in (base, dim, turned))
    assert lb.mean() > 1.25 * l2.mean()          # sRGB of half the light
    assert np.abs(lt - lb).mean() > 3


def test_bad_specs_get_ok_false_and_the_worker_carries_on(setup):
    scene, w, out = setup
    good = scene.spec(300, out)
    cases = {
        "not json": "{nope",
        "missing camera": {k: v for k, v in good.items() if k != "camera"},
        "bad iris": {**good, "eyeball": {**good["eyeball"], "iris_color": "purple"}},
        "non-rigid camera": {**good, "camera": {"world_to_camera": (2 * np.eye(4)).tolist(),
                                                "ortho_scale_mm": 32.0}},
        "zero quaternion": {**good, "eye_rotation": {"left": [0, 0, 0, 0], "right": [1, 0, 0, 0]}},
        "unknown hdri": {**good, "lighting": {"hdri": "mars.exr", "rotation_deg": 0, "strength": 1}},
        "path escape": {**good, "lighting": {"hdri": "../x.exr", "rotation_deg": 0, "strength": 1}},
        "bad detail": {**good, "skin_detail": "fur"},
        "relative png": {**good, "png": "x.png"},
        "landmarks shape": {**good, "landmarks_head_mm": [[0, 0, 0]]},
        "lid weight > 1": {**good, "lid_weights": {"lids_up": 1.5, "lids_down": 0.0}},
        "bad denoiser": {**good, "denoiser": "optix"},
    }
    for name, spec in cases.items():
        rep = w.send(spec)
        assert rep["ok"] is False and rep["error"], name
        if isinstance(spec, dict):
            assert rep["index"] == 300, name
    assert "purple" in w.send(cases["bad iris"])["error"]
    rep = w.send(good)
    assert rep["ok"] is True and rep["landmark_check_mm"] < 0.01
    assert Path(good["png"]).is_file()
    # a spec whose landmarks are wrong still renders; the check reports the error
    moved = {**good, "index": 301, "png": str(out / "000301.png"),
             "landmarks_head_mm": (np.asarray(good["landmarks_head_mm"]) + [0, 0.5, 0]).tolist()}
    assert w.send(moved)["landmark_check_mm"] == pytest.approx(0.5, abs=0.01)


def test_benchmark_keys_apply_to_one_image_only(setup):
    """``cycles`` overrides and ``skin_subdivision`` (bench_render_split / bench_render_curves)
    change that image and are undone on the next one."""
    scene, w, out = setup
    specs = [scene.spec(500 + k, out, **kw) for k, kw in enumerate(
        [{"skin_subdivision": 0}, {"cycles": {"sampling_pattern": "TABULATED_SOBOL"}, "skin_subdivision": 1},
         {"skin_subdivision": 0}])]
    for s in specs:
        s["cycles_seed"] = 7                                 # same samples: pixels depend on the settings only
    reps = [w.send(s) for s in specs]
    assert all(r["ok"] for r in reps), reps
    # the subdivided skin is smoothed, so its margin moves off the labels: benchmarks only
    assert reps[0]["landmark_check_mm"] < 0.01 and reps[2]["landmark_check_mm"] < 0.01
    assert reps[1]["landmark_check_mm"] > 0.01
    a, b, c = (np.asarray(Image.open(s["png"]), np.int16) for s in specs)
    assert np.array_equal(a, c)                              # defaults back after the override
    assert np.abs(a - b).mean() > 0.5
    p0, p1, p2 = (r["skin_polygons"] for r in reps)
    assert p0 == p2 and 3 * p0 <= p1 <= 4 * p0               # an n-gon becomes n quads
    assert "skin_polygons" not in w.send(scene.spec(503, out))
    assert "outside 0..3" in w.send(scene.spec(504, out, skin_subdivision=5))["error"]


def _pixels(spec) -> np.ndarray:
    return np.asarray(Image.open(spec["png"]).convert("RGB"), np.int16)


def test_worker_film_and_denoiser_give_blenders_pixels(setup):
    """The worker's own film (passes -> Standard view -> PNG) and OIDN filters against Blender's
    PNG and Cycles' denoiser on the same render (same seed): with Cycles' filters (the normal
    prefilter at HIGH, ``denoise_normal_quality``) the denoised floats are Cycles'
    (pipeline/blender/oidn.py), so the only difference left is Blender's +-1 level dither; the
    default's small normal network changes the image by about a level."""
    scene, w, out = setup
    assert w.ready["denoiser"] == "worker"
    light = {"hdri": "forest.exr", "rotation_deg": 40.0, "strength": 1.4}    # exposure log2(1.4) stops
    for k, denoise in enumerate((False, True)):
        ours, blender = (scene.spec(600 + 2 * k + j, out, denoise=denoise, denoiser=d, cycles_seed=11,
                                    lighting=light, **({"denoise_normal_quality": "HIGH"} if d == "worker" else {}))
                         for j, d in enumerate(("worker", "cycles")))
        r_ours, r_blender = w.send(ours), w.send(blender)
        assert r_ours["ok"] and r_blender["ok"], (r_ours, r_blender)
        assert r_ours["denoiser"] == ("worker" if denoise else None)
        assert r_blender["denoiser"] == ("cycles" if denoise else None)
        assert (r_ours["denoise_cpu_s"] > 0) == denoise
        a, b = _pixels(ours), _pixels(blender)
        assert np.abs(a - b).max() <= 1, denoise
        assert abs(float((a - b).mean())) < 0.05, denoise       # dither: no bias
        assert a.mean() > 20
        default = scene.spec(610 + k, out, denoise=denoise, cycles_seed=11, lighting=light)
        assert w.send(default)["ok"]
        c = _pixels(default)
        assert (np.abs(c - a).max() == 0) == (not denoise)
        assert np.abs(c - a).mean() < 1.0                  # measured: 0.28 level, at most 7
    # and the denoiser did denoise: the 4-spp image is smoother than the undenoised one
    grad = [np.abs(np.diff(luminance(scene.spec(600 + i, out)["png"]), axis=1)).mean() for i in (0, 2)]
    assert grad[1] < 0.8 * grad[0], grad


def test_without_the_oidn_library_cycles_denoises(setup, tmp_path):
    scene, _, out = setup
    missing = tmp_path / "libOpenImageDenoise.so.2"
    w2 = Worker(scene.paths["asset"], scene.paths["rig"] / "rig.npz", "--oidn-library", missing)
    try:
        assert w2.ready["ready"] is True and w2.ready["denoiser"] == "cycles", w2.ready
        specs = [scene.spec(700 + i, out, cycles_seed=5, **kw) for i, kw in enumerate(
            [{"denoise": False}, {"denoise": True}, {"denoise": True, "denoiser": "cycles"}])]
        reps = [w2.send(s) for s in specs]
        assert all(r["ok"] for r in reps), reps
        assert [r["denoiser"] for r in reps] == [None, "cycles", "cycles"]
        assert all(r["denoise_cpu_s"] == 0 for r in reps)
        noisy, fallback, cycles = (_pixels(s) for s in specs)
        assert np.array_equal(fallback, cycles)           # the fallback is Cycles' denoiser, Blender's PNG
        grad = [np.abs(np.diff(luminance(s["png"]), axis=1)).mean() for s in specs[:2]]
        assert grad[1] < 0.8 * grad[0], grad              # and it denoised
    finally:
        assert w2.close() == 0


def test_hdri_switches_keep_the_worker_going(setup):
    scene, w, out = setup
    reps = []
    for i, hdri in enumerate(["city.exr", "city.exr", "studio.exr", "city.exr"]):
        s = scene.spec(400 + i, out, lighting={"hdri": hdri, "rotation_deg": 30.0 * i, "strength": 1.0},
                       skin_detail=("displacement", "bump", "none")[i % 3])
        reps.append(w.send(s))
        assert reps[-1]["ok"] is True, reps[-1]
        assert luminance(s["png"]).mean() > 20
    rss = [r["rss_mib"] for r in reps]
    assert max(rss) < 1.25 * min(rss)                        # old maps purged


def test_pure_helpers():
    q = quat([0, 1, 0], 90)
    assert np.allclose(quat_to_matrix(q) @ [0, 0, 1], [1, 0, 0])
    with pytest.raises(ValueError):
        quat_to_matrix([0, 0, 0, 0])
    M = np.eye(4)
    M[:3, :3] = quat_to_matrix(quat([1, 2, 3], 40))
    M[:3, 3] = [1, 2, 3]
    assert np.allclose(camera_to_head(M) @ M, np.eye(4))
    with pytest.raises(ValueError):
        camera_to_head(np.diag([1.0, 1.0, -1.0, 1.0]))      # reflection


def test_unloadable_asset_reports_not_ready(tmp_path):
    bad = tmp_path / "x.usda"
    bad.write_text("#usda 1.0\n")
    npz = tmp_path / "rig.npz"
    np.savez(npz, a=np.zeros(1))
    w = Worker(bad, npz)
    assert w.ready["ready"] is False and w.ready["error"]
    assert w.p.wait(timeout=60) == 2
