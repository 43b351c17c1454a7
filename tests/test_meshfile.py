"""mesh.npz: the stage mesh contract (schema, layout checks, one-line refusals)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.errors import ScanError
from pipeline.io.meshfile import SCHEMA, StageMesh, load_mesh, read_stage_mesh, save_mesh


def _tet():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    F = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    return V, F


def test_round_trip_keeps_arrays_and_writes_the_schema(tmp_path):
    V, F = _tet()
    save_mesh(tmp_path / "mesh.npz", V=V, F=F, loop_left=np.array([0, 1, 2]), extra=np.arange(5))
    with np.load(tmp_path / "mesh.npz") as z:
        assert int(z["schema"]) == SCHEMA
    m = read_stage_mesh(tmp_path / "mesh.npz")
    assert set(m) == {"V", "F", "loop_left", "extra"} == set(load_mesh(tmp_path / "mesh.npz"))
    assert m["V"].dtype == np.float64 and m["F"].dtype == np.int64 and np.array_equal(m["F"], F)
    save_mesh(tmp_path / "again.npz", **m)           # re-saving what was read: same bytes
    assert (tmp_path / "again.npz").read_bytes() == (tmp_path / "mesh.npz").read_bytes()


@pytest.mark.parametrize("arrays, message", [
    (lambda V, F: dict(V=V[:, :2], F=F), r"V must be \(n, 3\) floats"),
    (lambda V, F: dict(V=np.where(V == 1, np.nan, V), F=F), "V has non-finite vertex positions"),
    (lambda V, F: dict(V=V, F=F + 1), "F indexes outside the 4 vertices"),
    (lambda V, F: dict(V=V, F=F, UV=np.zeros((3, 2))), "UV and FUV come together"),
    (lambda V, F: dict(V=V, F=F, UV=np.zeros((3, 2)), FUV=F), "FUV indexes outside the 3 texture"),
    (lambda V, F: dict(V=V, F=F, poly_counts=np.array([4]), poly_indices=np.array([0, 1, 2])),
     "poly_counts must be polygon sizes"),
    (lambda V, F: dict(V=V, F=F, loop_right=np.array([0, 9])), "loop_right indexes outside"),
    (lambda V, F: dict(V=V, F=F, VC=np.zeros((3, 3), np.uint8)), r"VC must be \(4, 3\) colours"),
])
def test_bad_layout_refused_in_one_line(tmp_path, arrays, message):
    V, F = _tet()
    save_mesh(tmp_path / "mesh.npz", **arrays(V, F))
    with pytest.raises(ScanError, match=message) as exc:
        read_stage_mesh(tmp_path / "mesh.npz")
    assert str(tmp_path / "mesh.npz") in str(exc.value) and "\n" not in str(exc.value)


def test_other_schema_or_garbage_refused(tmp_path):
    V, F = _tet()
    np.savez(tmp_path / "old.npz", V=V, F=F)          # no schema: written by an older eyerig
    with pytest.raises(ScanError, match="has mesh schema None, this eyerig reads schema 1"):
        read_stage_mesh(tmp_path / "old.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ScanError, match=r"cannot be read as a mesh \.npz"):
        read_stage_mesh(tmp_path / "junk.npz")
    with pytest.raises(ScanError, match="not found"):
        read_stage_mesh(tmp_path / "missing.npz")


def test_stage_mesh_names_its_arrays_and_keeps_the_file_order(tmp_path):
    V, F = _tet()
    save_mesh(tmp_path / "mesh.npz", V=V, F=F, loop_left=np.array([0, 1, 2]), extra=np.arange(5),
              UV=np.zeros((4, 2)), FUV=F)
    m = read_stage_mesh(tmp_path / "mesh.npz")
    assert isinstance(m, StageMesh)
    assert np.array_equal(m.F, F) and np.array_equal(m.loop_left, [0, 1, 2])
    assert m.loop_right is None and "loop_right" not in m and m.get("loop_right") is None
    assert np.array_equal(m.extra["extra"], np.arange(5))      # an unnamed array, by key too
    assert np.array_equal(m["extra"], np.arange(5))
    assert list(m) == ["V", "F", "loop_left", "extra", "UV", "FUV"]   # the file's order
    with pytest.raises(KeyError):
        m["VC"]
    # a library's copy with one more array writes the read arrays back in their order
    save_mesh(tmp_path / "plus.npz", {**m, "caruncle_faces": np.zeros(0, np.int64)})
    assert list(load_mesh(tmp_path / "plus.npz")) == list(m) + ["caruncle_faces"]
    save_mesh(tmp_path / "again.npz", m)
    assert (tmp_path / "again.npz").read_bytes() == (tmp_path / "mesh.npz").read_bytes()
    assert "V=(4, 3)" in repr(m)


def test_stage_mesh_always_has_V_and_F(tmp_path):
    V, F = _tet()
    np.savez(tmp_path / "noF.npz", V=V, schema=np.asarray(SCHEMA, np.int64))
    with pytest.raises(ScanError, match=r"needs arrays V and F and loop_left \(missing F, loop_left"):
        read_stage_mesh(tmp_path / "noF.npz", required=("loop_left",))
    with pytest.raises(ValueError, match="named arrays"):
        StageMesh(V=V, F=F, extra={"UV": np.zeros((4, 2))})


def _every_kind():
    """Arrays of every dtype and shape the stages write: floats, ints, uint8, 0-d, empty."""
    rng = np.random.default_rng(3)
    V, F = _tet()
    return {"V": V + rng.normal(size=V.shape), "F": F, "UV": rng.random((4, 2)), "FUV": F,
            "VC": rng.integers(0, 255, (4, 3), dtype=np.uint8), "band_left": np.arange(12).reshape(3, 4),
            "loop_snap_left": rng.random(3), "caruncle_faces": np.zeros(0, np.int64),
            "schema": np.asarray(SCHEMA, dtype=np.int64)}


def test_writer_gives_numpys_bytes(tmp_path):
    """save_mesh's zip writer (each array's own buffer, no ``tobytes`` copies) writes what
    ``np.savez`` writes, byte for byte: the outputs' hashes in dvc.lock do not move."""
    from pipeline.io.meshfile import _savez

    arrays = _every_kind()
    arrays["big"] = np.arange(3_000_000, dtype=np.int64).reshape(-1, 3)   # several of numpy's chunks
    arrays["strided"] = arrays["big"][::2, 1]                               # not contiguous
    np.savez(tmp_path / "numpy.npz", **arrays)
    with open(tmp_path / "ours.npz", "wb") as fh:
        _savez(fh, arrays)
    assert (tmp_path / "ours.npz").read_bytes() == (tmp_path / "numpy.npz").read_bytes()


