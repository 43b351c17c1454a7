"""The unseen-scan benchmark's own part: ``report`` (issue 21's bounds, tables). What it shares with
the tests, ``cases`` (the dev and held-out heads, how their scans are made) and ``metrics``
(per-eye figures against truth), is ``tests/fixtures/unseen/``. The command is
``benchmarks/bench_unseen_scans.py``."""
