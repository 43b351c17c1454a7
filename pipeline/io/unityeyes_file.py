"""UnityEyes label pairs (``renders/<scan>/unityeyes/NNNNNN.json`` + ``NNNNNN.jpg``): one writer,
one reader.

The document is built by :func:`pipeline.render.formats.unityeyes.unityeyes_document` (its
conventions, and where each comes from, are in that module's docstring): UnityEyes' keys only,
every vector a ``"(x, y, z)"`` string, numbers as strings, so GazeML's loader
(``src/datasources/unityeyes.py``: every ``*.json`` of a folder with the ``.jpg`` of the same
stem) reads the folder unchanged. The image is a JPEG copy of the rendered PNG (UnityEyes saves
``EncodeToJPG``); quality :data:`JPEG_QUALITY`.

:func:`read_unityeyes` parses the strings back (tuples of 3 or 4 numbers, nothing else) and
checks the point counts (16 / 7 / 32) and the keys a consumer uses, refusing anything else with
one line naming the file.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io import docfile as df
from pipeline.io.atomic import write_bytes, write_json

JPEG_QUALITY = 95
COUNTS = {"interior_margin_2d": 16, "caruncle_2d": 7, "iris_2d": 32}
_NUM = r"\s*(-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)\s*"
_TUPLE = {n: re.compile(r"\(" + ",".join([_NUM] * n) + r"\)") for n in (3, 4)}


def unityeyes_names(index: int) -> tuple[str, str]:
    """``(NNNNNN.json, NNNNNN.jpg)``: the pair of image ``index`` in the ``unityeyes/`` folder."""
    return f"{int(index):06d}.json", f"{int(index):06d}.jpg"


def write_unityeyes(folder, index: int, doc: dict, png, mirror: bool = False) -> list[Path]:
    """Write the pair of image ``index`` into ``folder`` (created), each atomically: the JPEG of
    ``png`` (``mirror``: flipped left to right, as ``doc``'s points are for a right eye, since
    UnityEyes renders left eyes only), then the JSON. Returns both paths."""
    from PIL import Image, ImageOps

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    name_json, name_jpg = unityeyes_names(index)
    buf = io.BytesIO()
    with Image.open(png, formats=["PNG"]) as im:     # the render's own PNG
        rgb = im.convert("RGB")
        (ImageOps.mirror(rgb) if mirror else rgb).save(buf, "JPEG", quality=JPEG_QUALITY)
    write_bytes(folder / name_jpg, buf.getvalue())
    write_json(folder / name_json, doc)
    return [folder / name_jpg, folder / name_json]


def parse_tuple(text, n: int, path, key: str) -> np.ndarray:
    """``"(x, y, z)"`` -> (n,) float64 (n = 3 or 4 numbers, nothing else)."""
    m = _TUPLE[n].fullmatch(text.strip()) if isinstance(text, str) else None
    if m is None:
        raise ScanError(path, f"{key} must be a string '(' {n} numbers ')' (got {str(text)[:40]!r})")
    return np.array([float(x) for x in m.groups()])


@dataclass
class UnityEyesLabel:
    """One UnityEyes JSON, parsed.

    Attributes
    ----------
    interior : (16, 3) ; caruncle : (7, 3) ; iris : (32, 3) float64
        Screen points as stored: x from the left, y from the BOTTOM, depth (Unity units).
    look_vec : (4,) float64      Unity camera axes (x right, y up, z away from the camera), w
    head_pose : (3,) float64     the camera's Unity Euler angles, degrees
    doc : dict                   the document as stored
    """

    path: Path
    interior: np.ndarray
    caruncle: np.ndarray
    iris: np.ndarray
    look_vec: np.ndarray
    head_pose: np.ndarray
    doc: dict = field(repr=False)


def read_unityeyes(path) -> UnityEyesLabel:
    """The UnityEyes JSON ``path``, parsed and checked.

    Raises
    ------
    ScanError
        One line naming the file: missing, not JSON, a missing key, a point list of another
        length, a string that is not a tuple of numbers.
    """
    path = Path(path)
    doc = df.read_json_doc(path, "UnityEyes label", None, "render")
    pts = {}
    for key, n in COUNTS.items():
        lst = df.field(doc, key, path, list)
        if len(lst) != n:
            raise ScanError(path, f"{key} must hold {n} points (got {len(lst)})")
        pts[key] = np.stack([parse_tuple(t, 3, path, f"{key}[{i}]") for i, t in enumerate(lst)])
    for key in ("eye_details.pupil_size", "eye_details.iris_size", "lighting_details.skybox_exposure"):
        try:
            float(df.field(doc, key, path, str))
        except ValueError:
            raise ScanError(path, f"{key} must be a number written as a string") from None
    return UnityEyesLabel(path=path, interior=pts["interior_margin_2d"], caruncle=pts["caruncle_2d"],
                          iris=pts["iris_2d"],
                          look_vec=parse_tuple(df.field(doc, "eye_details.look_vec", path, str), 4, path,
                                               "eye_details.look_vec"),
                          head_pose=parse_tuple(df.field(doc, "head_pose", path, str), 3, path, "head_pose"),
                          doc=doc)
