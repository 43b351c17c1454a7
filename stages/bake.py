"""Stage ``bake``: UV-unwrap the low-poly eye region and bake displacement and colour maps from the scan.

    python -m stages.bake RETOPO_DIR REMOVE_EYEBALLS_DIR OUT_DIR [--metrics PATH] [--params params.yaml]

Reads ``RETOPO_DIR/mesh.npz`` (V, F, loops [, polygons]) and the dense scan
``REMOVE_EYEBALLS_DIR/mesh.npz`` (+ ``texture.png`` when present); writes
``OUT_DIR/{mesh.npz, displacement.exr, displacement_preview.png, color.png, bake.json}``.
"""

from __future__ import annotations

import multiprocessing
import time
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.bake.bake import BakeSettings, bake_maps, reconstruction_baseline, reconstruction_error
from pipeline.bake.exr import preview_16bit, write_exr
from pipeline.bake.uv import unwrap
from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_dir, write_json
from pipeline.io.meshfile import load_mesh, save_mesh
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def _load(path: Path, need) -> dict:
    try:
        m = load_mesh(path)
    except (OSError, ValueError, KeyError) as exc:
        raise ScanError(path, f"cannot read mesh ({exc})") from None
    missing = [k for k in need if k not in m]
    if missing:
        raise ScanError(path, f"mesh.npz lacks {', '.join(missing)}")
    return m


def _fork_call(fn, *args, **kwargs):
    """Start ``fn(*args, **kwargs)`` in a forked child (the machine has 2 cores: overlap independent
    steps; fork shares the arrays without copying). Returns a job for :func:`_result`."""
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def target():
        t0 = time.perf_counter()
        try:
            send.send(("ok", fn(*args, **kwargs), time.perf_counter() - t0))
        except BaseException as exc:  # reported to the parent, which reruns the call itself
            send.send(("error", repr(exc), 0.0))

    proc = ctx.Process(target=target, daemon=True)
    proc.start()
    send.close()
    return proc, recv, fn, args, kwargs


def _result(job):
    """(value, seconds) of a :func:`_fork_call` job; reruns the call here if the child failed."""
    proc, recv, fn, args, kwargs = job
    try:
        status, value, dt = recv.recv()
    except (EOFError, OSError):
        status, value, dt = "error", None, 0.0
    proc.join()
    recv.close()
    if status != "ok":
        t0 = time.perf_counter()
        value = fn(*args, **kwargs)
        dt = time.perf_counter() - t0
    return value, dt


def main(argv) -> dict:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("retopo_dir", help="build/<scan>/retopo")
    parser.add_argument("dense_dir", help="build/<scan>/remove_eyeballs")
    parser.add_argument("out_dir", help="build/<scan>/bake")
    args = parser.parse_args(argv)
    settings = load_settings(BakeSettings, args.params)
    low = _load(Path(args.retopo_dir) / "mesh.npz", ("V", "F", "loop_left", "loop_right"))
    # the xatlas unwrap (holds the GIL) runs in a forked child while the scan and texture load
    uv_job = _fork_call(unwrap, low["V"], low["F"], settings.resolution, settings.uv_padding_texels)
    dense = _load(Path(args.dense_dir) / "mesh.npz", ("V", "F"))
    tex_path = Path(args.dense_dir) / "texture.png"
    texture = None
    if tex_path.exists():
        try:
            with Image.open(tex_path) as im:
                texture = np.asarray(im.convert("RGB"))
        except OSError as exc:
            raise ScanError(tex_path, f"cannot read texture ({exc})") from None
    loops = {"left": low["loop_left"], "right": low["loop_right"]}
    # while the child unwraps: the UV-independent half of the accuracy metric
    t0 = time.perf_counter()
    baseline = reconstruction_baseline(low["V"], low["F"], dense["V"], dense["F"],
                                       levels=settings.subdivision_levels, n_samples=settings.metric_samples)
    baseline_s = time.perf_counter() - t0
    (UV, FUV), unwrap_s = _result(uv_job)
    result = bake_maps(low["V"], low["F"], loops, dense, texture, settings, UV=UV, FUV=FUV)
    result.metrics["timings_s"]["unwrap_s"] = round(unwrap_s, 4)   # child process, overlapped with loading
    # the accuracy metric runs in a child while the maps are written
    err_job = _fork_call(reconstruction_error, low["V"], low["F"], result.UV, result.FUV, result.displacement,
                         dense["V"], dense["F"], levels=settings.subdivision_levels,
                         n_samples=settings.metric_samples, baseline=baseline)
    q, scale, offset = preview_16bit(result.displacement, result.mask)
    out = Path(args.out_dir)
    with atomic_dir(out) as tmp:
        save_mesh(tmp / "mesh.npz", **{k: v for k, v in low.items() if k not in ("UV", "FUV")},
                  UV=result.UV, FUV=result.FUV)
        write_exr(tmp / "displacement.exr", result.displacement)
        Image.fromarray(q).save(tmp / "displacement_preview.png", compress_level=3)
        colour = result.color if result.color is not None else np.full(
            result.displacement.shape + (3,), 200, dtype=np.uint8)
        Image.fromarray(colour).save(tmp / "color.png", compress_level=3)
        write_json(tmp / "bake.json", {
            "resolution": settings.resolution,
            "displacement": {"file": "displacement.exr", "channel": "Y", "units": "mm",
                             "meaning": "signed distance along the interpolated vertex normal of the "
                                        "flat (midpoint-subdivided) low-poly surface; positive = outward",
                             "falloff_mm_at_eyelid_loops": settings.falloff_mm},
            "preview": {"file": "displacement_preview.png", "bits": 16,
                        "value_mm = offset + scale * pixel": {"scale": scale, "offset": offset}},
            "color": {"file": "color.png", "source": result.metrics["colour"] or "none (flat grey)"},
            "uv": "mesh.npz UV/FUV, origin bottom-left; image rows top-down",
        })
    err, recon_s = _result(err_job)
    result.metrics["timings_s"]["reconstruction_error_s"] = round(baseline_s + recon_s, 4)
    return {"_path": args.metrics or default_metrics_path(out), **result.metrics, "reconstruction": err}


if __name__ == "__main__":
    stage_exit(main)
