"""What every stage script shares: params, error handling, timing, metrics.

A stage's ``main`` is wrapped by :func:`run_stage`, which turns
:class:`pipeline.errors.ScanError` into one line on stderr and exit status 2
(no traceback), and writes the stage's :class:`pipeline.results.StageResult`: its metrics, its
headline (:func:`headline`, what ``dvc metrics show`` prints) and its timings with the wall time,
CPU time and peak memory added.
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
from pipeline.io.strict_yaml import DuplicateKeyError, load_strict
from pipeline.results import StageResult

EXIT_BAD_INPUT = 2


# params.yaml is read with load_strict: a safe loader (plain YAML types only, never Python objects)
# that refuses a repeated key (scan.yaml's rules), on libyaml's parser when PyYAML has it (about
# 10x faster: the pure-Python one took 27 ms per read of params.yaml, and the usd stage reads
# every block)
_PARAMS_CACHE: dict = {}      # resolved path -> ((mtime_ns, size), parsed document)


def read_params_file(path="params.yaml") -> dict:
    """The whole params file as a mapping (empty when absent); ScanError when it is not one or
    repeats a key (``render: samples`` twice: no silent "last one wins").

    Parsed once per process while the file is unchanged; each call gets its own deep copy."""
    p = Path(path)
    if not p.exists():
        return {}
    try:
        st = p.stat()
        key, stamp = os.fspath(p.resolve()), (st.st_mtime_ns, st.st_size)
        hit = _PARAMS_CACHE.get(key)
        if hit is not None and hit[0] == stamp:
            data = hit[1]
        else:
            with open(p, encoding="utf-8") as fh:
                data = load_strict(fh)
            _PARAMS_CACHE[key] = (stamp, data)
    except DuplicateKeyError as exc:
        raise ScanError(p, f"{exc}: each key may appear once") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ScanError(p, f"cannot be read as YAML ({type(exc).__name__})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ScanError(p, "must be a mapping of blocks (scans:, ingest:, ...)")
    import copy

    return copy.deepcopy(data)


def load_params(stage: str, path="params.yaml") -> dict:
    """The ``stage:`` block of the params file ``path``.

    No file at ``path`` means no params file: every setting its default (``{}``); a stage's
    ``--params`` names an existing file or is refused (:func:`checked_params_path`), so only the
    default ``params.yaml`` may be absent. A file that is there must have the block (an empty ``stage:`` takes
    the defaults): its absence is a one-line ScanError naming the file and the block, as DVC and
    ``check_params`` refuse it, never a silent run on defaults."""
    data = read_params_file(path)
    if stage not in data:
        if not Path(path).exists():
            return {}
        raise ScanError(path, f"no {stage!r} block (every stage's block is required; see docs/settings.md)")
    block = data[stage]
    if block is None:
        return {}
    if not isinstance(block, dict):
        raise ScanError(path, f"{stage} must be a mapping of settings")
    return dict(block)


def load_settings(cls, path="params.yaml", block: str | None = None):
    """The ``cls.block`` block of ``path`` read into the settings dataclass ``cls``
    (a :class:`pipeline.settings.Settings`); a bad key or value is a one-line ScanError."""
    block = cls.block if block is None else block
    return cls.from_params(load_params(block, path), source=os.fspath(path), block=block)


def scan_folder_name(path) -> str:
    """The scan name a stage takes from the folder ``path``: its own name (``raw_scans/<name>``,
    ``rigged_assets/<name>``), or the resolved folder's for a path like ``.``."""
    p = Path(path)
    return p.name or p.resolve().name


class StageArgumentParser(argparse.ArgumentParser):
    """``argparse`` that checks the safe-name rule (pipeline.settings.check_scan_name) on the one
    folder whose own name a stage takes as the scan's name (``scan_arg``), as DVC would have it
    from ``params.yaml``'s ``scans:``: defence in depth for a stage run by hand. Every other path,
    and every parent folder, is ordinary (spaces, dots, leading dots, non-ASCII)."""

    scan_arg: str | None = None

    def parse_args(self, args=None, namespace=None):  # noqa: D102
        from pipeline.settings import check_scan_name

        ns = super().parse_args(args, namespace)
        value = getattr(ns, self.scan_arg) if self.scan_arg else None
        if value is not None:
            check_scan_name(scan_folder_name(value), source=os.fspath(value), key=None)
        if hasattr(ns, "params"):
            ns.params = checked_params_path(ns.params)
        return ns


def checked_params_path(given) -> str:
    """The params file a stage reads: ``params.yaml`` when ``--params`` was left out (no such
    file there: every setting its default), else ``given``, which must be a file. A mistyped
    ``--params`` is a one-line ScanError, never a silent run on the defaults."""
    if given is None:
        return "params.yaml"
    if not Path(given).is_file():
        raise ScanError(given, "no such params file (leave --params out to read ./params.yaml)")
    return os.fspath(given)


