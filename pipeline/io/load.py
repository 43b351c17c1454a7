"""Mesh and texture loading for untrusted scan files (OBJ+MTL, PLY, STL, GLB).

Every loader returns a :class:`LoadedMesh` in the file's own units and axes and
raises :class:`pipeline.errors.ScanError` (naming the file and the problem) for
anything it cannot read. Limits are checked before memory is spent: file size;
element counts in PLY/STL headers (the STL triangle count; its soup vertices are
limited once merged); ``v``/``f`` line counts of an OBJ before any line is parsed;
a GLB's JSON size, and every buffer view, accessor (count x type against the bytes
it reads), node hierarchy (a tree) and the vertices/faces of every node instance
(:func:`pipeline.io.formats.glb._glb_check_doc`) before trimesh decodes anything; image pixel counts from
the image header before decoding (decompression bombs). Textures are decoded only when their
first bytes say PNG, JPEG or TIFF (:mod:`pipeline.io.formats.image`).

Text readers keep memory proportional to the data, not the file: OBJ, ASCII PLY and
MTL are read in chunks with blank (and OBJ/MTL comment) lines dropped without a
Python object per line, lines over :data:`pipeline.io.formats.common.MAX_LINE_BYTES` are refused, and ASCII
PLY stops at the rows its header announces.

UVs are kept per corner (``UV`` + ``FUV``): OBJ seams keep their exact layout
(one ``UV`` row per ``vt`` line, the vertex positions are not split, unlike
trimesh's OBJ loader which duplicates seam vertices). PLY per-vertex ``s,t`` /
``u,v`` / ``texture_u,texture_v`` become ``UV`` with ``FUV = F``; PLY per-face
``texcoord`` lists become one ``UV`` row per corner.

Readers, one module per format in :mod:`pipeline.io.formats`: OBJ and PLY (ASCII and
binary) are parsed with numpy (vectorised, polygons of mixed sizes included, with a
row-by-row fallback for the rest that names the offending line); STL and GLB go through
trimesh after the checks above. This module picks the reader by suffix
(:func:`load_mesh_file`) and decodes textures (:func:`load_texture`).
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.formats.common import Limits, LoadedMesh, check_file_size, max_pixels
from pipeline.io.formats.glb import load_glb
from pipeline.io.formats.image import sniff_texture
from pipeline.io.formats.obj import load_obj
from pipeline.io.formats.ply import load_ply
from pipeline.io.formats.stl import load_stl
from pipeline.io.scan import one_line

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
    if not np.isfinite(mesh.V).all():               # one flat pass; the per-row count only to report
        bad = ~np.isfinite(mesh.V).all(axis=1)
        i = int(np.flatnonzero(bad)[0])
        raise ScanError(path, f"{int(bad.sum())} vertices have non-finite coordinates (NaN/inf), first is vertex {i}")
    fmin, fmax = int(mesh.F.min()), int(mesh.F.max())
    if fmin < 0 or fmax >= len(mesh.V):
        worst = fmax if fmax >= len(mesh.V) else fmin
        raise ScanError(path, f"face index {worst} out of range (the mesh has {len(mesh.V)} vertices)")
    if mesh.UV is not None:
        if not np.isfinite(mesh.UV).all():
            raise ScanError(path, "texture coordinates contain NaN or inf")
        if mesh.FUV.shape != mesh.F.shape or (mesh.FUV.size and (
                len(mesh.UV) == 0 or _index_range(mesh.FUV, mesh.F, fmin, fmax, len(mesh.UV)))):
            raise ScanError(path, "texture coordinate indices out of range")
    return mesh


def _index_range(FUV, F, fmin: int, fmax: int, n_uv: int) -> bool:
    """Whether ``FUV`` indexes outside ``[0, n_uv)``; a PLY's per-vertex UVs share ``F``, whose range
    is known already."""
    lo, hi = (fmin, fmax) if FUV is F else (int(FUV.min()), int(FUV.max()))
    return lo < 0 or hi >= n_uv


def load_texture(source, limits: Limits = Limits(), name=None):
    """Open and fully decode a texture image, refusing oversize images before decoding.

    Only PNG, JPEG and TIFF are decoded (:mod:`pipeline.io.formats.image`): the content's magic
    bytes are checked first and Pillow is given that one format, so no other decoder (nor any
    external program, such as Ghostscript for PostScript) ever sees the bytes.

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
    fmt = sniff_texture(data, label)          # PNG, JPEG or TIFF by its magic bytes, before any decoder
    with max_pixels(limits.max_texture_pixels), warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            img = Image.open(io.BytesIO(data), formats=[fmt])  # reads the header only, one plugin
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
