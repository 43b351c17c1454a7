"""The bake product (``build/<scan>/bake/``): the UV'd mesh and the baked maps, one writer, one reader.

Written by the ``bake`` stage; ``snap`` reads its ``mesh.npz`` (pipeline/io/meshfile.py),
``usd`` the maps (copied into the asset's ``textures/``), and ``render`` the displacement map
of the asset (:func:`read_displacement`). Files::

    mesh.npz                  the low-poly mesh with UV/FUV (origin bottom-left), loops
    displacement.exr          (res, res) float32, channel Y, mm along the normal, + outward
    displacement_preview.png  16-bit: value_mm = offset + scale * pixel
    color.png                 (res, res, 3) sRGB (flat grey without a scan colour)
    bake.json                 {"schema": 1, "resolution": res,
                               "displacement": {"file", "channel", "units", "meaning",
                                                "falloff_mm_at_eyelid_loops"},
                               "preview": {"file", "bits",
                                           "value_mm = offset + scale * pixel": {"scale", "offset"}},
                               "color": {"file", "source"}, "uv": "..."}

The reader validates ``bake.json`` (schema, every key above, plain file names of files that
exist) and refuses anything else with one line naming the file; :func:`read_displacement`
refuses a map that does not decode to a finite (H, W) image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io import docfile as df
from pipeline.io.atomic import write_json

SCHEMA = 1
BAKE_JSON = "bake.json"
PREVIEW_KEY = "value_mm = offset + scale * pixel"
GREY = 200            # colour map value without a scan colour


@dataclass
class BakeMaps:
    """``bake.json`` of a bake folder, validated, with the paths of its files.

    Attributes
    ----------
    folder : Path
    resolution : int
    displacement : Path          displacement.exr
    color : Path                 color.png
    preview : Path               displacement_preview.png
    preview_scale, preview_offset : float   value_mm = offset + scale * pixel
    mesh : Path                  mesh.npz (read with pipeline.io.meshfile.read_stage_mesh)
    doc : dict                   bake.json as stored
    """

    folder: Path
    resolution: int
    displacement: Path
    color: Path
    preview: Path
    preview_scale: float
    preview_offset: float
    mesh: Path
    doc: dict = field(repr=False)


def write_bake(folder, mesh: dict, displacement, mask, color, *, resolution: int, falloff_mm: float,
               colour_source: str | None) -> None:
    """Write the bake product into an existing (atomic output) folder.

    Parameters
    ----------
    mesh : dict of arrays        for mesh.npz (V, F, UV, FUV, loops, ...)
    displacement : (H, W) float  mm
    mask : (H, W) bool or None   texels covered by the atlas (sets the preview's range)
    color : (H, W, 3) uint8 or None   None: flat grey
    resolution : int
    falloff_mm : float           displacement fade-out distance at the eyelid loops
    colour_source : str or None  where the colour came from (None: no colour)
    """
    from PIL import Image

    from pipeline.io.exr import preview_16bit, write_exr
    from pipeline.io.meshfile import save_mesh

    from concurrent.futures import ThreadPoolExecutor

    folder = Path(folder)
    if color is None:
        color = np.full(np.shape(displacement) + (3,), GREY, dtype=np.uint8)
    # Pillow's PNG encoder releases the GIL: the colour map is encoded in a thread while this
    # one writes the rest (the two 2048² PNGs took 0.38 s one after the other, 0.2 s side by side)
    with ThreadPoolExecutor(1) as pool:
        colour_png = pool.submit(Image.fromarray(color).save, folder / "color.png", compress_level=3)
        q, scale, offset = preview_16bit(displacement, mask)
        save_mesh(folder / "mesh.npz", **mesh)
        write_exr(folder / "displacement.exr", displacement)
        Image.fromarray(q).save(folder / "displacement_preview.png", compress_level=3)
        colour_png.result()
    write_json(folder / BAKE_JSON, {
        "schema": SCHEMA,
        "resolution": resolution,
        "displacement": {"file": "displacement.exr", "channel": "Y", "units": "mm",
                         "meaning": "signed distance along the interpolated vertex normal of the "
                                    "flat (midpoint-subdivided) low-poly surface; positive = outward",
                         "falloff_mm_at_eyelid_loops": falloff_mm},
        "preview": {"file": "displacement_preview.png", "bits": 16,
                    PREVIEW_KEY: {"scale": scale, "offset": offset}},
        "color": {"file": "color.png", "source": colour_source or "none (flat grey)"},
        "uv": "mesh.npz UV/FUV, origin bottom-left; image rows top-down",
    })


def read_bake(folder) -> BakeMaps:
    """The bake product in ``folder`` (``build/<scan>/bake``), validated.

    Raises
    ------
    ScanError
        One line naming bake.json (or a file it names): missing, another schema, a missing or
        mistyped key, a file name with a folder part, a named file that does not exist.
    """
    folder = Path(folder)
    path = folder / BAKE_JSON
    doc = df.read_json_doc(path, BAKE_JSON, SCHEMA, "bake")
    res = df.field(doc, "resolution", path, int)
    if res <= 0:
        raise ScanError(path, f"resolution must be > 0 (got {res})")
    if df.field(doc, "displacement.units", path, str) != "mm":
        raise ScanError(path, "displacement.units must be \"mm\"")
    df.field(doc, "displacement.channel", path, str)
    df.number(doc, "displacement.falloff_mm_at_eyelid_loops", path)
    scale = df.number(doc, f"preview.{PREVIEW_KEY}.scale", path, low=0.0)
    offset = df.number(doc, f"preview.{PREVIEW_KEY}.offset", path)
    mesh = folder / "mesh.npz"
    if not mesh.is_file():
        raise ScanError(mesh, "not found")
    return BakeMaps(folder=folder, resolution=res,
                    displacement=df.plain_name(doc, "displacement.file", path, folder),
                    color=df.plain_name(doc, "color.file", path, folder),
                    preview=df.plain_name(doc, "preview.file", path, folder),
                    preview_scale=scale, preview_offset=offset, mesh=mesh, doc=doc)


def read_displacement(path, channel: str = "Y") -> np.ndarray:
    """A displacement map (bake's displacement.exr, or the asset's copy) as (H, W) float32 mm.

    Raises
    ------
    ScanError
        Missing, not decodable, no such channel, not 2-D, or non-finite texels.
    """
    from pipeline.io.exr import read_exr_product

    path = Path(path)
    d = read_exr_product(path, channel, "cannot read displacement map")
    if d.ndim != 2 or d.size == 0:
        raise ScanError(path, f"displacement map must be one (H, W) channel (got shape {d.shape})")
    if not np.isfinite(d).all():
        raise ScanError(path, "displacement map has non-finite texels")
    return d
