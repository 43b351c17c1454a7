"""The dask side of a render (pipeline/render/shard.py): a LocalCluster listens on 127.0.0.1
only, each server on a free port, with no dashboard unless asked for; concurrent runs neither
collide nor warn; on a real cluster (``dask scheduler`` and two ``dask worker`` processes) a worker
SIGKILLed mid-run loses nothing and changes no byte.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import psutil
import pytest

from fixtures import make_two_assets
from pipeline.io.labels_file import read_index

ROOT = Path(__file__).resolve().parents[1]
LOOPBACK = "127.0.0.1"
TINY = {"width": 24, "height": 16, "frame_margin_px": None, "samples": 1, "denoise": False, "shard_size": 2, "connect_timeout_s": 10,
        "sheet_images": 2}


def listening(proc: psutil.Process) -> set[tuple[int, str, int]]:
    """``(pid, address, port)`` of every listening socket of ``proc`` and its descendants."""
    found = set()
    try:
        family = [proc, *proc.children(recursive=True)]
    except psutil.NoSuchProcess:
        return found
    for p in family:
        try:
            found |= {(p.pid, c.laddr.ip, c.laddr.port) for c in p.net_connections(kind="inet")
                      if c.status == psutil.CONN_LISTEN}
        except (psutil.NoSuchProcess, psutil.ZombieProcess, psutil.AccessDenied):
            pass
    return found


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    return make_two_assets(tmp_path_factory.mktemp("shard"), TINY)


def _cmd(two, out, *extra, n=6):
    return [sys.executable, "-m", "stages.dataset", "--assets", *map(str, two["assets"]), "--n", str(n),
            "--out", str(out), "--params", str(two["params"]), "--no-progress", *extra]


def _labels(out: Path) -> int:
    return len(list(out.glob("0*.json")))


def _files(out: Path) -> dict:
    """Every file of a dataset but what a run measured (timings.json), by relative path."""
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name != "timings.json"}


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_local_cluster_listens_on_loopback_and_serves_a_dashboard_only_when_asked(workers):
    from pipeline.render.shard import _client

    for dashboard in (False, True):
        client, cluster = _client(workers, None, dashboard=dashboard)
        try:
            assert client.submit(int, "7").result() == 7
            sockets = listening(psutil.Process())
            port = cluster.scheduler.http_server.port
            try:
                with urllib.request.urlopen(f"http://{LOOPBACK}:{port}/status", timeout=10) as r:
                    status = r.status
            except urllib.error.HTTPError as exc:
                status = exc.code
        finally:
            client.close()
            cluster.close()
        # the scheduler's and each worker's HTTP server, the scheduler and (processes) each
        # nanny and worker: all on 127.0.0.1, none on a fixed port
        assert len(sockets) >= 2 and {ip for _, ip, _ in sockets} == {LOOPBACK}, sockets
        assert 8787 not in {p for _, _, p in sockets}
        assert status == (200 if dashboard else 404)


@pytest.mark.slow
def test_local_cluster_admits_only_the_runs_own_client():
    """The worker processes' LocalCluster speaks TLS with credentials made for the run (issue 31):
    another local process cannot connect, with no credentials, over plain TCP or with its own
    certificates, so it cannot run code in the workers; the run's own client can."""
    from dask.distributed import Client
    from distributed.security import Security

    from pipeline.render.shard import _client

    client, cluster = _client(2, None, 10.0)
    try:
        address = cluster.scheduler_address
        assert address.startswith(f"tls://{LOOPBACK}:"), address
        ran = []
        for how, kw in (("tcp", {"address": address.replace("tls://", "tcp://")}),
                        ("no credentials", {"address": address}),
                        ("its own certificates", {"address": address, "security": Security.temporary()})):
            t0 = time.perf_counter()
            with pytest.raises(Exception):  # noqa: B017 - refused any way dask likes (closed, TLS, config)
                intruder = Client(timeout="3s", **kw)
                ran.append((how, intruder.run(os.getpid)))
                intruder.close()
            assert time.perf_counter() - t0 < 8, how
        assert ran == []
        assert len(client.run(os.getpid)) == 2          # the run's own client reaches both workers
    finally:
        client.close()
        cluster.close()


@pytest.mark.blender
def test_concurrent_renders_listen_on_loopback_only_and_do_not_warn(two, tmp_path):
    """Two dataset runs at once (one worker in-process, two as processes): every listening socket
    of either process tree, sampled while images are rendered, is on 127.0.0.1; both finish
    cleanly with nothing on stderr."""
    outs = {w: tmp_path / f"w{w}" for w in (1, 2)}
    procs = {w: subprocess.Popen(_cmd(two, outs[w], "--workers", str(w)), cwd=ROOT, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True) for w in (1, 2)}
    seen = {w: set() for w in procs}
    mid_run = {w: 0 for w in procs}              # samples taken with images done and images to go
    try:
        while any(p.poll() is None for p in procs.values()):
            for w, p in procs.items():
                if p.poll() is None:
                    now = listening(psutil.Process(p.pid))
                    seen[w] |= now
                    mid_run[w] += bool(now) and 0 < _labels(outs[w]) < 6
            time.sleep(0.05)
        results = {w: p.communicate(timeout=60) for w, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
    for w, p in procs.items():
        assert p.returncode == 0 and results[w][1] == "", results[w]
        assert mid_run[w] > 0 and seen[w], (w, mid_run[w])
        off = {s for s in seen[w] if s[1] != LOOPBACK}
        assert not off, f"listening off loopback: {off}"
        assert json.loads((outs[w] / "timings.json").read_text())["rendered"] == 6


def _start(cmd, env):
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)


