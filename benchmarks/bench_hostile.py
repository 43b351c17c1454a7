"""Hostile scan folders through the ingest stage: per case the wall time and the child's peak memory.

    .venv/bin/python -m benchmarks.bench_hostile [--out benchmarks/results/hostile.json] [--cap-mib 1536]
                                                 [--at-limits]

Builds every case of :data:`CASES` (and :data:`ACCEPTED`, hostile-looking inputs that
are within the limits and must ingest) from a good synthetic head in a temporary
folder, runs ``python -m stages.ingest FOLDER OUT`` in a subprocess under an
address-space cap (``RLIMIT_AS``, ``--cap-mib``), and records the exit status, the
stderr line, the wall time and the child's own peak RSS (``os.wait4`` rusage).
Targets (issue 12): an over-limit input is refused within 2 s and 500 MiB; an input
within the limits ingests within 2.5 GiB. ``tests/test_hostile_inputs.py`` runs the
same cases and asserts the messages and bounds. ``--at-limits`` adds the largest scan
the default limits accept (the ``bench_ingest`` head at 4,998,002 vertices and 9,996,000
triangles: binary PLY with a 1024^2 texture, the same as OBJ + MTL, as GLB with UVs and as
binary STL; about 1.7 GB on disk, cached in the temp folder), run under the stage's own bound only.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tests.conftest import (edit_yaml, head_mesh, make_scan, png_header_only, sphere_uv, write_obj,
                            write_ply, write_png, write_sidecar)

ROOT = Path(__file__).resolve().parents[1]
REFUSE_WALL_S, REFUSE_PEAK_MIB, ACCEPT_PEAK_MIB = 2.0, 500.0, 2560.0
HUGE = "99999999999999999999"


# ---------------------------------------------------------------------------- GLB builders

def glb_bytes(doc: dict, blob: bytes = b"") -> bytes:
    """A GLB container: JSON chunk (space-padded) and, when ``blob`` is given, a BIN chunk (zero-padded)."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    out = struct.pack("<II", len(js), 0x4E4F534A) + js
    if blob:
        blob = blob + b"\0" * (-len(blob) % 4)
        out += struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<III", 0x46546C67, 2, 12 + len(out)) + out


def head_glb_doc(subdivisions: int = 3, uv: bool = False):
    """A valid one-mesh GLB document of the test head (float32 positions, uint32 indices, with ``uv``
    float32 TEXCOORD_0 as accessor 2) and its blob."""
    V, F, hints = head_mesh(subdivisions)
    pos = V.astype("<f4").tobytes()
    idx = F.astype("<u4").tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(pos) + len(idx)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(V), "type": "VEC3",
                       "min": V.min(axis=0).tolist(), "max": V.max(axis=0).tolist()},
                      {"bufferView": 1, "componentType": 5125, "count": F.size, "type": "SCALAR"}],
    }
    blob = pos + idx
    if uv:
        tex = sphere_uv(V).astype("<f4").tobytes()
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(tex)})
        doc["accessors"].append({"bufferView": 2, "componentType": 5126, "count": len(V), "type": "VEC2"})
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2
        blob += tex
        doc["buffers"][0]["byteLength"] = len(blob)
    return doc, blob, hints


def _glb_case(f, edit, pad_to: int = 0, uv: bool = False):
    """Write ``scan.glb`` from the head document after ``edit(doc, blob) -> blob`` and point scan.yaml at it."""
    doc, blob, hints = head_glb_doc(uv=uv)
    blob = edit(doc, blob) or blob
    data = glb_bytes(doc, blob)
    if pad_to > len(data):                       # pad the JSON chunk with spaces to reach a file size
        doc["extras"] = {"pad": " " * (pad_to - len(data))}
        data = glb_bytes(doc, blob)
    (f / "scan.glb").write_bytes(data)
    write_sidecar(f, hints, mesh="scan.glb")


def c_glb_accessor_1e9_no_view(f, t):
    def edit(doc, blob):
        doc["accessors"][0] = {"componentType": 5126, "count": 10**9, "type": "VEC3"}
    _glb_case(f, edit, pad_to=93_000)


def c_glb_accessor_past_view(f, t):
    def edit(doc, blob):
        doc["accessors"][0]["count"] = 10**9
    _glb_case(f, edit)


def c_glb_view_past_buffer(f, t):
    def edit(doc, blob):
        doc["bufferViews"][1]["byteLength"] = 1 << 40
    _glb_case(f, edit)


def c_glb_buffer_past_chunk(f, t):
    def edit(doc, blob):
        doc["buffers"][0]["byteLength"] = 1 << 33
    _glb_case(f, edit)


