"""Mesh and texture loading for untrusted scan files (OBJ+MTL, PLY, STL, GLB).

Every loader returns a :class:`LoadedMesh` in the file's own units and axes and
raises :class:`pipeline.errors.ScanError` (naming the file and the problem) for
anything it cannot read. Limits are checked before memory is spent: file size;
element counts in PLY/STL headers (the STL triangle count; its soup vertices are
limited once merged); ``v``/``f`` line counts of an OBJ before any line is parsed;
a GLB's JSON size, and every buffer view, accessor (count x type against the bytes
it reads), node hierarchy (a tree) and the vertices/faces of every node instance
(:func:`_glb_check_doc`) before trimesh decodes anything; image pixel counts from
the image header before decoding (decompression bombs).

Text readers keep memory proportional to the data, not the file: OBJ, ASCII PLY and
MTL are read in chunks with blank (and OBJ/MTL comment) lines dropped without a
Python object per line, lines over :data:`MAX_LINE_BYTES` are refused, and ASCII
PLY stops at the rows its header announces.

UVs are kept per corner (``UV`` + ``FUV``): OBJ seams keep their exact layout
(one ``UV`` row per ``vt`` line, the vertex positions are not split, unlike
trimesh's OBJ loader which duplicates seam vertices). PLY per-vertex ``s,t`` /
``u,v`` / ``texture_u,texture_v`` become ``UV`` with ``FUV = F``; PLY per-face
``texcoord`` lists become one ``UV`` row per corner.

Readers: OBJ and PLY (ASCII and binary) are parsed here with numpy (vectorised,
polygons of mixed sizes included, with a row-by-row fallback for the rest that
names the offending line); STL and GLB go through trimesh after the checks above.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.scan import TEXTURE_SUFFIXES, one_line, safe_path, short_repr
from pipeline.settings import Settings, setting


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


def _check_counts(path, n_vertices: int, n_faces: int, limits: Limits) -> None:
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


# ---------------------------------------------------------------------------- OBJ

def _parse_floats(rows: list, path: Path, what: str, first_line: np.ndarray, min_cols: int) -> np.ndarray:
    """Rows of whitespace-separated numbers -> float64 array (k, c); ragged rows keep min_cols."""
    if not rows:
        return np.zeros((0, min_cols))
    split = [r.split() for r in rows]
    lengths = np.fromiter((len(s) for s in split), dtype=np.int64, count=len(split))
    short = np.flatnonzero(lengths < min_cols)
    if short.size:
        raise ScanError(path, f"line {first_line[short[0]] + 1}: {what} needs {min_cols} numbers")
    cols = int(lengths.min())
    if not np.all(lengths == cols):
        split = [s[:cols] for s in split]
    try:
        return np.array(split, dtype=np.float64)
    except ValueError:
        for i, s in enumerate(split):
            try:
                [float(x) for x in s]
            except ValueError:
                raise ScanError(path, f"line {first_line[i] + 1}: cannot parse {what} numbers "
                                      f"{one_line(' '.join(s))[:60]!r}") from None
        raise


def _parse_obj_faces(face_rows: list, path: Path, line_no: np.ndarray):
    """Face rows -> (corner vertex idx, corner vt idx or None, corners per face) as flat arrays."""
    split = [r.split() for r in face_rows]
    counts = np.fromiter((len(s) for s in split), dtype=np.int64, count=len(split))
    bad = np.flatnonzero(counts < 3)
    if bad.size:
        raise ScanError(path, f"line {line_no[bad[0]] + 1}: a face needs at least 3 vertices")
    tokens = [t for s in split for t in s]
    first = tokens[0]
    n_fields = first.count("/") + 1
    has_vt = n_fields >= 2 and first.split("/")[1] != ""
    try:
        if n_fields == 1:
            vidx = np.array(tokens, dtype=np.int64)
            tidx = None
        else:
            # each token has fields separated by '/', empty fields allowed ("a//c")
            pieces = [t.split("/") for t in tokens]
            if any(len(p) != n_fields for p in pieces):
                raise ValueError("mixed face formats")
            vidx = np.array([p[0] for p in pieces], dtype=np.int64)
            tidx = np.array([p[1] for p in pieces], dtype=np.int64) if has_vt else None
    except (ValueError, OverflowError):
        raise _bad_face_line(split, path, line_no, n_fields) from None
    return vidx, tidx, counts


def _bad_face_line(split: list, path: Path, line_no: np.ndarray, n_fields: int) -> ScanError:
    """The error for the first face row whose indices do not parse or do not fit in int64."""
    for row, tokens in enumerate(split):
        for tok in tokens:
            fields = tok.split("/")
            if len(fields) != n_fields:
                return ScanError(path, f"line {line_no[row] + 1}: face corner {one_line(tok)[:40]!r} does not match "
                                       f"the first face's format ({n_fields} '/'-separated fields)")
            for j, x in enumerate(fields[:2]):
                if j == 1 and x == "":                   # "a//c": no texture coordinate
                    continue
                try:
                    value = int(x)
                except ValueError:
                    return ScanError(path, f"line {line_no[row] + 1}: cannot parse face index {one_line(x)[:40]!r}")
                if abs(value) >= 2**62:
                    return ScanError(path, f"line {line_no[row] + 1}: face index {one_line(x)[:40]} is out of "
                                           "range (too large)")
    return ScanError(path, f"faces: cannot parse vertex indices (first face is line {line_no[0] + 1})")


def _resolve_obj_index(idx: np.ndarray, count_before: np.ndarray, total: int, path: Path,
                       what: str, corner_line: np.ndarray) -> np.ndarray:
    """OBJ 1-based / negative-relative indices -> 0-based, range-checked."""
    out = np.where(idx < 0, count_before + idx, idx - 1)
    bad = np.flatnonzero((idx == 0) | (out < 0) | (out >= total))
    if bad.size:
        i = bad[0]
        plural = "vertices" if what == "vertex" else what + "s"
        raise ScanError(path, f"line {corner_line[i] + 1}: face refers to {what} {idx[i]} but the file has "
                              f"{total} {plural} (index out of range)")
    return out


def _parse_mtl(mtl_path: Path, folder: Path, obj_path: Path, limits: Limits) -> dict:
    """MTL -> {material name: resolved map_Kd path or None}."""
    check_file_size(mtl_path, limits)
    with open(mtl_path, "rb") as fh:
        text = _read_content(fh, mtl_path)[0].decode("utf-8", errors="replace")   # blank/comment lines dropped
    maps, current = {}, None
    for raw in text.split("\n"):
        line = raw.strip()
        if line.startswith("newmtl"):
            current = line[6:].strip()
            maps.setdefault(current, None)
        elif line.startswith("map_Kd") and current is not None:
            rest = line[6:].strip()
            name = rest.split()[-1] if rest.startswith("-") else rest
            if not name:
                continue
            maps[current] = safe_path(folder, name.replace("\\", "/"), mtl_path, "map_Kd", TEXTURE_SUFFIXES)
    return maps


def _obj_slow(raw: bytes, path: Path, limits: Limits, line_no=None):
    """Line-by-line OBJ parser: any layout (negative indices, mixed polygons), errors name the line.

    ``line_no`` : (lines,) int64, optional
        The file's (0-based) line number of each line of ``raw`` (when blank and comment lines were dropped).
    """
    lines = raw.decode("utf-8", errors="replace").split("\n")
    v_rows, v_ln, vt_rows, vt_ln, f_rows, f_ln = [], [], [], [], [], []
    mtllibs, usemtl = [], set()
    for i, line in enumerate(lines):
        if not line:
            continue
        if "#" in line:
            line = line.split("#", 1)[0]
        c = line[0] if line else ""
        if c == "v":
            if line.startswith("v "):
                v_rows.append(line[2:]); v_ln.append(i)
            elif line.startswith("vt ") or line.startswith("vt\t"):
                vt_rows.append(line[3:]); vt_ln.append(i)
            elif line.startswith("v\t"):
                v_rows.append(line[2:]); v_ln.append(i)
        elif c == "f" and (line.startswith("f ") or line.startswith("f\t")):
            f_rows.append(line[2:]); f_ln.append(i)
        elif c == "m" and line.startswith("mtllib"):
            mtllibs.append(line[6:].strip())
        elif c == "u" and line.startswith("usemtl"):
            usemtl.add(line[6:].strip())
    del lines
    v_ln, vt_ln, f_ln = (np.array(a, dtype=np.int64) for a in (v_ln, vt_ln, f_ln))
    if line_no is not None:
        v_ln, vt_ln, f_ln = line_no[v_ln], line_no[vt_ln], line_no[f_ln]
    _check_counts(path, len(v_rows), len(f_rows), limits)
    if not v_rows or not f_rows:
        raise ScanError(path, f"no mesh found ({len(v_rows)} vertices, {len(f_rows)} faces)")
    vdata = _parse_floats(v_rows, path, "vertex", v_ln, 3)
    del v_rows
    V = vdata[:, :3]
    VC = None
    if vdata.shape[1] >= 6:
        rgb = vdata[:, 3:6]
        if np.all(np.isfinite(rgb)):
            scale = 255.0 if rgb.max(initial=0.0) <= 1.0 else 1.0
            VC = np.clip(np.round(rgb * scale), 0, 255).astype(np.uint8)
    UV = _parse_floats(vt_rows, path, "texture coordinate", vt_ln, 2)[:, :2] if vt_rows else None
    del vt_rows
    vidx, tidx, counts = _parse_obj_faces(f_rows, path, f_ln)
    del f_rows
    corner_line = np.repeat(f_ln, counts)
    v_before = np.searchsorted(v_ln, corner_line)
    vidx = _resolve_obj_index(vidx, v_before, len(V), path, "vertex", corner_line)
    if tidx is not None:
        if UV is None:
            raise ScanError(path, "faces refer to texture coordinates but the file has no 'vt' lines")
        t_before = np.searchsorted(vt_ln, corner_line)
        tidx = _resolve_obj_index(tidx, t_before, len(UV), path, "texture coordinate", corner_line)
    else:
        UV = None
    # triangulate polygons, grouped by corner count
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    F_parts, FT_parts, order = [], [], []
    for k in np.unique(counts):
        sel = np.flatnonzero(counts == k)
        cols = starts[sel, None] + np.arange(k)[None, :]
        F_parts.append(fan_triangulate(vidx[cols]))
        if tidx is not None:
            FT_parts.append(fan_triangulate(tidx[cols]))
        order.append(np.repeat(sel, k - 2))
    # keep the file's face order
    perm = np.argsort(np.concatenate(order), kind="stable")
    F = np.concatenate(F_parts)[perm]
    FUV = np.concatenate(FT_parts)[perm] if tidx is not None else None
    _check_counts(path, len(V), len(F), limits)
    return V, VC, UV, F, FUV, int(np.count_nonzero(counts > 3)), mtllibs, usemtl


def _numbers(text: bytes, dtype=np.float64):
    """Whitespace-separated numbers of ``text`` in one C-level parse, or None when numpy cannot parse them
    (it then stops early: callers also compare the count)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return np.fromstring(text, dtype=dtype, sep=" ")
        except ValueError:
            return None


