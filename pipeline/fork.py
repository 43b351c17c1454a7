"""The process helper: run an independent step beside this one, where a stage composes its steps.

:func:`fork_call` starts ``fn(*args, **kwargs)`` in a forked child and returns at once;
:func:`fork_result` waits for its value. Fork shares the parent's arrays without copying them, and
only the result comes back (pickled). A child that fails (an exception, a crash, a result that
cannot be pickled) is rerun in the parent, so a result, and an error message, never depend on the
fork.

The off switch: with ``EYERIG_SERIAL=1`` in the environment, or on a machine with one core, no
child is started and :func:`fork_result` makes the call itself; outputs are the same bytes either
way (tests/test_fork.py, and the bake stage's test). The stages were tuned on two cores, where one
child beside the parent uses both.
"""

from __future__ import annotations

import multiprocessing
import os
import time

#: Environment variable that turns the helper off (every call runs in the parent, in order).
SERIAL_ENV = "EYERIG_SERIAL"


def forking() -> bool:
    """Does :func:`fork_call` start a child (not switched off, more than one core)?"""
    return os.environ.get(SERIAL_ENV, "") in ("", "0") and (os.cpu_count() or 1) > 1


def fork_call(fn, *args, **kwargs):
    """Start ``fn(*args, **kwargs)`` in a forked child (or, switched off, nothing yet); returns a
    job for :func:`fork_result`."""
    if not forking():
        return None, None, fn, args, kwargs
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def target():
        t0 = time.perf_counter()
        try:
            send.send(("ok", fn(*args, **kwargs), time.perf_counter() - t0))
        except Exception as exc:  # noqa: BLE001 -- reported to the parent, which reruns the call itself
            send.send(("error", repr(exc), 0.0))

    proc = ctx.Process(target=target, daemon=True)
    proc.start()
    send.close()
    return proc, recv, fn, args, kwargs


def fork_result(job):
    """(value, seconds) of a :func:`fork_call` job; the call runs here if it was switched off or
    the child failed."""
    proc, recv, fn, args, kwargs = job
    status, value, dt = "error", None, 0.0
    if proc is not None:
        try:
            status, value, dt = recv.recv()
        except (EOFError, OSError):
            pass
        proc.join()
        recv.close()
    if status != "ok":
        t0 = time.perf_counter()
        value = fn(*args, **kwargs)
        dt = time.perf_counter() - t0
    return value, dt
