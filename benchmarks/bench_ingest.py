"""Benchmark the ingest stage on a 1.4M-triangle binary PLY (target: <= 5 s wall, <= 2 GiB peak).

    .venv/bin/python -m benchmarks.bench_ingest [--runs 5] [--rows 701 --cols 1000] [--formats ply obj] [--scan DIR]

Builds (once, cached under a temp folder) a head-sized ellipsoid with two eye
bumps tessellated as a latitude/longitude grid of 2*C*(R-1) triangles
(1,400,000 by default), stored like the synthetic head: binary little-endian PLY,
float32 xyz + per-vertex ``s``, ``t`` UVs, a 1024x1024 PNG texture named in
scan.yaml. Each run starts ``python -m stages.ingest`` as a subprocess and
records its wall time and its own peak RSS (``os.wait4`` rusage).
The same head is also written as an OBJ (``f v/vt`` + MTL) for the OBJ figure.
Writes ``benchmarks/results/ingest.json`` with the medians and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from stages._common import read_stage_metrics

ROOT = Path(__file__).resolve().parents[1]
RADII = np.array([75.0, 100.0, 90.0])


def latlong_head(rows: int, cols: int):
    """Ellipsoid head (mm) with eye bumps; rows-1 latitude rings of ``cols`` vertices plus 2 poles.

    Returns V (n,3) float64, F (2*cols*(rows-1), 3) int64, UV (n,2), hints dict.
    """
    theta = np.linspace(0, np.pi, rows + 1)[1:-1]          # polar angle of the rings
    phi = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.column_stack([np.sin(t).ravel() * np.sin(p).ravel(), np.cos(t).ravel(),
                            np.sin(t).ravel() * np.cos(p).ravel()])
    unit = np.vstack([[0, 1, 0], unit, [0, -1, 0]])
    V = unit * RADII
    hints = {}
    for side, x in (("left", 32.0), ("right", -32.0)):
        y = 35.0
        c = np.array([x, y, RADII[2] * np.sqrt(1 - (x / RADII[0]) ** 2 - (y / RADII[1]) ** 2)])
        d = np.linalg.norm(V - c, axis=1)
        V = V + unit * (4.0 * np.exp(-0.5 * (d / 8.0) ** 2))[:, None]
        hints[side] = c + c / np.linalg.norm(c) * 5.0
    nr = rows - 1
    ring = lambda r, j: 1 + r * cols + (j % cols)  # noqa: E731
    j = np.arange(cols)
    top = np.column_stack([np.zeros(cols, np.int64), ring(0, j + 1), ring(0, j)])
    r, jj = np.meshgrid(np.arange(nr - 1), j, indexing="ij")
    r, jj = r.ravel(), jj.ravel()
    a, b, c, d = ring(r, jj), ring(r, jj + 1), ring(r + 1, jj), ring(r + 1, jj + 1)
    quads = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    bottom_pole = 1 + nr * cols
    bottom = np.column_stack([np.full(cols, bottom_pole), ring(nr - 1, j), ring(nr - 1, j + 1)])
    F = np.concatenate([top, quads, bottom]).astype(np.int64)
    UV = np.column_stack([0.5 + np.arctan2(unit[:, 0], unit[:, 2]) / (2 * np.pi),
                          0.5 + np.arcsin(np.clip(unit[:, 1], -1, 1)) / np.pi])
    return V, F, UV, hints


def build_scan(folder: Path, rows: int, cols: int) -> Path:
    import yaml
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    if (folder / "scan.yaml").exists():
        return folder
    V, F, UV, hints = latlong_head(rows, cols)
    vert = np.zeros(len(V), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("s", "<f4"), ("t", "<f4")])
    vert["x"], vert["y"], vert["z"] = V.T
    vert["s"], vert["t"] = UV.T
    face = np.zeros(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, F
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\nproperty float x\n"
              "property float y\nproperty float z\nproperty float s\nproperty float t\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(folder / "scan.ply", "wb") as fh:
        fh.write(header.encode())
        fh.write(vert.tobytes())
        fh.write(face.tobytes())
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 255, (1024, 1024, 3), dtype=np.uint8)).save(folder / "texture.png")
    sidecar = {"mesh": "scan.ply", "texture": "texture.png", "units": "mm", "up_axis": "+Y", "forward_axis": "+Z",
               "eyes": {s: {"hint": [float(x) for x in h]} for s, h in hints.items()},
               "licence": "CC0 (benchmark)"}
    (folder / "scan.yaml").write_text(yaml.safe_dump(sidecar, sort_keys=False))
    return folder


def build_obj_scan(folder: Path, ply_folder: Path, rows: int, cols: int) -> Path:
    """The same head as an OBJ with per-corner ``f v/vt`` UVs (written once, cached)."""
    import shutil

    folder.mkdir(parents=True, exist_ok=True)
    if (folder / "scan.yaml").exists():
        return folder
    import yaml

    V, F, UV, _ = latlong_head(rows, cols)
    with open(folder / "scan.obj", "w") as fh:
        fh.write("mtllib scan.mtl\n")
        np.savetxt(fh, V, fmt="v %.5f %.5f %.5f")
        np.savetxt(fh, UV, fmt="vt %.6f %.6f")
        fh.write("usemtl skin\n")
        np.savetxt(fh, np.repeat(F + 1, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
    (folder / "scan.mtl").write_text("newmtl skin\nmap_Kd texture.png\n")
    shutil.copy(ply_folder / "texture.png", folder / "texture.png")
    sidecar = yaml.safe_load((ply_folder / "scan.yaml").read_text())
    sidecar["mesh"] = "scan.obj"
    sidecar.pop("texture")
    (folder / "scan.yaml").write_text(yaml.safe_dump(sidecar, sort_keys=False))
    return folder


def run_once(scan: Path, out: Path):
    metrics = out.with_name(out.name + ".metrics.json")
    cmd = [sys.executable, "-m", "stages.ingest", str(scan), str(out), "--metrics", str(metrics)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"ingest failed ({proc.returncode}): {err}")
    return wall, usage.ru_maxrss / 1024.0, read_stage_metrics(metrics)   # metrics + timings


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--rows", type=int, default=701)
    ap.add_argument("--cols", type=int, default=1000)
    ap.add_argument("--scan", type=Path, default=None, help="use this scan folder instead of the generated one")
    ap.add_argument("--formats", nargs="+", default=["ply", "obj"], choices=["ply", "obj"])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "ingest.json")
    args = ap.parse_args(argv)
    work = Path(tempfile.gettempdir()) / "eyerig_bench_ingest"
    ply = args.scan or build_scan(work / f"head_{args.rows}x{args.cols}", args.rows, args.cols)
    scans = {"ply": ply}
    if "obj" in args.formats and args.scan is None:
        scans["obj"] = build_obj_scan(work / f"head_{args.rows}x{args.cols}_obj", ply, args.rows, args.cols)
    result = {
        "what": "python -m stages.ingest as a subprocess; ply = binary PLY (float32 xyz + s,t UVs) + 1024^2 "
                "PNG texture named in scan.yaml; obj = same head as OBJ (f v/vt) + MTL map_Kd",
        "command": ".venv/bin/python -m benchmarks.bench_ingest " + " ".join(argv if argv is not None else sys.argv[1:]),
        "targets": {"format": "ply", "wall_s": 5.0, "peak_rss_mib": 2048},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
    }
    for fmt, scan in scans.items():
        if fmt not in args.formats:
            continue
        walls, rss, m = [], [], None
        for i in range(args.runs):
            wall, peak, m = run_once(scan, work / "out" / "ingest")
            walls.append(wall)
            rss.append(peak)
            print(f"{fmt} run {i + 1}: wall {wall:.2f} s, peak RSS {peak:.0f} MiB, "
                  f"stage-reported {m['wall_time_s']:.2f} s")
        result[fmt] = {
            "faces": m["faces_in"], "vertices": m["vertices_in"], "runs": args.runs,
            "wall_s_median": round(statistics.median(walls), 3),
            "wall_s_all": [round(w, 3) for w in walls],
            "peak_rss_mib_median": round(statistics.median(rss), 1),
            "peak_rss_mib_all": [round(r, 1) for r in rss],
        }
        print(f"ingest {fmt} {m['faces_in']} faces: median wall {result[fmt]['wall_s_median']} s, "
              f"median peak RSS {result[fmt]['peak_rss_mib_median']} MiB")
    result["meets_targets"] = result["ply"]["wall_s_median"] <= 5.0 and result["ply"]["peak_rss_mib_median"] <= 2048
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"targets (ply): 5 s, 2048 MiB -> {'met' if result['meets_targets'] else 'NOT met'}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
