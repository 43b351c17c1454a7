"""Where benchmarks write what they measured: ``benchmarks/results/<name>.json`` (the summary) and,
for a curve, ``<name>.csv`` (one row per point; the DVC plots in dvc.yaml read it)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def write_results(name: str, summary: dict, rows: list[dict] | None = None) -> Path:
    """Write ``<name>.json`` (``summary``, indented) and, given ``rows``, ``<name>.csv``; says so
    on stdout and returns the JSON's path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps(summary, indent=1) + "\n")
    if rows:
        with open(RESULTS / f"{name}.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    print(f"wrote {path}" + (f" and {name}.csv" if rows else ""))
    return path