def test_reader_gives_numpys_arrays_and_refuses_a_short_or_lying_file(tmp_path):
    """The reader (each stored entry read in place by ``np.fromfile``) returns np.load's arrays:
    the same names in the same order, dtypes, shapes and values; compressed and Fortran-order
    entries go through np.load. A file cut short, or an entry whose header claims more data than
    the entry holds, is an error (read_stage_mesh's one line), never a short array."""
    from pipeline.io.meshfile import _load_npz

    arrays = _every_kind()
    arrays["fortran"] = np.asfortranarray(np.arange(12.0).reshape(3, 4))
    for name, save in (("plain.npz", np.savez), ("packed.npz", np.savez_compressed)):
        save(tmp_path / name, **arrays)
        got = _load_npz(tmp_path / name)
        with np.load(tmp_path / name) as ref:
            assert list(got) == list(ref.files)
            for k in ref.files:
                assert got[k].dtype == ref[k].dtype and got[k].shape == ref[k].shape
                assert np.array_equal(got[k], ref[k])
    V, F = _tet()
    save_mesh(tmp_path / "mesh.npz", V=V, F=F)
    data = (tmp_path / "mesh.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ScanError, match=r"cannot be read as a mesh \.npz"):
        read_stage_mesh(tmp_path / "cut.npz")
    # V's header (the first entry's) says (4, 3); make it say (9, 3) in place (the same length):
    # the entry then holds less than its header claims
    assert data.index(b"'shape': (4, 3), }") < data.index(b"F.npy")
    (tmp_path / "lying.npz").write_bytes(data.replace(b"'shape': (4, 3), }", b"'shape': (9, 3), }", 1))
    with pytest.raises(ScanError, match=r"cannot be read as a mesh \.npz"):
        read_stage_mesh(tmp_path / "lying.npz")