def c_glb_sparse_accessor(f, t):
    def edit(doc, blob):
        doc["accessors"][0]["sparse"] = {"count": 10**9, "indices": {"bufferView": 1, "componentType": 5125},
                                         "values": {"bufferView": 0}}
    _glb_case(f, edit)


def c_glb_bad_component_type(f, t):
    def edit(doc, blob):
        doc["accessors"][1]["componentType"] = 5130
    _glb_case(f, edit)


def c_glb_data_uri_buffer(f, t):
    def edit(doc, blob):
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + "A" * 4000
    _glb_case(f, edit)


def c_glb_data_uri_image(f, t):
    def edit(doc, blob):
        doc["images"] = [{"uri": "data:image/png;base64,iVBORw0KGgo=" + "A" * 4000}]
    _glb_case(f, edit)


def c_glb_external_image(f, t):
    png_header_only(t / "outside.png", 16, 16)

    def edit(doc, blob):
        doc["images"] = [{"uri": "../outside.png"}]
    _glb_case(f, edit)


def _instanced(n_nodes):
    def build(f, t):
        def edit(doc, blob):
            doc["nodes"] = [{"children": list(range(1, n_nodes + 1))}]
            doc["nodes"] += [{"mesh": 0, "translation": [0.001 * i, 0, 0]} for i in range(n_nodes)]
        _glb_case(f, edit)
    build.__name__ = f"c_glb_instanced_{n_nodes}_nodes"
    return build


def c_glb_textured_no_uv_rows(f, t):
    write_png(t / "tiny.png", (8, 8))
    png = (t / "tiny.png").read_bytes()

    def edit(doc, blob):                           # a textured mesh whose TEXCOORD_0 has no rows
        doc["accessors"][2]["count"] = 0
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
        doc["images"], doc["textures"] = [{"bufferView": 3, "mimeType": "image/png"}], [{"source": 0}]
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
        doc["buffers"][0]["byteLength"] = len(blob) + len(png)
        return blob + png
    _glb_case(f, edit, uv=True)


def c_glb_many_meshes(f, t):
    def edit(doc, blob):
        doc["meshes"] = doc["meshes"] * 20000      # 20,000 meshes reading the same accessors
    _glb_case(f, edit)


def c_glb_node_cycle(f, t):
    def edit(doc, blob):
        doc["nodes"] = [{"mesh": 0, "children": [1]}, {"children": [0]}]
    _glb_case(f, edit)


def c_glb_node_two_parents(f, t):
    def edit(doc, blob):
        # a DAG doubling at every level would expand to 2^40 instances
        doc["nodes"] = [{"children": [i + 1, i + 1]} for i in range(40)] + [{"mesh": 0}]
    _glb_case(f, edit)


def c_glb_deep_json(f, t):
    def edit(doc, blob):
        doc["extras"] = "@DEEP@"
    doc, blob, hints = head_glb_doc()
    edit(doc, blob)
    js = json.dumps(doc).replace('"@DEEP@"', "[" * 200_000 + "]" * 200_000).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
    (f / "scan.glb").write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    write_sidecar(f, hints, mesh="scan.glb")


def c_glb_json_over_limit(f, t):
    _glb_case(f, lambda doc, blob: None, pad_to=2 << 20)
    return {"max_json_mb": 1}


def c_obj_one_endless_line(f, t):
    V, F, hints = head_mesh(3)
    write_obj(f / "scan.obj", V, F)
    with open(f / "scan.obj", "ab") as fh:
        fh.write(b"v" + b" 1" * (4 << 20))      # 8 MiB without a newline: one "vertex" of 4M numbers
    write_sidecar(f, hints, mesh="scan.obj")


def c_glb_image_header_bomb(f, t):
    png_header_only(t / "bomb.png", 100_000, 100_000)
    png = (t / "bomb.png").read_bytes()

    def edit(doc, blob):
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
        doc["images"] = [{"bufferView": 2, "mimeType": "image/png"}]
        doc["buffers"][0]["byteLength"] = len(blob) + len(png)
        return blob + png
    _glb_case(f, edit)


# ---------------------------------------------------------------------------- text meshes

def c_obj_overflow_index(f, t):
    V, F, hints = head_mesh()
    write_obj(f / "scan.obj", V, F, extra_lines=[f"f 1 2 {HUGE}"])
    write_sidecar(f, hints, mesh="scan.obj")


def c_obj_overflow_uv_index(f, t):
    V, F, hints = head_mesh(3)
    UV = sphere_uv(V)
    write_obj(f / "scan.obj", V, F, UV=UV, FUV=F, extra_lines=[f"f 1/1 2/2 3/{HUGE}"])
    write_sidecar(f, hints, mesh="scan.obj")


