"""Where a render stage image's time goes (issue 15): the split of one image, worker and stage side.

    .venv/bin/python -m benchmarks.bench_render_split [--scan synthetic_head] [--images 24]

One persistent Blender worker (``pipeline.render.shard.BlenderProcess``, the stage's thread
count) renders ``--images`` specs of the stage's own sampler (default params, masks on, the
first 2 dropped as warm-up). Every spec is rendered in each of these variants in turn (ABAB:
load drifts hit all variants alike):

* ``default``: the stage's image (samples + OpenImageDenoise, seg and depth passes);
* ``no_masks``, ``no_denoise``, ``no_denoise_no_masks``;
* ``one_spp`` (1 sample, no denoiser, no masks), ``one_spp_again`` (the same spec once more:
  nothing in the scene changed, so no scene sync or BVH update), ``one_spp_no_lashes``;
* ``light_tree`` / ``sobol``: the default with Cycles' light tree on / the Sobol pattern
  (the settings before issue 15);
* ``cycles_denoiser``: the default with Cycles' own denoiser and Blender's PNG writing instead
  of the worker's persistent OIDN filters and film (the way before; same pixels).

The worker reports per image the wall and CPU seconds of its phases (posing, eyelash rebuild
and landmark check, mask set-up, the render call, pass reading); the render call is split by
differences of medians: scene sync + BVH = one_spp - one_spp_again, the rest of the fixed
render cost = one_spp_again (with the worker's film: reading the passes back and writing the
PNG), path tracing = no_denoise_no_masks - one_spp, denoising = default - no_denoise (also
reported directly: the worker's OIDN call, ``denoise_cpu_s``), masks = default - no_masks. The stage side is measured in this process on the same
specs: sampling and label building (main process), the apparent iris (refraction), masks and
visibility, file writing (dask worker), plus one Blender start-up and one LocalCluster start.

Writes benchmarks/results/render_split.json and prints the table (CPU seconds are the robust
figure on a shared machine; wall seconds with the load average).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.io.atomic import write_json

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _strip(spec: dict, **over) -> dict:
    out = {k: v for k, v in spec.items() if not (over.get("masks") is False and k in ("seg_png", "depth_exr"))}
    out.update({k: v for k, v in over.items() if k != "masks"})
    return out


VARIANTS = {
    "default": lambda s: s,
    "no_masks": lambda s: _strip(s, masks=False),
    "no_denoise": lambda s: _strip(s, denoise=False),
    "no_denoise_no_masks": lambda s: _strip(s, denoise=False, masks=False),
    "one_spp": lambda s: _strip(s, samples=1, denoise=False, masks=False),
    "one_spp_again": lambda s: _strip(s, samples=1, denoise=False, masks=False),
    "one_spp_no_lashes": lambda s: _strip(s, samples=1, denoise=False, masks=False, lashes=False),
    "light_tree": lambda s: _strip(s, cycles={"use_light_tree": True}),
    "sobol": lambda s: _strip(s, cycles={"sampling_pattern": "TABULATED_SOBOL"}),
    "cycles_denoiser": lambda s: _strip(s, denoiser="cycles"),
}
PHASES = ("check_s", "pose_s", "lashes_s", "seg_setup_s", "render_s", "passes_s", "total_s")


def _med(rows, key):
    return float(np.median([r[key] for r in rows]))


def client_side(asset, settings, specs_labels, out: Path) -> dict:
    """CPU seconds per image of the stage's own Python: main process and dask worker."""
    from pipeline.io.labels_file import label_name, write_label
    from pipeline.io.png import strip_png_metadata
    from pipeline.render import formats as lf
    from pipeline.render import labels as lb
    from pipeline.render import sampling as sp
    from pipeline.render import shard as sh
    from pipeline.render.spec import RenderSpec

    n = len(specs_labels)
    t = time.process_time()
    for i in range(n):
        smp = sp.make_sample(asset, settings, i, sp.tmp_png(out, i))
        lab = lb.make_label(smp, settings, asset.name)
        lb.apparent_job(smp, asset.eyes[smp.side], settings)
        lf.format_job(asset, smp, settings.label_formats)
    main = (time.process_time() - t) / n
    t_app = t_mask = t_write = 0.0
    for spec, label, job in specs_labels:
        t = time.process_time()
        extra = sh.apparent_landmarks(job)
        t_app += time.process_time() - t
        lab = dict(label, landmark_check_mm=1e-5)
        typed = RenderSpec.from_dict(spec)
        t = time.process_time()
        sh.add_masks(lab, typed, extra)
        t_mask += time.process_time() - t
        t = time.process_time()
        png = out / "copy.png"
        shutil.copyfile(spec["png"], png)
        strip_png_metadata(png)
        write_label(out / label_name(int(spec["index"])), lab)
        t_write += time.process_time() - t
    return {"sampling_and_labels_main_cpu_s": round(main, 5), "apparent_iris_cpu_s": round(t_app / n, 5),
            "masks_visibility_cpu_s": round(t_mask / n, 5), "file_writing_cpu_s": round(t_write / n, 5)}


def cluster_start_s() -> float:
    """Wall seconds to start and close the stage's LocalCluster (one in-process worker)."""
    from pipeline.render.shard import _client

    t = time.perf_counter()
    client, cluster = _client(1, None)
    client.close()
    cluster.close()
    return round(time.perf_counter() - t, 3)


