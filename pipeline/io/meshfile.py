"""The pipeline's own mesh container: one ``.npz`` of named arrays.

Stages hand meshes to each other as ``mesh.npz`` files. Arrays and their names
are the same everywhere (one name across code, tests and docs):

``V``   (n, 3) float64   vertex positions, mm, head frame
``F``   (m, 3) int64     triangles, counter-clockwise seen from outside
``UV``  (k, 2) float64   texture coordinates, origin bottom-left (OBJ/USD convention)
``FUV`` (m, 3) int64     per-corner indices into ``UV`` (UV seams allowed)
``VC``  (n, 3) uint8     per-vertex sRGB colour, when the scan has no texture

Polygon meshes (quad-dominant retopology) add ``poly_counts`` (p,) int64 and
``poly_indices`` (sum(poly_counts),) int64 in USD's faceVertexCounts/Indices
layout; ``F`` is then their fan triangulation. Eyelid-opening loops are
``loop_left`` / ``loop_right`` (L,) int64 vertex indices. Any other array is kept as is.

Later stages add ``lateral_index_left`` / ``lateral_index_right`` (1,) int64 and, with the
grid band, ``band_left`` / ``band_right`` (rings + 1, L) int64 (retopo); ``loop_snap_left`` /
``loop_snap_right`` (L,) float64, ``corner_strip_left`` / ``corner_strip_right`` (k, 2) int64
(a strip vertex, the loop vertex it hangs from; each loop vertex's last one is the strip's inner
edge, inside the eye, the ones before it the caruncle's mound), ``caruncle_faces`` (c,) int64
and, with a caruncle, ``caruncle_weight`` (n,) float64 (each vertex's share of its colour) (snap).

The file carries ``schema`` (a 0-d int64, :data:`SCHEMA`), written by :func:`save_mesh` and
left out of the dict :func:`load_mesh` returns. A stage reads its input mesh with
:func:`read_stage_mesh`, which checks the schema and the arrays above (shapes, finite
positions, indices inside the mesh), refuses anything else with one line naming the file, and
returns a :class:`StageMesh`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.io.atomic import atomic_file

SCHEMA = 1

_DTYPES = {
    "V": np.float64,
    "F": np.int64,
    "UV": np.float64,
    "FUV": np.int64,
    "VC": np.uint8,
    "poly_counts": np.int64,
    "poly_indices": np.int64,
}


# the arrays a StageMesh names (every other array rides in ``extra``)
_NAMED = ("V", "F", "UV", "FUV", "VC", "poly_counts", "poly_indices", "loop_left", "loop_right",
          "lateral_index_left", "lateral_index_right", "band_left", "band_right", "loop_snap_left",
          "loop_snap_right", "corner_strip_left", "corner_strip_right", "caruncle_faces")
_NAMED_SET = frozenset(_NAMED)


@dataclass(frozen=True, eq=False)
class StageMesh(Mapping):
    """One ``mesh.npz`` as read by a stage: the arrays of the module docstring by name (None
    when the file has none), any other array in ``extra``.

    It is also a read-only mapping of the arrays present (``mesh["V"]``, ``"UV" in mesh``,
    ``dict(mesh)``, ``save_mesh(path, **mesh)``), iterated in the file's order: libraries that
    copy a mesh into a dict and add arrays write them back in the same order, so a stage that
    changes nothing writes the same bytes.
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    FUV: np.ndarray | None = None
    VC: np.ndarray | None = None
    poly_counts: np.ndarray | None = None
    poly_indices: np.ndarray | None = None
    loop_left: np.ndarray | None = None
    loop_right: np.ndarray | None = None
    lateral_index_left: np.ndarray | None = None
    lateral_index_right: np.ndarray | None = None
    band_left: np.ndarray | None = None
    band_right: np.ndarray | None = None
    loop_snap_left: np.ndarray | None = None
    loop_snap_right: np.ndarray | None = None
    corner_strip_left: np.ndarray | None = None
    corner_strip_right: np.ndarray | None = None
    caruncle_faces: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    # names in the order they came (the file's); names set but not listed follow, named first
    order: tuple[str, ...] = field(default=(), repr=False)

    def __post_init__(self):
        clash = (_NAMED_SET | {"schema"}).intersection(self.extra)
        if clash:
            raise ValueError(f"StageMesh.extra holds named arrays {sorted(clash)}")
        present = [k for k in _NAMED if getattr(self, k) is not None] + list(self.extra)
        keys = [k for k in self.order if k in present]
        keys += [k for k in present if k not in keys]
        object.__setattr__(self, "_keys", tuple(keys))

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> StageMesh:
        """The StageMesh of named arrays (a ``load_mesh`` dict; ``schema`` is dropped)."""
        arrays = {k: v for k, v in arrays.items() if k != "schema"}
        named = {k: arrays[k] for k in _NAMED if k in arrays}
        extra = {k: v for k, v in arrays.items() if k not in _NAMED_SET}
        return cls(**named, extra=extra, order=tuple(arrays))

    def __getitem__(self, key: str) -> np.ndarray:
        if key in _NAMED_SET:
            value = getattr(self, key)
            if value is None:
                raise KeyError(key)
            return value
        return self.extra[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def __repr__(self) -> str:      # names and shapes: the arrays themselves bury a traceback
        return "StageMesh(" + ", ".join(f"{k}={self[k].shape}" for k in self) + ")"

    # arrays do not compare to one truth value: two meshes are equal only when they are one
    __eq__ = object.__eq__
    __hash__ = object.__hash__


def save_mesh(path, mesh: Mapping | None = None, /, **arrays) -> None:
    """Atomically write named arrays to ``path`` (an uncompressed ``.npz``).

    Parameters
    ----------
    path : str or os.PathLike
    mesh : StageMesh or mapping, optional
        Arrays to write (in its order), before any keyword arrays.
    **arrays : numpy.ndarray
        At least ``V`` and ``F`` (with ``mesh``); standard names are cast to their dtype.
    """
    if mesh is not None:
        arrays = {**mesh, **arrays}
    if "V" not in arrays or "F" not in arrays:
        raise ValueError("save_mesh needs at least V and F")
    out = {k: np.ascontiguousarray(v, dtype=_DTYPES.get(k)) for k, v in arrays.items() if k != "schema"}
    out["schema"] = np.asarray(SCHEMA, dtype=np.int64)
    with atomic_file(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            _savez(fh, out)


def _savez(fh, arrays: Mapping) -> None:
    """``np.savez(fh, **arrays)``, the same bytes (tests/test_meshfile.py), without its copies:
    numpy writes an array to a zip entry in 16 MiB ``tobytes`` chunks (a copy of the whole
    mesh, 95 MB on the 1.4M-face scan, and its page faults); here each C-contiguous array's
    own buffer is written."""
    import zipfile

    from numpy.lib import format as npy

    with zipfile.ZipFile(fh, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, a in arrays.items():
            a = np.asanyarray(a)
            with zf.open(name + ".npy", "w", force_zip64=True) as fid:
                if a.dtype.hasobject or not a.flags.c_contiguous or a.dtype.itemsize == 0:
                    npy.write_array(fid, a, allow_pickle=False)
                    continue
                npy._write_array_header(fid, npy.header_data_from_array_1_0(a), None)
                fid.write(memoryview(a.reshape(-1)).cast("B"))


def _load_npz(path) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``path``, as ``np.load`` reads them (pickles refused).

    An entry stored uncompressed (as :func:`save_mesh` writes them) is read with one
    ``np.fromfile`` from its place in the file: ``np.load`` reads an entry into a bytes object,
    checks its CRC and copies it again (0.12-0.16 s against 0.02-0.03 s for the 95 MB of the
    1.4M-face scan). Only an entry whose header accounts for its size exactly is read so (a
    short read is then an error); any other (compressed, Fortran order, object, or a header that
    claims more or less data than the entry holds) goes through ``np.load``, which refuses a
    short one as before."""
    import zipfile

    from numpy.lib import format as npy

    out, rest = {}, []
    with open(path, "rb") as fh:
        with zipfile.ZipFile(fh) as zf:
            infos = zf.infolist()
        names = [zi.filename[:-4] if zi.filename.endswith(".npy") else zi.filename for zi in infos]
        for zi, name in zip(infos, names):
            if zi.compress_type != zipfile.ZIP_STORED or not zi.filename.endswith(".npy"):
                rest.append(name)
                continue
            fh.seek(zi.header_offset)
            local = fh.read(30)
            if len(local) != 30 or local[:4] != b"PK\x03\x04":
                raise ValueError(f"{path}: {zi.filename}: bad zip entry header")
            start = zi.header_offset + 30 + int.from_bytes(local[26:28], "little") \
                + int.from_bytes(local[28:30], "little")
            fh.seek(start)
            version = npy.read_magic(fh)
            shape, fortran, dtype = npy._read_array_header(fh, version, max_header_size=npy._MAX_HEADER_SIZE)
            count = int(np.prod(shape, dtype=np.int64))
            if fortran or dtype.hasobject or fh.tell() - start + count * dtype.itemsize != zi.file_size:
                rest.append(name)
                continue
            a = np.fromfile(fh, dtype=dtype, count=count)
            if a.size != count:
                raise ValueError(f"{path}: {zi.filename}: {a.size} of {count} values")
            out[name] = a.reshape(shape)
    if rest:
        with np.load(path, allow_pickle=False) as data:
            out.update({k: data[k] for k in rest})
    return {k: out[k] for k in names}


def load_mesh(path) -> dict[str, np.ndarray]:
    """Read a mesh written by :func:`save_mesh` into a dict of arrays (without ``schema``;
    nothing is checked: stages use :func:`read_stage_mesh`)."""
    return {k: v for k, v in _load_npz(path).items() if k != "schema"}


def _load_with_schema(path) -> tuple[int | None, dict[str, np.ndarray]]:
    """(the file's schema: None when absent, -1 when not a 0-d integer; the other arrays)."""
    arrays = _load_npz(path)
    a = arrays.pop("schema", None)
    if a is None:
        return None, arrays
    return (int(a) if a.shape == () and a.dtype.kind in "iu" else -1), arrays


def check_mesh(mesh: Mapping, path) -> None:
    """Refuse (ScanError, one line naming ``path``) arrays that break the layout above."""
    from pipeline.errors import ScanError

    def bad(msg):
        raise ScanError(path, msg)

    V, F = mesh.get("V"), mesh.get("F")
    n = None
    if V is not None:
        if V.ndim != 2 or V.shape[1] != 3 or V.dtype.kind != "f":
            bad(f"V must be (n, 3) floats, got {V.shape} {V.dtype}")
        if not np.isfinite(V).all():
            bad("V has non-finite vertex positions")
        n = len(V)

    def indices(k, a, cols, limit, of):
        if a.dtype.kind not in "iu" or (cols and (a.ndim != 2 or a.shape[1] != cols)) \
                or (not cols and a.ndim != 1):
            bad(f"{k} must be {'(m, %d)' % cols if cols else '(k,)'} integers, got {a.shape} {a.dtype}")
        if a.size and limit is not None and (a.min() < 0 or a.max() >= limit):
            bad(f"{k} indexes outside the {limit} {of}")

    if F is not None:
        indices("F", F, 3, n, "vertices")
    if "UV" in mesh or "FUV" in mesh:
        UV, FUV = mesh.get("UV"), mesh.get("FUV")
        if UV is None or FUV is None:
            bad("UV and FUV come together (one is missing)")
        if UV.ndim != 2 or UV.shape[1] != 2 or not np.isfinite(UV).all():
            bad(f"UV must be (k, 2) finite floats, got {UV.shape}")
        indices("FUV", FUV, 3, len(UV), "texture coordinates")
        if F is not None and len(FUV) != len(F):
            bad(f"FUV has {len(FUV)} faces, F {len(F)}")
    if "VC" in mesh and n is not None and mesh["VC"].shape != (n, 3):
        bad(f"VC must be ({n}, 3) colours, got {mesh['VC'].shape}")
    if "poly_counts" in mesh or "poly_indices" in mesh:
        pc, pi = mesh.get("poly_counts"), mesh.get("poly_indices")
        if pc is None or pi is None:
            bad("poly_counts and poly_indices come together (one is missing)")
        indices("poly_indices", pi, 0, n, "vertices")
        if pc.ndim != 1 or (pc.size and pc.min() < 3) or int(pc.sum()) != len(pi):
            bad("poly_counts must be polygon sizes (>= 3) summing to len(poly_indices)")
    for side in ("left", "right"):
        if f"loop_{side}" in mesh:
            indices(f"loop_{side}", mesh[f"loop_{side}"], 0, n, "vertices")


def read_stage_mesh(path, required=("V", "F")) -> StageMesh:
    """:func:`load_mesh` for a stage's input: missing, unreadable or incomplete is a ScanError.

    Parameters
    ----------
    path : str or os.PathLike
    required : tuple of str
        Array names that must be present besides ``V`` and ``F`` (always required: a
        StageMesh has them).
    """
    from pipeline.errors import ScanError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        schema, mesh = _load_with_schema(path)
    except Exception as exc:  # corrupt zip / npy: whatever numpy raises
        raise ScanError(path, f"cannot be read as a mesh .npz ({type(exc).__name__})") from None
    if schema != SCHEMA:
        raise ScanError(path, f"has mesh schema {schema}, this eyerig reads schema {SCHEMA} "
                              f"(rebuild it with the stage that wrote it)")
    required = ("V", "F") + tuple(k for k in required if k not in ("V", "F"))
    missing = [k for k in required if k not in mesh]
    if missing:
        raise ScanError(path, f"needs arrays {' and '.join(required)} (missing {', '.join(missing)})")
    check_mesh(mesh, path)
    return StageMesh.from_arrays(mesh)