def padded_obj(f, padding: bytes) -> None:
    """The good head as ``scan.obj`` followed by ``padding`` (blank or comment lines)."""
    V, F, hints = head_mesh()
    write_obj(f / "scan.obj", V, F)
    with open(f / "scan.obj", "ab") as fh:
        fh.write(padding)
    write_sidecar(f, hints, mesh="scan.obj")


def c_obj_blank_padded_over_limit(f, t):
    padded_obj(f, b"\n" * (20 << 20))
    return {"max_faces": 1000}


def c_obj_comment_padded_over_limit(f, t):
    padded_obj(f, b"# padding\n" * (2 << 20))
    return {"max_vertices": 1000}


def c_obj_huge_coordinates(f, t):
    V, F, hints = head_mesh(3)
    write_obj(f / "scan.obj", V * 1e300, F)       # area / normal arithmetic overflows: no warnings printed
    write_sidecar(f, {k: v * 1e300 for k, v in hints.items()}, mesh="scan.obj")


def c_ply_ascii_overflow_index(f, t):
    V, F, _ = head_mesh(3)
    write_ply(f / "scan.ply", V, F, binary=False)
    text = (f / "scan.ply").read_text()
    (f / "scan.ply").write_text(text.replace("\n3 0 ", f"\n3 {HUGE} ", 1))


def c_ply_header_1e9_vertices(f, t):
    (f / "scan.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\n"
                                 b"property float x\nproperty float y\nproperty float z\nelement face 1\n"
                                 b"property list uchar int vertex_indices\nend_header\n" + b"\0" * 90_000)


def _ply_binary_faces(f, counts: list) -> None:
    """A binary PLY of 3 vertices whose faces are ``int`` lists with the given claimed lengths (each with 3 indices)."""
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {len(counts)}\nproperty list int int vertex_indices\nend_header\n")
    body = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    body += b"".join(struct.pack("<4i", k, 0, 1, 2) for k in counts)
    (f / "scan.ply").write_bytes(head.encode() + body)


def c_ply_binary_list_2e31(f, t):
    _ply_binary_faces(f, [2**31 - 1, 3])


def c_ply_binary_list_negative(f, t):
    _ply_binary_faces(f, [3, -5])


def c_stl_header_over_limit(f, t):
    _, _, hints = head_mesh(3)
    (f / "scan.stl").write_bytes(b"\0" * 80 + struct.pack("<I", 20_000_000) + b"\0" * 50 * 100)
    write_sidecar(f, hints, mesh="scan.stl")


def ascii_stl(f) -> None:
    """The good head as an ASCII ``scan.stl``."""
    import trimesh

    V, F, hints = head_mesh()
    (f / "scan.stl").write_bytes(trimesh.Trimesh(V, F, process=False).export(file_type="stl_ascii").encode())
    write_sidecar(f, hints, mesh="scan.stl")


def c_stl_ascii_over_limit(f, t):
    ascii_stl(f)
    return {"max_faces": 1000}


def c_stl_header_lies(f, t):
    _, _, hints = head_mesh(3)
    (f / "scan.stl").write_bytes(b"\0" * 80 + struct.pack("<I", 1_000_000) + b"\0" * 50 * 100)
    write_sidecar(f, hints, mesh="scan.stl")


# ---------------------------------------------------------------------------- sidecar and paths

def c_yaml_duplicate_key(f, t):
    text = (f / "scan.yaml").read_text()
    (f / "scan.yaml").write_text(text + "units: cm\n")


def sidecar_eyes(f, fmt=repr, keys=("left", "right"), left=None) -> None:
    """Rewrite scan.yaml's eyes as flow mappings ``<key>: {hint: [...]}``, numbers written by ``fmt``;
    ``left`` replaces the left hint's text."""
    _, _, hints = head_mesh()
    text = (f / "scan.yaml").read_text().split("eyes:")[0]
    h = {k: ", ".join(fmt(float(x)) for x in v) for k, v in hints.items()}
    if left is not None:
        h["left"] = left
    lines = [f"  {key}: {{hint: [{h[side]}]}}" for key, side in zip(keys, ("left", "right"))]
    (f / "scan.yaml").write_text(text + "eyes:\n" + "\n".join(lines) + "\nlicence: CC0\n")


def c_yaml_duplicate_nested_key(f, t):
    sidecar_eyes(f, keys=("left", "left"))


def c_yaml_hint_huge_integer(f, t):
    sidecar_eyes(f, left="1" + "0" * 400 + ", 35.0, 80.0")


