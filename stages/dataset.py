"""The dataset command: labelled images of several rigged assets, mixed by weight, in one folder.

    python -m stages.dataset --assets rigged_assets/* --n 10000 --preset generic --out DIR \\
        [--weights 2 1 1] [--rigs build/a/rig ...] [--seed S] [--params params.yaml] \\
        [--set KEY=VALUE ...] [--workers N] [--scheduler ADDRESS [--tls-ca-file F --tls-cert F --tls-key F]] \\
        [--no-progress] [--dashboard] \\
        [--overwrite | --resume]

Not a DVC stage (its output folder is the user's), but a script like them: it reads the
``render:`` block of ``--params`` (``--set KEY=VALUE``, ``--n``, ``--preset``, ``--seed`` and
``--workers`` override it), checks the assets and the output folder, says what it skips,
doubts and removes, and calls the library (pipeline/render/dataset.py: the plan, the folder,
the files, the card). Bad input (a missing or invalid asset or rig, ``--n`` out of range, a
weight count that does not match, an output folder that is not a dataset or holds another plan, or
a symbolic link where the run would write or delete) ends with one line and exit 2 before anything
is written. ``--out`` belongs to one run at a time (pipeline/io/folder_lock.py): a second run is
refused naming the holder's pid and host; a lock whose process is provably gone on this host is
taken over with a warning line.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from pipeline.errors import ScanError
from pipeline.render import dataset as ds
from pipeline.render.shard import client_security, dashboard_text
from stages._common import load_params


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line and exit 2, like every bad input."""

    def error(self, message):
        self.exit(2, f"error: {self.prog}: {message}\n")


def main(argv=None) -> int:
    ap = _Parser(prog="python -m stages.dataset", description=__doc__.splitlines()[0])
    ap.add_argument("--assets", nargs="+", required=True, help="rigged_assets/<scan> folders (rigged_assets/* "
                                                               "works: the shared eyeball is skipped)")
    ap.add_argument("--n", type=int, required=True, help="images in the dataset (another --n is the same plan, "
                                                        "grown or shrunk: no --overwrite)")
    ap.add_argument("--out", type=Path, required=True, help="the dataset folder (new, empty or earlier dataset)")
    ap.add_argument("--weights", nargs="+", default=None, help="one weight per asset (default: equal)")
    ap.add_argument("--rigs", nargs="+", default=None, help="build/<scan>/rig per asset (default: beside it)")
    ap.add_argument("--preset", default=None, help="render preset (default: the params' render.preset)")
    ap.add_argument("--seed", type=int, default=None, help="default: the params' render.seed")
    ap.add_argument("--params", default="params.yaml", help="its render: block gives the settings")
    ap.add_argument("--set", nargs="+", default=None, metavar="KEY=VALUE",
                    help="override render settings (YAML values), e.g. width=240 height=160 samples=32")
    ap.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes")
    ap.add_argument("--scheduler", default=None, help="dask scheduler address (default: a LocalCluster, "
                                                      "TLS with credentials made for the run)")
    for flag, what in (("--tls-ca-file", "CA certificate"), ("--tls-cert", "client certificate"),
                       ("--tls-key", "client key")):
        ap.add_argument(flag, type=Path, default=None,
                        help=f"with --scheduler tls://...: the {what} (PEM; default: Dask's config, "
                             "distributed.comm.tls.*; docs/datasets.md)")
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--dashboard", action="store_true",
                    help="serve the LocalCluster's dask dashboard on 127.0.0.1 (a free port, printed)")
    how = ap.add_mutually_exclusive_group()
    how.add_argument("--overwrite", action="store_true",
                     help="replace a dataset of another plan in --out (its images the new plan shares are kept)")
    how.add_argument("--resume", action="store_true", help="only continue the dataset of this plan in --out")
    args = ap.parse_args(argv)

    def say(line):
        print(line, file=sys.stderr)

    try:
        if args.params != "params.yaml" and not Path(args.params).is_file():
            raise ScanError(args.params, "params file not found")
        block = load_params("render", args.params)      # {} without a params.yaml; refused without render:
        settings = ds.dataset_settings(block, args.n, args.set, args.preset, args.seed, args.workers,
                                       not args.no_progress, source=args.params)
        security = client_security(args.tls_ca_file, args.tls_cert, args.tls_key, scheduler=args.scheduler)
        pairs, skipped = ds.asset_inputs(args.assets, args.rigs)
        assets, m = ds.make_dataset(args.out, pairs, skipped, args.weights, settings, args.n,
                                    overwrite=args.overwrite, resume=args.resume, note=say,
                                    scheduler=args.scheduler, progress=not args.no_progress, security=security,
                                    on_dashboard=(lambda url: say(dashboard_text(url))) if args.dashboard else None)
    except ScanError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted (a re-run resumes)", file=sys.stderr)
        return 130
    print(ds.run_line(args.out, m, len(assets)))
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    raise SystemExit(main())
