"""The dataset command's render over a TLS LocalCluster (as shipped) against plain TCP (issue 31).

    .venv/bin/python -m benchmarks.bench_tls_render [--assets rigged_assets/synthetic_head]
        [--n 24] [--workers 2] [--repeats 3]

Each repeat renders the same ``--n`` image ``generic`` dataset twice into fresh folders, one
after the other (TCP first, then TLS), each in its own process: ``on`` is ``stages.dataset`` as
shipped; ``off`` the same with the LocalCluster given no credentials and the ``tcp://`` protocol
(the only change). Prints the wall time of every run and the medians, checks that both runs
wrote the same labels, and writes ``benchmarks/results/tls_render.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _plain_tcp():
    """The LocalCluster without TLS: no credentials, tcp://."""
    import dask.distributed as dd
    from distributed.security import Security

    import pipeline.render.shard as shard

    base = dd.LocalCluster

    class PlainCluster(base):
        def __init__(self, *a, **kw):
            kw.pop("security", None)
            kw.pop("protocol", None)
            super().__init__(*a, **kw)

    dd.LocalCluster = PlainCluster
    shard.local_security = lambda: Security()


def _labels_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.glob("0*.json")):
        h.update(p.read_bytes())
    return h.hexdigest()


def _one(mode: str, assets: str, n: int, workers: int, out: Path) -> None:
    if mode == "off":
        _plain_tcp()
    from stages.dataset import main

    rc = main(["--assets", assets, "--n", str(n), "--preset", "generic", "--out", str(out),
               "--workers", str(workers), "--no-progress"])
    sys.exit(int(rc or 0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--assets", default=str(ROOT / "rigged_assets" / "synthetic_head"))
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--one", nargs=2, metavar=("MODE", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "tls_render.json"))
    a = ap.parse_args(argv)
    if a.one:
        return _one(a.one[0], a.assets, a.n, a.workers, Path(a.one[1]))
    runs = {"off": [], "on": []}
    same = True
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeats):
            digests = {}
            for mode in ("off", "on"):
                out = Path(tmp) / f"{mode}{i}"
                t0 = time.perf_counter()
                r = subprocess.run([sys.executable, "-m", "benchmarks.bench_tls_render", "--assets", a.assets,
                                    "--n", str(a.n), "--workers", str(a.workers), "--one", mode, str(out)],
                                   cwd=ROOT, capture_output=True, text=True)
                wall = time.perf_counter() - t0
                if r.returncode:
                    sys.exit(f"error: {mode} run failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}")
                runs[mode].append(round(wall, 2))
                digests[mode] = _labels_digest(out)
                print(f"repeat {i}: TLS {mode:3s} {wall:6.2f} s", flush=True)
            same &= digests["on"] == digests["off"]
    med = {m: statistics.median(v) for m, v in runs.items()}
    doc = {"images": a.n, "workers": a.workers, "runs_s": runs, "median_s": med,
           "tls_over_tcp": round(med["on"] / med["off"], 3), "labels_identical": same,
           "per_image_s": {m: round(v / a.n, 4) for m, v in med.items()}}
    Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"median TCP {med['off']:.2f} s, TLS {med['on']:.2f} s (x{doc['tls_over_tcp']}), labels identical: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
