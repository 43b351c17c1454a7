"""Atomic writes: outputs appear whole or not at all, with ordinary permissions."""

import json
import os
import stat

import numpy as np
import pytest

from pipeline.io.atomic import atomic_dir, atomic_file, write_json
from pipeline.io.meshfile import load_mesh, save_mesh


def _siblings(folder):
    return sorted(p.name for p in folder.iterdir())


def test_atomic_dir_failure_leaves_nothing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with atomic_dir(out) as tmp:
            (tmp / "half.bin").write_bytes(b"x")
            raise RuntimeError("killed")
    assert _siblings(tmp_path) == []


def test_atomic_dir_failure_keeps_previous_output(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(ValueError):
        with atomic_dir(out) as tmp:
            (tmp / "a.txt").write_text("new, half")
            raise ValueError
    assert (out / "a.txt").read_text() == "old"
    assert _siblings(tmp_path) == ["out"]


def test_atomic_dir_replaces_whole_folder(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        (tmp / "stale.txt").write_text("1")
    with atomic_dir(out) as tmp:
        (tmp / "fresh.txt").write_text("2")
    assert _siblings(out) == ["fresh.txt"]
    assert _siblings(tmp_path) == ["out"]


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
    with pytest.raises(OSError):
        with atomic_file(target) as tmp:
            assert tmp.name.endswith(".npz")
            raise OSError("disk full")
    assert _siblings(tmp_path) == []


def test_write_json_refuses_nan_and_converts_numpy(tmp_path):
    with pytest.raises(ValueError):
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
    with pytest.raises(ValueError):
        save_mesh(tmp_path / "x.npz", V=V)
