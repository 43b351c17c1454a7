"""Two independent calls at once on the 2-core machine: one in a forked child, one here.

Fork shares the parent's arrays without copying them. A child that fails (an exception, a crash,
a result that cannot be pickled) is rerun in the parent, so a result, and an error message,
never depend on the fork.
"""

from __future__ import annotations

import multiprocessing
import time


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
