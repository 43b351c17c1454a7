"""Self-contained binary glTF (GLB) reader: all meshes with their node transforms, one texture.

Before trimesh decodes anything, the JSON chunk's size and every buffer view, accessor (count x
type against the bytes it reads), node hierarchy (a tree) and the vertices/faces of every node
instance are checked (:func:`_glb_check_doc`), and every embedded image's format is checked from
its first bytes (PNG, JPEG or TIFF only, :mod:`pipeline.io.formats.image`) and its pixel count read
from its header (decompression bombs). External or data: URIs are refused.
"""

from __future__ import annotations

import io
import json
import struct
import warnings
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.formats.common import Limits, LoadedMesh, check_counts, check_file_size, max_pixels
from pipeline.io.formats.image import sniff_texture
from pipeline.io.scan import one_line, short_repr


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
        fmt = sniff_texture(data, path, f"GLB image {i}")   # before trimesh hands it to Pillow
        try:
            with max_pixels(2**62):
                w, h = Image.open(io.BytesIO(data), formats=[fmt]).size  # header only
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
            with max_pixels(limits.max_texture_pixels):
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
    check_counts(path, len(V), len(F), limits)
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