def _stop(proc) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


@pytest.mark.blender
@pytest.mark.slow
def test_worker_killed_on_a_real_cluster_loses_nothing(two, tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes on loopback; a dataset rendered on
    them, then the same plan again with one worker SIGKILLed while its Blender renders: every
    index once, and every file byte-identical to the uninterrupted run's."""
    dask = Path(sys.executable).with_name("dask")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    info = tmp_path / "scheduler.json"
    procs = [_start([str(dask), "scheduler", "--host", LOOPBACK, "--port", "0", "--no-dashboard",
                     "--dashboard-address", f"{LOOPBACK}:0", "--scheduler-file", str(info)], env)]
    try:
        t0 = time.time()
        while not info.is_file() and time.time() - t0 < 60:
            time.sleep(0.1)
        workers = [_start([str(dask), "worker", "--scheduler-file", str(info), "--nthreads", "1", "--no-nanny",
                           "--host", LOOPBACK, "--no-dashboard", "--dashboard-address", f"{LOOPBACK}:0",
                           "--name", f"w{k}"], env) for k in range(2)]
        procs += workers
        address = json.loads(info.read_text())["address"]
        n = 8
        whole, killed = tmp_path / "whole" / "ds", tmp_path / "killed" / "ds"
        r = subprocess.run(_cmd(two, whole, "--scheduler", address, n=n), cwd=ROOT, capture_output=True,
                           text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        run = subprocess.Popen(_cmd(two, killed, "--scheduler", address, n=n), cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        victim = psutil.Process(workers[0].pid)
        t0 = time.time()
        while time.time() - t0 < 300 and run.poll() is None:
            if _labels(killed) >= 1 and victim.children():       # images done, the victim's Blender at work
                break
            time.sleep(0.02)
        assert run.poll() is None and victim.children(), "the run ended before the worker could be killed"
        done_at_kill = _labels(killed)
        os.kill(victim.pid, signal.SIGKILL)
        out, err = run.communicate(timeout=600)
        assert run.returncode == 0, err
        assert workers[0].wait(timeout=10) == -signal.SIGKILL and workers[1].poll() is None
    finally:
        for p in procs:
            _stop(p)
    assert 1 <= done_at_kill < n
    assert [row["index"] for row in read_index(killed / "index.jsonl")] == list(range(n))
    a, b = _files(whole), _files(killed)
    assert sorted(a) == sorted(b) and len([k for k in a if k.endswith(".png") and k[0] == "0"]) == 2 * n
    assert [k for k in a if a[k] != b[k]] == []


def test_only_the_shutdown_timeout_of_an_unawaited_future_is_muted(caplog):
    """A future that failed with tornado's TimeoutError('Timeout') and that nothing awaits is
    logged by asyncio when collected (once on stderr of a dataset run that succeeded); the filter
    drops exactly that, not another exception nor another timeout."""
    import asyncio
    import gc
    import logging

    from pipeline.render.shard import _ShutdownTimeout, mute_shutdown_timeout

    def abandon(exc):
        loop = asyncio.new_event_loop()
        try:
            fut = loop.create_future()
            fut.set_exception(exc)
            del fut
            gc.collect()
        finally:
            loop.close()

    log = logging.getLogger("asyncio")
    before = list(log.filters)
    try:
        with caplog.at_level(logging.ERROR, logger="asyncio"):
            abandon(TimeoutError("Timeout"))
            assert [r.getMessage().splitlines()[0] for r in caplog.records] == [
                "Future exception was never retrieved"]      # what reached stderr before the filter
            caplog.clear()
            mute_shutdown_timeout()
            mute_shutdown_timeout()
            abandon(TimeoutError("Timeout"))
            abandon(TimeoutError("connect timed out"))
            abandon(ValueError("Timeout"))
        assert [r.exc_info[1].args for r in caplog.records] == [("connect timed out",), ("Timeout",)]
        assert sum(isinstance(f, _ShutdownTimeout) for f in log.filters) == 1
    finally:
        log.filters[:] = before


def test_only_the_heartbeat_error_is_muted_and_only_while_asked(caplog):
    """The shutdown filter drops the worker's heartbeat traceback and nothing else, and is gone
    again after unmute (a run with an in-process worker leaves the logger as it found it)."""
    import logging

    from pipeline.render.shard import mute_shutdown_heartbeat, unmute_shutdown_heartbeat

    log = logging.getLogger("distributed.worker")
    before = list(log.filters)
    with caplog.at_level(logging.ERROR, logger="distributed.worker"):
        mute_shutdown_heartbeat()
        mute_shutdown_heartbeat()
        log.error("Failed to communicate with scheduler during heartbeat.")
        log.error("Compute Failed")
        unmute_shutdown_heartbeat()
        log.error("Failed to communicate with scheduler during heartbeat.")
    assert [r.getMessage() for r in caplog.records] == [
        "Compute Failed", "Failed to communicate with scheduler during heartbeat."]
    assert log.filters == before
