"""make bench (benchmarks.run_all) runs every benchmark module."""

from __future__ import annotations

from benchmarks import run_all


def test_every_benchmark_module_is_listed():
    assert run_all.unlisted() == [], "add them to benchmarks/run_all.py BENCHMARKS"


def test_every_requirement_is_known():
    for b in run_all.BENCHMARKS:
        for need in b.needs:
            run_all.missing(need)       # raises ValueError on an unknown requirement name
