"""STL reader (ASCII and binary): a triangle soup with bit-identical corners merged.

The binary header's triangle count is checked against the file size and the limits, an ASCII
file's ``vertex`` words are counted, before anything is parsed. Plain ASCII files are parsed in
chunks with numpy; any other layout goes through trimesh.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.formats.common import Limits, LoadedMesh, check_counts, check_file_size, parse_numbers
from pipeline.io.scan import one_line


def _count_word(path: Path, word: bytes, chunk: int = 1 << 22) -> int:
    """Occurrences of ``word`` in a file, read in chunks (no copy of the file is kept)."""
    n, tail = 0, b""
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            buf = tail + block
            n += buf.count(word)
            tail = buf[-(len(word) - 1):]            # too short to hold the word again: no double count
    return n


_STL_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def _stl_mesh(path: Path, corners: np.ndarray) -> LoadedMesh:
    """A triangle soup's corners (3 per facet) -> LoadedMesh with bit-identical corners merged.

    Merging here keeps the soup's three copies of every vertex from being converted and
    repaired (10M triangles: 30M corners); the repair step merges the rest within its tolerance.
    """
    if len(corners) == 0:
        raise ScanError(path, "no triangles found")
    bits = corners.view(np.uint32 if corners.dtype.itemsize == 4 else np.uint64)
    key = bits[:, 0].astype(np.int64) * np.int64(73856093)
    key ^= bits[:, 1].astype(np.int64) * np.int64(19349663)
    key ^= bits[:, 2].astype(np.int64) * np.int64(83492791)
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    del key
    inverse = inverse.reshape(-1)
    same = all(np.array_equal(bits[first[inverse[i:i + (1 << 20)]]], bits[i:i + (1 << 20)])
               for i in range(0, len(bits), 1 << 20))
    if not same:                                 # a hash collision: leave the merging to the repair step
        return LoadedMesh(V=corners.astype(np.float64), F=np.arange(len(corners)).reshape(-1, 3),
                          files_read=[path])
    order = np.argsort(first, kind="stable")     # keep the order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    V = corners[first[order]].astype(np.float64)
    return LoadedMesh(V=V, F=rank[inverse].reshape(-1, 3), files_read=[path],
                      merged_vertices=len(corners) - len(V))


_STL_WORDS = (b"endfacet", b"facet", b"normal", b"outer", b"endloop", b"loop", b"vertex")   # longest first


def _stl_ascii_corners(path: Path, chunk: int = 1 << 24):
    """The corners (3 per facet, float64 (3n, 3)) of a plain ASCII STL, read in chunks of whole facets
    with the keywords blanked and one numpy parse per chunk (memory: the corners, not the text).
    None when the file does not have the plain one-solid lower-case layout (trimesh then reads it)."""
    parts, pending = [], b""
    with open(path, "rb") as fh:
        fh.readline(1 << 16)                     # "solid <name>"
        while True:
            block = fh.read(chunk)
            data = pending + block
            if not block:
                rest = data.strip()
                if rest and not rest.startswith(b"endsolid"):
                    return None
                break
            cut = data.rfind(b"endfacet")
            if cut < 0:
                if len(data) > chunk:            # no facet end in a whole chunk: not the plain layout
                    return None
                pending = data
                continue
            cut += len(b"endfacet")
            body, pending = data[:cut], data[cut:]
            n = body.count(b"endfacet")
            for word in _STL_WORDS:
                body = body.replace(word, b" ")
            vals = parse_numbers(body)
            if vals is None or vals.size != 12 * n:
                return None
            parts.append(vals.reshape(n, 12)[:, 3:])             # drop the facet normals
    return np.concatenate(parts).reshape(-1, 3) if parts else np.zeros((0, 3))


def load_stl(path, folder, limits: Limits = Limits()) -> LoadedMesh:
    """Load an ASCII or binary STL (a triangle soup; duplicates are merged by the repair step)."""
    path = Path(path)
    size = check_file_size(path, limits)
    with open(path, "rb") as fh:
        head = fh.read(84)
    is_ascii = head[:5].lower() == b"solid" and b"\x00" not in head
    if not is_ascii:
        if len(head) < 84:
            raise ScanError(path, "not an STL file (too short for a binary STL header)")
        n = struct.unpack("<I", head[80:84])[0]
        check_counts(path, 0, n, limits)       # vertices (3 per triangle) are checked once merged
        if 84 + 50 * n != size:
            raise ScanError(path, f"binary STL header says {n} triangles ({84 + 50 * n} bytes) but the file "
                                  f"has {size} bytes (truncated or not an STL)")
        records = np.fromfile(path, dtype=_STL_RECORD, count=n, offset=84)
        return _stl_mesh(path, records["corners"].reshape(-1, 3))
    else:                                        # no header count: count the corners before parsing
        check_counts(path, 0, _count_word(path, b"vertex") // 3, limits)
        corners = _stl_ascii_corners(path)
        if corners is not None:
            return _stl_mesh(path, corners)
    from trimesh.exchange import stl as tstl

    try:
        with open(path, "rb") as fh, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            kw = tstl.load_stl(fh)
    except Exception as exc:  # noqa: BLE001
        raise ScanError(path, f"cannot read STL: {one_line(exc)[:120]}") from None
    V = np.asarray(kw.get("vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    F = np.asarray(kw.get("faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    if len(F) == 0:
        raise ScanError(path, "no triangles found")
    check_counts(path, 0, len(F), limits)
    return LoadedMesh(V=V, F=F, files_read=[path])
