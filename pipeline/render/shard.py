"""Render shards through ``dask.distributed`` with one persistent Blender process per dask worker.

* :class:`BlenderProcess` runs the render worker (``pipeline.blender.render_worker ASSET RIG``),
  started through the door to Blender (pipeline/blender/launch.py): one
  :class:`pipeline.render.spec.RenderSpec` a JSON line on stdin, ``@@render@@``-prefixed reply
  lines on stdout, Blender's chatter on stderr goes to a log file. It dies with its parent
  (``PR_SET_PDEATHSIG``) and on stdin EOF.
* :func:`render_shard` is the dask task: it takes the shard's ``(spec, label)`` pairs (one
  HDRI per shard), keeps ONE Blender process per dask worker process in the module-level
  cache :data:`_BLENDER` (so Blender starts once per worker, not per task), renders every
  image whose label is not yet on disk, moves the PNG from ``.tmp/`` into place and writes
  ``NNNNNN.json`` last (atomically): a file pair with its JSON is a finished image, so a
  killed worker loses at most its in-flight image and a resumed run skips finished ones. The
  other label formats of ``render.label_formats`` (pipeline/render/formats/) are written just
  before that JSON.
* :func:`run_shards` submits the shards to a ``LocalCluster(n_workers, threads_per_worker=1)``
  (one worker: a thread of this process; more: processes) or, given a scheduler address, to
  that cluster (``Client(address)``) -- the same code path -- and shows a tqdm progress bar
  (images/s, ETA).
"""

from __future__ import annotations

import atexit
import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pipeline.blender import launch
from pipeline.errors import ScanError
from pipeline.io.png import strip_png_metadata
from pipeline.io.seg_file import depth_name, read_depth, read_seg, seg_name
from pipeline.render.formats import write_formats
from pipeline.render.spec import RenderSpec

REPLY_PREFIX = "@@render@@ "
#: The worker every render shard talks to (started by pipeline/blender/launch.py).
WORKER = "pipeline.blender.render_worker"
_BLENDER: dict = {}
_STARTS = [0]                         # Blender processes started by this process (stats)


class WorkerDied(RuntimeError):
    """The Blender subprocess exited or stopped answering."""


