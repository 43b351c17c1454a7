"""The five probes of issue 31, run as a hostile local user would; each hole is open or closed.

    .venv/bin/python -m benchmarks.bench_holes [--out benchmarks/results/holes.json] [--tasks 400]

1. texture: PostScript, EPS, PDF and XPM content under a ``.png`` name, through ``stages.ingest``
   (closed: exit 2, one line naming the file and the format, no output);
2. lock: a second ``stages.dataset`` run into a folder a first run holds (closed: refused in one
   line naming the holder's pid);
3. cluster: a client with no credentials, and one with its own, against the render's LocalCluster
   of two worker processes (closed: neither can run code in the workers);
4. links: ``card/`` linked to another folder, and ``.tmp`` linked elsewhere, in an earlier dataset,
   re-run with ``--overwrite`` (closed: one line, the other folder untouched);
5. settings: a params.yaml with ``samples`` twice under ``render:`` through ``stages.check_params``
   and ``stages.dataset --params`` (closed: exit 2, one line naming the key).

Also the Dask dispatch cost with TLS on against off: ``--tasks`` trivial tasks through a
LocalCluster of two worker processes, each way (the render's shards are the same round trip; a
Blender image takes about 0.4 s, so the overhead per shard is what this measures).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(args, **kw):
    return subprocess.run([sys.executable, "-m", *map(str, args)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, **kw)


def _one_line_refusal(p, *must) -> bool:
    lines = p.stderr.strip().splitlines()
    return p.returncode == 2 and len(lines) == 1 and all(m in lines[0] for m in must)


def _fake_assets(tmp: Path) -> list[str]:
    """An asset folder and its rig file: enough for the dataset command to reach its folder checks."""
    (tmp / "rigged_assets" / "head").mkdir(parents=True)
    (tmp / "build" / "head" / "rig").mkdir(parents=True)
    (tmp / "build" / "head" / "rig" / "rig.npz").write_bytes(b"")
    return [str(tmp / "rigged_assets" / "head")]


def probe_texture(tmp: Path) -> dict:
    from tests.fixtures import build_case
    from tests.fixtures.hostile import NOT_IMAGES, _not_image_texture

    rows = {}
    for kind in NOT_IMAGES:
        case = tmp / kind.split()[0]
        case.mkdir()
        folder, _ = build_case(_not_image_texture(kind), case)
        p = _run(["stages.ingest", folder, case / "out"])
        rows[kind] = {"closed": _one_line_refusal(p, "skin.png", f"texture is {kind}, not PNG/JPEG/TIFF")
                      and not (case / "out").exists(), "stderr": p.stderr.strip()}
    return {"closed": all(r["closed"] for r in rows.values()), "cases": rows}


def probe_lock(tmp: Path) -> dict:
    from pipeline.io.folder_lock import folder_lock

    out = tmp / "ds"
    with folder_lock(out):                  # the first run, holding the folder
        p = _run(["stages.dataset", "--assets", *_fake_assets(tmp), "--n", "2", "--out", out, "--params",
                  ROOT / "params.yaml", "--no-progress"])
    return {"closed": _one_line_refusal(p, "is in use by another dataset run", f"pid {os.getpid()}"),
            "stderr": p.stderr.strip()}


def probe_cluster() -> dict:
    from dask.distributed import Client
    from distributed.security import Security

    from pipeline.render.shard import _client

    client, cluster = _client(2, None, 10.0)
    got = {}
    try:
        address = cluster.scheduler_address
        for how, kw in (("plain tcp", {"address": address.replace("tls://", "tcp://")}),
                        ("no credentials", {"address": address}),
                        ("its own certificates", {"address": address, "security": Security.temporary()})):
            t0 = time.perf_counter()
            try:
                intruder = Client(timeout="3s", **kw)
                intruder.run(os.getpid)
                intruder.close()
                got[how] = {"refused": False}
            except Exception as exc:  # noqa: BLE001
                got[how] = {"refused": True, "as": type(exc).__name__, "s": round(time.perf_counter() - t0, 2)}
        own = len(client.run(os.getpid)) == 2
    finally:
        client.close()
        cluster.close()
    return {"closed": own and all(g["refused"] for g in got.values()), "address": address, "intruders": got,
            "own_client_reaches_workers": own}


def probe_links(tmp: Path) -> dict:
    rows = {}
    for name in ("card", ".tmp"):
        case = tmp / name.strip(".")
        out, other = case / "ds", case / "mine"
        out.mkdir(parents=True)
        other.mkdir()
        (other / "gaze.png").write_bytes(b"mine")
        (out / "config.json").write_text(json.dumps({"config_hash": "0" * 64, "dataset": {}}))
        os.symlink(other, out / name)
        p = _run(["stages.dataset", "--assets", *_fake_assets(case), "--n", "2", "--out", out, "--params",
                  ROOT / "params.yaml", "--no-progress", "--overwrite"])
        rows[name] = {"closed": _one_line_refusal(p, f"{out / name}: is a symbolic link")
                      and sorted(os.listdir(other)) == ["gaze.png"] and (other / "gaze.png").read_bytes() == b"mine",
                      "stderr": p.stderr.strip()}
    return {"closed": all(r["closed"] for r in rows.values()), "cases": rows}


def probe_settings(tmp: Path) -> dict:
    params = tmp / "params.yaml"
    params.write_text((ROOT / "params.yaml").read_text().replace("\nrender:\n", "\nrender:\n  samples: 99\n", 1))
    a = _run(["stages.check_params", params, tmp / "ok"])
    b = _run(["stages.dataset", "--assets", *_fake_assets(tmp), "--n", "2", "--out", tmp / "ds", "--params",
              params, "--no-progress"])
    return {"closed": all(_one_line_refusal(p, "duplicate key 'samples'") for p in (a, b)),
            "check_params": a.stderr.strip(), "dataset": b.stderr.strip()}


def dispatch(tasks: int) -> dict:
    """Seconds for ``tasks`` trivial round trips through a 2-process LocalCluster, TLS on and off."""
    import logging

    from dask.distributed import Client, LocalCluster

    from pipeline.render.shard import LOOPBACK, local_security

    out = {}
    for tls in (False, True):
        kw = {"security": local_security(), "protocol": "tls://"} if tls else {"protocol": "tcp://"}
        t0 = time.perf_counter()
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host=LOOPBACK,
                               dashboard_address=f"{LOOPBACK}:0", memory_limit=0, silence_logs=logging.ERROR, **kw)
        client = Client(cluster, **({"security": kw["security"]} if tls else {}))
        start = time.perf_counter() - t0
        client.submit(int, "1").result()
        t1 = time.perf_counter()
        assert sum(client.gather(client.map(int, [str(i) for i in range(tasks)], pure=False))) == tasks * (tasks - 1) // 2
        run = time.perf_counter() - t1
        client.close()
        cluster.close()
        out["tls" if tls else "tcp"] = {"cluster_start_s": round(start, 3), "tasks": tasks, "tasks_s": round(run, 3),
                                       "ms_per_task": round(1000 * run / tasks, 3)}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "holes.json"))
    ap.add_argument("--tasks", type=int, default=400)
    args = ap.parse_args(argv)
    probes = {}
    with tempfile.TemporaryDirectory(prefix="holes-") as tmp:
        tmp = Path(tmp)
        for name, fn in (("texture", probe_texture), ("lock", probe_lock), ("cluster", probe_cluster),
                         ("links", probe_links), ("settings", probe_settings)):
            (tmp / name).mkdir()
            t0 = time.perf_counter()
            probes[name] = fn() if name == "cluster" else fn(tmp / name)
            probes[name]["wall_s"] = round(time.perf_counter() - t0, 2)
            print(f"{name:9s} {'closed' if probes[name]['closed'] else 'OPEN'}  ({probes[name]['wall_s']} s)", flush=True)
    timing = dispatch(args.tasks)
    print(f"dispatch, 2 worker processes, {args.tasks} trivial tasks: TCP {timing['tcp']['ms_per_task']} ms/task "
          f"(start {timing['tcp']['cluster_start_s']} s), TLS {timing['tls']['ms_per_task']} ms/task "
          f"(start {timing['tls']['cluster_start_s']} s)")
    n_open = sum(not p["closed"] for p in probes.values())
    result = {"what": "issue 31's five probes, as a hostile local user", "command": ".venv/bin/python -m "
              "benchmarks.bench_holes", "open": n_open, "of": len(probes), "probes": probes,
              "dispatch_tls_vs_tcp": timing,
              "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}: {n_open} of {len(probes)} holes open")


if __name__ == "__main__":
    main()