def main(argv=None) -> int:
    from pipeline.io.seg_file import depth_name, seg_name
    from pipeline.render import asset as ra
    from pipeline.render import labels as lb
    from pipeline.render import sampling as sp
    from pipeline.render.run import run_options
    from pipeline.render.settings import RenderSettings
    from pipeline.render.shard import BlenderProcess
    from stages._common import load_params

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scan", default="synthetic_head")
    ap.add_argument("--images", type=int, default=24)
    args = ap.parse_args(argv)
    asset_dir, rig_dir = ROOT / "rigged_assets" / args.scan, ROOT / "build" / args.scan / "rig"
    if not (rig_dir / "rig.npz").is_file():
        raise SystemExit(f"error: {rig_dir / 'rig.npz'}: missing (run `dvc repro usd@{args.scan}` first)")
    asset = ra.load_render_asset(asset_dir, rig_dir)
    settings = RenderSettings.from_dict(load_params("render", ROOT / "params.yaml"))
    threads = run_options(settings, ROOT / "renders" / args.scan)["threads"]
    load0 = os.getloadavg()[0]
    rows = {v: [] for v in VARIANTS}
    kept = []
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        t0 = time.perf_counter()
        bp = BlenderProcess(asset.usda, asset.rig_npz, threads=threads)
        blender_start = time.perf_counter() - t0
        try:
            for i in range(args.images):
                smp = sp.make_sample(asset, settings, i, td / f"{i:06d}.png")
                spec = dict(smp.spec.to_dict(), seg_png=str(td / seg_name(i)), depth_exr=str(td / depth_name(i)))
                for name, make in VARIANTS.items():
                    r = bp.render(make(spec))
                    if not r.get("ok"):
                        raise SystemExit(f"image {i} ({name}) failed: {r.get('error')}")
                    if i >= 2:
                        rows[name].append(r)
                    if name == "default" and i >= 2:       # the stage-side work runs on these files
                        keep = td / f"k{i:06d}"
                        keep.mkdir()
                        ks = dict(spec)
                        for k in ("png", "seg_png", "depth_exr"):
                            ks[k] = str(keep / Path(spec[k]).name)
                            shutil.copyfile(spec[k], ks[k])
                        kept.append((ks, lb.make_label(smp, settings, asset.name),
                                     lb.apparent_job(smp, asset.eyes[smp.side], settings)))
        finally:
            bp.close()
        client = client_side(asset, settings, kept, td)
    cluster_s = cluster_start_s()
    med = {v: {k: round(_med(rs, k), 5) for k in PHASES + ("total_cpu_s", "render_cpu_s", "denoise_s", "denoise_cpu_s")}
           for v, rs in rows.items()}

    def diff(a, b, key):
        return round(med[a][key] - med[b][key], 5)

    d = med["default"]
    split = {   # (wall s, CPU s) per image of the default render
        "posing (checks, pose, scene update)": (d["check_s"] + d["pose_s"], None),
        "eyelash rebuild + landmark check": (d["lashes_s"], None),
        "mask planes (before render)": (d["seg_setup_s"], None),
        "render: scene sync + BVH update": (diff("one_spp", "one_spp_again", "render_s"),
                                            diff("one_spp", "one_spp_again", "render_cpu_s")),
        "render: session, film, passes, PNG (1 spp, nothing changed)": (med["one_spp_again"]["render_s"],
                                                                 med["one_spp_again"]["render_cpu_s"]),
        f"render: path tracing ({settings.samples - 1} more samples)": (
            diff("no_denoise_no_masks", "one_spp", "render_s"), diff("no_denoise_no_masks", "one_spp", "render_cpu_s")),
        "render: OpenImageDenoise": (diff("default", "no_denoise", "render_s"),
                                     diff("default", "no_denoise", "render_cpu_s")),
        "  of it the worker's OIDN call": (d["denoise_s"], d["denoise_cpu_s"]),
        "render: mask and depth passes": (diff("no_denoise", "no_denoise_no_masks", "render_s"),
                                          diff("no_denoise", "no_denoise_no_masks", "render_cpu_s")),
        "pass reading, seg PNG + depth EXR writing": (d["passes_s"], None),
        "worker total": (d["total_s"], d["total_cpu_s"]),
    }
    res = {"scan": args.scan, "images": len(rows["default"]), "threads": threads, "samples": settings.samples,
           "size": [settings.width, settings.height], "loadavg_before": round(load0, 2),
           "loadavg_after": round(os.getloadavg()[0], 2),
           "split_s": {k: {"wall_s": round(v[0], 4), "cpu_s": None if v[1] is None else round(v[1], 4)}
                       for k, v in split.items()},
           "lashes_in_render_s": diff("one_spp", "one_spp_no_lashes", "render_s"),
           "levers": {"light_tree_on_cpu_ratio": round(med["light_tree"]["total_cpu_s"] / d["total_cpu_s"], 4),
                      "sobol_cpu_ratio": round(med["sobol"]["total_cpu_s"] / d["total_cpu_s"], 4),
                      "cycles_denoiser_cpu_ratio": round(med["cycles_denoiser"]["total_cpu_s"] / d["total_cpu_s"], 4),
                      "cycles_denoiser_wall_ratio": round(med["cycles_denoiser"]["total_s"] / d["total_s"], 4)},
           "stage_side_cpu_s_per_image": client, "blender_start_s": round(blender_start, 3),
           "local_cluster_start_s": cluster_s, "variants_median": med,
           "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json(RESULTS / "render_split.json", res)
    print(f"{'phase':55s} {'wall s':>8s} {'CPU s':>8s}")
    for k, v in res["split_s"].items():
        cpu = "" if v["cpu_s"] is None else f"{v['cpu_s']:8.4f}"
        print(f"{k:55s} {v['wall_s']:8.4f} {cpu}")
    print(f"stage side, CPU s per image: {client}")
    print(f"Blender start-up {res['blender_start_s']} s, LocalCluster start {cluster_s} s; "
          f"levers (CPU ratio to default): {res['levers']}; load {res['loadavg_before']} -> {res['loadavg_after']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