class BlenderProcess:
    """One persistent ``pipeline.blender.render_worker`` subprocess."""

    def __init__(self, asset, rig, threads: int = 0, tile_size: int | None = None,
                 log_path=None, start_timeout_s: float = 600.0, python: str | None = None):
        args = [asset, rig, "--threads", int(threads)] + (["--tile-size", int(tile_size)] if tile_size else [])
        self.log_path = Path(log_path) if log_path else None
        self._log = open(self.log_path, "ab") if self.log_path else subprocess.DEVNULL
        self.proc = launch.start(WORKER, args, stderr=self._log, python=python)
        self._buf = b""
        t0 = time.perf_counter()
        ready = self._reply(start_timeout_s)
        self.startup_s = time.perf_counter() - t0
        if not ready.get("ready"):
            self.close()
            raise WorkerDied(f"Blender worker could not load the asset: {ready.get('error')}")
        self.ready = ready
        self.rendered = 0

    def _reply(self, timeout_s: float) -> dict:
        deadline = time.monotonic() + timeout_s
        fd = self.proc.stdout.fileno()
        while True:
            while b"\n" in self._buf:
                line, self._buf = self._buf.split(b"\n", 1)
                text = line.decode("utf-8", "replace")
                if text.startswith(REPLY_PREFIX):
                    return json.loads(text[len(REPLY_PREFIX):])
            left = deadline - time.monotonic()
            if left <= 0:
                self.close()
                raise WorkerDied(f"no reply from the Blender worker within {timeout_s:.0f} s")
            r, _, _ = select.select([fd], [], [], min(left, 5.0))
            if r:
                chunk = os.read(fd, 65536)
                if not chunk:
                    code = self.proc.wait()
                    raise WorkerDied(f"Blender worker exited (status {code}); log: {self.log_path}")
                self._buf += chunk

    def alive(self) -> bool:
        return self.proc.poll() is None

    def send(self, spec: RenderSpec | dict) -> None:
        """Send one spec (the reply is read with :meth:`receive`); a mapping in the wire layout
        is read as a :class:`RenderSpec` first (a bad one raises ValueError here)."""
        if not isinstance(spec, RenderSpec):
            spec = RenderSpec.from_dict(spec)
        try:
            self.proc.stdin.write((spec.to_json() + "\n").encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            raise WorkerDied(f"Blender worker is gone ({exc})") from None

    def receive(self, timeout_s: float = 600.0) -> dict:
        reply = self._reply(timeout_s)
        self.rendered += 1
        return reply

    def render(self, spec: RenderSpec | dict, timeout_s: float = 600.0) -> dict:
        """Send one spec, wait for its reply."""
        self.send(spec)
        return self.receive(timeout_s)

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write(b'{"quit": true}\n')
                self.proc.stdin.close()
                self.proc.wait(timeout=20)
            except (OSError, subprocess.TimeoutExpired, ValueError):
                self.proc.kill()
                self.proc.wait()
        if self._log is not subprocess.DEVNULL:
            self._log.close()


def _close_all() -> None:
    while _BLENDER:
        _, bp = _BLENDER.popitem()
        bp.close()


atexit.register(_close_all)


def blender_stats() -> dict:
    """Blender starts of this process and its live Blender's pid / images / start-up (for client.run)."""
    out = {"starts": _STARTS[0], "alive": []}
    for bp in _BLENDER.values():
        out["alive"].append({"pid": bp.proc.pid, "rendered": bp.rendered, "startup_s": round(bp.startup_s, 3),
                             "rss_mib_ready": bp.ready.get("rss_mib")})
    return out


def close_blender() -> int:
    """Close this process's Blender workers (for client.run at the end of a run)."""
    n = len(_BLENDER)
    _close_all()
    return n


class _ShutdownHeartbeat:
    """A logging filter that drops the worker's "Failed to communicate with scheduler during
    heartbeat" error. Installed only once every image is in, it hides a race in
    ``distributed`` (dask/distributed#7105, #9032): a worker's heartbeat already in flight when
    the cluster closes reads a stream the scheduler has closed, and logs a traceback to stderr
    of a run that succeeded. Before that point the message still reaches stderr."""

    def filter(self, record) -> bool:
        return "during heartbeat" not in record.getMessage()


def mute_shutdown_heartbeat() -> None:
    """Install :class:`_ShutdownHeartbeat` on this process's ``distributed.worker`` logger (for
    client.run once the work is done); idempotent."""
    import logging

    log = logging.getLogger("distributed.worker")
    if not any(isinstance(f, _ShutdownHeartbeat) for f in log.filters):
        log.addFilter(_ShutdownHeartbeat())


def unmute_shutdown_heartbeat() -> None:
    """Remove :class:`_ShutdownHeartbeat` from this process's ``distributed.worker`` logger."""
    import logging

    log = logging.getLogger("distributed.worker")
    for f in [f for f in log.filters if isinstance(f, _ShutdownHeartbeat)]:
        log.removeFilter(f)


class _ShutdownTimeout:
    """A logging filter that drops asyncio's "Future exception was never retrieved" for tornado's
    ``TimeoutError('Timeout')`` (``gen.with_timeout``, the message it sets). Closing the
    in-process worker can leave ``distributed``'s batched stream waiting on its stopped event
    with a timeout when the loop stops; nothing awaits that future again, and when it is
    collected asyncio logs it to stderr of a run that succeeded (seen once in 20 runs of
    test_shard's loopback test). The future is collected whenever the garbage collector gets to
    it, after the close and possibly at exit, so the filter stays once installed; any other
    exception, or another timeout's message, still reaches stderr."""

    def filter(self, record) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (record.getMessage().startswith("Future exception was never retrieved")
                    and isinstance(exc, TimeoutError) and exc.args == ("Timeout",))


def mute_shutdown_timeout() -> None:
    """Install :class:`_ShutdownTimeout` on this process's ``asyncio`` logger; idempotent."""
    import logging

    log = logging.getLogger("asyncio")
    if not any(isinstance(f, _ShutdownTimeout) for f in log.filters):
        log.addFilter(_ShutdownTimeout())


def get_blender(asset, rig, opts: dict) -> BlenderProcess:
    """The persistent Blender process of this (dask worker) process, started on first use."""
    key = (str(asset), str(rig), json.dumps(opts, sort_keys=True))
    bp = _BLENDER.get(key)
    if bp is not None and not bp.alive():
        _BLENDER.pop(key).close()
        bp = None
    if bp is None:
        for k in list(_BLENDER):          # another asset: free the old Blender first
            _BLENDER.pop(k).close()
        log = Path(opts["log_dir"]) / f"blender-{os.getpid()}.log" if opts.get("log_dir") else None
        bp = BlenderProcess(asset, rig, threads=int(opts.get("threads", 0)),
                            tile_size=opts.get("tile_size"), log_path=log,
                            start_timeout_s=float(opts.get("start_timeout_s", 600)))
        _BLENDER[key] = bp
        _STARTS[0] += 1
    return bp


def apparent_landmarks(job: dict) -> dict:
    """Label fields of the iris/pupil landmarks as seen through the cornea (see labels.apparent_job)."""
    from pipeline.eyeball.geometry import EyeballParams
    from pipeline.render import refraction as rf
    from pipeline.render.camera import Camera

    camera = Camera.from_dict(job)
    pts = rf.apparent_points_camera(job["points_head"], camera.world_to_camera, job["model_to_head"],
                                    EyeballParams.from_dict(job["eyeball_params"]), job["ior"], camera.kind == "pinhole")
    px = camera.project(pts, job["width"], job["height"])
    px = [None if not np.all(np.isfinite(p)) else [float(p[0]), float(p[1])] for p in px]
    return {"apparent_px": px, "apparent_order": job["order"]}


def add_masks(label: dict, spec: RenderSpec, extra: dict | None) -> None:
    """Add the mask and depth files and the landmarks' visibility (pipeline/render/visibility.py,
    from the worker's seg PNG and depth EXR) to ``label``."""
    from pipeline.io.seg_file import DEPTH_CONVENTION, classes_text
    from pipeline.render import visibility as vis
    from pipeline.render.seg import RULE

    w, h = spec.width, spec.height
    seg = read_seg(spec.seg_png, (w, h))
    depth = read_depth(spec.depth_exr, (w, h))
    lm = label["landmarks"]
    v = vis.landmark_visibility(lm["px"], (extra or {}).get("apparent_px"),
                                -np.asarray(lm["camera_mm"], float)[:, 2], seg, depth, label["camera"]["mm_per_px"])
    label["landmarks"] = dict(lm, visible=v["visible"], occlusion=v["occlusion"], visibility_rule=vis.RULE)
    label["seg"] = {"file": Path(spec.seg_png).name, "classes": classes_text(), "rule": RULE}
    label["depth"] = {"file": Path(spec.depth_exr).name, "units": "mm", "channel": "Z",
                      "convention": DEPTH_CONVENTION}


def done(out_dir, index: int) -> bool:
    """Is image ``index`` finished (its PNG and, written last, its JSON exist)?"""
    out = Path(out_dir)
    return (out / f"{index:06d}.json").is_file() and (out / f"{index:06d}.png").is_file()


def render_shard(items, asset, rig, out_dir, opts: dict) -> list[dict]:
    """Dask task: render one shard. ``items`` = list of ``(spec, label)``; returns one result each.

    A result is ``{"index", "ok", "render_s", "rss_mib", "landmark_check_mm", "error", "skipped"}``.
    Images whose JSON exists are skipped (a retried task after a lost worker). A label is
    written only when the worker's landmark check is within ``opts["tolerance_mm"]``.
    As soon as an image's reply arrives the next spec of the shard is sent, so Blender renders
    it while this process reads the masks and writes the files (Blender would otherwise idle
    through that Python work, about 5 % of an image).
    """
    out = Path(out_dir)
    tol = float(opts.get("tolerance_mm", 0.01))
    results = []
    jobs = []
    for spec, label in items:
        i = spec.index
        if done(out, i):
            results.append({"index": i, "ok": True, "skipped": True})
            continue
        label = dict(label)
        job = label.pop("_apparent_job", None)
        formats = label.pop("_formats", None)
        if opts.get("masks"):             # seg mask + depth map from the same render (into .tmp/)
            tmp = Path(spec.png).parent
            spec = spec.with_masks(tmp / seg_name(i), tmp / depth_name(i))
        jobs.append((i, spec, label, job, formats))
    sent = False                          # jobs[k]'s spec already sent to the live Blender
    try:
        for k, (i, spec, label, job, formats) in enumerate(jobs):
            reply, extra = None, None
            for attempt in range(2):      # one restart if Blender died under us
                try:
                    bp = get_blender(asset, rig, opts)
                    if not sent:
                        bp.send(spec)
                    sent = False
                    if job is not None and extra is None:      # computed while Blender renders
                        extra = apparent_landmarks(job)
                    reply = bp.receive(float(opts.get("image_timeout_s", 600)))
                    if reply.get("index") != i:
                        raise WorkerDied(f"Blender answered image {reply.get('index')} for image {i}")
                    break
                except WorkerDied as exc:
                    reply = {"index": i, "ok": False, "error": str(exc)}
                    sent = False
                    _close_all()
            if k + 1 < len(jobs) and _BLENDER:
                try:
                    bp.send(jobs[k + 1][1])
                    sent = True
                except WorkerDied:
                    _close_all()
            results.append(_finish(out, i, spec, label, extra, formats, reply, tol, opts))
    finally:
        if sent:                          # a reply nobody will read: the next task needs a clean pipe
            _close_all()
    return results


def _finish(out: Path, i: int, spec: RenderSpec, label: dict, extra, formats, reply: dict, tol: float,
            opts: dict) -> dict:
    """Check one image's reply and, when it passes, move its files into ``out`` and write its
    label files (the eyerig JSON last). Returns the image's result."""
    res = {"index": i, "ok": bool(reply.get("ok")), "render_s": reply.get("render_s"),
           "total_cpu_s": reply.get("total_cpu_s"),
           "rss_mib": reply.get("rss_mib"), "landmark_check_mm": reply.get("landmark_check_mm"),
           "error": reply.get("error"), "pid": os.getpid()}
    if not res["ok"]:
        return res
    check = reply.get("landmark_check_mm")
    if check is None or not check <= tol:
        res.update(ok=False, error=f"landmark check {check} mm > {tol} mm: labels do not "
                                   "match the rendered scene")
        return res
    if extra is not None:
        label["landmarks"] = dict(label["landmarks"], **extra)
    label["landmark_check_mm"] = float(check)
    # timings (render_s, cpu seconds, rss) go to the stage metrics, never into the
    # label: the same sample must give the same bytes
    if opts.get("masks"):
        try:
            add_masks(label, spec, extra)
        except ScanError as exc:          # the worker's seg / depth file is unusable
            res.update(ok=False, error=f"masks: {exc}")
            return res
    strip_png_metadata(spec.png)           # Blender's Date/Time/RenderTime text chunks
    os.replace(spec.png, out / f"{i:06d}.png")
    for p in (spec.seg_png, spec.depth_exr):
        if p is not None:
            os.replace(p, out / Path(p).name)
    write_formats(out, i, label, formats, out / f"{i:06d}.png")     # the eyerig label last (= done)
    return res


#: Length of dask's low-level logs (scheduler, client, workers). They keep references to recent
#: tasks, payloads included, so at dask's default of 1000 a long run held ~1000 shards of specs
#: and labels (55 KB per image: +180 MiB over 3,600 tiny images, still growing); at 32 the stage's
#: memory stays flat for any n_images.
LOW_LEVEL_LOG_LENGTH = 32


#: Where a LocalCluster listens: loopback only. A dask scheduler runs whatever pickled function it
#: is sent, so one reachable from the network runs code as the user.
LOOPBACK = "127.0.0.1"


def local_security():
    """TLS credentials made for one run (``Security.temporary()``: a fresh self-signed CA and key
    pair, in memory only): the scheduler, its workers and this process's client hold them, so no
    other process can connect to the LocalCluster, let alone submit work."""
    from distributed.security import Security

    return Security.temporary()


def client_security(ca_file, cert, key, *, scheduler=None):
    """A ``distributed.security.Security`` for a client of ``scheduler`` from three PEM files
    (``--tls-ca-file``, ``--tls-cert``, ``--tls-key``), or None when none is given (Dask's config,
    ``distributed.comm.tls.*``).

    Raises
    ------
    ScanError
        One line: only some of the three given, given without a scheduler, or a file missing.
    """
    given = {"tls_ca_file": ca_file, "tls_cert": cert, "tls_key": key}
    if not any(given.values()):
        return None
    if not all(given.values()) or not scheduler:
        raise ScanError("--tls-ca-file", "give --tls-ca-file, --tls-cert and --tls-key together, with --scheduler")
    for k, p in given.items():
        if not Path(p).is_file():
            raise ScanError(p, f"--{k.replace('_', '-')}: file not found")
    from distributed.security import Security

    return Security(tls_ca_file=str(ca_file), tls_client_cert=str(cert), tls_client_key=str(key),
                    require_encryption=True)


def _client(workers: int, scheduler: str | None, connect_timeout_s: float = 10.0, dashboard: bool = False,
            security=None):
    """``(client, cluster)``: a Client of the cluster at ``scheduler`` (with ``security``, a
    ``distributed.security.Security``; None: Dask's config, ``distributed.comm.tls.*``), else of a new
    LocalCluster (``cluster``, None for a given scheduler) whose every server listens on 127.0.0.1
    only, each on a free port (concurrent runs never collide), with the dashboard only when
    ``dashboard``. Worker processes talk to its scheduler over TLS with credentials made for the run
    (:func:`local_security`); one worker is a thread of this process and talks in memory (inproc), so
    there is nothing to connect to."""
    import logging

    import dask
    from dask.distributed import Client, LocalCluster

    dask.config.set({"distributed.admin.low-level-log-length": LOW_LEVEL_LOG_LENGTH})

    if scheduler:
        try:
            kw = {} if security is None else {"security": security}
            return Client(scheduler, timeout=f"{connect_timeout_s}s", **kw), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise ScanError(scheduler, f"cannot connect to the dask scheduler ({type(exc).__name__})") from None
    # One worker runs in this process (a thread): no nanny and worker processes to start and
    # import dask in (~2 CPU-s), no pickling of every shard; its Blender is still a subprocess.
    # Several workers get processes: the Blender cache (_BLENDER) is per process.
    # Every dask server also starts an HTTP server (health and metrics routes, and the dashboard
    # when asked): given no address it binds every interface for an in-process (inproc) cluster
    # and tries port 8787 (a second run warns), so each is given 127.0.0.1 and a free port. (The
    # in-process cluster talks inproc, which a host would turn into tcp that fails to start.)
    http = f"{LOOPBACK}:0"
    processes = int(workers) > 1
    # a scheduler asked for a dashboard without bokeh appends a route to this config list in
    # place, which would serve that page from every later scheduler of the process: a copy each
    routes = list(dask.config.get("distributed.scheduler.http.routes"))
    tls = {"security": local_security(), "protocol": "tls://"} if processes else {}
    with dask.config.set({"distributed.scheduler.http.routes": routes}):
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=processes,
                               host=LOOPBACK if processes else None, dashboard_address=http,
                               scheduler_kwargs={"dashboard": bool(dashboard)},
                               worker_class=None if processes else _loopback_worker_class(),
                               memory_limit=0, silence_logs=logging.ERROR, **tls)
    return Client(cluster, **({"security": tls["security"]} if tls else {})), cluster


