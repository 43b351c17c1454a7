"""Shared fixtures.

Real scans live outside the project (``../shared/scans``); tests that need them
read the folder from ``EYERIG_EXTRA_SCANS`` and skip cleanly when it is unset.

Builders shared by several test files live here; import them with
``from conftest import make_scan, ...``:

* scan folders (a head-sized ellipsoid with two eye bumps, written as PLY / OBJ with a
  ``scan.yaml``): ingest, frame and hostile-input tests;
* ``face_patch``: a bumpy height-field face with two eyelid openings (retopo, bake);
* ``make_inputs`` / ``usd_argv``: the usd stage's inputs for a tiny fake scan (usd, render,
  Blender import and asset-preview tests); ``make_render_asset``: that scan through the usd
  stage, with the rig the render needs (render and dataset tests).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def extra_scans_dir() -> Path | None:
    # absolute: the README's command gives ../shared/scans, and tests run stages from other folders
    value = os.environ.get("EYERIG_EXTRA_SCANS")
    return Path(value).resolve() if value else None


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


# ---------------------------------------------------------------------------- face patch (retopo, bake)

EYE_CENTRES = {"left": np.array([32.0, 36.0, 70.0]), "right": np.array([-32.0, 36.0, 70.0])}


def height(x, y):
    return 80.0 + 2.0 * np.sin(x / 7.0) * np.cos(y / 9.0) + 0.3 * np.sin(x / 1.3 + y / 1.7)


def face_patch(step=0.8, hole_a=12.0, hole_b=5.0):
    """A bumpy height-field 'face' (z up to the viewer) with two elliptical eye openings.

    Returns V, F (CCW seen from +z) and eyes = {side: {center, loop_indices}} with each
    loop ordered from the medial canthus over the upper lid (contract of remove_eyeballs).
    """
    from pipeline.geometry import mesh_checks as mc

    xs = np.arange(-60.0, 60.0 + 1e-9, step)
    ys = np.arange(0.0, 72.0 + 1e-9, step)
    X, Y = np.meshgrid(xs, ys)
    V = np.stack([X.ravel(), Y.ravel(), height(X, Y).ravel()], axis=1)
    nx = len(xs)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(len(ys) - 1))
    a = (j * nx + i).ravel()
    b, c, d = a + 1, a + nx + 1, a + nx
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    cen = V[F].mean(axis=1)
    keep = np.ones(len(F), dtype=bool)
    for c0 in EYE_CENTRES.values():
        keep &= ((cen[:, 0] - c0[0]) / hole_a) ** 2 + ((cen[:, 1] - (c0[1] - 3)) / hole_b) ** 2 > 1.0
    F = F[keep]
    used = np.unique(F)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    eyes = {}
    for side, c0 in EYE_CENTRES.items():
        loop = min(mc.boundary_loops(F), key=lambda l: np.linalg.norm(V[l].mean(0)[:2] - c0[:2]))
        P = V[loop]
        loop = np.roll(loop, -int(np.argmin(np.abs(P[:, 0]))))
        if V[loop[len(loop) // 4], 1] < V[loop, 1].mean():
            loop = np.roll(loop[::-1], 1)
        eyes[side] = {"center": c0, "loop_indices": loop}
    return V, F, eyes


# ---------------------------------------------------------------------------- usd-stage inputs (usd, render, Blender)

EYES = {"left": {"center": [32.0, 0.5, 76.0], "radius": 12.5,
                 "forward": list(np.array([0.08, 0.05, 1.0]) / np.linalg.norm([0.08, 0.05, 1.0]))},
        "right": {"center": [-31.0, -0.4, 76.5], "radius": 12.5, "forward": [0.0, 0.0, 1.0]}}
R1 = 12.0   # parametric eyeball radius


def _shape(name, idx, off, sag):
    from pipeline.rig.lids import BlendShape

    w = np.array([1 / 3, 2 / 3])
    ib = np.stack([wi * off + sag * np.sin(np.pi * wi) for wi in w])
    return BlendShape(name=name, point_indices=np.asarray(idx, np.int64), offsets=off,
                      inbetween_weights=w, inbetween_offsets=ib)


def make_inputs(root: Path, n_x: int = 23, n_y: int = 11, name: str = "tiny",
                licence: str = "CC0-1.0 (test)") -> dict:
    """build/<name>/{snap,bake,rig,ingest} + rigged_assets/eyeball for a tiny fake scan under ``root``
    (the eyeball is written once per ``root``)."""
    from PIL import Image

    from pipeline.eyeball import geometry as geo
    from pipeline.eyeball import textures as etex
    from pipeline.io.bake_file import write_bake
    from pipeline.io.meshfile import save_mesh
    from pipeline.io.rig_file import write_rig
    from pipeline.rig import lids
    from pipeline.usd.eyeball import write_eyeball_usd

    b = root / "build" / name
    dirs = {k: b / k for k in ("snap", "bake", "rig", "ingest")}
    for d in dirs.values():
        d.mkdir(parents=True)
    eb = root / "rigged_assets" / "eyeball"
    if not (eb / "eyeball.usda").is_file():
        (eb / "textures").mkdir(parents=True)
        for tex, img in etex.texture_set(0, 32, (32, 16)).items():
            Image.fromarray(img).save(eb / "textures" / tex)
        write_eyeball_usd(geo.build_eyeball(resolution="low"), eb / "eyeball.usda")

    x, y = np.meshgrid(np.linspace(-55, 55, n_x), np.linspace(-25, 25, n_y))
    V = np.stack([x.ravel(), y.ravel(), 86.0 + 0.01 * x.ravel() ** 2 * 0], 1)
    g = np.arange(n_x * n_y).reshape(n_y, n_x)
    a, bq, c, d = g[:-1, :-1].ravel(), g[:-1, 1:].ravel(), g[1:, 1:].ravel(), g[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, bq, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    UV = (V[:, :2] - V[:, :2].min(0)) / np.ptp(V[:, :2], 0)
    save_mesh(dirs["snap"] / "mesh.npz", V=V, F=F, UV=UV, FUV=F.copy())

    near = np.flatnonzero(np.abs(V[:, 1]) < 12)
    fall = np.exp(-(V[near, 1] / 6) ** 2)[:, None]
    shapes = [_shape(lids.SHAPE_UP, near, fall * [0, 1.5, 0.2], fall * [0, 0, -0.15]),
              _shape(lids.SHAPE_DOWN, near, fall * [0, -1.2, 0.1], fall * [0, 0, -0.1])]
    arrays = lids.shapes_to_arrays(shapes)
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    for side, e in EYES.items():
        c = np.asarray(e["center"])
        pts = c + np.stack([-np.cos(t) * 12 * np.sign(c[0]), 5 * np.sin(t), np.full(12, 10.0)], 1)
        lup = [_shape(lids.SHAPE_UP, np.arange(12), np.tile([0, 1.0, 0], (12, 1)), np.zeros((12, 3))),
               _shape(lids.SHAPE_DOWN, np.arange(12), np.tile([0, -1.0, 0], (12, 1)), np.zeros((12, 3)))]
        arrays[f"landmarks.{side}.points"] = pts
        arrays.update(lids.shapes_to_arrays(lup, prefix=f"landmarks.{side}."))
    write_rig(dirs["rig"], arrays, {"weight_rule": lids.weight_rule(25.0),
                                    "eyes": {s: dict(e, joint=f"eye_{s}", surface={"parametric_eye": {"r1": R1}})
                                             for s, e in EYES.items()}})
    (dirs["ingest"] / "scan.json").write_text(json.dumps(
        {"name": name, "source_sha256": "ab" * 32, "licence": licence,
         "eyes": {s: {"hint": e["center"]} for s, e in EYES.items()}}))
    write_bake(dirs["bake"], {"V": V, "F": F, "UV": UV, "FUV": F.copy()},
               np.linspace(-0.2, 0.2, 256).reshape(16, 16), None, np.full((16, 16, 3), 180, np.uint8),
               resolution=16, falloff_mm=2.0, colour_source="flat test colour")
    return {"dirs": dirs, "eyeball": eb, "out": root / "rigged_assets" / name, "V": V, "F": F,
            "shapes": shapes, "arrays": arrays, "metrics": b / "usd.metrics.json"}


def usd_argv(inp, out=None):
    """The usd stage's command line for ``make_inputs``' folders (no params file: the defaults)."""
    d = inp["dirs"]
    return [str(d["snap"]), str(d["bake"]), str(d["rig"]), str(d["ingest"]), str(inp["eyeball"]),
            str(out or inp["out"]), "--metrics", str(inp["metrics"]), "--params", "/nonexistent.yaml"]


def _ring(V, center, side):
    """16 grid vertices on a square ring (10 mm) around the eye, medial first, upper lid first."""
    gx, gy = np.round(center[0] / 5) * 5, np.round(center[1] / 5) * 5
    d = np.maximum(np.abs(V[:, 0] - gx), np.abs(V[:, 1] - gy))
    ring = np.flatnonzero(np.isclose(d, 10.0))
    ang = np.arctan2(V[ring, 1] - gy, V[ring, 0] - gx)
    if side == "left":          # medial = -X (angle pi), over the top to angle 0, then below
        key = np.mod(np.pi - ang, 2 * np.pi)
    else:                       # medial = +X (angle 0), over the top to angle pi
        key = np.mod(ang, 2 * np.pi)
    loop = ring[np.argsort(key)]
    lat = int(np.flatnonzero(np.isclose(np.sort(key), np.pi))[0])
    return loop, lat


def make_render_asset(root: Path, name: str = "tiny", licence: str = "CC0-1.0 (test)") -> dict:
    """``rigged_assets/<name>`` and ``build/<name>/rig`` as the render stage takes them:
    :func:`make_inputs`' scan with 16-vertex lid loops and eyelid landmark edges added to its
    rig, through the usd stage (no usdz, no preview). Returns root, asset_dir and rig_dir."""
    from pipeline.io.rig_file import read_rig, write_rig
    from pipeline.rig.eye_frame import EyeFrame
    from pipeline.rig.landmarks import eyelid_landmarks
    from stages import usd as usd_stage
    from stages._common import run_stage

    inp = make_inputs(root, name=name, licence=licence)
    rig = read_rig(inp["dirs"]["rig"])
    arrays = dict(rig.npz.arrays)
    V = inp["V"]
    for side, e in EYES.items():
        loop, lat = _ring(V, e["center"], side)
        frame = EyeFrame(side=side, center=np.asarray(e["center"]), radius=e["radius"],
                         forward=np.asarray(e["forward"]), loop=loop, lateral_index=lat)
        lm = eyelid_landmarks(V, frame)
        arrays[f"loop_{side}"] = loop
        arrays[f"landmarks.{side}.edge"] = lm.edge
        arrays[f"landmarks.{side}.t"] = lm.t
        arrays[f"landmarks.{side}.points"] = lm.points
    write_rig(inp["dirs"]["rig"], arrays, rig.doc)
    params = root / "usd_params.yaml"
    params.write_text("usd:\n  usdz: false\n  preview: false\n")
    args = usd_argv(inp)
    args[args.index("--params") + 1] = str(params)
    assert run_stage(usd_stage.main, args) == 0
    return {"root": root, "asset_dir": inp["out"], "rig_dir": inp["dirs"]["rig"]}


def make_two_assets(root: Path, render: dict, licences: dict | None = None) -> dict:
    """Two tiny assets, ``alpha`` and ``beta`` (:func:`make_render_asset`), and a ``params.yaml``
    whose ``render:`` block is ``render``, under ``root``: the dataset command's inputs."""
    licences = licences or {"alpha": "CC0-1.0 (test)", "beta": "CC0-1.0 (test)"}
    made = [make_render_asset(root, name, licence=lic) for name, lic in licences.items()]
    params = root / "params.yaml"
    params.write_text(yaml.safe_dump({"render": render}))
    return {"root": root, "assets": [m["asset_dir"] for m in made], "params": params}
