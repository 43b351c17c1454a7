"""What every mesh-format reader shares: the resource limits, the loaded-mesh container, size and
count checks made before memory is spent, fan triangulation, and the vectorised text helpers
(chunked reading of the lines that carry data, whitespace-separated numbers in one C-level parse).
"""

from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError

MAX_LINE_BYTES = 1 << 20          # longest line of a text mesh or material file


@dataclass(frozen=True)
class Limits:
    """Resource limits for untrusted inputs.

    Attributes
    ----------
    max_file_bytes : int
        Largest mesh, material or texture file read.
    max_vertices, max_faces : int
        Largest vertex / (triangulated) face count accepted.
    max_texture_pixels : int
        Largest texture (width * height), checked from the header before decoding.
    max_json_bytes : int
        Largest GLB JSON chunk (decoded JSON takes many times its size).
    """

    max_file_bytes: int = 1 << 30
    max_vertices: int = 5_000_000
    max_faces: int = 10_000_000
    max_texture_pixels: int = 8192 * 8192
    max_json_bytes: int = 64 << 20


@dataclass
class LoadedMesh:
    """A mesh as stored in its file (file units and axes).

    Attributes
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    UV : (k, 2) float64 or None
        Texture coordinates, origin bottom-left.
    FUV : (m, 3) int64 or None
        Per-corner indices into ``UV``.
    VC : (n, 3) uint8 or None
        Per-vertex colour.
    texture_path : pathlib.Path or None
        Texture named by the mesh file (MTL ``map_Kd``, PLY ``TextureFile``), resolved inside the folder.
    texture_bytes : bytes or None
        Texture embedded in the mesh file (GLB), still encoded.
    files_read : list of pathlib.Path
        Every file read (mesh, MTL), for the source hash.
    polygons_triangulated : int
        Faces with more than three corners that were fan-triangulated.
    merged_vertices : int
        Bit-identical vertices the loader already merged (an STL soup), counted with the repairs.
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    FUV: np.ndarray | None = None
    VC: np.ndarray | None = None
    texture_path: Path | None = None
    texture_bytes: bytes | None = None
    files_read: list = field(default_factory=list)
    polygons_triangulated: int = 0
    merged_vertices: int = 0


def check_file_size(path, limits: Limits) -> int:
    """Refuse a file over ``limits.max_file_bytes``; return its size in bytes."""
    size = Path(path).stat().st_size
    if size > limits.max_file_bytes:
        raise ScanError(path, f"file is {size / 2**20:.3g} MiB, over the limit of "
                              f"{limits.max_file_bytes / 2**20:.3g} MiB (ingest.max_file_mb)")
    if size == 0:
        raise ScanError(path, "file is empty")
    return size


def check_counts(path, n_vertices: int, n_faces: int, limits: Limits) -> None:
    if n_vertices > limits.max_vertices:
        raise ScanError(path, f"{n_vertices} vertices, over the limit of {limits.max_vertices} (ingest.max_vertices)")
    if n_faces > limits.max_faces:
        raise ScanError(path, f"{n_faces} faces, over the limit of {limits.max_faces} (ingest.max_faces)")


def fan_triangulate(polys: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons of one size.

    Parameters
    ----------
    polys : (p, k) int array, k >= 3

    Returns
    -------
    (p * (k - 2), 3) int64, triangles of each polygon consecutive.
    """
    polys = np.asarray(polys, dtype=np.int64)
    k = polys.shape[1]
    if k == 3:
        return polys
    i = np.arange(1, k - 1)
    tris = np.stack([np.repeat(polys[:, :1], k - 2, axis=1), polys[:, i], polys[:, i + 1]], axis=2)
    return tris.reshape(-1, 3)


