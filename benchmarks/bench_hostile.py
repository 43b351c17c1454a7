"""Hostile scan folders through the ingest stage: per case the wall time and the child's peak memory.

    .venv/bin/python -m benchmarks.bench_hostile [--out benchmarks/results/hostile.json] [--cap-mib 1536]
                                                 [--at-limits]

Builds every case of :data:`CASES` (and :data:`ACCEPTED`, hostile-looking inputs that
are within the limits and must ingest) from a good synthetic head in a temporary
folder, runs ``python -m stages.ingest FOLDER OUT`` in a subprocess under an
address-space cap (``RLIMIT_AS``, ``--cap-mib``), and records the exit status, the
stderr line, the wall time and the child's own peak RSS (``os.wait4`` rusage).
Targets (issue 12): an over-limit input is refused within 2 s and 500 MiB; an input
within the limits ingests within 2.5 GiB. ``tests/test_hostile_inputs.py`` runs the
same cases and asserts the messages and bounds. ``--at-limits`` adds the largest scan
the default limits accept (the ``bench_ingest`` head at 4,998,002 vertices and 9,996,000
triangles: binary PLY with a 1024^2 texture, the same as OBJ + MTL, as GLB with UVs and as
binary STL; about 1.7 GB on disk, cached in the temp folder), run under the stage's own bound only.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import struct
import tempfile
from pathlib import Path

import numpy as np

from tests.fixtures import build_case, run_ingest, write_sidecar
from tests.fixtures.hostile import ACCEPT_PEAK_MIB, ACCEPTED, CASES, REFUSE_PEAK_MIB, REFUSE_WALL_S, glb_bytes

ROOT = Path(__file__).resolve().parents[1]


def glb_scan(folder: Path, rows: int, cols: int) -> Path:
    """The bench_ingest lat/long head as a one-mesh GLB (float32 positions and UVs, uint32 indices); cached."""
    from benchmarks.bench_ingest import latlong_head

    if (folder / "scan.yaml").exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    V, F, UV, hints = latlong_head(rows, cols)
    parts = [V.astype("<f4").tobytes(), F.astype("<u4").tobytes(), UV.astype("<f4").tobytes()]
    offsets = np.cumsum([0] + [len(p) for p in parts])
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 1}]}],
           "buffers": [{"byteLength": int(offsets[-1])}],
           "bufferViews": [{"buffer": 0, "byteOffset": int(o), "byteLength": len(p)} for o, p in zip(offsets, parts)],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(V), "type": "VEC3",
                          "min": V.min(axis=0).tolist(), "max": V.max(axis=0).tolist()},
                         {"bufferView": 1, "componentType": 5125, "count": F.size, "type": "SCALAR"},
                         {"bufferView": 2, "componentType": 5126, "count": len(V), "type": "VEC2"}]}
    (folder / "scan.glb").write_bytes(glb_bytes(doc, b"".join(parts)))
    write_sidecar(folder, hints, mesh="scan.glb")
    return folder


def stl_scan(folder: Path, rows: int, cols: int) -> Path:
    """The bench_ingest lat/long head as a binary STL (a triangle soup); cached."""
    from benchmarks.bench_ingest import latlong_head

    if (folder / "scan.yaml").exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    V, F, _, hints = latlong_head(rows, cols)
    records = np.zeros(len(F), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    records["corners"] = V[F]
    with open(folder / "scan.stl", "wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", len(F)))
        fh.write(records.tobytes())
    write_sidecar(folder, hints, mesh="scan.stl")
    return folder


def at_limits(fmt: str) -> dict:
    """Ingest the largest head the default limits accept (cached bench_ingest folders); one result row."""
    from benchmarks.bench_ingest import build_obj_scan, build_scan

    rows_, cols = 2500, 2000                     # 2 * 2000 * 2499 = 9,996,000 triangles
    work = Path(tempfile.gettempdir()) / "eyerig_bench_ingest"
    if fmt in ("glb", "stl"):
        folder = (glb_scan if fmt == "glb" else stl_scan)(work / f"head_{rows_}x{cols}_{fmt}", rows_, cols)
    else:
        folder = build_scan(work / f"head_{rows_}x{cols}", rows_, cols)
    if fmt == "obj":
        folder = build_obj_scan(work / f"head_{rows_}x{cols}_obj", folder, rows_, cols)
    size = sum(p.stat().st_size for p in folder.iterdir())
    with tempfile.TemporaryDirectory(prefix="hostile-") as tmp:
        r = run_ingest(folder, Path(tmp) / "out", cap_mib=1 << 20, cpu_s=600)
        faces = json.loads((Path(tmp) / "out.metrics.json").read_text())["faces_in"] if r.returncode == 0 else None
    print(f"{'at_limits_' + fmt:34s} accepted exit {r.returncode}  {r.wall_s:6.2f} s  {r.peak_mib:7.1f} MiB", flush=True)
    return {"case": f"at_limits_{fmt}", "expect": "accepted", "ok": r.returncode == 0,
            "within_targets": r.peak_mib <= ACCEPT_PEAK_MIB, "folder_mib": round(size / 2**20, 2),
            "faces": faces, "exit": r.returncode, "wall_s": round(r.wall_s, 3), "cpu_s": round(r.cpu_s, 3),
            "peak_mib": round(r.peak_mib, 1), "stderr": r.stderr.strip()[:300]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "hostile.json"))
    ap.add_argument("--cap-mib", type=float, default=1536, help="address-space cap of each ingest child")
    ap.add_argument("--at-limits", action="store_true", help="also ingest a 10M-triangle PLY, OBJ, GLB and STL")
    args = ap.parse_args(argv)
    rows = []
    todo = [(c.name, c.build, "refused") for c in CASES] + [(a.__name__[2:], a, "accepted") for a in ACCEPTED]
    if args.at_limits:
        rows += [at_limits(fmt) for fmt in ("ply", "obj", "glb", "stl")]
    for name, build, expect in todo:
        with tempfile.TemporaryDirectory(prefix="hostile-") as tmp:
            tmp = Path(tmp)
            folder, params = build_case(build, tmp)
            size = sum(p.stat().st_size for p in folder.iterdir() if p.is_file() and not p.is_symlink())
            r = run_ingest(folder, tmp / "out", params, cap_mib=args.cap_mib)
            ok = (r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
                  and not (tmp / "out").exists()) if expect == "refused" else r.returncode == 0
            within = (r.wall_s <= REFUSE_WALL_S and r.peak_mib <= REFUSE_PEAK_MIB) if expect == "refused" \
                else r.peak_mib <= ACCEPT_PEAK_MIB
        rows.append({"case": name, "expect": expect, "ok": ok, "within_targets": within,
                     "folder_mib": round(size / 2**20, 2), "exit": r.returncode, "wall_s": round(r.wall_s, 3),
                     "cpu_s": round(r.cpu_s, 3), "peak_mib": round(r.peak_mib, 1),
                     "stderr": r.stderr.strip()[:300]})
        print(f"{name:34s} {expect:8s} exit {r.returncode}  {r.wall_s:6.2f} s  {r.peak_mib:7.1f} MiB"
              f"  {'ok' if ok and within else 'FAIL'}", flush=True)
    result = {
        "what": "python -m stages.ingest on hostile scan folders (built from the test head of tests/fixtures); "
                "peak = the child's own ru_maxrss (os.wait4)",
        "command": ".venv/bin/python -m benchmarks.bench_hostile",
        "targets": {"refused_wall_s": REFUSE_WALL_S, "refused_peak_mib": REFUSE_PEAK_MIB,
                    "accepted_peak_mib": ACCEPT_PEAK_MIB},
        "address_space_cap_mib": args.cap_mib,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "all_ok": all(r["ok"] and r["within_targets"] for r in rows),
        "max_refused_wall_s": max(r["wall_s"] for r in rows if r["expect"] == "refused"),
        "max_refused_peak_mib": max(r["peak_mib"] for r in rows if r["expect"] == "refused"),
        "max_accepted_peak_mib": max(r["peak_mib"] for r in rows if r["expect"] == "accepted"),
        "cases": rows,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}: all ok {result['all_ok']}, refused max {result['max_refused_wall_s']} s / "
          f"{result['max_refused_peak_mib']} MiB, accepted max {result['max_accepted_peak_mib']} MiB")


if __name__ == "__main__":
    main()
