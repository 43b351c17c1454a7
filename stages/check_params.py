"""Stage ``check_params``: check ``params.yaml`` before any other stage runs.

    python -m stages.check_params params.yaml build/check_params.ok

Every stage of ``dvc.yaml`` depends on ``build/check_params.ok``, so DVC runs this first. It
refuses, with one line naming ``params.yaml`` and exit 2 (and so nothing else runs):

* a scan name under ``scans:`` that is not a safe name (letters, digits, ``.``, ``_``, ``-``,
  not starting with a dot; pipeline.settings.check_scan_name) or is listed twice: names become
  folder names and command-line words, so they must never carry shell syntax or ``..``;
* a key given twice in one mapping (``samples`` twice under ``render:``: no silent "last one wins");
* a block that is not a stage's, or a block (or ``scans:`` / ``identities:``) that is missing;
* a bad value or unknown key in any block (each block's settings dataclass);
* an ``identities:`` entry (a procedural head the ``synthetic_head`` stage builds into
  ``raw_scans/<name>``) that is not a safe name, is not also listed under ``scans:`` (the
  per-scan stages would never build it), or whose keys over the ``synthetic_head:`` block are
  unknown or out of range.

The check itself is :func:`pipeline.params_check.check_params`.

The output's content never changes, so editing a param re-runs this check but none of the
stages downstream of it.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.io.atomic import write_text
from pipeline.params_check import check_params
from stages._common import read_params_file, stage_exit, stage_parser

OK_TEXT = "params.yaml checked: scan names safe, every block valid\n"


def main(argv) -> None:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("params_file", type=Path, help="params.yaml")
    parser.add_argument("out", type=Path, help="build/check_params.ok (written when everything is valid)")
    args = parser.parse_args(argv)
    check_params(read_params_file(args.params_file), source=str(args.params_file), complete=True)
    write_text(args.out, OK_TEXT)
    return None


if __name__ == "__main__":
    stage_exit(main)
