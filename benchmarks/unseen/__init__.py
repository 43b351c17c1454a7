"""The unseen-scan benchmark's parts: ``cases`` (the dev and held-out heads, how their scans are
made), ``metrics`` (per-eye figures against truth), ``report`` (issue 21's bounds, tables). The
command is ``benchmarks/bench_unseen_scans.py``."""
