"""The corner model in a rendered mask (issue 21: "no see-through gap at the canthi").

The small synthetic head is built through the real stages (as in test_render_worker); its baked
eye region then gets both medial corners lifted 4 mm off the globe (as a real medial fissure end,
past the caruncle, lies 3-7 mm off it), and snap -> rig -> usd run on that twice: with the corner
strips (default) and without them (``snap.close_corners: false``). The render worker renders the
masks of the left eye looking across the opening into its medial canthus from the temple side,
framed on it, at rest and with the eye turned to the anatomical limits (the lids following its
pitch). With the strip
no pixel near the canthus is background and the caruncle shows; without it the gap lets the
background through, which is what the test would catch.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.io.eyes_file import read_eyes
from pipeline.io.meshfile import load_mesh, save_mesh
from pipeline.render import seg as sg

ROOT = Path(__file__).resolve().parents[1]
W = H = 64
POSES = {"rest": (0.0, 0.0), "up": (25.0, 0.0), "down": (-25.0, 0.0), "in": (0.0, -35.0),
         "out": (0.0, 35.0)}


def lift_medial_corners(mesh: dict, eyes: dict, lift_mm=4.0, reach_mm=5.0) -> dict:
    """The mesh with each medial canthus and the surface within ``reach_mm`` of it (edge-graph
    distance, smoothstep) moved ``lift_mm`` radially off its eye."""
    from scipy.sparse.csgraph import dijkstra

    from pipeline.snap.snap import edge_graph, smoothstep_falloff

    V = np.asarray(mesh["V"], float).copy()
    G = edge_graph(V, np.asarray(mesh["F"], np.int64))
    for s in ("left", "right"):
        c = eyes[s].center
        d = dijkstra(G, directed=False, indices=[int(mesh[f"loop_{s}"][0])], limit=reach_mm)[0]
        w = smoothstep_falloff(d, reach_mm)
        idx = np.flatnonzero(w > 0)
        r = V[idx] - c
        V[idx] += (lift_mm * w[idx])[:, None] * r / np.linalg.norm(r, axis=1)[:, None]
    return dict(mesh, V=V)


def _run(stage, *args, params):
    cmd = [sys.executable, "-m", f"stages.{stage}", *map(str, args), "--metrics",
           str(Path(args[-1]).with_suffix(".json")), "--params", str(params)]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (stage, r.stderr[-2000:])


@pytest.fixture(scope="module")
def corner_masks(tmp_path_factory):
    from test_render_worker import Worker, build_small_synthetic_asset

    from pipeline.render.asset import load_render_asset
    from pipeline.render.sampling import RenderSettings, make_sample

    root = tmp_path_factory.mktemp("corners")
    paths = build_small_synthetic_asset(root)
    b, ra = root / "build" / "s", root / "rigged_assets"
    eyes = read_eyes(b / "remove_eyeballs" / "eyes.json")
    lifted = b / "bake_lifted"
    lifted.mkdir()
    for f in (b / "bake").iterdir():
        if f.name != "mesh.npz":
            (lifted / f.name).write_bytes(f.read_bytes())
    save_mesh(lifted / "mesh.npz", **lift_medial_corners(load_mesh(b / "bake" / "mesh.npz"), eyes))
    out = {}
    for variant, close in (("strip", True), ("open", False)):
        params = root / f"params_{variant}.yaml"
        doc = yaml.safe_load((root / "params.yaml").read_text())
        doc["snap"]["close_corners"] = close
        params.write_text(yaml.safe_dump(doc))
        snap, rig, asset = b / f"snap_{variant}", b / f"rig_{variant}", ra / f"s_{variant}"
        _run("snap", lifted, b / "remove_eyeballs", ra / "eyeball", snap, params=params)
        _run("rig", snap, rig, "--eyeball", ra / "eyeball", params=params)
        _run("usd", snap, lifted, rig, b / "ingest", ra / "eyeball", asset, params=params)
        asset_dir = asset
        render_asset = load_render_asset(asset_dir, rig)
        s = RenderSettings.from_params({"width": W, "height": H, "samples": 1, "denoise": False})
        w = Worker(asset_dir / f"s_{variant}.usda", rig / "rig.npz")
        assert w.ready["ready"] is True, w.ready
        masks = {}
        for name, (pitch, yaw) in POSES.items():
            # the left eye seen from the temple side (30 deg), across the opening into its medial
            # corner, framed on the medial canthus (landmark 0): the view that looks past the
            # eyeball's medial rim into the gap (from the front the eyeball fills it)
            view = {"side": "left", "polar_deg": 30.0, "azimuth_deg": 0.0, "ortho_scale_mm": 10.0,
                    "jitter": np.zeros(2), "gaze_pitch_deg": pitch, "gaze_yaw_deg": yaw}
            smp = make_sample(render_asset, s, 0, root / "x.png", view, reject=False)
            view["jitter"] = np.asarray(smp.landmarks_cam[0][:2], float)
            png = root / f"{variant}_{name}.png"
            smp = make_sample(render_asset, s, 0, png, view, reject=False)
            spec = dict(smp.spec.to_dict(), seg_png=str(root / f"{variant}_{name}_seg.png"),
                        depth_exr=str(root / f"{variant}_{name}_depth.exr"))
            rep = w.send(spec)
            assert rep["ok"] is True, rep
            from pipeline.io.seg_file import read_seg
            masks[name] = (read_seg(spec["seg_png"], (W, H)), smp.landmarks_px[0])
        assert w.close() == 0
        out[variant] = masks
    return out


def _near(seg, px, radius_px):
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    return seg[(xx - px[0]) ** 2 + (yy - px[1]) ** 2 <= radius_px ** 2]


@pytest.mark.slow
@pytest.mark.blender
@pytest.mark.parametrize("pose", list(POSES))
def test_no_background_at_the_canthus_with_the_strip(corner_masks, pose):
    seg, px = corner_masks["strip"][pose]
    near = _near(seg, px, 0.3 * W)        # 3 mm around the medial canthus (10 mm frame)
    assert (near == sg.BACKGROUND).sum() == 0, (pose, np.bincount(near, minlength=7))
    assert (seg == sg.CARUNCLE).sum() > 0, pose


@pytest.mark.slow
@pytest.mark.blender
def test_without_the_strip_the_gap_shows(corner_masks):
    holes = sum(int((_near(seg, px, 0.3 * W) == sg.BACKGROUND).sum())
                for seg, px in corner_masks["open"].values())
    assert holes > 0
