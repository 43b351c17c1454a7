"""PLY reader (ASCII and binary): vertices, triangles and polygons, UVs, vertex colours, TextureFile.

The header's element counts are checked against the limits before any data is read. Uniform
elements are parsed in one numpy call; lists of varying length (triangles and quads) by a
vectorised gather, and anything else row by row, naming the file's line. Per-vertex ``s,t`` /
``u,v`` / ``texture_u,texture_v`` become ``UV`` with ``FUV = F``; per-face ``texcoord`` lists one
``UV`` row per corner.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.formats.common import (Limits, LoadedMesh, check_counts, check_file_size, fan_by_counts,
                                        fan_triangulate, parse_numbers, read_content, tokens_per_row)
from pipeline.io.scan import TEXTURE_SUFFIXES, one_line, safe_path


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
        return (fan_by_counts(polys.flat.astype(np.int64), polys.counts),
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


def _float64_columns(cols) -> np.ndarray:
    """(n, k) float64 from k columns (n,) of PLY scalars, converted straight into place (no
    intermediate stacked copy; every PLY scalar type is exact in float64)."""
    out = np.empty((len(cols[0]), len(cols)), dtype=np.float64)
    for k, c in enumerate(cols):
        out[:, k] = c
    return out


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
    vals = parse_numbers(text, np.float64)
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
    raw, line_no = read_content(fh, path, max_lines=n_rows, comment=None)
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
        n_tok = tokens_per_row(text, n)
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
            vals = parse_numbers(text, np.float64)
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
        check_counts(path, n_v, n_f, limits)
        if fmt == "ascii":
            _ply_ascii(fh, elements, data_start, head[:data_start].count(b"\n"), path)
        else:
            fh.seek(data_start)
            _ply_binary(fh, elements, "<" if fmt == "binary_little_endian" else ">", size - data_start, path)
    vdata = elements.get("vertex", {}).get("data")
    xyz = [_column(vdata, c) for c in "xyz"]
    if any(c is None for c in xyz):
        raise ScanError(path, "PLY has no vertex x, y, z properties")
    V = _float64_columns(xyz)
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
                UV = _float64_columns([cu, cv])
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
