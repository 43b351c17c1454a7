"""Atomic writes: outputs appear whole or not at all, with ordinary permissions."""

import json
import os
import stat
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_dir, atomic_file, write_json
from pipeline.io.meshfile import load_mesh, save_mesh


def _siblings(folder):
    return sorted(p.name for p in folder.iterdir())


def test_atomic_dir_failure_leaves_nothing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="^killed$"):
        with atomic_dir(out) as tmp:
            (tmp / "half.bin").write_bytes(b"x")
            raise RuntimeError("killed")
    assert _siblings(tmp_path) == []


def test_atomic_dir_failure_keeps_previous_output(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(ValueError, match="^half written$"):
        with atomic_dir(out) as tmp:
            (tmp / "a.txt").write_text("new, half")
            raise ValueError("half written")
    assert (out / "a.txt").read_text() == "old"
    assert _siblings(tmp_path) == ["out"]


def test_atomic_dir_replaces_an_earlier_write_of_the_same_output(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        (tmp / "sub").mkdir()
        (tmp / "sub" / "a.txt").write_text("1")
    with atomic_dir(out) as tmp:
        (tmp / "sub").mkdir()
        (tmp / "sub" / "a.txt").write_text("2")
        (tmp / "b.txt").write_text("new")
    assert _siblings(out) == ["b.txt", "sub"] and (out / "sub" / "a.txt").read_text() == "2"
    assert _siblings(tmp_path) == ["out"]


def test_atomic_dir_never_deletes_a_file_it_would_not_write(tmp_path):
    """A folder holding a file the new output has no namesake for is someone's work (or an older
    output with other files): refused, left as it was, nothing of the run left behind."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.txt").write_text("mine")
    (out / "notes.txt").write_text("mine too")
    with pytest.raises(ScanError, match=r"out: holds 'notes.txt' that this run does not write"):
        with atomic_dir(out) as tmp:
            (tmp / "a.txt").write_text("new")
    assert (out / "a.txt").read_text() == "mine" and _siblings(out) == ["a.txt", "notes.txt"]
    assert _siblings(tmp_path) == ["out"]
    (tmp_path / "f").write_text("a file")
    with pytest.raises(ScanError, match="f: exists and is not a folder"):
        with atomic_dir(tmp_path / "f") as tmp:
            pytest.fail("ran into a file's place")
    assert (tmp_path / "f").read_text() == "a file" and _siblings(tmp_path) == ["f", "out"]


def test_outputs_honour_umask(tmp_path):
    old = os.umask(0o022)
    try:
        with atomic_dir(tmp_path / "d") as tmp:
            (tmp / "f").write_text("x")
        write_json(tmp_path / "m.json", {"a": 1})
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "m.json").stat().st_mode) == 0o644


def test_atomic_file_keeps_suffix_and_cleans_up(tmp_path):
    target = tmp_path / "mesh.npz"
    with pytest.raises(OSError, match="^disk full$"):
        with atomic_file(target) as tmp:
            assert tmp.name.endswith(".npz")
            raise OSError("disk full")
    assert _siblings(tmp_path) == []


def test_write_json_refuses_nan_and_converts_numpy(tmp_path):
    with pytest.raises(ValueError, match="not JSON compliant: nan"):
        write_json(tmp_path / "bad.json", {"x": float("nan")})
    assert not (tmp_path / "bad.json").exists()
    write_json(tmp_path / "ok.json", {"v": np.arange(3), "s": np.float64(1.5)})
    assert json.loads((tmp_path / "ok.json").read_text()) == {"v": [0, 1, 2], "s": 1.5}


def test_mesh_container_round_trip_casts_dtypes(tmp_path):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    F = np.array([[0, 1, 2]], dtype=np.int32)
    save_mesh(tmp_path / "m.npz", V=V, F=F, loop_left=np.array([0, 1]))
    m = load_mesh(tmp_path / "m.npz")
    assert m["V"].dtype == np.float64 and m["F"].dtype == np.int64
    np.testing.assert_array_equal(m["loop_left"], [0, 1])
    with pytest.raises(ValueError, match="save_mesh needs at least V and F"):
        save_mesh(tmp_path / "x.npz", V=V)


# ---------------------------------------------------------------------------- stale temporaries, scratch, children

DEAD_PID = 2**22 + 12345          # above Linux's pid_max: never a live process


def test_stale_tmp_siblings_of_dead_processes_are_removed(tmp_path):
    out = tmp_path / "out"
    dead = tmp_path / f".out.tmp-{DEAD_PID}-abc"
    legacy = tmp_path / ".out.tmp-x1y2"
    live = tmp_path / f".out.tmp-{os.getpid()}-zzz"      # another writer, still running
    other = tmp_path / f".other.tmp-{DEAD_PID}-abc"       # another output's: not ours to touch
    for d in (dead, legacy, live, other):
        d.mkdir()
        (d / "half.bin").write_bytes(b"x" * 100)
    with atomic_dir(out) as tmp:
        assert tmp.name.startswith(f".out.tmp-{os.getpid()}-")
        (tmp / "a.txt").write_text("whole")
    assert _siblings(tmp_path) == sorted([live.name, other.name, "out"])
    (tmp_path / f".m.json.tmp-{DEAD_PID}-q.json").write_text("{")
    write_json(tmp_path / "m.json", {"a": 1})
    assert not (tmp_path / f".m.json.tmp-{DEAD_PID}-q.json").exists()


def test_a_zombie_writer_is_gone_and_its_sibling_removed(tmp_path):
    """A writer killed mid-write and not yet reaped by its parent (a dask worker SIGKILLed while it
    wrote a label, as in test_shard's kill test) is a zombie: it writes nothing more, so its
    sibling is stale, while a live writer's is kept."""
    import signal
    import subprocess
    import sys

    from pipeline.io.scratch import pid_alive

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        assert pid_alive(child.pid)
        os.kill(child.pid, signal.SIGKILL)
        t0 = time.time()
        while Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
            assert time.time() - t0 < 10
            time.sleep(0.01)
        assert not pid_alive(child.pid)               # dead, though os.kill(pid, 0) still succeeds
        (tmp_path / f".m.json.tmp-{child.pid}-q.json").write_text("{")
        write_json(tmp_path / "m.json", {"a": 1})
        assert _siblings(tmp_path) == ["m.json"]
    finally:
        child.kill()
        child.wait()
    assert not pid_alive(child.pid) and pid_alive(os.getpid())


def test_atomic_writes_fsync_file_and_folder_before_and_after_rename(tmp_path, monkeypatch):
    import pipeline.io.atomic as at

    synced, renamed = [], []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(at.os, "fsync", lambda fd: (synced.append(os.readlink(f"/proc/self/fd/{fd}")),
                                                     real_fsync(fd))[1])
    monkeypatch.setattr(at.os, "replace", lambda a, b: (renamed.append((str(a), len(synced))),
                                                         real_replace(a, b))[1])
    write_json(tmp_path / "m.json", {"a": 1})
    final_rename = [r for r in renamed if r[0].endswith(".json") and ".tmp-" in r[0]][-1]
    assert any(".m.json.tmp-" in s for s in synced[:final_rename[1]])     # the data, before the rename
    assert synced[-1] == str(tmp_path)                                     # the folder, after it
    synced.clear()
    with atomic_dir(tmp_path / "d") as tmp:
        (tmp / "f.bin").write_bytes(b"1")
    assert any(s.endswith("/f.bin") for s in synced) and synced[-1] == str(tmp_path)


def test_stage_scratch_is_tmpdir_of_the_stage_and_removed(tmp_path, monkeypatch):
    import subprocess
    import sys
    import tempfile

    from pipeline.io.scratch import stage_scratch

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)
    stale = tmp_path / f"eyerig-render-{DEAD_PID}-abc123"
    stale.mkdir()
    (stale / "dask-scratch-space").mkdir()
    with stage_scratch("render") as folder:
        assert not stale.exists()
        assert folder.parent == tmp_path and folder.name.startswith(f"eyerig-render-{os.getpid()}-")
        assert tempfile.gettempdir() == str(folder) and os.environ["TMPDIR"] == str(folder)
        child = subprocess.run([sys.executable, "-c", "import tempfile; print(tempfile.gettempdir())"],
                               capture_output=True, text=True, check=True)
        assert child.stdout.strip() == str(folder)                  # children scratch there too
        (folder / "blender_xyz").mkdir()
    assert not folder.exists() and os.environ["TMPDIR"] == str(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_children_die_with_their_parent(tmp_path):
    """A child started with die_with_parent (Blender previews, render workers) gets SIGTERM when
    the process that started it is killed with SIGKILL."""
    import signal
    import subprocess
    import sys
    import time

    code = ("import subprocess, sys; from pipeline.io.scratch import die_with_parent; "
            "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'], "
            "preexec_fn=die_with_parent); print(p.pid, flush=True); time.sleep(60)")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    child = int(parent.stdout.readline())
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{child}/stat") as fh:
                if fh.read().split(") ")[1][0] == "Z":     # reaped by init soon; gone already
                    break
        except FileNotFoundError:
            break
        time.sleep(0.05)
    else:
        os.kill(child, signal.SIGKILL)
        pytest.fail("the child outlived its killed parent")


def test_run_stage_gives_each_stage_its_own_scratch_and_removes_it(tmp_path, monkeypatch):
    import tempfile

    from stages._common import run_stage

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)
    seen = []

    def main(argv):
        seen.append(Path(tempfile.gettempdir()))
        (seen[0] / "blender_scratch").mkdir()
        return None

    assert run_stage(main, []) == 0
    assert seen[0].parent == tmp_path and seen[0].name.startswith(f"eyerig-test_atomic-{os.getpid()}-")
    assert not seen[0].exists() and list(tmp_path.iterdir()) == []


def test_a_starting_stage_clears_stale_siblings_of_its_paths(tmp_path, capsys):
    """A killed run left a temporary output folder (its pid is gone): the next run of the stage
    removes it when it starts, even if it then fails before writing anything; a live
    process's temporary is kept."""
    import os

    from stages._common import run_stage

    out = tmp_path / "out"
    dead = tmp_path / ".out.tmp-999999999-abc"        # no such pid
    live = tmp_path / f".out.tmp-{os.getpid()}-def"
    dead.mkdir()
    live.mkdir()

    def main(argv):
        raise MemoryError

    assert run_stage(main, [str(out)]) == 2
    assert not dead.exists() and live.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ran out of memory" in err[0]


def test_files_inside_atomic_dir_are_flushed_once_with_the_tree(tmp_path, monkeypatch):
    # every file of a published folder is flushed before the rename, exactly once; a lone
    # atomic_file still flushes itself and its folder
    import os
    from pipeline.io import atomic
    synced = []
    real = os.fsync

    def record(fd):
        synced.append(os.path.basename(os.readlink(f"/proc/self/fd/{fd}")))
        real(fd)

    monkeypatch.setattr(atomic.os, "fsync", record)
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        write_json(tmp / "a.json", {"x": 1})
        (tmp / "sub").mkdir()
        with atomic_file(tmp / "sub" / "b.bin") as t:
            t.write_bytes(b"b")
        (tmp / "c.txt").write_text("c")
    names = [n for n in synced if not n.startswith(".out.tmp-")]
    assert sorted(names) == ["a.json", "b.bin", "c.txt", "sub", tmp_path.name]
    assert sum(n.startswith(".out.tmp-") for n in synced) == 1       # the folder, once
    assert atomic._OPEN_DIRS == set()
    assert json.loads((out / "a.json").read_text()) == {"x": 1} and (out / "sub" / "b.bin").read_bytes() == b"b"
    synced.clear()
    write_json(tmp_path / "lone.json", [1])
    assert len(synced) == 2 and synced[1] == tmp_path.name and synced[0].endswith(".json")
    # a failed folder leaves no open entry behind: later files outside it are flushed again
    with pytest.raises(RuntimeError):
        with atomic_dir(tmp_path / "bad") as tmp:
            raise RuntimeError("x")
    assert atomic._OPEN_DIRS == set()