def c_yaml_bad_explicit_tag(f, t):
    text = (f / "scan.yaml").read_text()
    (f / "scan.yaml").write_text(text.replace("units: mm", "units: !!int mm"))


def c_licence_nul(f, t):
    edit_yaml(f, licence="CC-BY 4.0\0 all rights reserved")


def c_licence_escape(f, t):
    edit_yaml(f, licence="CC0 \x1b[31mred\x1b[0m")


def c_mesh_symlinked_folder(f, t):
    (t / "elsewhere").mkdir()
    shutil.copy(f / "scan.ply", t / "elsewhere" / "scan.ply")
    os.symlink(t / "elsewhere", f / "sub")
    edit_yaml(f, mesh="sub/scan.ply")


def c_mesh_symlink_dev_zero(f, t):
    os.symlink("/dev/zero", f / "zero.ply")
    edit_yaml(f, mesh="zero.ply")


def c_texture_symlink_outside(f, t):
    V, F, hints = head_mesh(3)
    write_ply(f / "scan.ply", V, F, uv=sphere_uv(V))
    write_png(t / "secret.png")
    os.symlink(t / "secret.png", f / "skin.png")
    write_sidecar(f, hints, texture="skin.png")


def c_mesh_fifo(f, t):
    (f / "scan.ply").unlink()
    os.mkfifo(f / "scan.ply")


def c_sidecar_fifo(f, t):
    (f / "scan.yaml").unlink()
    os.mkfifo(f / "scan.yaml")


def c_texture_fifo(f, t):
    V, F, hints = head_mesh(3)
    write_ply(f / "scan.ply", V, F, uv=sphere_uv(V))
    os.mkfifo(f / "skin.png")
    write_sidecar(f, hints, texture="skin.png")


def c_mtllib_fifo(f, t):
    V, F, hints = head_mesh(3)
    write_obj(f / "scan.obj", V, F, UV=sphere_uv(V), FUV=F, mtl="scan.mtl")
    os.mkfifo(f / "scan.mtl")
    write_sidecar(f, hints, mesh="scan.obj")


def c_mtl_data_uri(f, t):
    V, F, hints = head_mesh(3)
    write_obj(f / "scan.obj", V, F, UV=sphere_uv(V), FUV=F, mtl="scan.mtl")
    (f / "scan.mtl").write_text("newmtl skin\nmap_Kd data:image/png;base64," + "A" * 10000 + "\n")
    write_sidecar(f, hints, mesh="scan.obj")


def c_mtl_name_too_long(f, t):
    V, F, hints = head_mesh(3)
    write_obj(f / "scan.obj", V, F, UV=sphere_uv(V), FUV=F, mtl="scan.mtl")
    (f / "scan.mtl").write_text("newmtl skin\nmap_Kd " + "a" * 5000 + ".png\n")
    write_sidecar(f, hints, mesh="scan.obj")


def c_tiff_samples_per_pixel(f, t):
    """A TIFF claiming 40 samples per pixel: PIL logs an error before refusing it; only our line shows."""
    from PIL import Image

    V, F, hints = head_mesh(3)
    write_ply(f / "scan.ply", V, F, uv=sphere_uv(V))
    Image.new("RGB", (8, 8)).save(f / "skin.tif", compression=None)
    data = (f / "skin.tif").read_bytes()
    entry = struct.pack("<HHIH", 277, 3, 1, 3)              # SamplesPerPixel = 3 (SHORT)
    (f / "skin.tif").write_bytes(data.replace(entry, struct.pack("<HHIH", 277, 3, 1, 40), 1))
    write_sidecar(f, hints, texture="skin.tif")


def c_mtl_texture_header_bomb(f, t):
    V, F, hints = head_mesh(3)
    write_obj(f / "scan.obj", V, F, UV=sphere_uv(V), FUV=F, mtl="scan.mtl")
    (f / "scan.mtl").write_text("newmtl skin\nmap_Kd bomb.png\n")
    png_header_only(f / "bomb.png", 100_000, 100_000)
    write_sidecar(f, hints, mesh="scan.obj")


def c_texture_data_uri(f, t):
    edit_yaml(f, texture="data:image/png;base64,iVBORw0KGgo=")


@dataclass(frozen=True)
class Case:
    """A hostile scan folder: ``build(folder, tmp) -> params or None`` edits a good scan folder;
    the refusal must name ``fname`` and contain ``problem``."""

    build: object
    fname: str
    problem: str

    @property
    def name(self) -> str:
        return self.build.__name__.removeprefix("c_")


