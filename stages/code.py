"""Stage ``code``: one fingerprint file per DVC stage, the hash of the code that stage runs.

    python -m stages.code build/code check_params ingest remove_eyeballs ...

Writes ``build/code/<stage>.sha256`` for each stage named (:func:`pipeline.sources.closure_digest`:
the sha256 of ``stages/<stage>.py`` and every project module it runs). Each stage of ``dvc.yaml``
depends on its own file, not on its modules one by one: DVC reads and rewrites ``dvc.lock`` for
every stage it runs, and 50 code deps a stage made that file about 2,900 lines for one scan and
2,500 more for each scan added (2 s of parsing a stage on the 2-core machine). This stage depends
on the ``pipeline/`` and ``stages/`` folders, so it runs after any code change; a stage whose
closure did not change gets the same bytes, and DVC leaves it alone.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipeline.io.atomic import write_text
from pipeline.sources import ROOT, closure_digest


def main(argv) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="build/code")
    parser.add_argument("stages", nargs="+", help="stage names (stages/<name>.py)")
    args = parser.parse_args(argv)
    bad = [s for s in args.stages if not s.isidentifier() or not (ROOT / "stages" / f"{s}.py").is_file()]
    if bad:
        print(f"error: {args.out}: no stage script stages/{bad[0]}.py", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    for s in args.stages:
        write_text(args.out / f"{s}.sha256", closure_digest(s))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