def fan_by_counts(flat: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Polygons given as consecutive corners (``counts[i]`` corners each) -> fan triangles, file order."""
    if counts.min() == counts.max():
        return fan_triangulate(flat.reshape(len(counts), int(counts[0])))
    ntri = counts - 2
    poly = np.repeat(np.arange(len(counts)), ntri)
    first = np.cumsum(counts) - counts                   # first corner of each polygon
    j = np.arange(len(poly)) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    base = first[poly]
    del poly
    return np.stack([flat[base], flat[base + j], flat[base + j + 1]], axis=1)


def parse_numbers(text: bytes, dtype=np.float64):
    """Whitespace-separated numbers of ``text`` in one C-level parse, or None when numpy cannot parse them
    (it then stops early: callers also compare the count)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return np.fromstring(text, dtype=dtype, sep=" ")
        except ValueError:
            return None


def tokens_per_row(text: bytes, n_rows: int, block: int = 1 << 23) -> np.ndarray:
    """Whitespace-separated token count of each newline-separated row of ``text``, shape (n_rows,).

    Counted in blocks of whole rows (about ``block`` bytes), so the temporaries stay small."""
    counts = np.zeros(n_rows, dtype=np.int64)
    pos, row, size = 0, 0, len(text)
    while pos < size:
        end = min(pos + block, size)
        if end < size:
            cut = text.rfind(b"\n", pos, end)
            end = cut + 1 if cut >= pos else (text.find(b"\n", end) + 1 or size)
        b = np.frombuffer(text, dtype=np.uint8, count=end - pos, offset=pos)
        ws = (b == 32) | (b == 9) | (b == 10) | (b == 13)
        start = ~ws                                  # a block starts a row: no token continues into it
        start[1:] &= ws[:-1]
        nl = np.flatnonzero(b == 10)
        per_row = np.bincount(np.searchsorted(nl, np.flatnonzero(start)))   # rows of this block
        hi = min(row + len(per_row), n_rows)
        counts[row:hi] += per_row[:hi - row]
        row += len(nl)
        pos = end
    return counts


def _content_lines(block: bytes, first_line: int, parts: bytearray, numbers: list, comment: int | None) -> int:
    """Append the lines of ``block`` (whole lines, ending in a newline) that are neither blank nor
    comments (first non-blank byte ``comment``) to ``parts``, and their file line numbers (0-based)
    to ``numbers``. Returns the number of lines in ``block``. Vectorised: no Python object per line."""
    b = np.frombuffer(block, dtype=np.uint8)
    ends = np.flatnonzero(b == 10)
    starts = np.empty_like(ends)
    starts[0], starts[1:] = 0, ends[:-1] + 1
    content = np.flatnonzero((b != 32) & (b != 9) & (b != 13) & (b != 10))
    k = np.searchsorted(content, starts)
    first = content[np.minimum(k, len(content) - 1)] if len(content) else starts
    keep = (k < len(content)) & (first < ends)
    if comment is not None:
        keep &= b[np.minimum(first, len(b) - 1)] != comment
    if keep.all():
        parts += block
    elif keep.any():
        parts += b[np.repeat(keep, ends - starts + 1)].tobytes()
    numbers.append(first_line + np.flatnonzero(keep))
    return len(ends)


def read_content(fh, path: Path, max_lines: int | None = None, comment: bytes | None = b"#",
                  chunk: int = 1 << 18, max_line: int = MAX_LINE_BYTES):
    """The lines that carry data from ``fh``'s position on (blank and comment lines dropped, read in
    chunks), stopping once ``max_lines`` are found.

    Returns ``(text, line_no)``: the kept lines, each ending in a newline, and the 0-based line number
    (counted from the starting position) of each. Memory follows the data, not the file: a file
    padded with gigabytes of blank lines costs the size of its data. A line longer than ``max_line``
    bytes is refused (naming ``path``).
    """
    parts, numbers, pending = bytearray(), [], []
    line, found = 0, 0
    code = comment[0] if comment else None
    while max_lines is None or found < max_lines:
        block = fh.read(chunk)
        if not block:
            if pending:
                line += _content_lines(b"".join(pending) + b"\n", line, parts, numbers, code)
            break
        cut = block.rfind(b"\n")
        if cut < 0:                                   # a line longer than the chunk
            pending.append(block)
            if len(pending) * chunk > max_line:
                raise ScanError(path, f"line {line + 1} is longer than {max_line} bytes (not a text mesh file?)")
            continue
        whole = b"".join(pending + [block[:cut + 1]]) if pending else block[:cut + 1]
        pending = [block[cut + 1:]] if cut + 1 < len(block) else []
        line += _content_lines(whole, line, parts, numbers, code)
        found += len(numbers[-1])
    text = bytes(parts)                              # numpy's text parsers take read-only bytes
    del parts
    line_no = np.concatenate(numbers) if numbers else np.zeros(0, np.int64)
    if max_lines is not None and len(line_no) > max_lines:
        ends = np.flatnonzero(np.frombuffer(text, dtype=np.uint8) == 10)
        text, line_no = text[:ends[max_lines - 1] + 1], line_no[:max_lines]
    return text, line_no


@contextlib.contextmanager
def max_pixels(limit: int):
    from PIL import Image

    old = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = int(limit)
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = old
