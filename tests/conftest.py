"""Shared fixtures.

Real scans live outside the project (``../shared/scans``); tests that need them
read the folder from ``EYERIG_EXTRA_SCANS`` and skip cleanly when it is unset.

The scan-folder builders below (a head-sized ellipsoid with two eye bumps, written
as PLY / OBJ with a ``scan.yaml``) are shared by the ingest tests: import them with
``from conftest import make_scan, ...``.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def extra_scans_dir() -> Path | None:
    value = os.environ.get("EYERIG_EXTRA_SCANS")
    return Path(value) if value else None


@pytest.fixture
def extra_scan():
    """``extra_scan("james")`` -> path of that real scan folder, or skip."""

    def get(name: str) -> Path:
        base = extra_scans_dir()
        if base is None:
            pytest.skip("EYERIG_EXTRA_SCANS is not set")
        folder = base / name
        if not folder.is_dir():
            pytest.skip(f"{folder} not found")
        return folder

    return get


# ---------------------------------------------------------------------------- scan-folder builders

RADII = np.array([75.0, 100.0, 90.0])      # head-sized ellipsoid, mm (x, y, z)
EYE_XY = {"left": (32.0, 35.0), "right": (-32.0, 35.0)}  # subject's left = +X
BUMP_MM, BUMP_SIGMA = 4.0, 8.0


def head_mesh(subdivisions: int = 4):
    """A head-sized ellipsoid with two eye bumps, head frame mm.

    Returns
    -------
    V : (n, 3) float64, F : (m, 3) int64, hints : dict side -> (3,) float64 (on the bump surface + 1 mm)
    """
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    unit = np.asarray(s.vertices, dtype=np.float64)
    V = unit * RADII
    F = np.asarray(s.faces, dtype=np.int64)
    hints = {}
    for side, (x, y) in EYE_XY.items():
        z = RADII[2] * np.sqrt(1 - (x / RADII[0]) ** 2 - (y / RADII[1]) ** 2)
        c = np.array([x, y, z])
        d = np.linalg.norm(V - c, axis=1)
        V = V + unit * (BUMP_MM * np.exp(-0.5 * (d / BUMP_SIGMA) ** 2))[:, None]
        hints[side] = c + c / np.linalg.norm(c) * (BUMP_MM + 1.0)
    return V, F, hints


def sphere_uv(V):
    """Per-vertex spherical UVs in [0, 1], shape (n, 2)."""
    d = V / np.linalg.norm(V, axis=1, keepdims=True)
    u = 0.5 + np.arctan2(d[:, 0], d[:, 2]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(d[:, 1], -1, 1)) / np.pi
    return np.column_stack([u, v])


def write_ply(path, V, F, *, binary=True, uv=None, vc=None, uv_names=("s", "t"), header_extra=""):
    """Write a PLY with float32 xyz, optional per-vertex UV (``s``, ``t``) and uchar colours."""
    V = np.asarray(V)
    props = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if uv is not None:
        props += [(uv_names[0], "<f4"), (uv_names[1], "<f4")]
    if vc is not None:
        props += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    head = ["ply", "format binary_little_endian 1.0" if binary else "format ascii 1.0"]
    if header_extra:
        head.append(header_extra)
    head.append(f"element vertex {len(V)}")
    for name, dt in props:
        head.append(f"property {'float' if dt == '<f4' else 'uchar'} {name}")
    head += [f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    text = "\n".join(head) + "\n"
    vert = np.zeros(len(V), dtype=props)
    vert["x"], vert["y"], vert["z"] = V[:, 0], V[:, 1], V[:, 2]
    if uv is not None:
        vert[uv_names[0]], vert[uv_names[1]] = uv[:, 0], uv[:, 1]
    if vc is not None:
        vert["red"], vert["green"], vert["blue"] = vc[:, 0], vc[:, 1], vc[:, 2]
    with open(path, "wb") as fh:
        fh.write(text.encode())
        if binary:
            fh.write(vert.tobytes())
            face = np.zeros(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
            face["n"], face["i"] = 3, F
            fh.write(face.tobytes())
        else:
            lines = [" ".join(repr(float(x)) if isinstance(x, (float, np.floating)) else str(x) for x in row)
                     for row in vert.tolist()]
            lines += [f"3 {a} {b} {c}" for a, b, c in F]
            fh.write(("\n".join(lines) + "\n").encode())


def write_obj(path, V, F, *, UV=None, FUV=None, mtl=None, extra_lines=()):
    """Write an OBJ with optional per-corner UVs (``f v/vt``) and ``mtllib``."""
    out = []
    if mtl:
        out.append(f"mtllib {mtl}")
    out += [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(V, dtype=float).tolist()]
    if UV is not None:
        out += [f"vt {u!r} {v!r}" for u, v in np.asarray(UV, dtype=float).tolist()]
        if mtl:
            out.append("usemtl skin")
        out += [f"f {a + 1}/{p + 1} {b + 1}/{q + 1} {c + 1}/{r + 1}" for (a, b, c), (p, q, r) in zip(F, FUV)]
    else:
        out += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    out += list(extra_lines)
    Path(path).write_text("\n".join(out) + "\n")


def write_png(path, size=(64, 32)):
    from PIL import Image

    w, h = size
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[..., 0] = np.linspace(0, 255, w)[None, :]
    img[..., 1] = np.linspace(0, 255, h)[:, None]
    img[..., 2] = 128
    Image.fromarray(img).save(path)


def write_sidecar(folder, hints, *, mesh="scan.ply", units="mm", up="+Y", forward="+Z", texture=None,
                  licence="CC0 test data", **extra):
    data = {"mesh": mesh, "units": units, "up_axis": up, "forward_axis": forward,
            "eyes": {s: {"hint": [float(x) for x in hints[s]]} for s in ("left", "right")},
            "licence": licence}
    if texture:
        data["texture"] = texture
    data.update(extra)
    Path(folder, "scan.yaml").write_text(yaml.safe_dump(data, sort_keys=False))


def make_scan(folder, fmt="ply", **kw):
    """A good synthetic scan folder in the head frame (mm). Returns (V, F, hints)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    V, F, hints = head_mesh()
    if fmt == "ply":
        write_ply(folder / "scan.ply", V, F)
        write_sidecar(folder, hints, **kw)
    elif fmt == "obj":
        write_obj(folder / "scan.obj", V, F)
        write_sidecar(folder, hints, mesh="scan.obj", **kw)
    else:
        raise ValueError(fmt)
    return V, F, hints


def ingest(scan, out, params=None, capsys=None):
    """Run the stage in-process; returns exit code."""
    from stages._common import run_stage
    from stages.ingest import main

    argv = [str(scan), str(out), "--metrics", str(Path(out).with_suffix(".metrics.json"))]
    if params is not None:
        argv += ["--params", str(params)]
    return run_stage(main, argv)


def edit_yaml(folder, **changes):
    """Set (or, with None, remove) top-level keys of ``folder/scan.yaml``."""
    path = Path(folder, "scan.yaml")
    data = yaml.safe_load(path.read_text())
    for k, v in changes.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def png_header_only(path, width, height):
    """A PNG whose IHDR claims width x height, with a tiny (wrong) IDAT: a decompression-bomb header."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 16))
                           + chunk(b"IEND", b""))
