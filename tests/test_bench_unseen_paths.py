"""benchmarks.bench_unseen_scans writes a head's folders relative to its work folder
(``tests/fixtures/unseen/metrics.within``): a results file committed from one machine names no
path of it."""

from pathlib import Path

from fixtures.unseen.metrics import within


def test_paths_under_the_work_folder_are_written_relative_to_it(tmp_path):
    work = tmp_path / "work"
    (work / "scans" / "n1").mkdir(parents=True)
    line = f"warning: {work}/scans/n1: left eye: placed from little evidence; see {work.resolve()}/build/n1"
    assert within(line, work) == "warning: scans/n1: left eye: placed from little evidence; see build/n1"
    # a path elsewhere, and the work folder's name inside a word, are left as they are
    other = "error: /elsewhere/workshop/x.npz: cannot be read"
    assert within(other, work) == other
    assert within(f"{work}x/scans", work) == f"{work}x/scans"
    assert str(tmp_path) not in within(line, Path(str(work)))
