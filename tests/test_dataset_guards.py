"""The dataset folder belongs to one run, and a run never writes or deletes through a link (issue 31).

No Blender: the command runs in-process on two tiny assets up to the point where it would start the
renders (``pipeline.render.run.run_options`` is replaced by a stop), which is after it has taken the
folder's lock, cleaned the folder and written its ``config.json``.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest
import yaml

from fixtures import make_render_asset
from pipeline.errors import ScanError
from pipeline.io.folder_lock import LOCK_NAME, folder_lock

TINY = {"width": 24, "height": 16, "frame_margin_px": None, "samples": 1, "denoise": False, "workers": 1, "shard_size": 2,
        "connect_timeout_s": 3, "sheet_images": 4}
STOP = "stopped before rendering (test)"


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    root = tmp_path_factory.mktemp("guards")
    made = [make_render_asset(root, name) for name in ("alpha", "beta")]
    params = root / "params.yaml"
    params.write_text(yaml.safe_dump({"render": TINY}))
    return {"assets": [str(m["asset_dir"]) for m in made], "params": str(params)}


@pytest.fixture
def run(two, monkeypatch, capsys):
    """``run(out, *extra) -> (exit status, stderr lines)``: the dataset command, stopped before rendering."""
    from pipeline.render import run as rr
    from stages import dataset

    def stop(*a, **k):
        raise ScanError("render", STOP)
    monkeypatch.setattr(rr, "run_options", stop)

    def go(out, *extra):
        rc = dataset.main(["--assets", *two["assets"], "--n", "2", "--out", str(out), "--params", two["params"],
                           "--no-progress", *extra])
        return rc, capsys.readouterr().err.strip().splitlines()
    return go


def _lock(out, pid, host=None):
    out.mkdir(parents=True, exist_ok=True)
    (out / LOCK_NAME).write_text(json.dumps({"pid": pid, "host": host or socket.gethostname()}))


# ---------------------------------------------------------------------------- the lock

def test_a_second_run_is_refused_while_the_first_holds_the_folder(tmp_path, run):
    out = tmp_path / "ds"
    with folder_lock(out) as note:                  # a run in progress (this process, its own open file)
        assert note is None
        rc, err = run(out)
        assert rc == 2 and len(err) == 1, err
        assert err[0].startswith(f"error: {out}: is in use by another dataset run (pid {os.getpid()} on host "
                                 f"{socket.gethostname()!r}"), err
        assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]     # nothing else written
    assert not out.exists()                         # the lock created the folder and removed it again


def test_a_lock_of_a_live_process_is_refused(tmp_path, run):
    out = tmp_path / "ds"
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        _lock(out, child.pid)
        rc, err = run(out)
        assert rc == 2 and len(err) == 1, err
        assert f"is in use by another dataset run (pid {child.pid} on host {socket.gethostname()!r}" in err[0]
        assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]
    finally:
        child.kill()
        child.wait()


def test_a_lock_of_a_dead_process_is_taken_over_with_a_warning(tmp_path, run):
    out = tmp_path / "ds"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    _lock(out, int(dead))
    rc, err = run(out)
    assert err[0] == (f"warning: took over the stale lock {out / LOCK_NAME} of pid {dead} on host "
                      f"{socket.gethostname()!r}: that process is gone"), err
    assert rc == 2 and err[-1] == f"error: render: {STOP}", err        # the run went on to render
    assert (out / "config.json").is_file() and not (out / LOCK_NAME).exists()   # released on the error


def test_a_lock_of_another_host_is_never_taken_over(tmp_path, run):
    out = tmp_path / "ds"
    _lock(out, 1, host="elsewhere.example")
    rc, err = run(out)
    assert rc == 2 and len(err) == 1 and "is locked by pid 1 on host 'elsewhere.example', another host" in err[0]
    assert (out / LOCK_NAME).exists()


# ---------------------------------------------------------------------------- links

def _earlier_dataset(out):
    out.mkdir(parents=True)
    (out / "config.json").write_text(json.dumps({"config_hash": "0" * 64, "dataset": {"n": 9}}))


def test_a_card_folder_linked_elsewhere_is_refused_untouched(tmp_path, run):
    out, other = tmp_path / "ds", tmp_path / "mine"
    _earlier_dataset(out)
    other.mkdir()
    (other / "gaze.png").write_bytes(b"my own picture")
    os.symlink(other, out / "card")
    rc, err = run(out, "--overwrite")
    assert rc == 2 and len(err) == 1, err
    assert err[0] == (f"error: {out / 'card'}: is a symbolic link where this command writes or deletes; it "
                      "follows no link out of its folder (remove the link; nothing was changed)")
    assert (other / "gaze.png").read_bytes() == b"my own picture" and os.listdir(other) == ["gaze.png"]
    assert sorted(os.listdir(out)) == ["card", "config.json"]


def test_a_linked_tmp_is_refused_in_one_line(tmp_path, run):
    out, other = tmp_path / "ds", tmp_path / "elsewhere"
    _earlier_dataset(out)
    other.mkdir()
    os.symlink(other, out / ".tmp")
    rc, err = run(out, "--overwrite")
    assert rc == 2 and err == [f"error: {out / '.tmp'}: is a symbolic link where this command writes or "
                               "deletes; it follows no link out of its folder (remove the link; nothing was "
                               "changed)"], err
    assert os.listdir(other) == []


def test_a_linked_label_file_is_refused(tmp_path, run):
    out, target = tmp_path / "ds", tmp_path / "notes.txt"
    _earlier_dataset(out)
    target.write_text("mine")
    os.symlink(target, out / "000000.json")
    rc, err = run(out, "--overwrite")
    assert rc == 2 and len(err) == 1 and f"{out / '000000.json'}: is a symbolic link" in err[0], err
    assert target.read_text() == "mine"


def test_atomic_writers_refuse_a_link(tmp_path):
    from pipeline.io.atomic import atomic_dir, write_text

    (tmp_path / "real").mkdir()
    os.symlink(tmp_path / "real", tmp_path / "out")
    with pytest.raises(ScanError, match="out: is a symbolic link"):
        with atomic_dir(tmp_path / "out"):
            pass
    with pytest.raises(ScanError, match="out: is a symbolic link"):
        write_text(tmp_path / "out" / "a.txt", "x", root=tmp_path)
    (tmp_path / "t.txt").write_text("theirs")
    os.symlink(tmp_path / "t.txt", tmp_path / "link.txt")
    with pytest.raises(ScanError, match="link.txt: is a symbolic link"):
        write_text(tmp_path / "link.txt", "x")
    assert (tmp_path / "t.txt").read_text() == "theirs" and os.listdir(tmp_path / "real") == []
