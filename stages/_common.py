"""What every stage script shares: params, error handling, timing, metrics.

A stage's ``main`` is wrapped by :func:`run_stage`, which turns
:class:`pipeline.errors.ScanError` into one line on stderr and exit status 2
(no traceback), and adds wall time and peak memory to the stage's metrics.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path
from typing import Callable

import yaml

from pipeline.errors import ScanError
from pipeline.io.atomic import write_json

EXIT_BAD_INPUT = 2


def load_params(stage: str, path="params.yaml") -> dict:
    """The ``stage:`` block of ``params.yaml`` (empty when the file or block is absent)."""
    p = Path(path)
    if not p.exists():
        return {}
    with open(p, encoding="utf-8") as fh:
        data = yaml.safe_load(fh) or {}
    return dict(data.get(stage) or {})


def peak_memory_mib() -> float:
    """Peak resident memory of this process and its waited-for children, MiB."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0


def default_metrics_path(out_dir) -> Path:
    """``build/<scan>/<stage>.metrics.json`` beside the stage's output folder.

    Not inside it: DVC refuses a metrics file inside a tracked output folder
    ("overlapping outputs"), and whole-folder outputs keep optional files simple.
    """
    out_dir = Path(out_dir)
    return out_dir.with_name(out_dir.name + ".metrics.json")


def stage_parser(description: str) -> argparse.ArgumentParser:
    """An argument parser with the ``--metrics PATH`` option every stage takes."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--metrics", default=None,
                        help="where to write metrics JSON (default: OUT_DIR.metrics.json)")
    parser.add_argument("--params", default="params.yaml", help="params file (default: params.yaml)")
    return parser


def run_stage(main: Callable[[list[str]], dict | None], argv=None) -> int:
    """Run a stage ``main(argv) -> metrics`` with the house error handling.

    ``main`` returns its metrics dict and the path to write them to under the key
    ``"_path"``; wall time and peak memory are added here.
    """
    argv = sys.argv[1:] if argv is None else argv
    t0 = time.perf_counter()
    try:
        metrics = main(argv)
    except ScanError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    if metrics is not None:
        path = metrics.pop("_path")
        metrics["wall_time_s"] = round(time.perf_counter() - t0, 4)
        metrics["peak_memory_mib"] = round(peak_memory_mib(), 1)
        write_json(path, metrics)
    return 0


def stage_exit(main, argv=None) -> None:
    """Entry point helper: ``if __name__ == "__main__": stage_exit(main)``."""
    os.environ.setdefault("PYTHONHASHSEED", "0")
    raise SystemExit(run_stage(main, argv))
