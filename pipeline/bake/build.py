"""The bake stage's work: read the low-poly mesh and the dense scan, unwrap, bake, write the
bake product (pipeline/io/bake_file.py) and measure the reconstruction error.

The steps are the algorithm's (pipeline/bake/bake.py); independent ones run side by side
(``EYERIG_SERIAL=1`` turns it off, with the same bytes). On threads (Embree, scipy's trees and
distance transform and numpy's big loops let go of the GIL): the unwrap while the dense scan and
its texture load; the texels' falloff weights and padding while the rays are cast. Both halves
of the accuracy metric run in forked children (pipeline/fork.py): the UV-independent one beside
the Embree scene and the rasteriser, the UV-dependent one beside the colour map and the writes.
They are libigl's closest-point queries, which hold the GIL (a query on a thread beside a Python
loop takes as long as both one after the other): on threads they had doubled the rasteriser's
time and slowed the colour map. Forked, the stage takes 0.92x the wall time and 1.10x the CPU
time (farm-bench, 10 pairs on the 1.4M head: the children's copy-on-write faults, system time
+0.46 s). The weights ran in a child too until issue 32's second bake round, when the children's
copy-on-write page faults and the pickled weights cost 0.7-1.0 CPU-s of the stage's 6.4; forked
again beside today's children they gain nothing (wall 1.00x, CPU 1.01x), so they stay on a
thread.
Threads share one tree cache (pipeline.geometry.mesh_checks, locked): no two steps that run
side by side ask it about the same mesh.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from pipeline.bake.bake import (BakeSettings, atlas_texels, atlas_unwrap, bake_metrics, cast_texels, colour_map,
                                colour_source, dense_scene, displacement_map, loop_gaps, reconstruction_baseline,
                                reconstruction_error, texel_weights)
from pipeline.errors import ScanError
from pipeline.fork import fork_call, fork_result, forking
from pipeline.io.bake_file import write_bake
from pipeline.io.meshfile import read_stage_mesh
from pipeline.results import StageResult


def _beside(fn, *args, **kwargs):
    """Start ``fn(*args, **kwargs)`` on a thread beside this one (or, switched off: no side by
    side, pipeline.fork.forking(), nothing yet); returns a job for :func:`_result`."""
    if not forking():
        return None, fn, args, kwargs
    from concurrent.futures import ThreadPoolExecutor

    def timed():
        t0 = time.perf_counter()
        return fn(*args, **kwargs), time.perf_counter() - t0

    pool = ThreadPoolExecutor(1)
    job = pool.submit(timed)
    pool.shutdown(wait=False)
    return job, fn, args, kwargs


def _result(job):
    """(value, seconds) of a :func:`_beside` job (its exception raised here)."""
    future, fn, args, kwargs = job
    if future is not None:
        return future.result()
    t0 = time.perf_counter()
    return fn(*args, **kwargs), time.perf_counter() - t0


def _texture(path: Path):
    """The dense scan's colour texture as (H, W, 3) uint8, or None when there is none."""
    from PIL import Image

    if not path.exists():
        return None
    try:
        with Image.open(path, formats=["PNG"]) as im:     # ingest writes a PNG; nothing else is decoded
            return np.asarray(im.convert("RGB"))
    except OSError as exc:
        raise ScanError(path, f"cannot read texture ({exc})") from None


def bake_scan(retopo_dir, dense_dir, settings: BakeSettings, out_dir) -> StageResult:
    """Bake ``retopo_dir/mesh.npz`` (V, F, loop_left, loop_right) against the dense scan
    ``dense_dir/mesh.npz`` (+ ``texture.png``) and write the bake product into ``out_dir``
    (an existing, empty folder: the stage's atomic output). The steps are
    :func:`pipeline.bake.bake.bake_maps`'s, the independent ones side by side (module doc).

    Raises
    ------
    ScanError
        A missing or incomplete input mesh, an unreadable texture.
    """
    s = settings
    retopo_dir, dense_dir, out_dir = Path(retopo_dir), Path(dense_dir), Path(out_dir)
    low = read_stage_mesh(retopo_dir / "mesh.npz", required=("loop_left", "loop_right"))
    V, F = np.asarray(low.V, dtype=np.float64), np.asarray(low.F, dtype=np.int64)
    t = {}
    t0 = time.perf_counter()
    loops = {"left": low.loop_left, "right": low.loop_right}
    # the unwrap runs beside (libigl's lscm lets go of the GIL; xatlas, where it runs, holds it):
    # loading the scan and its texture, the UV-independent half of the accuracy metric and the
    # ray-casting BVH
    uv_job = _beside(atlas_unwrap, V, F, list(loops.values()), s)
    dense = read_stage_mesh(dense_dir / "mesh.npz")
    texture = _texture(dense_dir / "texture.png")
    # the unwrap's thread has finished before the fork: a child never starts with a lock that
    # another thread of the parent held (the tree cache's, an import's)
    (UV, FUV, method), t["unwrap_s"] = _result(uv_job)
    baseline_job = fork_call(reconstruction_baseline, V, F, dense.V, dense.F, levels=s.subdivision_levels,
                             n_samples=s.metric_samples)
    t1 = time.perf_counter()
    scene = dense_scene(V, dense, s)
    t["scene_s"] = time.perf_counter() - t1
    res = int(s.resolution)
    t1 = time.perf_counter()
    tx = atlas_texels(V, F, UV, FUV, res)
    t["rasterize_s"] = time.perf_counter() - t1
    # the falloff weights and the padding need the texels only: beside the ray casting
    gaps = loop_gaps(V, list(loops.values()), dense.V, dense.F) if s.falloff_per_mm > 0 else None
    weights_job = _beside(texel_weights, V, F, tx, list(loops.values()), s, gaps)
    t1 = time.perf_counter()
    disp, hface, hbary, n_miss = cast_texels(scene, tx, s)
    t["raycast_s"] = time.perf_counter() - t1
    weights, t["weights_padding_s"] = _result(weights_job)
    t1 = time.perf_counter()
    dimg, disp_w = displacement_map(tx, disp, weights, res)
    baseline, baseline_s = fork_result(baseline_job)
    # the accuracy metric needs the final displacement map: beside the colour map and the writes
    # (no thread of this process runs at the fork: the unwrap's and the weights' have finished)
    error_job = fork_call(reconstruction_error, V, F, UV, FUV, dimg, dense.V, dense.F,
                          levels=s.subdivision_levels, n_samples=s.metric_samples, baseline=baseline)
    cimg = colour_map(tx, dense, texture, hface, hbary, weights, res)
    t["maps_s"] = time.perf_counter() - t1
    colour = colour_source(dense, texture, cimg)
    mesh = {**{k: v for k, v in low.items() if k not in ("UV", "FUV")}, "UV": UV, "FUV": FUV}
    write_bake(out_dir, mesh, dimg, tx.mask, cimg, resolution=res, falloff_mm=s.falloff_mm, colour_source=colour)
    t["total_s"] = time.perf_counter() - t0
    err, recon_s = fork_result(error_job)
    t["reconstruction_error_s"] = baseline_s + recon_s
    timings = {k: round(v, 4) for k, v in t.items()}
    return StageResult({**bake_metrics(tx, disp_w, n_miss, colour, res), "unwrap": method, "reconstruction": err},
                       {"timings_s": timings, "time_s": timings["total_s"]})
