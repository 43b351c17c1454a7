"""The bake stage's work: read the low-poly mesh and the dense scan, unwrap, bake, write the
bake product (pipeline/io/bake_file.py) and measure the reconstruction error.

The machine has 2 cores, so independent steps overlap in forked children (pipeline/fork.py):
the xatlas unwrap (which holds the GIL) runs while the dense scan and its texture load, the
UV-independent half of the accuracy metric runs and the Embree scene of the scan is built; the
UV-dependent half runs while the colour map is made and the maps are written.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from pipeline.bake.bake import BakeSettings, bake_maps, dense_scene, reconstruction_baseline, reconstruction_error
from pipeline.bake.uv import unwrap
from pipeline.errors import ScanError
from pipeline.fork import fork_call, fork_result
from pipeline.io.bake_file import write_bake
from pipeline.io.meshfile import read_stage_mesh


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
    jobs = []

    def start_metric(UV, FUV, displacement):
        # the accuracy metric runs in a child while the colour map is made and the maps are written
        jobs.append(fork_call(reconstruction_error, low["V"], low["F"], UV, FUV, displacement,
                              dense["V"], dense["F"], levels=settings.subdivision_levels,
                              n_samples=settings.metric_samples, baseline=baseline))

    result = bake_maps(low["V"], low["F"], loops, dense, texture, settings, UV=UV, FUV=FUV, scene=scene,
                       on_displacement=start_metric)
    result.metrics["timings_s"]["unwrap_s"] = round(unwrap_s, 4)   # child process, overlapped with loading
    result.metrics["timings_s"]["scene_s"] = round(scene_s, 4)     # while the child unwraps
    mesh = {**{k: v for k, v in low.items() if k not in ("UV", "FUV")}, "UV": result.UV, "FUV": result.FUV}
    write_bake(out_dir, mesh, result.displacement, result.mask, result.color,
               resolution=settings.resolution, falloff_mm=settings.falloff_mm,
               colour_source=result.metrics["colour"])
    err, recon_s = fork_result(jobs[0])
    result.metrics["timings_s"]["reconstruction_error_s"] = round(baseline_s + recon_s, 4)
    return {**result.metrics, "reconstruction": err}