CASES = [
    Case(c_glb_accessor_1e9_no_view, "scan.glb", "accessor 0 has no bufferView (count 1000000000)"),
    Case(c_glb_accessor_past_view, "scan.glb", "accessor 0 claims 1000000000 elements"),
    Case(c_glb_view_past_buffer, "scan.glb", "bufferView 1 reads bytes"),
    Case(c_glb_buffer_past_chunk, "scan.glb", "buffer 0 claims 8589934592 bytes"),
    Case(c_glb_sparse_accessor, "scan.glb", "accessor 0 is sparse"),
    Case(c_glb_bad_component_type, "scan.glb", "accessor 1 has an invalid componentType"),
    Case(c_glb_data_uri_buffer, "scan.glb", "buffer 0 refers to a data: URI"),
    Case(c_glb_data_uri_image, "scan.glb", "image 0 refers to a data: URI"),
    Case(c_glb_external_image, "scan.glb", "image 0 refers to an external URI"),
    Case(_instanced(10_000), "scan.glb", "6420000 vertices once 10000 node instances of 1 mesh are expanded"),
    Case(_instanced(30_000), "scan.glb", "19260000 vertices once 30000 node instances"),
    Case(c_glb_textured_no_uv_rows, "scan.glb", "texture coordinate indices out of range"),
    Case(c_glb_many_meshes, "scan.glb", "12840000 vertices, over the limit of 5000000"),
    Case(c_glb_node_cycle, "scan.glb", "is in a cycle"),
    Case(c_glb_node_two_parents, "scan.glb", "has more than one parent"),
    Case(c_glb_deep_json, "scan.glb", "JSON chunk is invalid"),
    Case(c_glb_json_over_limit, "scan.glb", "GLB JSON chunk is 1.98 MiB, over the limit of 1 MiB (ingest.max_json_mb)"),
    Case(c_obj_one_endless_line, "scan.obj", "line 1923 is longer than 1048576 bytes"),
    Case(c_glb_image_header_bomb, "scan.glb", "image 0 header claims 100000x100000"),
    Case(c_obj_overflow_index, "scan.obj", f"line 7683: face index {HUGE} is out of range"),
    Case(c_obj_overflow_uv_index, "scan.obj", f"line 2565: face index {HUGE} is out of range"),
    Case(c_obj_blank_padded_over_limit, "scan.obj", "5120 faces, over the limit of 1000"),
    Case(c_obj_comment_padded_over_limit, "scan.obj", "2562 vertices, over the limit of 1000"),
    Case(c_obj_huge_coordinates, "scan.obj", "not a plausible head"),
    Case(c_ply_ascii_overflow_index, "scan.ply", f"line 652: PLY data row (face 0) cannot be parsed: '3 {HUGE} "),
    Case(c_ply_header_1e9_vertices, "scan.ply", "1000000000 vertices, over the limit"),
    Case(c_ply_binary_list_2e31, "scan.ply", "PLY data is shorter than its header says (element 'face'"),
    Case(c_ply_binary_list_negative, "scan.ply", "PLY face 1 has a list of negative length -5"),
    Case(c_stl_header_over_limit, "scan.stl", "20000000 faces, over the limit of 10000000"),
    Case(c_stl_ascii_over_limit, "scan.stl", "5120 faces, over the limit of 1000"),
    Case(c_stl_header_lies, "scan.stl", "header says 1000000 triangles"),
    Case(c_yaml_duplicate_key, "scan.yaml", "duplicate key 'units'"),
    Case(c_yaml_duplicate_nested_key, "scan.yaml", "duplicate key 'left'"),
    Case(c_yaml_hint_huge_integer, "scan.yaml", "eyes.left.hint [10000000"),
    Case(c_yaml_bad_explicit_tag, "scan.yaml", "YAML error: a tagged value cannot be read (invalid literal for int()"),
    Case(c_licence_nul, "scan.yaml", "licence contains a control character (U+0000)"),
    Case(c_licence_escape, "scan.yaml", "licence contains a control character (U+001B)"),
    Case(c_mesh_symlinked_folder, "scan.yaml", "resolves outside the scan folder"),
    Case(c_mesh_symlink_dev_zero, "scan.yaml", "resolves outside the scan folder"),
    Case(c_texture_symlink_outside, "scan.yaml", "texture path 'skin.png' resolves outside the scan folder"),
    Case(c_mesh_fifo, "scan.ply", "mesh is not a regular file"),
    Case(c_sidecar_fifo, "scan.yaml", "is not a regular file"),
    Case(c_texture_fifo, "skin.png", "texture is not a regular file"),
    Case(c_mtllib_fifo, "scan.mtl", "mtllib is not a regular file"),
    Case(c_mtl_data_uri, "scan.mtl", "map_Kd is a data: URI"),
    Case(c_mtl_name_too_long, "scan.mtl", "cannot be used: File name too long"),
    Case(c_tiff_samples_per_pixel, "skin.tif", "texture cannot be opened"),
    Case(c_mtl_texture_header_bomb, "bomb.png", "texture is over the limit of 67108864 pixels"),
    Case(c_texture_data_uri, "scan.yaml", "texture is a data: URI"),
]