def _tokens_per_row(text: bytes, n_rows: int, block: int = 1 << 23) -> np.ndarray:
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


def _floats_fast(text: bytes, n_rows: int, min_cols: int):
    """Newline-separated rows of numbers -> (n_rows, c) float64 by one C-level parse, or None when irregular."""
    if not n_rows:
        return np.zeros((0, min_cols))
    cols = len(text[:text.find(b"\n") if b"\n" in text else len(text)].split())
    if cols < min_cols:
        return None
    vals = _numbers(text, np.float64)
    if vals is None:
        return None
    if vals.size != n_rows * cols or np.any(_tokens_per_row(text, n_rows) != cols):
        return None
    return vals.reshape(n_rows, cols)


def _obj_line_blocks(raw: bytes):
    """Classify OBJ lines with numpy; return a getter for the text of one line kind.

    ``get(kind)`` -> (text of those lines joined by newlines with the keyword blanked, line count),
    or None when the lines are too scattered (the caller then falls back to the slow parser).
    """
    b = np.frombuffer(raw, dtype=np.uint8)
    nl = np.flatnonzero(b == 10)
    starts = np.empty(len(nl) + 1, dtype=np.int64)
    starts[0], starts[1:] = 0, nl + 1
    top = len(b) - 1

    def at(offset):                                  # the byte at line start + offset (a newline past the end)
        if top < 0:
            return np.full(len(starts), 10, dtype=np.uint8)
        return b[np.minimum(starts + offset, top)]

    c0, c1, c2 = at(0), at(1), at(2)
    ws1, ws2 = (c1 == 32) | (c1 == 9), (c2 == 32) | (c2 == 9)
    masks = {"v": (c0 == 118) & ws1, "vt": (c0 == 118) & (c1 == 116) & ws2, "f": (c0 == 102) & ws1,
             "mtllib": c0 == 109, "usemtl": c0 == 117}
    del c0, c1, c2, ws1, ws2
    runs, counts = {}, {}                            # byte ranges of each kind's runs of consecutive lines
    for kind, mask in masks.items():
        idx = np.flatnonzero(mask)
        counts[kind] = len(idx)
        brk = np.flatnonzero(np.diff(idx) != 1)
        r0, r1 = (idx[np.r_[0, brk + 1]], idx[np.r_[brk, len(idx) - 1]]) if len(idx) else ([], [])
        runs[kind] = None if len(r0) > 10000 else \
            [(int(starts[i]), int(nl[j]) if j < len(nl) else len(raw)) for i, j in zip(r0, r1)]
    del masks, starts, nl, b                         # the line tables are the size of the file

    def get(kind):
        if runs[kind] is None:
            return None
        return b"\n".join(raw[i:j] for i, j in runs[kind]), counts[kind]

    get.count = counts.__getitem__
    # every line of kind a comes before the first line of kind b (relative indices need no line order)
    get.precedes = lambda a, b: not runs[a] or not runs[b] or runs[a][-1][1] < runs[b][0][0]
    return get


def _obj_fast(raw: bytes, path: Path, limits: Limits, get=None):
    """Numpy OBJ parser for the usual case (one face format, indices in range, relative indices only
    where every vertex precedes every face, no trailing comments; polygons of any and mixed sizes).
    Returns None for anything else (the slow parser then handles it and names the offending line).
    ``get``: :func:`_obj_line_blocks` of ``raw``."""
    get = _obj_line_blocks(raw) if get is None else get
    n_v, n_f, n_t = get.count("v"), get.count("f"), get.count("vt")
    _check_counts(path, n_v, n_f, limits)
    if not n_v or not n_f:
        return None
    block = get("v")                                 # one kind at a time: each is a copy of its lines
    if block is None:
        return None
    vdata = _floats_fast(block[0].replace(b"v", b" "), n_v, 3)
    block = None
    if vdata is None:
        return None
    block = get("f")
    if block is None:
        return None
    ftext, block = block[0], None
    first = ftext[:ftext.find(b"\n") if b"\n" in ftext else len(ftext)].replace(b"f", b" ", 1).split()
    text = ftext.replace(b"f", b" ")
    del ftext
    tok = first[0] if first else b""
    n_fields = tok.count(b"/") + 1
    has_vt = n_fields >= 2 and tok.split(b"/")[1] != b""
    counts = _tokens_per_row(text, n_f)
    if counts.min() < 3 or b"#" in text:
        return None                                   # short faces or trailing comments: the slow parser
    n_tok, slashes = int(counts.sum()), text.count(b"/")
    if n_fields == 3 and not has_vt:
        if text.count(b"//") != n_tok or slashes != 2 * n_tok:
            return None                               # mixed face formats
        text = text.replace(b"//", b" ")
        per = 2
    else:
        if slashes != (n_fields - 1) * n_tok:
            return None
        text = text.replace(b"/", b" ")
        per = n_fields
    if b"." in text:
        return None                                   # malformed indices
    idx = _numbers(text, np.int64)
    if idx is None:
        return None
    del text
    if idx.size != n_tok * per:
        return None
    idx = idx.reshape(n_tok, per)
    V = vdata[:, :3]
    vidx = _obj_fast_index(idx[:, 0], len(V), get.precedes("v", "f"))
    if vidx is None:
        return None
    UV = tidx = None
    if has_vt:
        block = get("vt")
        if block is None:
            return None
        UV, block = _floats_fast(block[0].replace(b"vt", b"  "), n_t, 2), None
        if UV is None or len(UV) == 0:
            return None
        UV = UV[:, :2]
        tidx = _obj_fast_index(idx[:, 1], len(UV), get.precedes("vt", "f"))
        if tidx is None:
            return None
    del idx
    VC = None
    if vdata.shape[1] >= 6 and np.all(np.isfinite(vdata[:, 3:6])):
        rgb = vdata[:, 3:6]
        scale = 255.0 if rgb.max(initial=0.0) <= 1.0 else 1.0
        VC = np.clip(np.round(rgb * scale), 0, 255).astype(np.uint8)
    mtllibs, usemtl = [], set()
    for kind in ("mtllib", "usemtl"):
        block = get(kind)
        if block is None:
            return None
        for line in block[0].decode("utf-8", errors="replace").splitlines():
            if line.startswith(kind):
                name = line[len(kind):].strip()
                (mtllibs.append(name) if kind == "mtllib" else usemtl.add(name))
    F = _fan_by_counts(vidx, counts)
    FUV = _fan_by_counts(tidx, counts) if tidx is not None else None
    return V, VC, UV, F, FUV, int(np.count_nonzero(counts > 3)), mtllibs, usemtl


