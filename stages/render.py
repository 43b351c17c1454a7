"""Stage ``render``: labelled close-up eye images of one scan (Cycles, sharded with Dask).

    python -m stages.render rigged_assets/<scan> build/<scan>/rig renders/<scan> \
        --metrics build/<scan>/render.metrics.json [--scheduler ADDRESS] [--workers N] [--n-images N]

Per image: ``NNNNNN.png`` + ``NNNNNN.json`` (label, written last = done; pipeline/io/labels_file.py);
at the end ``index.jsonl`` (every index 0..n-1 exactly once), ``contact_sheet.png`` (landmarks
drawn) and ``config.json`` (the hash of everything that changes images or labels). Re-running
resumes: finished images are skipped; a config change deletes the stale images first (only the
render's own files: a folder that holds no earlier render is refused). An asset
that remove_eyeballs or rig doubted (its metadata's ``eyes.<side>.doubts``) is rendered all the same,
with one ``warning:`` line per doubt on stderr. Images
are rendered by persistent Blender processes, one per dask worker: a ``LocalCluster`` of
``workers`` processes by default, or the cluster at ``--scheduler`` / params ``scheduler`` (its
workers must see the same paths). The work is in pipeline/render/run.py (``render_scan``).
"""

from __future__ import annotations

import sys
from pathlib import Path

from stages._common import default_metrics_path, load_params, stage_exit, stage_parser


def main(argv):
    ap = stage_parser(__doc__.splitlines()[0])
    ap.add_argument("asset", type=Path, help="rigged_assets/<scan> (holds <scan>.usda)")
    ap.add_argument("rig", type=Path, help="build/<scan>/rig (rig.npz + rig.json)")
    ap.add_argument("out", type=Path, help="renders/<scan>")
    ap.add_argument("--scheduler", default=None, help="dask scheduler address (default: a LocalCluster)")
    ap.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes")
    ap.add_argument("--n-images", type=int, default=None, help="override params render.n_images")
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--dashboard", action="store_true",
                    help="serve the LocalCluster's dask dashboard on 127.0.0.1 (a free port, printed)")
    args = ap.parse_args(argv)

    from pipeline.render.asset import load_render_asset
    from pipeline.render.run import check_render_out, render_scan
    from pipeline.render.settings import RenderSettings
    from pipeline.render.shard import dashboard_text

    check_render_out(args.out)            # someone else's folder: refused before any work
    params = load_params("render", args.params)
    for key, value in (("n_images", args.n_images), ("workers", args.workers)):
        if value is not None:
            params[key] = value
    settings = RenderSettings.from_params(params, source=args.params)
    asset = load_render_asset(args.asset, args.rig)
    for doubt in asset.doubts():          # rendered all the same: say so where the user looks
        print(f"warning: {args.asset}: {doubt}", file=sys.stderr)
    def dashboard(url):
        print(dashboard_text(url), file=sys.stderr)

    result = render_scan(asset, settings, args.out, source=args.asset, scheduler=args.scheduler,
                         progress=not args.no_progress, on_dashboard=dashboard if args.dashboard else None)
    run = result.timings
    if run["stale_config"] and run["removed_files"]:
        print(f"note: {args.out}: the render config changed: {run['removed_files']} files of the "
              "earlier renders were removed", file=sys.stderr)
    return result.at(args.metrics or default_metrics_path(args.out))


if __name__ == "__main__":
    stage_exit(main)
