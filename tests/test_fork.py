"""The process helper (pipeline/fork.py): a call beside this process gives what the call gives
here, switched off or not, and a child that fails is rerun here (its error is the call's own)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from pipeline import fork


def _pid_and_sum(a):
    return os.getpid(), float(np.sum(a))


def _fails(x):
    raise ValueError(f"bad {x}")


@pytest.mark.parametrize("serial", ["0", "1"])
def test_the_value_is_the_calls_own(monkeypatch, serial):
    monkeypatch.setenv(fork.SERIAL_ENV, serial)
    a = np.arange(10.0)
    (pid, total), dt = fork.fork_result(fork.fork_call(_pid_and_sum, a))
    assert total == 45.0 and dt >= 0
    ran_here = pid == os.getpid()
    assert ran_here == (serial == "1" or (os.cpu_count() or 1) == 1)


def test_switched_off_nothing_runs_until_the_result_is_asked(monkeypatch):
    monkeypatch.setenv(fork.SERIAL_ENV, "1")
    calls = []
    job = fork.fork_call(calls.append, 1)
    assert calls == [] and not fork.forking()
    fork.fork_result(job)
    assert calls == [1]


def test_a_failing_child_is_rerun_here_with_its_own_error(monkeypatch):
    monkeypatch.setenv(fork.SERIAL_ENV, "0")
    job = fork.fork_call(_fails, 3)
    with pytest.raises(ValueError, match="bad 3"):
        fork.fork_result(job)