# ---------------------------------------------------------------------------- accepted (within the limits)

def a_obj_blank_padded(f, t):
    """A valid OBJ followed by 20 MiB of blank lines: memory follows the data, not the file."""
    padded_obj(f, b"\n" * (20 << 20))


def a_obj_mixed_polygons_relative_indices_comments(f, t):
    """Quads among triangles, negative (relative) indices, trailing comments: all in the vectorised reader."""
    V, F, hints = head_mesh()
    n = len(V)
    faces = [f"f {a - n} {b - n} {c - n} {c - n} # quad" for a, b, c in F[:500]]   # a zero-area half each
    faces += [f"f {a - n} {b - n} {c - n}" for a, b, c in F[500:]]
    (f / "scan.obj").write_text("\n".join([f"v {x!r} {y!r} {z!r}" for x, y, z in V.tolist()] + faces) + "\n")
    write_sidecar(f, hints, mesh="scan.obj")


def a_ply_binary_mixed_polygons(f, t):
    """Binary PLY with quads among triangles (lists of varying length)."""
    V, F, hints = head_mesh()
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    quads = b"".join(struct.pack("<B4i", 4, a, b, c, c) for a, b, c in F[:500].tolist())
    tris = np.zeros(len(F) - 500, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    tris["n"], tris["i"] = 3, F[500:]
    (f / "scan.ply").write_bytes(head.encode() + V.astype("<f4").tobytes() + quads + tris.tobytes())


def a_ply_ascii_blank_padded(f, t):
    V, F, hints = head_mesh()
    write_ply(f / "scan.ply", V, F, binary=False)
    with open(f / "scan.ply", "ab") as fh:
        fh.write(b"\n" * (20 << 20))


def a_yaml12_float_hint(f, t):
    sidecar_eyes(f, fmt=lambda x: f"{x / 10:.17g}e1")          # 3.45e1: YAML 1.1 reads text


def a_zero_area_faces_near_eyes(f, t):
    """9 % of each eye region's faces are zero-area extras: removed as a safe repair."""
    V, F, hints = head_mesh()
    extra = []
    for h in hints.values():
        near = np.flatnonzero(np.linalg.norm(V - h, axis=1) <= 20.0)
        k = int(0.09 * np.count_nonzero(np.isin(F, near).any(axis=1))) + 1
        extra.append(np.stack([near[:k], near[1:k + 1], near[1:k + 1]], axis=1))   # repeated corner: no area
    write_ply(f / "scan.ply", V, np.vstack([F, *extra]))


def a_stl_soup_over_vertex_limit(f, t):
    """An STL soup has 3 vertices per triangle; the vertex limit applies once they are merged."""
    import trimesh

    V, F, hints = head_mesh()
    trimesh.Trimesh(V, F, process=False).export(f / "scan.stl")
    write_sidecar(f, hints, mesh="scan.stl")
    return {"max_vertices": 3000}                # 15360 soup vertices, 2562 merged


def a_stl_ascii(f, t):
    ascii_stl(f)


def a_licence_newlines_tabs(f, t):
    edit_yaml(f, licence="CC-BY 4.0\n\tattribution: eyerig tests")


ACCEPTED = [a_obj_blank_padded, a_obj_mixed_polygons_relative_indices_comments, a_ply_binary_mixed_polygons,
            a_ply_ascii_blank_padded, a_yaml12_float_hint, a_zero_area_faces_near_eyes,
            a_stl_soup_over_vertex_limit, a_stl_ascii, a_licence_newlines_tabs]


# ---------------------------------------------------------------------------- running

@dataclass
class Run:
    """One ingest subprocess: exit status, stderr, wall and CPU seconds, the child's peak RSS (MiB)."""

    returncode: int
    stderr: str
    stdout: str
    wall_s: float
    cpu_s: float
    peak_mib: float


def build_case(build, tmp: Path):
    """A good scan folder ``tmp/scan`` edited by ``build``; returns (folder, params path or None)."""
    folder = tmp / "scan"
    make_scan(folder)
    params = build(folder, tmp)
    if not params:
        return folder, None
    path = tmp / "params.yaml"
    path.write_text(yaml.safe_dump({"ingest": params}))
    return folder, path


# Runs the stage as a grandchild and reports its own rusage: a child spawned straight from this
# (large) process starts with this process's RSS high-water mark in its ru_maxrss (vfork/fork + exec
# keep the signal struct's maxrss), so its peak could not be told from ours.
_WRAPPER = """
import json, os, resource, sys
fd, cap, cpu = (int(x) for x in sys.argv[1:4])
resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu))
pid = os.fork()
if pid == 0:
    os.close(fd)
    os.execv(sys.executable, [sys.executable] + sys.argv[4:])
_, status, ru = os.wait4(pid, 0)
os.write(fd, json.dumps([os.waitstatus_to_exitcode(status), ru.ru_maxrss, ru.ru_utime + ru.ru_stime]).encode())
"""


def run_ingest(folder, out, params=None, cap_mib: float = 1536, cpu_s: int = 60, wall_s: float = 120) -> Run:
    """``python -m stages.ingest folder out`` under an address-space cap, a CPU-time cap and a wall-time
    limit (a stage blocked on a FIFO uses no CPU; it is killed and reported with exit -9 and stderr
    ``timeout``), with its wall time, CPU time and its own peak RSS."""
    r, w = os.pipe()
    cmd = [sys.executable, "-c", _WRAPPER, str(w), str(int(cap_mib * 2**20)), str(cpu_s),
           "-m", "stages.ingest", str(folder), str(out)]
    if params is not None:
        cmd += ["--params", str(params)]
    with tempfile.TemporaryFile() as err, tempfile.TemporaryFile() as so:
        t0 = time.perf_counter()
        with os.fdopen(r, "rb") as report:
            proc = subprocess.Popen(cmd, cwd=ROOT, stdout=so, stderr=err, stdin=subprocess.DEVNULL,
                                    pass_fds=(w,), start_new_session=True)
            os.close(w)
            try:
                proc.wait(timeout=wall_s)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                return Run(-9, "timeout", "", time.perf_counter() - t0, float("nan"), float("nan"))
            code, maxrss_kib, cpu = json.loads(report.read() or b"[null, 0, 0]")
        wall = time.perf_counter() - t0
        err.seek(0)
        so.seek(0)
        code = proc.returncode if code is None else code
        return Run(code, err.read().decode(errors="replace"), so.read().decode(errors="replace"),
                   wall, cpu, maxrss_kib / 1024.0)


def glb_scan(folder: Path, rows: int, cols: int) -> Path:
    """The bench_ingest lat/long head as a one-mesh GLB (float32 positions and UVs, uint32 indices); cached."""
    from benchmarks.bench_ingest import latlong_head

    if (folder / "scan.yaml").exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    V, F, UV, hints = latlong_head(rows, cols)
    parts = [V.astype("<f4").tobytes(), F.astype("<u4").tobytes(), UV.astype("<f4").tobytes()]
    offsets = np.cumsum([0] + [len(p) for p in parts])
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "indices": 1}]}],
           "buffers": [{"byteLength": int(offsets[-1])}],
           "bufferViews": [{"buffer": 0, "byteOffset": int(o), "byteLength": len(p)} for o, p in zip(offsets, parts)],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(V), "type": "VEC3",
                          "min": V.min(axis=0).tolist(), "max": V.max(axis=0).tolist()},
                         {"bufferView": 1, "componentType": 5125, "count": F.size, "type": "SCALAR"},
                         {"bufferView": 2, "componentType": 5126, "count": len(V), "type": "VEC2"}]}
    (folder / "scan.glb").write_bytes(glb_bytes(doc, b"".join(parts)))
    write_sidecar(folder, hints, mesh="scan.glb")
    return folder