def _obj_fast_index(col: np.ndarray, total: int, all_before: bool):
    """OBJ indices (1-based, or negative = relative to the elements read so far) -> 0-based, or None
    when out of range or when a relative index needs the line order (the slow parser then reports it)."""
    neg = col < 0
    if neg.any():
        if not all_before:
            return None
        col = np.where(neg, col + total, col - 1)
    else:
        col = col - 1
    if len(col) and (col.min() < 0 or col.max() >= total):
        return None
    return col


def _fan_by_counts(flat: np.ndarray, counts: np.ndarray) -> np.ndarray:
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


def _read_content(fh, path: Path, max_lines: int | None = None, comment: bytes | None = b"#",
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


def load_obj(path, folder, limits: Limits = Limits()) -> LoadedMesh:
    """Load a Wavefront OBJ (+ MTL ``map_Kd``) keeping per-corner UVs.

    Parameters
    ----------
    path : pathlib.Path
        The OBJ file (already checked to be inside ``folder``).
    folder : pathlib.Path
        The scan folder; ``mtllib`` and ``map_Kd`` must stay inside it.
    limits : Limits

    Returns
    -------
    LoadedMesh
    """
    path, folder = Path(path), Path(folder)
    check_file_size(path, limits)
    with open(path, "rb") as fh:
        if b"\x00" in fh.read(65536):
            raise ScanError(path, "not a text OBJ file (binary bytes found)")
        fh.seek(0)
        raw, line_no = _read_content(fh, path)
    if b"#" in raw:                                  # trailing comments ("f 1 2 3 # x"): cut, lines kept
        raw = re.sub(rb"#[^\n]*", b"", raw)
    get = _obj_line_blocks(raw)
    _check_counts(path, get.count("v"), get.count("f"), limits)    # before any line is parsed
    parsed = _obj_fast(raw, path, limits, get)
    del get
    if parsed is None:
        parsed = _obj_slow(raw, path, limits, line_no)
    del raw
    V, VC, UV, F, FUV, n_poly, mtllibs, usemtl = parsed
    files = [path]
    texture_path = None
    if mtllibs:
        maps = {}
        for name in mtllibs:
            mtl = safe_path(folder, name.replace("\\", "/"), path, "mtllib")
            files.append(mtl)
            maps.update(_parse_mtl(mtl, folder, path, limits))
        used = [maps.get(m) for m in (usemtl or maps.keys())]
        textures = sorted({p for p in used if p is not None})
        if len(textures) > 1:
            raise ScanError(path, f"materials use {len(textures)} different textures "
                                  f"({', '.join(p.name for p in textures)}); one texture per scan is supported")
        texture_path = textures[0] if textures else None
    return LoadedMesh(V=V, F=F, UV=UV, FUV=FUV, VC=VC, texture_path=texture_path, files_read=files,
                      polygons_triangulated=n_poly)


# ---------------------------------------------------------------------------- PLY

def _column(data, name):
    """A scalar property of a parsed PLY element (structured array or dict) or None."""
    if data is None:
        return None
    if isinstance(data, dict):
        if name not in data:
            return None
        return np.asarray(data[name]).reshape(-1)
    if data.dtype.names and name in data.dtype.names:
        return np.asarray(data[name]).reshape(-1)
    return None


def _list_property(data, names):
    """A list property (faces) -> (m, k) array or list of 1-D arrays, or None."""
    if data is None:
        return None
    for name in names:
        if isinstance(data, dict) and name in data:
            return data[name]
        if not isinstance(data, dict) and data.dtype.names and name in data.dtype.names:
            col = data[name]
            if col.dtype.names and "f1" in col.dtype.names:
                return col["f1"]
            return col
    return None


@dataclass
class _Ragged:
    """Lists of varying length: ``flat`` values, ``counts`` per row."""

    flat: np.ndarray
    counts: np.ndarray

    def __len__(self) -> int:
        return len(self.counts)


def _polys_to_tris(polys, path: Path, what: str):
    """(m, k) array, :class:`_Ragged` or ragged list of polygons -> (t, 3) int64 triangles, #polygons split."""
    if isinstance(polys, np.ndarray) and polys.dtype != object and polys.ndim == 2:
        if polys.shape[1] < 3:
            raise ScanError(path, f"{what} with fewer than 3 corners")
        return fan_triangulate(polys), (len(polys) if polys.shape[1] > 3 else 0)
    if isinstance(polys, _Ragged):
        if len(polys) and polys.counts.min() < 3:
            raise ScanError(path, f"{what} with fewer than 3 corners")
        if not len(polys):
            return np.zeros((0, 3), np.int64), 0
        return (_fan_by_counts(polys.flat.astype(np.int64), polys.counts),
                int(np.count_nonzero(polys.counts > 3)))
    rows = [np.asarray(p, dtype=np.int64).reshape(-1) for p in polys]
    counts = np.array([len(r) for r in rows], dtype=np.int64)
    if np.any(counts < 3):
        raise ScanError(path, f"{what} with fewer than 3 corners")
    flat = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    parts, order = [], []
    for k in np.unique(counts):
        sel = np.flatnonzero(counts == k)
        parts.append(fan_triangulate(flat[starts[sel, None] + np.arange(k)[None, :]]))
        order.append(np.repeat(sel, k - 2))
    perm = np.argsort(np.concatenate(order), kind="stable")
    return np.concatenate(parts)[perm], int(np.count_nonzero(counts > 3))


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _ply_header(head: bytes, path: Path):
    """Parse a PLY header -> (format, {element: {"length", "props": [(name, dtype | (count_dtype, item_dtype))]}},
    TextureFile name or None, offset of the data)."""
    end = head.index(b"end_header")
    nl = head.find(b"\n", end)
    if nl < 0:
        raise ScanError(path, "PLY header is not terminated by a newline")
    lines = head[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements, current, image = None, {}, None, None
    for raw in lines[1:]:
        t = raw.split()
        if not t:
            continue
        try:
            if t[0] == "format":
                fmt = t[1]
            elif t[0] == "element":
                current = elements.setdefault(t[1], {"length": int(t[2]), "props": []})
                if current["length"] < 0:
                    raise ValueError("negative element count")
            elif t[0] == "property":
                if current is None:
                    raise ValueError("property before any element")
                if t[1] == "list":
                    current["props"].append((t[4], (_PLY_TYPES[t[2]], _PLY_TYPES[t[3]])))
                else:
                    current["props"].append((t[2], _PLY_TYPES[t[1]]))
            elif t[0] in ("comment", "obj_info") and len(t) > 2 and t[1].lower() == "texturefile":
                image = raw.split(None, 2)[2].strip()
        except (IndexError, KeyError, ValueError) as exc:
            raise ScanError(path, f"cannot parse PLY header line {one_line(raw)[:60]!r} "
                                  f"({one_line(exc)[:40]})") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ScanError(path, f"unknown PLY format {fmt!r}")
    return fmt, elements, image, nl + 1


def _fits(values: np.ndarray, dtype: str) -> bool:
    """Whether float ``values`` are whole numbers within the range of an integer PLY ``dtype`` (floats: True)."""
    dt = np.dtype(dtype)
    if dt.kind not in "iu":
        return True
    info = np.iinfo(dt)
    return bool(np.all((values >= info.min) & (values <= info.max) & (values == np.round(values))))


def _ply_number(token: bytes, dtype: str):
    """One ASCII PLY value as ``dtype`` would hold it; ValueError when an integer does not fit."""
    value = float(token)
    if not _fits(np.array([value]), dtype):
        raise ValueError(f"{token!r} is not a {dtype} integer")
    return value


def _ply_ascii_one_list(text: bytes, n_tok: np.ndarray, props: list):
    """ASCII PLY rows with one list property of varying length (triangles and quads), parsed in one
    numpy call; None when the rows do not fit that layout or their types (the row reader then names the line)."""
    lists = [i for i, (_, dt) in enumerate(props) if isinstance(dt, tuple)]
    if len(lists) != 1:
        return None
    li = lists[0]
    vals = _numbers(text, np.float64)
    if vals is None:
        return None
    if vals.size != n_tok.sum():
        return None
    row0 = np.cumsum(n_tok) - n_tok
    k = n_tok - len(props)                       # items of each row's list
    if np.any(k < 0) or np.any(vals[row0 + li] != k) or not _fits(vals[row0 + li], props[li][1][0]):
        return None
    data = {}
    for j, (pname, dt) in enumerate(props):
        if j == li:
            at = np.repeat(row0 + li + 1, k) + np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
            flat, dt = vals[at], dt[1]
        else:
            flat = vals[row0 + j + (k if j > li else 0)]
        if not _fits(flat, dt):
            return None
        data[pname] = _Ragged(flat.astype(np.dtype(dt)), k) if j == li else flat.astype(np.dtype(dt))
    return data


def _ply_ascii(fh, elements: dict, data_start: int, header_lines: int, path: Path) -> None:
    """Read ASCII PLY data into ``elements[name]["data"]`` (dict of arrays; lists as (m, k) arrays
    or lists of arrays). Uniform elements are parsed in one numpy call; others row by row.

    Only the rows the header announces are read, blank lines skipped, so memory follows the data
    (not trailing padding); errors name the file's line.
    """
    fh.seek(data_start)
    n_rows = sum(el["length"] for el in elements.values())
    raw, line_no = _read_content(fh, path, max_lines=n_rows, comment=None)
    ends = np.flatnonzero(np.frombuffer(raw, dtype=np.uint8) == 10)
    row = 0
    for name, el in elements.items():
        n, props = el["length"], el["props"]
        if row + n > len(ends):
            raise ScanError(path, f"PLY has {max(len(ends) - row, 0)} {name} rows but its header says {n} "
                                  "(truncated file)")
        first_line = row
        row += n
        if n == 0:
            el["data"] = {p: np.zeros(0) for p, _ in props}
            continue
        text = raw[(ends[first_line - 1] + 1 if first_line else 0):ends[row - 1]]
        n_tok = _tokens_per_row(text, n)
        lists = [i for i, (_, dt) in enumerate(props) if isinstance(dt, tuple)]
        width = len(props)
        if lists:
            first = (text[:text.find(b"\n")] if b"\n" in text else text).split()
            try:
                k = int(first[lists[0]]) if len(first) > lists[0] else -1
            except ValueError:
                k = -1
            width = len(props) + len(lists) * k if k >= 0 else -1
        vals = None
        if width > 0 and np.all(n_tok == width):
            vals = _numbers(text, np.float64)
            if vals is not None and vals.size != n * width:
                vals = None
        if vals is not None:
            vals = vals.reshape(n, width)
            data, col = {}, 0
            for pname, dt in props:
                if isinstance(dt, tuple):
                    if np.any(vals[:, col] != k) or not _fits(vals[:, col + 1:col + 1 + k], dt[1]):
                        vals = None
                        break
                    data[pname] = vals[:, col + 1:col + 1 + k].astype(np.dtype(dt[1]))
                    col += 1 + k
                else:
                    if not _fits(vals[:, col], dt):
                        vals = None
                        break
                    data[pname] = vals[:, col].astype(np.dtype(dt))
                    col += 1
            if vals is not None:
                el["data"] = data
                continue
        data = _ply_ascii_one_list(text, n_tok, props)
        if data is not None:
            el["data"] = data
            continue
        # row by row: any layout; errors name the file's line
        cols = {p: [] for p, _ in props}
        for i, line in enumerate(text.split(b"\n")):
            tok = line.split()
            j = 0
            try:
                for pname, dt in props:
                    if isinstance(dt, tuple):
                        cnt = int(tok[j])
                        cols[pname].append(np.array([_ply_number(x, dt[1]) for x in tok[j + 1:j + 1 + cnt]],
                                                    dtype=np.dtype(dt[1])))
                        if len(cols[pname][-1]) != cnt:
                            raise IndexError
                        j += 1 + cnt
                    else:
                        cols[pname].append(_ply_number(tok[j], dt))
                        j += 1
            except (IndexError, ValueError):
                raise ScanError(path, f"line {header_lines + line_no[first_line + i] + 1}: PLY data row "
                                      f"({name} {i}) cannot be parsed: "
                                      f"{one_line(line.decode('ascii', 'replace'))[:60]!r}") from None
        el["data"] = {p: (v if isinstance(dt, tuple) else np.array(v, dtype=np.dtype(dt)))
                      for (p, dt), v in zip(props, cols.values())}


def _ply_binary(fh, elements: dict, endian: str, n_bytes: int, path: Path) -> None:
    """Read binary PLY data into ``elements[name]["data"]`` (dict of arrays; lists as (m, k) arrays).

    Fast path: every list of an element has the length of its first row (checked);
    otherwise a row-by-row reader (slow, rare: mixed triangles and quads).
    """
    buf = fh.read(n_bytes)
    pos = 0
    for name, el in elements.items():
        n, props = el["length"], el["props"]
        fields, row_probe, fits = [], pos, True
        for pname, dt in props:
            if isinstance(dt, tuple):
                cdt = np.dtype(endian + dt[0])
                if row_probe + cdt.itemsize > len(buf):
                    k = 0
                else:
                    k = int(np.frombuffer(buf, cdt, 1, row_probe)[0]) if n else 0
                if k < 0 or row_probe + cdt.itemsize + k * np.dtype(dt[1]).itemsize > len(buf):
                    k, fits = 0, False                   # a first row past the end: the row reader says so
                fields.append((pname + "__n", endian + dt[0]))
                fields.append((pname, endian + dt[1], (k,)))
                row_probe += cdt.itemsize + k * np.dtype(dt[1]).itemsize
            else:
                fields.append((pname, endian + dt))
                row_probe += np.dtype(dt).itemsize
        dtype = np.dtype(fields)
        need = n * dtype.itemsize
        ok = fits and pos + need <= len(buf)
        if ok:
            arr = np.frombuffer(buf, dtype, n, pos)
            ok = all(np.all(arr[p + "__n"] == dtype[p].shape[0]) for p, dt in props if isinstance(dt, tuple))
        if ok:
            el["data"] = {p: arr[p] for p, _ in props}
            pos += need
        elif not any(isinstance(dt, tuple) for _, dt in props):
            raise ScanError(path, f"PLY data is shorter than its header says (element {name!r}: truncated file)")
        else:
            el["data"], pos = _ply_binary_rows(buf, pos, n, props, endian, path, name)
    if pos != len(buf):
        raise ScanError(path, f"PLY has {len(buf) - pos} bytes after the data its header describes (corrupt?)")


def _ply_binary_rows(buf, pos, n, props, endian, path, name):
    """Binary PLY element with lists of varying length (e.g. triangles and quads).

    One Python loop walks the rows to find where each value sits (no object per row); the
    values are then gathered with numpy. Lists come back as :class:`_Ragged`.
    """
    from array import array

    steps = []                                   # per property: (name, count struct or None, item dtype)
    for p, dt in props:
        if isinstance(dt, tuple):
            steps.append((p, struct.Struct(endian + np.dtype(dt[0]).char), np.dtype(endian + dt[1])))
        else:
            steps.append((p, None, np.dtype(endian + dt)))
    offsets = {p: array("q") for p, _, _ in steps}
    counts = {p: array("q") for p, c, _ in steps if c is not None}
    try:
        for row in range(n):
            for p, cstruct, idt in steps:
                if cstruct is None:
                    offsets[p].append(pos)
                    pos += idt.itemsize
                    continue
                k = cstruct.unpack_from(buf, pos)[0]
                if k < 0:
                    raise ScanError(path, f"PLY {name} {row} has a list of negative length {k}")
                pos += cstruct.size
                offsets[p].append(pos)
                counts[p].append(k)
                pos += k * idt.itemsize
    except struct.error:
        pos = len(buf) + 1
    if pos > len(buf):
        raise ScanError(path, f"PLY data is shorter than its header says (element {name!r}: truncated file)")
    b = np.frombuffer(buf, dtype=np.uint8)
    out = {}
    for p, cstruct, idt in steps:
        starts = np.frombuffer(offsets[p], dtype=np.int64)
        if cstruct is not None:                  # item start of every list element, rows in order
            cnt = np.frombuffer(counts[p], dtype=np.int64)
            first = np.cumsum(cnt) - cnt
            starts = np.repeat(starts, cnt) + (np.arange(int(cnt.sum())) - np.repeat(first, cnt)) * idt.itemsize
        raw = np.empty((len(starts), idt.itemsize), dtype=np.uint8)
        for t in range(idt.itemsize):
            raw[:, t] = b[starts + t]
        values = raw.view(idt).reshape(-1)
        out[p] = values if cstruct is None else _Ragged(values, np.frombuffer(counts[p], dtype=np.int64))
    return out, pos


def load_ply(path, folder, limits: Limits = Limits()) -> LoadedMesh:
    """Load an ASCII or binary PLY (vertices, triangles/polygons, UVs, vertex colours).

    The header's element counts are checked against ``limits`` before any data is read.
    A ``comment TextureFile name`` is resolved inside ``folder``.
    """
    path, folder = Path(path), Path(folder)
    size = check_file_size(path, limits)
    with open(path, "rb") as fh:
        head = fh.read(min(size, 65536))
        if not head.lower().startswith(b"ply"):
            raise ScanError(path, "not a PLY file (no 'ply' magic)")
        if b"end_header" not in head:
            raise ScanError(path, "PLY header has no end_header in its first 64 KiB")
        fmt, elements, image_name, data_start = _ply_header(head, path)
        n_v = int(elements.get("vertex", {}).get("length", 0))
        n_f = int(elements.get("face", {}).get("length", 0))
        _check_counts(path, n_v, n_f, limits)
        if fmt == "ascii":
            _ply_ascii(fh, elements, data_start, head[:data_start].count(b"\n"), path)
        else:
            fh.seek(data_start)
            _ply_binary(fh, elements, "<" if fmt == "binary_little_endian" else ">", size - data_start, path)
    vdata = elements.get("vertex", {}).get("data")
    xyz = [_column(vdata, c) for c in "xyz"]
    if any(c is None for c in xyz):
        raise ScanError(path, "PLY has no vertex x, y, z properties")
    V = np.column_stack(xyz).astype(np.float64)
    fdata = elements.get("face", {}).get("data")
    polys = _list_property(fdata, ("vertex_indices", "vertex_index"))
    if polys is None or len(V) == 0:
        raise ScanError(path, f"no mesh found ({len(V)} vertices, {0 if polys is None else len(polys)} faces)")
    F, n_poly = _polys_to_tris(polys, path, "face")
    UV = FUV = None
    texcoord = _list_property(fdata, ("texcoord",))
    if texcoord is not None:
        tc = np.asarray(texcoord, dtype=np.float64) if isinstance(texcoord, np.ndarray) else None
        if tc is None or tc.ndim != 2 or tc.shape[1] != 6 or n_poly or tc.shape[0] != len(F):
            raise ScanError(path, "per-face 'texcoord' lists are supported for triangle faces only")
        UV = tc.reshape(-1, 2)
        FUV = np.arange(len(UV), dtype=np.int64).reshape(-1, 3)
    else:
        for u, v in (("texture_u", "texture_v"), ("u", "v"), ("s", "t")):
            cu, cv = _column(vdata, u), _column(vdata, v)
            if cu is not None and cv is not None:
                UV = np.column_stack([cu, cv]).astype(np.float64)
                FUV = F                          # shared: neither is changed in place
                break
    VC = None
    rgb = [_column(vdata, c) for c in ("red", "green", "blue")]
    if all(c is not None for c in rgb):
        rgb = np.column_stack(rgb)
        if rgb.dtype.kind == "f":
            rgb = np.round(np.clip(np.nan_to_num(rgb), 0, 1) * 255)
        VC = np.clip(rgb, 0, 255).astype(np.uint8)
    texture_path = None
    if image_name:
        texture_path = safe_path(folder, image_name.replace("\\", "/"), path, "TextureFile", TEXTURE_SUFFIXES)
    return LoadedMesh(V=V, F=F, UV=UV, FUV=FUV, VC=VC, texture_path=texture_path, files_read=[path],
                      polygons_triangulated=n_poly)


# ---------------------------------------------------------------------------- STL

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
            vals = _numbers(body)
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
        _check_counts(path, 0, n, limits)       # vertices (3 per triangle) are checked once merged
        if 84 + 50 * n != size:
            raise ScanError(path, f"binary STL header says {n} triangles ({84 + 50 * n} bytes) but the file "
                                  f"has {size} bytes (truncated or not an STL)")
        records = np.fromfile(path, dtype=_STL_RECORD, count=n, offset=84)
        return _stl_mesh(path, records["corners"].reshape(-1, 3))
    else:                                        # no header count: count the corners before parsing
        _check_counts(path, 0, _count_word(path, b"vertex") // 3, limits)
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
    _check_counts(path, 0, len(F), limits)
    return LoadedMesh(V=V, F=F, files_read=[path])


# ---------------------------------------------------------------------------- GLB

def _glb_check_images(path: Path, doc: dict, limits: Limits) -> None:
    """Check every embedded GLB image's pixel count from its header before trimesh decodes it."""
    from PIL import Image

    images = doc.get("images", []) or []
    if not images:
        return
    with open(path, "rb") as fh:
        fh.seek(12)
        json_len = struct.unpack("<I", fh.read(4))[0]
        fh.seek(20 + json_len)
        head = fh.read(8)
        if len(head) < 8:
            raise ScanError(path, "GLB has images but no binary chunk")
        bin_len = struct.unpack("<I", head[:4])[0]
        blob = fh.read(bin_len)
    views = doc.get("bufferViews", []) or []
    for i, img in enumerate(images):
        try:
            view = views[int(img["bufferView"])]
            start = int(view.get("byteOffset", 0))
            data = blob[start:start + int(view["byteLength"])]
        except (KeyError, IndexError, TypeError, ValueError):
            raise ScanError(path, f"GLB image {i} has no valid bufferView") from None
        try:
            with _max_pixels(2**62):
                w, h = Image.open(io.BytesIO(data)).size  # header only
        except Exception as exc:  # noqa: BLE001
            raise ScanError(path, f"GLB image {i} cannot be opened: {one_line(exc)[:100]}") from None
        if w * h > limits.max_texture_pixels:
            raise ScanError(path, f"GLB image {i} header claims {w}x{h} = {w * h} pixels, over the limit of "
                                  f"{limits.max_texture_pixels} (ingest.max_texture_pixels); not decoded")


def _glb_json(path: Path, size: int, max_json_bytes: int = Limits.max_json_bytes):
    """The GLB's JSON document and the byte length of its BIN chunk (0 when absent), chunk sizes checked."""
    with open(path, "rb") as fh:
        header = fh.read(20)
        if len(header) < 20 or header[:4] != b"glTF":
            raise ScanError(path, "not a GLB file (no 'glTF' magic)")
        version, length, chunk_len, chunk_type = struct.unpack("<IIII", header[4:20])
        if version != 2:
            raise ScanError(path, f"GLB version {version} is not supported (need 2)")
        if length != size or chunk_type != 0x4E4F534A or chunk_len > size - 20:
            raise ScanError(path, "GLB header is inconsistent with the file (truncated or corrupt)")
        if chunk_len > max_json_bytes:
            raise ScanError(path, f"GLB JSON chunk is {chunk_len / 2**20:.3g} MiB, over the limit of "
                                  f"{max_json_bytes / 2**20:.3g} MiB (ingest.max_json_mb)")
        text = fh.read(chunk_len)
        bin_len = 0
        rest = size - 20 - chunk_len
        if rest:
            head = fh.read(8)
            if len(head) < 8:
                raise ScanError(path, "GLB has a partial chunk after its JSON (truncated or corrupt)")
            bin_len, bin_type = struct.unpack("<II", head)
            if bin_type != 0x004E4942 or bin_len > rest - 8:
                raise ScanError(path, f"GLB binary chunk claims {bin_len} bytes but {rest - 8} follow "
                                      "(truncated or corrupt)")
    try:
        doc = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ScanError(path, f"GLB JSON chunk is invalid: {one_line(exc)[:100]}") from None
    if not isinstance(doc, dict):
        raise ScanError(path, "GLB JSON chunk is not an object")
    return doc, bin_len


_GLTF_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _glb_list(path: Path, doc: dict, key: str) -> list:
    items = doc.get(key, [])
    if items is None:
        return []
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise ScanError(path, f"GLB {key} must be a list of objects")
    return items


def _glb_int(path: Path, item: dict, key: str, what: str, default=None, lo: int = 0, hi: int = 2**53) -> int:
    value = item.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise ScanError(path, f"GLB {what} has an invalid {key} {short_repr(value)}")
    return value


def _glb_check_doc(path: Path, doc: dict, bin_len: int, limits: Limits) -> None:
    """Check a GLB document against the file's real byte sizes and the limits before anything is decoded.

    Refused: buffers with URIs (data: or external), buffer views outside the binary chunk,
    accessors without a buffer view or reading past it (a header claiming 1e9 vertices in a
    small file), sparse accessors, node hierarchies that are not trees, and meshes whose
    vertices / faces, counted over every node instance, are over the limits.
    """
    for kind in ("buffers", "images"):
        for i, item in enumerate(_glb_list(path, doc, kind)):
            uri = item.get("uri")
            if uri is not None:
                what = "a data: URI" if isinstance(uri, str) and uri[:5].lower() == "data:" else "an external URI"
                raise ScanError(path, f"GLB {kind[:-1]} {i} refers to {what}; only self-contained GLB is supported")
    buffers = _glb_list(path, doc, "buffers")
    if len(buffers) > 1:
        raise ScanError(path, f"GLB has {len(buffers)} buffers; a self-contained GLB has one (its binary chunk)")
    buf_len = _glb_int(path, buffers[0], "byteLength", "buffer 0", 0) if buffers else 0
    if buf_len > bin_len:
        raise ScanError(path, f"GLB buffer 0 claims {buf_len} bytes but the binary chunk has {bin_len}")
    views = _glb_list(path, doc, "bufferViews")
    for i, v in enumerate(views):
        what = f"bufferView {i}"
        _glb_int(path, v, "buffer", what, None, 0, len(buffers) - 1)
        off = _glb_int(path, v, "byteOffset", what, 0)
        n = _glb_int(path, v, "byteLength", what)
        if "byteStride" in v:
            _glb_int(path, v, "byteStride", what, None, 1, 252)
        if off + n > buf_len:
            raise ScanError(path, f"GLB {what} reads bytes {off}..{off + n} but the buffer has {buf_len}")
    accessors = _glb_list(path, doc, "accessors")
    total = 0
    for i, a in enumerate(accessors):
        what = f"accessor {i}"
        count = _glb_int(path, a, "count", what, None, 0)
        if "sparse" in a:
            raise ScanError(path, f"GLB {what} is sparse; sparse accessors are not supported")
        if a.get("bufferView") is None:
            raise ScanError(path, f"GLB {what} has no bufferView (count {count}); every accessor must "
                                  "read stored data")
        view = views[_glb_int(path, a, "bufferView", what, None, 0, len(views) - 1)]
        ctype, atype = a.get("componentType"), a.get("type")
        csize = _GLTF_COMPONENT_BYTES.get(ctype) if isinstance(ctype, int) and not isinstance(ctype, bool) else None
        ncomp = _GLTF_TYPE_SIZES.get(atype) if isinstance(atype, str) else None
        if csize is None or ncomp is None:
            raise ScanError(path, f"GLB {what} has an invalid componentType/type "
                                  f"{short_repr(a.get('componentType'))}/{short_repr(a.get('type'))}")
        elem = csize * ncomp
        stride = view.get("byteStride") or elem
        off = _glb_int(path, a, "byteOffset", what, 0)
        need = off + stride * (count - 1) + elem if count else 0
        if need > view["byteLength"]:
            raise ScanError(path, f"GLB {what} claims {count} elements ({need} bytes) but its bufferView has "
                                  f"{view['byteLength']} bytes")
        total += count * elem
    if total > 4 * bin_len + (1 << 20):
        raise ScanError(path, f"GLB accessors read {total} bytes from a {bin_len}-byte binary chunk "
                              "(overlapping accessors)")
    meshes = _glb_list(path, doc, "meshes")
    counts = []
    for i, m in enumerate(meshes):
        prims = m.get("primitives", [])
        if not isinstance(prims, list) or not all(isinstance(p, dict) for p in prims):
            raise ScanError(path, f"GLB mesh {i} primitives must be a list of objects")
        nv = nf = 0
        for p in prims:
            attrs = p.get("attributes", {})
            if not isinstance(attrs, dict) or "POSITION" not in attrs:
                continue
            for name, idx in list(attrs.items()) + ([("indices", p["indices"])] if "indices" in p else []):
                if not isinstance(idx, int) or isinstance(idx, bool) or not 0 <= idx < len(accessors):
                    raise ScanError(path, f"GLB mesh {i} {name} refers to accessor {short_repr(idx)}, "
                                          f"which does not exist")
            n_pos = accessors[attrs["POSITION"]]["count"]
            nv += n_pos
            corners = accessors[p["indices"]]["count"] if "indices" in p else n_pos
            nf += max(corners - 2, 0) if p.get("mode") in (5, 6) else corners // 3   # strips / fans
        counts.append((nv, nf))
    nodes = _glb_list(path, doc, "nodes")
    parent = [-1] * len(nodes)
    for i, node in enumerate(nodes):
        children = node.get("children", [])
        if not isinstance(children, list):
            raise ScanError(path, f"GLB node {i} children must be a list")
        for c in children:
            if not isinstance(c, int) or isinstance(c, bool) or not 0 <= c < len(nodes):
                raise ScanError(path, f"GLB node {i} has a child {short_repr(c)} that does not exist")
            if parent[c] != -1:
                raise ScanError(path, f"GLB node {c} has more than one parent; the node hierarchy must be a tree")
            parent[c] = i
        if "mesh" in node:
            _glb_int(path, node, "mesh", f"node {i}", None, 0, len(meshes) - 1)
    for i in range(len(nodes)):                      # a cycle has no root: walk up at most len(nodes) steps
        j, steps = i, 0
        while parent[j] != -1:
            j, steps = parent[j], steps + 1
            if steps > len(nodes):
                raise ScanError(path, f"GLB node {i} is in a cycle; the node hierarchy must be a tree")
    mesh_nodes = [node["mesh"] for node in nodes if "mesh" in node]
    instanced = (sum(counts[m][0] for m in mesh_nodes), sum(counts[m][1] for m in mesh_nodes))
    loaded = (sum(c[0] for c in counts), sum(c[1] for c in counts))
    nv, nf = max(instanced[0], loaded[0]), max(instanced[1], loaded[1])
    n_used = len(set(mesh_nodes))
    how = (f" once {len(mesh_nodes)} node instances of {n_used} mesh{'es' if n_used > 1 else ''} are expanded"
           if len(mesh_nodes) > len(set(mesh_nodes)) else "")
    if nv > limits.max_vertices:
        raise ScanError(path, f"{nv} vertices{how}, over the limit of {limits.max_vertices} (ingest.max_vertices)")
    if nf > limits.max_faces:
        raise ScanError(path, f"{nf} faces{how}, over the limit of {limits.max_faces} (ingest.max_faces)")


def _glb_parts(scene, trimesh):
    """Per mesh of a loaded GLB scene (node transforms applied): vertices, faces (offset into one
    vertex list), UVs or None, vertex colours or None; and the base colour images found."""
    meshes = [g for g in scene.dump(concatenate=False) if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    Vs, Fs, UVs, VCs, images = [], [], [], [], []
    offset = 0
    for g in meshes:
        Vs.append(np.asarray(g.vertices, dtype=np.float64))
        faces = np.asarray(g.faces, dtype=np.int64)
        Fs.append(faces + offset if offset else faces)
        offset += len(g.vertices)
        vis = g.visual
        uv = getattr(vis, "uv", None) if getattr(vis, "kind", None) == "texture" else None
        UVs.append(None if uv is None else np.asarray(uv, dtype=np.float64))
        if getattr(vis, "kind", None) == "vertex":
            VCs.append(np.asarray(vis.vertex_colors)[:, :3].astype(np.uint8))
        else:
            VCs.append(None)
        mat = getattr(vis, "material", None)
        img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        if img is not None:
            images.append(img)
    return Vs, Fs, UVs, VCs, images


def load_glb(path, folder, limits: Limits = Limits()) -> LoadedMesh:
    """Load a self-contained binary glTF (GLB): all meshes with their node transforms, one texture.

    External URIs (buffers or images outside the file) are refused: they could point
    anywhere. Embedded images are returned still encoded (checked later by :func:`load_texture`).
    Everything trimesh would allocate is checked first (:func:`_glb_check_doc`).
    """
    path = Path(path)
    size = check_file_size(path, limits)
    doc, bin_len = _glb_json(path, size, limits.max_json_bytes)
    _glb_check_doc(path, doc, bin_len, limits)
    n_img = len(doc.get("images", []) or [])
    _glb_check_images(path, doc, limits)
    import trimesh
    try:
        from PIL import Image
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with _max_pixels(limits.max_texture_pixels):
                scene = trimesh.load(str(path), file_type="glb", process=False, force="scene")
    except ScanError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ScanError(path, f"cannot read GLB: {one_line(exc)[:120]}") from None
    try:            # trimesh builds these from the untrusted document: anything odd is the file's fault
        Vs, Fs, UVs, VCs, images = _glb_parts(scene, trimesh)
    except ScanError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ScanError(path, f"cannot read GLB: {type(exc).__name__}: {one_line(exc)[:100]}") from None
    if not Vs:
        raise ScanError(path, "no triangle mesh found in the GLB")
    if not all(isinstance(i, Image.Image) for i in images):
        raise ScanError(path, "GLB material's base colour texture is not a readable image")
    del scene

    def joined(parts):                           # one mesh (the usual case) without a copy
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    V, F = joined(Vs), joined(Fs)
    del Vs, Fs
    _check_counts(path, len(V), len(F), limits)
    UV = FUV = None
    if all(u is not None for u in UVs):
        UV, FUV = joined(UVs), F                 # shared: neither is changed in place
    VC = joined(VCs) if all(c is not None for c in VCs) else None
    texture_bytes = None
    if images:
        if len({id(i) for i in images}) > 1 and n_img > 1:
            raise ScanError(path, f"GLB uses {n_img} different textures; one texture per scan is supported")
        buf = io.BytesIO()
        images[0].save(buf, format="PNG")
        texture_bytes = buf.getvalue()
    return LoadedMesh(V=V, F=F, UV=UV, FUV=FUV, VC=VC, texture_bytes=texture_bytes, files_read=[path])


LOADERS = {".obj": load_obj, ".ply": load_ply, ".stl": load_stl, ".glb": load_glb}


def load_mesh_file(path, folder, limits: Limits = Limits()) -> LoadedMesh:
    """Load any supported mesh file (by suffix) and check the basic facts.

    Checks: non-empty, finite coordinates, face indices in range, UV indices in
    range and finite UVs.
    """
    path = Path(path)
    loader = LOADERS.get(path.suffix.lower())
    if loader is None:
        raise ScanError(path, f"unsupported mesh format {path.suffix!r}; use OBJ, PLY, STL or GLB")
    mesh = loader(path, folder, limits)
    if len(mesh.V) == 0 or len(mesh.F) == 0:
        raise ScanError(path, f"mesh is empty ({len(mesh.V)} vertices, {len(mesh.F)} faces)")
    bad = ~np.isfinite(mesh.V).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ScanError(path, f"{int(bad.sum())} vertices have non-finite coordinates (NaN/inf), first is vertex {i}")
    if mesh.F.min() < 0 or mesh.F.max() >= len(mesh.V):
        worst = int(mesh.F.max()) if mesh.F.max() >= len(mesh.V) else int(mesh.F.min())
        raise ScanError(path, f"face index {worst} out of range (the mesh has {len(mesh.V)} vertices)")
    if mesh.UV is not None:
        if not np.isfinite(mesh.UV).all():
            raise ScanError(path, "texture coordinates contain NaN or inf")
        if mesh.FUV.shape != mesh.F.shape or (mesh.FUV.size and (
                len(mesh.UV) == 0 or mesh.FUV.min() < 0 or mesh.FUV.max() >= len(mesh.UV))):
            raise ScanError(path, "texture coordinate indices out of range")
    return mesh


# ---------------------------------------------------------------------------- textures

@contextlib.contextmanager
def _max_pixels(limit: int):
    from PIL import Image

    old = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = int(limit)
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = old


def load_texture(source, limits: Limits = Limits(), name=None):
    """Open and fully decode a texture image, refusing oversize images before decoding.

    Parameters
    ----------
    source : pathlib.Path or bytes
        An image file inside the scan folder, or encoded bytes (GLB).
    limits : Limits
    name : str or pathlib.Path, optional
        What to name in errors for ``bytes`` sources.

    Returns
    -------
    PIL.Image.Image
        Decoded, in mode ``RGB`` or ``RGBA``; ``info["source_format"]`` / ``info["source_mode"]``
        hold the file's own format and mode.
    """
    from PIL import Image, UnidentifiedImageError

    label = name if isinstance(source, (bytes, bytearray)) else source
    if not isinstance(source, (bytes, bytearray)):
        check_file_size(source, limits)
        data = Path(source).read_bytes()
    else:
        data = bytes(source)
    with _max_pixels(limits.max_texture_pixels), warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            img = Image.open(io.BytesIO(data))  # reads the header only
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            raise ScanError(label, f"texture is over the limit of {limits.max_texture_pixels} pixels "
                                   f"(ingest.max_texture_pixels), possible decompression bomb; not decoded "
                                   f"({one_line(exc)[:80]})") from None
        except UnidentifiedImageError:
            raise ScanError(label, "texture cannot be opened: not an image format PIL can read, or a "
                                   "corrupt header") from None
        except Exception as exc:  # noqa: BLE001
            raise ScanError(label, f"texture cannot be opened: {one_line(exc)[:140]}") from None
        w, h = img.size
        if w <= 0 or h <= 0 or w * h > limits.max_texture_pixels:
            raise ScanError(label, f"texture header claims {w}x{h} = {w * h} pixels, over the limit of "
                                   f"{limits.max_texture_pixels} (ingest.max_texture_pixels); not decoded")
        try:
            img.load()
        except Exception as exc:  # noqa: BLE001 - truncated/corrupt image data
            raise ScanError(label, f"texture cannot be decoded: {one_line(exc)[:140]}") from None
    fmt, mode = img.format, img.mode
    if img.mode not in ("RGB", "RGBA"):
        img = img.convert("RGBA" if "A" in img.getbands() or "transparency" in img.info else "RGB")
    img.info["source_format"], img.info["source_mode"] = fmt, mode
    return img


# ---------------------------------------------------------------------------- the whole ingest

@dataclass(frozen=True)
class IngestSettings(Settings):
    """Every limit and threshold of the ingest stage (the ``ingest:`` block of params.yaml);
    defaults here, values checked by :mod:`pipeline.settings` (type, range, finite, no unknown keys).

    Attributes
    ----------
    max_file_mb, max_yaml_bytes, max_vertices, max_faces, max_texture_pixels
        Resource limits (see :class:`Limits`).
    head_size_mm : (2,) float
        Accepted range of the largest bounding-box side, mm.
    eye_separation_mm : (2,) float
        Accepted distance between the eye hints, mm.
    float32_tolerance_mm : float
        Largest float32 step accepted at the largest coordinate, mm.
    max_hint_distance_mm : float
        Largest distance from an eye hint to the mesh surface, mm.
    merge_tolerance_mm, degenerate_area_mm2, max_degenerate_fraction, debris_max_fraction,
    eye_radius_mm, max_eye_region_removed_fraction
        See :class:`pipeline.geometry.repair.RepairSettings`.
    flip_inward_winding : bool
        Flip all faces when the faces around the eyes point backward (inward winding);
        when False such a scan is refused.
    max_json_mb : float
        Largest GLB JSON chunk, MiB.
    max_memory_mb : float
        Address-space bound (``RLIMIT_AS``) the ingest stage sets on itself, MiB; 0 for none.
        The header checks refuse over-limit files long before this; it is the backstop.
    """

    block: ClassVar[str] = "ingest"

    max_file_mb: float = setting(1024.0, gt=0)
    max_yaml_bytes: int = setting(65536, ge=1)
    max_vertices: int = setting(5_000_000, ge=3)
    max_faces: int = setting(10_000_000, ge=1)
    max_texture_pixels: int = setting(8192 * 8192, ge=1)
    head_size_mm: tuple[float, float] = setting((40.0, 1000.0), gt=0, ordered=True)
    eye_separation_mm: tuple[float, float] = setting((30.0, 120.0), gt=0, ordered=True)
    float32_tolerance_mm: float = setting(0.01, gt=0)
    max_hint_distance_mm: float = setting(15.0, gt=0)
    merge_tolerance_mm: float = setting(1e-4, ge=0)
    degenerate_area_mm2: float = setting(1e-10, ge=0)
    max_degenerate_fraction: float = setting(0.1, ge=0, le=1)
    debris_max_fraction: float = setting(0.01, ge=0, le=1)
    eye_radius_mm: float = setting(20.0, gt=0)
    max_eye_region_removed_fraction: float = setting(0.05, ge=0, le=1)
    flip_inward_winding: bool = True
    max_json_mb: float = setting(64.0, gt=0)
    max_memory_mb: float = setting(4096.0, ge=0)

    @property
    def limits(self) -> Limits:
        return Limits(max_file_bytes=int(self.max_file_mb * 2**20), max_vertices=int(self.max_vertices),
                      max_faces=int(self.max_faces), max_texture_pixels=int(self.max_texture_pixels),
                      max_json_bytes=int(self.max_json_mb * 2**20))

    @property
    def repair(self):
        from pipeline.geometry.repair import RepairSettings

        return RepairSettings(merge_tolerance_mm=self.merge_tolerance_mm,
                              degenerate_area_mm2=self.degenerate_area_mm2,
                              max_degenerate_fraction=self.max_degenerate_fraction,
                              debris_max_fraction=self.debris_max_fraction,
                              eye_radius_mm=self.eye_radius_mm,
                              max_eye_region_removed_fraction=self.max_eye_region_removed_fraction)


@dataclass
class IngestResult:
    """A validated, repaired scan in the head frame (mm).

    Attributes
    ----------
    mesh : dict of numpy.ndarray
        ``V`` (n,3) float64, ``F`` (m,3) int64, optional ``UV`` (k,2) + ``FUV`` (m,3), ``VC`` (n,3) uint8.
    texture : PIL.Image.Image or None
    texture_png_bytes : bytes or None
        The texture file's own bytes when it already is a PNG (copied unchanged).
    scan : dict
        Contents of ``scan.json`` (``texture`` is ``"texture.png"`` or None).
    metrics : dict
    """

    mesh: dict
    texture: object
    texture_png_bytes: bytes | None
    scan: dict
    metrics: dict


def source_sha256(folder, files) -> str:
    """SHA-256 over the (relative path, content hash) of every file read, sorted by path."""
    import hashlib

    folder = Path(folder).resolve()
    outer = hashlib.sha256()
    for rel, p in sorted({(Path(f).resolve().relative_to(folder).as_posix(), Path(f).resolve()) for f in files}):
        h = hashlib.sha256()
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 22), b""):
                h.update(chunk)
        outer.update(f"{rel}\0{h.hexdigest()}\n".encode())
    return outer.hexdigest()


def ingest_scan(folder, settings: IngestSettings = IngestSettings()) -> IngestResult:
    """Load, validate, convert to head-frame mm and safely repair one scan folder.

    Parameters
    ----------
    folder : str or os.PathLike
        The scan folder (``scan.yaml`` + mesh [+ texture]); only files it names are read.
    settings : IngestSettings

    Returns
    -------
    IngestResult

    Raises
    ------
    pipeline.errors.ScanError
        For any bad input, naming the file and the problem.
    """
    from pipeline.io.scan import read_sidecar

    spec = read_sidecar(folder, settings.max_yaml_bytes)
    try:
        return _ingest(folder, spec, settings)
    except MemoryError:
        raise ScanError(spec.mesh, "ran out of memory ingesting this mesh (the stage's address-space bound, "
                                   "ingest.max_memory_mb): a malformed file, or limits too high for the bound") from None
    except OverflowError as exc:
        raise ScanError(spec.mesh, f"a number is too large ({one_line(exc)[:80]})") from None


def _ingest(folder, spec, settings: IngestSettings) -> IngestResult:
    from pipeline.geometry import frame, repair

    limits = settings.limits
    loaded = load_mesh_file(spec.mesh, spec.folder, limits)
    files = [spec.sidecar, *loaded.files_read]
    n_in, m_in = len(loaded.V) + loaded.merged_vertices, len(loaded.F)
    mesh_file = spec.mesh
    V = frame.to_head_frame(loaded.V, spec.units, spec.up_axis, spec.forward_axis)
    loaded.V = None
    hints = {s: frame.to_head_frame(h, spec.units, spec.up_axis, spec.forward_axis) for s, h in spec.hints.items()}
    step = frame.check_float32(V, mesh_file, settings.float32_tolerance_mm)
    frame.check_head_size(V, spec.units, mesh_file, settings.head_size_mm)
    separation = frame.check_eye_layout(hints["left"], hints["right"], spec.sidecar, settings.eye_separation_mm)
    fixed = repair.repair_mesh(V, loaded.F, hints, settings.repair, path=mesh_file)
    fixed.counts["merged_vertices"] += loaded.merged_vertices
    del V
    loaded.F = None                              # the repaired F replaces it (memory at the limits)
    V, F = fixed.V, fixed.F
    if len(V) > limits.max_vertices:             # an STL soup's vertices are only counted once merged
        raise ScanError(mesh_file, f"{len(V)} vertices after merging duplicates, over the limit of "
                                   f"{limits.max_vertices} (ingest.max_vertices)")
    # texture coordinates and colours follow the kept faces / vertices
    UV = FUV = None
    if loaded.UV is not None:
        FUV_all = loaded.FUV[fixed.face_index]
        used = np.zeros(len(loaded.UV), dtype=bool)
        used[FUV_all.ravel()] = True
        remap = np.cumsum(used) - 1
        UV, FUV = loaded.UV[used], remap[FUV_all].astype(np.int64)
        loaded.UV = loaded.FUV = None
        del FUV_all, used, remap
    VC = loaded.VC[fixed.vertex_index] if loaded.VC is not None else None
    hint_dist = {}
    edges = repair.face_longest_edges(V, F)
    for side, h in hints.items():
        d = repair.point_surface_distance(V, F, h, edges)
        hint_dist[side] = round(d, 4)
        if d > settings.max_hint_distance_mm:
            raise ScanError(spec.sidecar, f"eyes.{side}.hint is {d:.1f} mm from the mesh surface, over the limit "
                                          f"of {settings.max_hint_distance_mm:g} mm (wrong hint, units or axes?)")
    normal_z = sum(float(repair.mean_normal_near(V, F, h, settings.eye_radius_mm)[2]) for h in hints.values())
    flipped = False
    if normal_z < 0:
        if not settings.flip_inward_winding:
            raise ScanError(mesh_file, "faces around the eyes point backward (-Z): inward winding or wrong "
                                       "forward_axis")
        F = F[:, ::-1].copy()
        if FUV is not None:
            FUV = FUV[:, ::-1].copy()
        flipped = True
    # texture
    texture = png_bytes = None
    tex_src = spec.texture or loaded.texture_path
    tex_label = tex_src if tex_src is not None else f"{mesh_file} (embedded texture)"
    if tex_src is not None or loaded.texture_bytes is not None:
        if UV is None:
            raise ScanError(tex_label, f"a texture is given but the mesh {mesh_file.name} has no texture coordinates")
        texture = load_texture(tex_src if tex_src is not None else loaded.texture_bytes, limits, name=tex_label)
        if tex_src is not None:
            files.append(tex_src)
            if texture.info.get("source_format") == "PNG" and texture.info.get("source_mode") in ("RGB", "RGBA"):
                png_bytes = Path(tex_src).read_bytes()
    mesh = {"V": V, "F": F}
    if UV is not None:
        mesh.update(UV=UV, FUV=FUV)
    if VC is not None:
        mesh["VC"] = VC
    scan = {
        "name": Path(folder).name or spec.folder.name,
        "source_sha256": source_sha256(spec.folder, files),
        "licence": spec.licence,
        "eyes": {s: {"hint": [float(x) for x in hints[s]]} for s in ("left", "right")},
        "texture": "texture.png" if texture is not None else None,
        "units_in": spec.units,
        "up_axis_in": spec.up_axis,
        "forward_axis_in": spec.forward_axis,
    }
    lo, hi = V.min(axis=0), V.max(axis=0)
    metrics = {
        "mesh_file": mesh_file.name,
        "vertices_in": n_in, "faces_in": m_in,
        "vertices_out": int(len(V)), "faces_out": int(len(F)),
        "polygons_triangulated": loaded.polygons_triangulated,
        "repairs": fixed.counts,
        "edges": repair.edge_stats(F, len(V)),
        "flipped_winding": flipped,
        "eye_region": fixed.eye_region,
        "hint_surface_distance_mm": hint_dist,
        "eye_hint_separation_mm": round(separation, 3),
        "bbox_min_mm": [round(float(x), 4) for x in lo],
        "bbox_max_mm": [round(float(x), 4) for x in hi],
        "float32_step_mm": step,
        "has_uv": UV is not None,
        "uv_count": 0 if UV is None else int(len(UV)),
        "uv_outside_unit_square_fraction": 0.0 if UV is None else
        round(float(np.mean(np.any((UV < 0) | (UV > 1), axis=1))), 6),
        "has_vertex_colors": VC is not None,
        "texture_size": list(texture.size) if texture is not None else None,
        "unknown_sidecar_keys": list(spec.unknown_keys),
        "files_read": sorted(Path(f).resolve().relative_to(spec.folder).as_posix() for f in set(files)),
    }
    return IngestResult(mesh=mesh, texture=texture, texture_png_bytes=png_bytes, scan=scan, metrics=metrics)
