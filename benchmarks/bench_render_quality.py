"""Render quality vs time of the render worker: samples x denoising against a 2048-spp reference.

    .venv/bin/python -m benchmarks.bench_render_quality [--asset rigged_assets/synthetic_head/synthetic_head.usda]
        [--rig build/synthetic_head/rig] [--samples 8 16 32 64 128 150 256] [--repeats 3]
        [--reference-samples 2048] [--threads 2]

One fixed frame (120 x 80, the subject's left eye, frontal orthographic camera 32 mm wide,
gaze forward, lids at rest, blue iris, ``forest.exr`` at strength 1, bump skin detail, lashes
on) is rendered by ONE persistent worker (``pipeline.blender.render_worker``):

* the reference with ``--reference-samples`` samples, adaptive sampling off, no denoiser;
* for every sample count, without and with OpenImageDenoise, ``--repeats`` renders with
  different Cycles seeds. ``time_s`` = median over the repeats of the wall time per image
  seen by the client (spec sent -> reply read: posing, lash rebuild, landmark check, render,
  PNG write); ``render_s`` = the median of the worker's own render-call time; ``cpu_s`` =
  the median CPU seconds of the worker process per image (all threads; what an image costs
  on a busy machine: ~``cpu_s / threads`` of wall time when the cores are free). ``psnr_db`` /
  ``ssim`` = mean over the repeats of the 8-bit PNG against the reference PNG.

PSNR: on the RGB values (0..255), ``10 log10(255^2 / MSE)``. SSIM: Wang et al. 2004 on the
luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` of the 8-bit values (L = 255, K1 = 0.01,
K2 = 0.03), Gaussian window sigma 1.5 truncated at 3.5 sigma (11 x 11), means over the
valid interior (5 px border dropped), implemented with ``scipy.ndimage.gaussian_filter``.

Choice of the default: the quality bar is PSNR(150 spp, no denoiser); among all settings
reaching it, the cheapest (median CPU seconds per image; wall time too noisy on a shared
2-core machine) is chosen. The reference and the bar are rendered with the Cycles settings of
issue 15's starting point (:data:`BAR_CYCLES`: Sobol pattern, light tree on), so that a
change of the worker's defaults is judged against the same reference and the same bar
(30.16 dB then); every other row uses the worker's defaults. Writes
``benchmarks/results/render_quality.json`` (+ ``.csv`` with columns
samples,denoise,time_s,psnr_db,ssim for ``dvc plots``) and prints a table.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.io.rig_file import read_rig

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
W, H = 120, 80
# the reference's and the 150-spp bar's Cycles settings (the worker's defaults before issue 15)
BAR_CYCLES = {"sampling_pattern": "TABULATED_SOBOL", "use_light_tree": True}
BAR_SAMPLES = 150


def psnr(a, b) -> float:
    """PSNR (dB) of two uint8 images (any shape), peak 255."""
    mse = np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(255.0 ** 2 / mse))


def luminance(rgb) -> np.ndarray:
    return np.asarray(rgb, np.float64)[..., :3] @ np.array([0.2126, 0.7152, 0.0722])


def ssim(a, b, sigma: float = 1.5, L: float = 255.0) -> float:
    """Mean SSIM of two (H, W) luminance images, Gaussian window (Wang et al. 2004)."""
    from scipy.ndimage import gaussian_filter

    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    g = lambda im: gaussian_filter(im, sigma, truncate=3.5, mode="reflect")  # noqa: E731
    mx, my = g(x), g(y)
    sxx = g(x * x) - mx * mx
    syy = g(y * y) - my * my
    sxy = g(x * y) - mx * my
    c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    r = int(math.ceil(3.5 * sigma))
    return float(m[r:-r, r:-r].mean())


def frame_spec(rig_dir: Path, png: Path, samples: int, denoise: bool, seed: int) -> dict:
    """The fixed benchmark frame (see the module docstring)."""
    eye = read_rig(rig_dir).eyes["left"]
    c, f = eye.center, eye.forward
    M = np.eye(4)
    M[:3, 3] = -(c + 12.0 * f + 30.0 * np.array([0.0, 0.0, 1.0]))     # axes = head axes
    return {"index": seed, "png": str(png), "width": W, "height": H, "samples": int(samples),
            "denoise": bool(denoise), "cycles_seed": int(seed), "eye": "left",
            "camera": {"world_to_camera": M.tolist(), "ortho_scale_mm": 32.0},
            "eye_rotation": {"left": [1, 0, 0, 0], "right": [1, 0, 0, 0]},
            "lid_weights": {"lids_up": 0.0, "lids_down": 0.0},
            "eyeball": {"iris_color": "blue", "sclera_tint": "white", "veins": "clear",
                        "blend": {"pupil_dilate": 0.0, "pupil_constrict": 0.0, "iris_large": 0.0,
                                  "iris_small": 0.0}},
            "lighting": {"hdri": "forest.exr", "rotation_deg": 0.0, "strength": 1.0},
            "skin_detail": "bump", "landmarks_head_mm": np.zeros((28, 3)).tolist()}


class Client:
    def __init__(self, asset: Path, rig_npz: Path, threads: int, extra=()):
        from pipeline.blender.render_worker import REPLY_PREFIX

        self.prefix = REPLY_PREFIX
        t = time.perf_counter()
        from pipeline.blender import launch

        self.p = subprocess.Popen(launch.command("pipeline.blender.render_worker",
                                                 [asset, rig_npz, "--threads", threads, *extra]), cwd=ROOT,
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.DEVNULL, text=True)
        self.ready = self.read()
        self.startup_s = time.perf_counter() - t
        if not self.ready.get("ready"):
            raise SystemExit(f"worker failed: {self.ready}")

    def read(self) -> dict:
        for line in self.p.stdout:
            if line.startswith(self.prefix):
                return json.loads(line[len(self.prefix):])
        raise SystemExit("worker ended")

    def render(self, spec: dict) -> tuple[dict, float]:
        t = time.perf_counter()
        self.p.stdin.write(json.dumps(spec) + "\n")
        self.p.stdin.flush()
        rep = self.read()
        if not rep.get("ok"):
            raise SystemExit(f"render failed: {rep}")
        return rep, time.perf_counter() - t

    def close(self):
        self.p.stdin.close()
        self.p.wait(timeout=60)


def load(png) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(png).convert("RGB"))


def choose_default(rows: list[dict], key: str = "cpu_s", bar: float | None = None) -> dict:
    """Cheapest setting (by ``key``) whose PSNR reaches ``bar`` (default: that of the 150-spp
    undenoised row).

    CPU seconds of the worker are the default key: on a shared machine the wall time of one
    image swings by 2-4x with other people's load, the CPU time much less.
    """
    if bar is None:
        bar = next(r for r in rows if r["samples"] == 150 and not r["denoise"])["psnr_db"]
    ok = [r for r in rows if r["psnr_db"] >= bar]
    best = min(ok, key=lambda r: r[key])
    return {"samples": best["samples"], "denoise": best["denoise"], "denoiser": best.get("denoiser"),
            "time_s": best["time_s"],
            "cpu_s": best["cpu_s"], "psnr_db": best["psnr_db"], "ssim": best["ssim"],
            "psnr_bar_db": bar, "chosen_by": key}


def write_csvs(rows: list[dict], out: Path) -> None:
    """``out.csv`` (every row) plus ``out_raw.csv`` / ``out_denoised.csv``: one time-vs-PSNR
    curve each for ``dvc plots`` (a plot draws one line per file)."""
    cols = ["samples", "denoise", "time_s", "psnr_db", "ssim", "cpu_s"]
    for path, keep in ((out.with_suffix(".csv"), lambda r: True),
                       (out.with_name(out.name + "_raw.csv"), lambda r: not r["denoise"]),
                       (out.with_name(out.name + "_denoised.csv"), lambda r: r["denoise"])):
        with open(path, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(cols)
            for r in rows:
                if keep(r):
                    wr.writerow([r["samples"], int(r["denoise"]), r["time_s"], r["psnr_db"], r["ssim"], r["cpu_s"]])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--asset", type=Path, default=ROOT / "rigged_assets/synthetic_head/synthetic_head.usda")
    ap.add_argument("--rig", type=Path, default=ROOT / "build/synthetic_head/rig")
    ap.add_argument("--samples", type=int, nargs="+", default=[8, 16, 32, 64, 128, 150, 256])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--reference-samples", type=int, default=2048)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=RESULTS / "render_quality")
    ap.add_argument("--denoisers", nargs="+", default=["worker"], choices=["worker", "cycles"],
                    help="denoised rows with the worker's own OIDN filters and/or Cycles' denoiser")
    ap.add_argument("--keep", type=Path, default=None, help="copy the reference and 16-spp PNGs here")
    ap.add_argument("--extra-samples", type=int, nargs="*", default=[9, 10, 11, 12, 20, 24],
                    help="denoised-only sample counts added around the expected default")
    args = ap.parse_args(argv)
    if 150 not in args.samples:
        args.samples.append(150)
    for p in (args.asset, args.rig / "rig.npz", args.rig / "rig.json"):
        if not p.is_file():
            print(f"error: {p}: missing (run `dvc repro usd@synthetic_head` first)", file=sys.stderr)
            return 2
    client = Client(args.asset, args.rig / "rig.npz", args.threads)
    rows = []
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        ref_png = td / "reference.png"
        spec = frame_spec(args.rig, ref_png, args.reference_samples, False, 1)
        spec["adaptive_sampling"] = False
        spec["cycles"] = BAR_CYCLES
        spec["denoiser"] = "cycles"                                         # Blender's own film, as before
        client.render(frame_spec(args.rig, td / "warm.png", 4, True, 0))      # warm-up (first sync)
        rep, ref_s = client.render(spec)
        ref = load(ref_png)
        print(f"reference: {args.reference_samples} spp in {ref_s:.1f} s; worker start-up {client.startup_s:.2f} s",
              flush=True)
        bars = []
        for k in range(args.repeats):
            png = td / f"bar_{k}.png"
            client.render(dict(frame_spec(args.rig, png, BAR_SAMPLES, False, 1000 + k), cycles=BAR_CYCLES,
                               denoiser="cycles"))
            bars.append(psnr(load(png), ref))
        bar = round(float(np.mean(bars)), 3)
        print(f"bar: {BAR_SAMPLES} spp undenoised with {BAR_CYCLES}: PSNR {bar:.2f} dB", flush=True)
        for denoise, denoiser in [(False, "cycles")] + [(True, d) for d in args.denoisers]:
            for s in sorted(set(args.samples) | (set(args.extra_samples) if denoise else set())):
                times, rtimes, cpus, ps, ss = [], [], [], [], []
                for k in range(args.repeats):
                    png = td / f"s{s}_d{int(denoise)}{denoiser}_{k}.png"
                    rep, t = client.render(dict(frame_spec(args.rig, png, s, denoise, 1000 + k), denoiser=denoiser))
                    img = load(png)
                    times.append(t)
                    rtimes.append(rep["render_s"])
                    cpus.append(rep["total_cpu_s"])
                    ps.append(psnr(img, ref))
                    ss.append(ssim(luminance(img), luminance(ref)))
                    if args.keep and k == 0 and s == 16:
                        args.keep.mkdir(parents=True, exist_ok=True)
                        (args.keep / f"bench_16spp_denoise{int(denoise)}.png").write_bytes(png.read_bytes())
                row = {"samples": s, "denoise": denoise, "denoiser": denoiser if denoise else None, "time_s": round(float(np.median(times)), 4),
                       "render_s": round(float(np.median(rtimes)), 4),
                       "cpu_s": round(float(np.median(cpus)), 4),
                       "psnr_db": round(float(np.mean(ps)), 3), "ssim": round(float(np.mean(ss)), 5),
                       "times_s": [round(t, 4) for t in times]}
                rows.append(row)
                print(f"{s:5d} spp  denoise={str(denoise):5s} {row['denoiser'] or '':6s} {row['time_s']:.3f} s/img "
                      f"(render {row['render_s']:.3f}, CPU {row['cpu_s']:.3f} s)  PSNR {row['psnr_db']:.2f} dB  SSIM {row['ssim']:.4f}",
                      flush=True)
        if args.keep:
            args.keep.mkdir(parents=True, exist_ok=True)
            (args.keep / "bench_reference.png").write_bytes(ref_png.read_bytes())
    rss = client.ready.get("rss_mib")
    client.close()
    best = choose_default(rows, bar=bar)
    result = {"frame": {"size": [W, H], "eye": "left", "view": "frontal orthographic, 32 mm wide",
                        "hdri": "forest.exr", "skin_detail": "bump", "lashes": True},
              "reference_samples": args.reference_samples, "reference_time_s": round(ref_s, 2),
              "reference_cycles": BAR_CYCLES, "bar": {"samples": BAR_SAMPLES, "denoise": False,
                                                      "cycles": BAR_CYCLES, "psnr_db": bar},
              "repeats": args.repeats, "threads": args.threads, "worker_startup_s": round(client.startup_s, 3),
              "worker_rss_at_ready_mib": rss,
              "metrics": {"psnr": "RGB 8-bit, peak 255", "ssim": "luminance (Rec. 709) of the 8-bit values, "
                          "Gaussian window sigma 1.5 (11x11), K1 0.01, K2 0.03, 5 px border dropped"},
              "rows": rows, "chosen_default": best}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    write_csvs(rows, args.out)
    print(f"default: {best['samples']} spp, denoise={best['denoise']}: {best['time_s']:.3f} s/img "
          f"(CPU {best['cpu_s']:.3f} s), "
          f"PSNR {best['psnr_db']:.2f} dB >= {best['psnr_bar_db']:.2f} dB (150 spp, no denoiser)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