def stl_scan(folder: Path, rows: int, cols: int) -> Path:
    """The bench_ingest lat/long head as a binary STL (a triangle soup); cached."""
    from benchmarks.bench_ingest import latlong_head

    if (folder / "scan.yaml").exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    V, F, _, hints = latlong_head(rows, cols)
    records = np.zeros(len(F), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    records["corners"] = V[F]
    with open(folder / "scan.stl", "wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", len(F)))
        fh.write(records.tobytes())
    write_sidecar(folder, hints, mesh="scan.stl")
    return folder


def at_limits(fmt: str) -> dict:
    """Ingest the largest head the default limits accept (cached bench_ingest folders); one result row."""
    from benchmarks.bench_ingest import build_obj_scan, build_scan

    rows_, cols = 2500, 2000                     # 2 * 2000 * 2499 = 9,996,000 triangles
    work = Path(tempfile.gettempdir()) / "eyerig_bench_ingest"
    if fmt in ("glb", "stl"):
        folder = (glb_scan if fmt == "glb" else stl_scan)(work / f"head_{rows_}x{cols}_{fmt}", rows_, cols)
    else:
        folder = build_scan(work / f"head_{rows_}x{cols}", rows_, cols)
    if fmt == "obj":
        folder = build_obj_scan(work / f"head_{rows_}x{cols}_obj", folder, rows_, cols)
    size = sum(p.stat().st_size for p in folder.iterdir())
    with tempfile.TemporaryDirectory(prefix="hostile-") as tmp:
        r = run_ingest(folder, Path(tmp) / "out", cap_mib=1 << 20, cpu_s=600)
        faces = json.loads((Path(tmp) / "out.metrics.json").read_text())["faces_in"] if r.returncode == 0 else None
    print(f"{'at_limits_' + fmt:34s} accepted exit {r.returncode}  {r.wall_s:6.2f} s  {r.peak_mib:7.1f} MiB", flush=True)
    return {"case": f"at_limits_{fmt}", "expect": "accepted", "ok": r.returncode == 0,
            "within_targets": r.peak_mib <= ACCEPT_PEAK_MIB, "folder_mib": round(size / 2**20, 2),
            "faces": faces, "exit": r.returncode, "wall_s": round(r.wall_s, 3), "cpu_s": round(r.cpu_s, 3),
            "peak_mib": round(r.peak_mib, 1), "stderr": r.stderr.strip()[:300]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "hostile.json"))
    ap.add_argument("--cap-mib", type=float, default=1536, help="address-space cap of each ingest child")
    ap.add_argument("--at-limits", action="store_true", help="also ingest a 10M-triangle PLY, OBJ, GLB and STL")
    args = ap.parse_args(argv)
    rows = []
    todo = [(c.name, c.build, "refused") for c in CASES] + [(a.__name__[2:], a, "accepted") for a in ACCEPTED]
    if args.at_limits:
        rows += [at_limits(fmt) for fmt in ("ply", "obj", "glb", "stl")]
    for name, build, expect in todo:
        with tempfile.TemporaryDirectory(prefix="hostile-") as tmp:
            tmp = Path(tmp)
            folder, params = build_case(build, tmp)
            size = sum(p.stat().st_size for p in folder.iterdir() if p.is_file() and not p.is_symlink())
            r = run_ingest(folder, tmp / "out", params, cap_mib=args.cap_mib)
            ok = (r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
                  and not (tmp / "out").exists()) if expect == "refused" else r.returncode == 0
            within = (r.wall_s <= REFUSE_WALL_S and r.peak_mib <= REFUSE_PEAK_MIB) if expect == "refused" \
                else r.peak_mib <= ACCEPT_PEAK_MIB
        rows.append({"case": name, "expect": expect, "ok": ok, "within_targets": within,
                     "folder_mib": round(size / 2**20, 2), "exit": r.returncode, "wall_s": round(r.wall_s, 3),
                     "cpu_s": round(r.cpu_s, 3), "peak_mib": round(r.peak_mib, 1),
                     "stderr": r.stderr.strip()[:300]})
        print(f"{name:34s} {expect:8s} exit {r.returncode}  {r.wall_s:6.2f} s  {r.peak_mib:7.1f} MiB"
              f"  {'ok' if ok and within else 'FAIL'}", flush=True)
    result = {
        "what": "python -m stages.ingest on hostile scan folders (built from the conftest test head); "
                "peak = the child's own ru_maxrss (os.wait4)",
        "command": ".venv/bin/python -m benchmarks.bench_hostile",
        "targets": {"refused_wall_s": REFUSE_WALL_S, "refused_peak_mib": REFUSE_PEAK_MIB,
                    "accepted_peak_mib": ACCEPT_PEAK_MIB},
        "address_space_cap_mib": args.cap_mib,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "all_ok": all(r["ok"] and r["within_targets"] for r in rows),
        "max_refused_wall_s": max(r["wall_s"] for r in rows if r["expect"] == "refused"),
        "max_refused_peak_mib": max(r["peak_mib"] for r in rows if r["expect"] == "refused"),
        "max_accepted_peak_mib": max(r["peak_mib"] for r in rows if r["expect"] == "accepted"),
        "cases": rows,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}: all ok {result['all_ok']}, refused max {result['max_refused_wall_s']} s / "
          f"{result['max_refused_peak_mib']} MiB, accepted max {result['max_accepted_peak_mib']} MiB")


if __name__ == "__main__":
    main()
