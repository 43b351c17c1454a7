"""How much the band round each eye turns on the last bits of its arithmetic: each head's cached
``remove_eyeballs`` output is retopologised once in this process to catch each eye's grid as the
harmonic map lays it (``build_band``); the grid is then smoothed and raised again (``smooth_grid``)
as it is and with its inner rings moved by ``--sigma`` mm (1e-9: the size of what the order and
alignment of the process's arrays change) under ``--runs - 1`` seeds. Per band and run, the grid's
smallest quad quality: the better split's smaller triangle angle, 180 less where a triangle is
turned against the scan (what the raise climbs). A band whose figure differs from run to run
is one another machine may build differently from the same scan.

    .venv/bin/python -m benchmarks.bench_band_jitter --set heldout=<builds>:<params.yaml> \\
        [--set ...] [--runs 4] [--sigma 1e-9] [--out band_jitter]

``<builds>`` holds ``<head>/remove_eyeballs`` (as ``bench_band``'s). Writes
``benchmarks/results/<out>.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from benchmarks.bench_band import parse_sets
from benchmarks.results_files import write_results
from pipeline.geometry import mesh_checks as mc
from pipeline.io.eyes_file import read_eye_loops
from pipeline.io.meshfile import read_stage_mesh
from pipeline.retopo import eye_band
from pipeline.retopo.retopo import RetopoSettings, retopologize
from stages._common import load_settings


def grid_quality(G, ref_V, ref_F) -> float:
    """Smallest quad quality (:func:`eye_band.grid_quality`, deg) of the grid ``G`` (R + 1, S, 3)
    against the scan's normals nearest its nodes."""
    closest = mc.closest_points_on(ref_V, ref_F)
    N = closest.face_normals()[closest(G.reshape(-1, 3))[1]].reshape(G.shape)
    return float(eye_band.grid_quality(G, N).min())


def caught_grids(re_dir: Path, params: Path) -> list[dict]:
    """The arguments of each eye's ``smooth_grid`` call in one retopologising of ``re_dir``."""
    caught, smooth = [], eye_band.smooth_grid

    def catch(G, d, ref_V, ref_F, outer_line=None, **kw):
        caught.append({"G": np.array(G), "d": np.array(d), "ref_V": np.array(ref_V), "ref_F": np.array(ref_F),
                       "outer_line": None if outer_line is None else np.array(outer_line), "kw": kw})
        return smooth(G, d, ref_V, ref_F, outer_line, **kw)

    mesh = read_stage_mesh(re_dir / "mesh.npz")
    eyes = read_eye_loops(re_dir / "eyes.json", len(mesh.V))
    os.environ["EYERIG_SERIAL"] = "1"                # both eyes built here, where the catch is
    eye_band.smooth_grid = catch
    try:
        retopologize(mesh.V, mesh.F, eyes, load_settings(RetopoSettings, params))
    finally:
        eye_band.smooth_grid = smooth
    return caught


def jitter(grid: dict, runs: int, sigma: float) -> list[float]:
    out = []
    for seed in range(runs):
        G = grid["G"].copy()
        if seed:
            G[1:] += np.random.default_rng(seed).normal(0.0, sigma, G[1:].shape)
        Gs = eye_band.smooth_grid(G, grid["d"], grid["ref_V"], grid["ref_F"], grid["outer_line"], **grid["kw"])
        out.append(round(grid_quality(Gs, grid["ref_V"], grid["ref_F"]), 2))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--set", action="append", required=True, metavar="NAME=BUILDS:PARAMS")
    p.add_argument("--runs", type=int, default=4)
    p.add_argument("--sigma", type=float, default=1e-9)
    p.add_argument("--out", default="band_jitter")
    a = p.parse_args(argv)
    result = {}
    for name, builds, params in parse_sets(p, a.set):
        rows = []
        for re_dir in sorted(builds.glob("*/remove_eyeballs")):
            grids = caught_grids(re_dir, params)
            for eye, grid in enumerate(grids):
                q = jitter(grid, a.runs, a.sigma)
                rows.append({"head": re_dir.parent.name, "eye": eye, "quality_deg": q})
                print(name, re_dir.parent.name, eye, q, flush=True)
        q = np.array([r["quality_deg"] for r in rows])
        result[name] = {"summary": {"bands": len(rows), "runs": int(q.size), "sigma_mm": a.sigma,
                                    "runs_under_20_deg": int((q < 20.0).sum()),
                                    "runs_turned": int((q < 0.0).sum()),
                                    "bands_moving_over_1_deg": int((np.ptp(q, axis=1) > 1.0).sum()),
                                    "smallest_deg": float(q.min())},
                        "rows": rows}
        print(name, result[name]["summary"], flush=True)
    write_results(a.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
