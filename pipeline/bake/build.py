"""The bake stage's work: read the low-poly mesh and the dense scan, unwrap, bake, write the
bake product (pipeline/io/bake_file.py) and measure the reconstruction error.

The machine has 2 cores, so independent steps overlap in forked children (fork shares the
arrays without copying): the xatlas unwrap (which holds the GIL) runs while the dense scan and
its texture load, the UV-independent half of the accuracy metric runs and the Embree scene of
the scan is built; the UV-dependent
half runs while the maps are written. A child that fails is rerun in the parent, so a result
never depends on the fork.
"""

from __future__ import annotations

import multiprocessing
import time
from pathlib import Path

import numpy as np

from pipeline.bake.bake import BakeSettings, bake_maps, dense_scene, reconstruction_baseline, reconstruction_error
from pipeline.bake.uv import unwrap
from pipeline.errors import ScanError
from pipeline.io.bake_file import write_bake
from pipeline.io.meshfile import read_stage_mesh


def fork_call(fn, *args, **kwargs):
    """Start ``fn(*args, **kwargs)`` in a forked child; returns a job for :func:`fork_result`."""
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


def fork_result(job):
    """(value, seconds) of a :func:`fork_call` job; reruns the call here if the child failed."""
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


def _texture(path: Path):
    """The dense scan's colour texture as (H, W, 3) uint8, or None when there is none."""
    from PIL import Image

    if not path.exists():
        return None
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except OSError as exc:
        raise ScanError(path, f"cannot read texture ({exc})") from None


def bake_scan(retopo_dir, dense_dir, settings: BakeSettings, out_dir) -> dict:
    """Bake ``retopo_dir/mesh.npz`` (V, F, loop_left, loop_right) against the dense scan
    ``dense_dir/mesh.npz`` (+ ``texture.png``) and write the bake product into ``out_dir``
    (an existing, empty folder: the stage's atomic output). Returns the metrics.

    Raises
    ------
    ScanError
        A missing or incomplete input mesh, an unreadable texture.
    """
    retopo_dir, dense_dir, out_dir = Path(retopo_dir), Path(dense_dir), Path(out_dir)
    low = read_stage_mesh(retopo_dir / "mesh.npz", required=("V", "F", "loop_left", "loop_right"))
    # the xatlas unwrap (holds the GIL) runs in a forked child while the scan and texture load
    uv_job = fork_call(unwrap, low["V"], low["F"], settings.resolution, settings.uv_padding_texels)
    dense = read_stage_mesh(dense_dir / "mesh.npz")
    texture = _texture(dense_dir / "texture.png")
    loops = {"left": low["loop_left"], "right": low["loop_right"]}
    # while the child unwraps: the UV-independent half of the accuracy metric
    t0 = time.perf_counter()
    baseline = reconstruction_baseline(low["V"], low["F"], dense["V"], dense["F"],
                                       levels=settings.subdivision_levels, n_samples=settings.metric_samples)
    baseline_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    scene = dense_scene(low["V"], dense, settings)        # and the ray-casting BVH
    scene_s = time.perf_counter() - t0
    (UV, FUV), unwrap_s = fork_result(uv_job)
    result = bake_maps(low["V"], low["F"], loops, dense, texture, settings, UV=UV, FUV=FUV, scene=scene)
    result.metrics["timings_s"]["unwrap_s"] = round(unwrap_s, 4)   # child process, overlapped with loading
    result.metrics["timings_s"]["scene_s"] = round(scene_s, 4)     # while the child unwraps
    # the accuracy metric runs in a child while the maps are written
    err_job = fork_call(reconstruction_error, low["V"], low["F"], result.UV, result.FUV, result.displacement,
                        dense["V"], dense["F"], levels=settings.subdivision_levels,
                        n_samples=settings.metric_samples, baseline=baseline)
    mesh = {**{k: v for k, v in low.items() if k not in ("UV", "FUV")}, "UV": result.UV, "FUV": result.FUV}
    write_bake(out_dir, mesh, result.displacement, result.mask, result.color,
               resolution=settings.resolution, falloff_mm=settings.falloff_mm,
               colour_source=result.metrics["colour"])
    err, recon_s = fork_result(err_job)
    result.metrics["timings_s"]["reconstruction_error_s"] = round(baseline_s + recon_s, 4)
    return {**result.metrics, "reconstruction": err}