def peak_memory_mib() -> float:
    """Peak resident memory of this process and its waited-for children, MiB."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0


def cpu_time_s() -> float:
    """CPU seconds (user + system) of this process and its waited-for children (forked helpers,
    Blender workers): unlike the wall time, hardly moved by other jobs on the machine."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timings_path(metrics_path) -> Path:
    """``build/<scan>/<stage>.timings.json`` beside ``build/<scan>/<stage>.metrics.json``.

    Not a DVC output: wall times change on every run, and DVC records the hash of every
    metrics output in dvc.lock, so they would make ``dvc repro --force`` change dvc.lock.
    ``dvc metrics show -R build`` (or naming the file) shows them.
    """
    p = Path(metrics_path)
    if p.name.endswith(".metrics.json"):
        return p.with_name(p.name[: -len(".metrics.json")] + ".timings.json")
    return p.with_name(p.stem + ".timings.json")


def summary_path(metrics_path) -> Path:
    """``build/<scan>/<stage>.summary.json`` beside ``build/<scan>/<stage>.metrics.json``: the
    stage's headline (:func:`headline`), the only file dvc.yaml declares as its DVC metrics."""
    p = Path(metrics_path)
    if p.name.endswith(".metrics.json"):
        return p.with_name(p.name[: -len(".metrics.json")] + ".summary.json")
    return p.with_name(p.stem + ".summary.json")


#: The headline of each stage: a few keys shared by every stage, so that ``dvc metrics show``
#: (one column per key of every metrics file it lists) stays a narrow table: ``faces`` (the mesh
#: the stage wrote), ``images``, ``err_mm`` (the stage's accuracy figure, the worst of the named
#: keys) and ``issues`` (what the stage counts as a problem: doubts, failed checks, validation
#: errors, flipped or non-manifold faces; 0 is clean). Each entry: key -> the metrics' dotted keys
#: it sums (``err_mm``: takes the largest of). The full metrics stay in ``<stage>.metrics.json``.
HEADLINES = {
    "synthetic_head": {"faces": ["n_faces"],
                       "err_mm": ["left_margin_to_sphere_max_mm", "right_margin_to_sphere_max_mm"]},
    "eyeball": {"faces": ["outer_polygons", "inner_polygons"], "issues": ["validation_errors"]},
    "ingest": {"faces": ["faces_out"], "issues": ["edges.non_manifold", "edges.inconsistent_winding"]},
    "remove_eyeballs": {"faces": ["faces_out"], "err_mm": ["left.residual_rms_mm", "right.residual_rms_mm"],
                        "issues": ["left.doubts", "right.doubts"]},
    "retopo": {"faces": ["mesh.n_faces"], "err_mm": ["distance_symmetric_mean_mm"],
               "issues": ["mesh.nonmanifold_edges", "mesh.inconsistent_edges", "mesh.degenerate_faces",
                          "flipped_faces"]},
    "bake": {"err_mm": ["reconstruction.with_displacement.symmetric_mean_mm"]},
    "snap": {"err_mm": ["gap_max_mm", "inside_max_mm"], "issues": ["flipped_faces"]},
    "rig": {"faces": ["n_faces"], "err_mm": ["interpolation_error_mm"], "issues": ["sweep_flipped_faces"]},
    "usd": {"faces": ["n_faces"], "issues": ["validation_errors"]},
    "preview": {"err_mm": ["preview_lid_max_error_mm"]},
    "render": {"images": ["n_images"], "err_mm": ["landmark_check_max_mm"]},
}
#: What ``err_mm`` is for each stage (docs/layout.md says the same).
ERR_MM = {
    "synthetic_head": "the lid margin's largest distance to the eyeball sphere",
    "remove_eyeballs": "the eyeball sphere fit's residual (RMS, worse eye)",
    "retopo": "the low-poly mesh's mean distance to the scan (symmetric)",
    "bake": "the mean distance of the displaced low-poly mesh to the scan (symmetric)",
    "snap": "the largest gap or overlap between lid margin and eyeball",
    "rig": "the largest interpolation error of the lid shapes",
    "preview": "the largest lid error in the published asset's preview",
    "render": "the largest landmark check error over the images",
}


def _dotted(doc: dict, key: str):
    for part in key.split("."):
        if not isinstance(doc, dict) or part not in doc:
            return None
        doc = doc[part]
    return doc


