"""Wavefront OBJ (+ MTL ``map_Kd``) reader: per-corner UVs, polygons of any and mixed sizes.

The usual layout is parsed with numpy (:func:`_obj_fast`); anything else (negative indices
between vertex blocks, mixed face formats, trailing comments) goes to the line-by-line parser
(:func:`_obj_slow`), whose errors name the offending line. ``v``/``f`` line counts are checked
against the limits before any line is parsed; seams keep their exact UV layout (one ``UV`` row per
``vt`` line; the vertex positions are not split, unlike trimesh's OBJ loader).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.formats.common import (Limits, LoadedMesh, check_counts, check_file_size, fan_by_counts,
                                        fan_triangulate, parse_numbers, read_content, tokens_per_row)
from pipeline.io.scan import TEXTURE_SUFFIXES, one_line, safe_path


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
        text = read_content(fh, mtl_path)[0].decode("utf-8", errors="replace")   # blank/comment lines dropped
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
    check_counts(path, len(v_rows), len(f_rows), limits)
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
    check_counts(path, len(V), len(F), limits)
    return V, VC, UV, F, FUV, int(np.count_nonzero(counts > 3)), mtllibs, usemtl


def _floats_fast(text: bytes, n_rows: int, min_cols: int):
    """Newline-separated rows of numbers -> (n_rows, c) float64 by one C-level parse, or None when irregular."""
    if not n_rows:
        return np.zeros((0, min_cols))
    cols = len(text[:text.find(b"\n") if b"\n" in text else len(text)].split())
    if cols < min_cols:
        return None
    vals = parse_numbers(text, np.float64)
    if vals is None:
        return None
    if vals.size != n_rows * cols or np.any(tokens_per_row(text, n_rows) != cols):
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
    check_counts(path, n_v, n_f, limits)
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
    counts = tokens_per_row(text, n_f)
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
    idx = parse_numbers(text, np.int64)
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
    F = fan_by_counts(vidx, counts)
    FUV = fan_by_counts(tidx, counts) if tidx is not None else None
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
        raw, line_no = read_content(fh, path)
    if b"#" in raw:                                  # trailing comments ("f 1 2 3 # x"): cut, lines kept
        raw = re.sub(rb"#[^\n]*", b"", raw)
    get = _obj_line_blocks(raw)
    check_counts(path, get.count("v"), get.count("f"), limits)    # before any line is parsed
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