def dashboard_text(url: str) -> str:
    """The one line a command prints for the dashboard at ``url``."""
    import importlib.util

    need = "" if importlib.util.find_spec("bokeh") else " (install bokeh to see it; without it the page says so)"
    return f"note: dask dashboard (this machine only): {url}{need}"


def _loopback_worker_class():
    from dask.distributed import Worker

    class LoopbackWorker(Worker):
        """The in-process worker with its HTTP server on 127.0.0.1 and no dashboard (LocalCluster
        passes ``dashboard_address=None``, which binds every interface for an inproc worker)."""

        def __init__(self, *args, **kwargs):
            kwargs.update(dashboard_address=f"{LOOPBACK}:0", dashboard=False)
            super().__init__(*args, **kwargs)

    return LoopbackWorker


def run_shards(shards, asset, rig, out_dir, opts: dict, workers: int = 1, scheduler: str | None = None,
               progress: bool = True, connect_timeout_s: float = 10.0, total: int | None = None,
               on_result=None, max_in_flight: int | None = None, on_dashboard=None, security=None) -> dict:
    """Render every shard (an iterable of lists of ``(spec, label)``, consumed lazily: at most
    ``max_in_flight`` shards, default 2 per worker + 2, are sampled and submitted ahead).

    ``on_result(result)`` is called for each image's result as it arrives; without it the
    results are collected in the returned ``"results"`` list. Given ``on_dashboard``, a
    LocalCluster serves the dask dashboard (on 127.0.0.1) and ``on_dashboard(url)`` is called.

    Returns
    -------
    dict  {"results": [...] (empty with on_result), "workers": n, "blender": {worker: stats}}
    """
    from dask.distributed import as_completed
    from tqdm import tqdm

    results = []
    if on_result is None:
        on_result = results.append
    shards = iter(shards)
    first = next(shards, None)
    if first is None:
        return {"results": results, "workers": 0, "blender": {}}
    client, cluster = _client(workers, scheduler, connect_timeout_s, dashboard=on_dashboard is not None,
                              security=security)
    try:
        if cluster is not None and on_dashboard is not None:
            on_dashboard(f"http://{LOOPBACK}:{cluster.scheduler.http_server.port}/status")
        n_workers = len(client.scheduler_info().get("workers", {}))
        limit = max_in_flight or 2 * max(1, n_workers or int(workers)) + 2
        bar = tqdm(total=total, unit="img", desc="render", disable=not progress or total == 0,
                   file=sys.stderr, dynamic_ncols=True, smoothing=0.1)
        ac = as_completed()
        count = [0]

        def submit(shard):
            ac.add(client.submit(render_shard, shard, str(asset), str(rig), str(out_dir), opts,
                                 pure=False, key=f"render-shard-{count[0]}-{os.getpid()}"))
            count[0] += 1

        submit(first)
        for _ in range(limit - 1):
            nxt = next(shards, None)
            if nxt is None:
                break
            submit(nxt)
        failed = 0
        for fut in ac:
            try:
                res = fut.result()
            except Exception as exc:  # noqa: BLE001 -- a task that raised (Blender could not start, ...)
                msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
                hint = (" (the dask scheduler and workers need the project importable: start them with "
                        "PYTHONPATH=<repository root>)" if "serializ" in msg or isinstance(exc, ImportError)
                        else "")
                raise ScanError(asset, f"render task failed: {type(exc).__name__}: {msg}{hint}") from None
            fut.release()
            for r in res:
                on_result(r)
            failed += sum(1 for r in res if not r.get("ok"))
            bar.update(len(res))
            el = bar.format_dict.get("elapsed") or 0.0
            post = {"img/s": f"{bar.n / el:.2f}" if el > 0 else "-"}
            if failed:
                post["failed"] = failed
            bar.set_postfix(post)
            nxt = next(shards, None)          # keep the pipeline full: one out, one in
            if nxt is not None:
                submit(nxt)
        bar.close()
        stats = client.run(blender_stats)
        client.run(close_blender)
        if cluster is not None:                   # our own workers, closed next
            client.run(mute_shutdown_heartbeat)
            mute_shutdown_timeout()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
            unmute_shutdown_heartbeat()           # an in-process worker shares this logger
    return {"results": results, "workers": n_workers, "blender": stats}