def headline(stage: str, metrics: dict) -> dict | None:
    """The stage's headline (:data:`HEADLINES`) from its metrics; None for a stage without one.

    Values are numbers: sums of the named keys (a list counts its entries, a bool as 0/1), or for
    ``err_mm`` the largest absolute value rounded to 4 significant digits; a key none of whose
    sources is in the metrics is left out."""
    spec = HEADLINES.get(stage)
    if spec is None:
        return None
    out = {}
    for key, sources in spec.items():
        vals = [v for v in (_dotted(metrics, k) for k in sources) if v is not None]
        vals = [len(v) if isinstance(v, (list, tuple)) else v for v in vals]
        vals = [v for v in vals if isinstance(v, (int, float))]
        if not vals:
            continue
        if key == "err_mm":
            worst = max(abs(float(v)) for v in vals)
            out[key] = float(f"{worst:.4g}")
        else:
            out[key] = int(sum(vals))
    return out


def read_stage_metrics(metrics_path) -> dict:
    """A stage's metrics file merged with its timings file (when present), as one dict."""
    def merge(a: dict, b: dict) -> dict:
        out = dict(a)
        for k, v in b.items():
            out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
        return out

    import json

    m = json.loads(Path(metrics_path).read_text(encoding="utf-8"))
    t = timings_path(metrics_path)
    return merge(m, json.loads(t.read_text(encoding="utf-8"))) if t.is_file() else m


def default_metrics_path(out_dir) -> Path:
    """``build/<scan>/<stage>.metrics.json`` beside the stage's output folder.

    Not inside it: DVC refuses a metrics file inside a tracked output folder
    ("overlapping outputs"), and whole-folder outputs keep optional files simple.
    """
    out_dir = Path(out_dir)
    return out_dir.with_name(out_dir.name + ".metrics.json")


def stage_parser(description: str, scan_arg: str | None = None) -> argparse.ArgumentParser:
    """An argument parser with the ``--metrics PATH`` option every stage takes; ``scan_arg`` names
    the argument (added by the stage) of the folder whose own name is the scan's name."""
    parser = StageArgumentParser(description=description)
    parser.scan_arg = scan_arg
    parser.add_argument("--metrics", default=None,
                        help="where to write metrics JSON (default: OUT_DIR.metrics.json)")
    parser.add_argument("--params", default=None,
                        help="params file (default: params.yaml, every default where there is none)")
    return parser


def run_stage(main: Callable[[list[str]], StageResult | None], argv=None) -> int:
    """Run a stage ``main(argv) -> StageResult`` with the house error handling.

    ``main`` returns its :class:`pipeline.results.StageResult` with the ``path`` of its metrics
    file (or None: no metrics). The metrics go there, a DVC output with the same bytes for the
    same inputs; the timings, with the wall time, CPU time and peak memory added here, go to the
    timings file beside it (:func:`timings_path`). ``main`` runs with its own scratch folder as
    ``TMPDIR`` (pipeline.io.scratch.stage_scratch), removed when it returns.
    """
    from pipeline.io.scratch import stage_scratch

    argv = sys.argv[1:] if argv is None else argv
    t0 = time.perf_counter()
    module = str(getattr(getattr(main, "func", main), "__module__", "stage"))
    if module == "__main__":          # python -m stages.<stage>
        spec = getattr(sys.modules.get("__main__"), "__spec__", None)
        module = spec.name if spec is not None else "stage"
    stage = module.rsplit(".", 1)[-1]
    # a stage that starts clears what killed runs left: temporary siblings of its paths whose
    # writer is gone (only those: a live run's are kept)
    from pipeline.io.atomic import remove_stale_siblings

    for word in argv:
        if word and not word.startswith("-"):
            remove_stale_siblings(Path(word))
    try:
        with stage_scratch(stage):      # its own TMPDIR (Blender, Dask), removed at exit
            result = main(argv)
    except ScanError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print(f"error: {stage}: ran out of memory (peak {peak_memory_mib():.0f} MiB); the input is "
              f"too large for this machine or over the limits", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OverflowError as exc:
        print(f"error: {stage}: a number overflowed ({str(exc)[:100]})", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    if result is not None:
        timings = {**result.timings, "wall_time_s": round(time.perf_counter() - t0, 4),
                   "cpu_time_s": round(cpu_time_s(), 4), "peak_memory_mib": round(peak_memory_mib(), 1)}
        write_json(result.path, result.metrics)
        head = headline(stage, result.metrics)
        if head is not None:
            write_json(summary_path(result.path), head)
        write_json(timings_path(result.path), timings)
    return 0


def stage_exit(main, argv=None) -> None:
    """Entry point helper: ``if __name__ == "__main__": stage_exit(main)``."""
    os.environ.setdefault("PYTHONHASHSEED", "0")
    raise SystemExit(run_stage(main, argv))
