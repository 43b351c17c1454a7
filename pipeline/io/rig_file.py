"""The rig product (``build/<scan>/rig/``): ``rig.npz`` + ``rig.json``, one writer, one reader.

Written by the ``rig`` stage, read by ``usd`` (blend shapes, landmark curves, eyes) and
``render`` (lid shapes, eyelid landmark edges, lid loops), and by tests and benchmarks.

``rig.json`` (schema :data:`SCHEMA`)::

    {"schema": 1,
     "weight_rule": {"max_pitch_deg": 25.0, "formula": ..., ...},
     "eyes": {"left": {"center": [x, y, z], "radius": r, "forward": [x, y, z],
                       "surface": "sphere" | {"parametric_eye": {"r1": ..., ...}},
                       "joint": "eye_left", ...},
              "right": {...}},
     "shapes": [...], "landmarks": {...}, "npz_layout": {...}, ...}

``rig.npz`` (layout in ``rig.json["npz_layout"]``, conversions in
:func:`pipeline.io.blend_shapes.shapes_to_arrays`): ``shape_names`` and per shape
``<name>.point_indices/.offsets/.inbetween_weights/.inbetween_offsets``; per eye
``landmarks.<side>.points`` (12, 3), optional ``landmarks.<side>.edge`` (12, 2) and
``.t`` (12,), the landmark curve's shapes under the ``landmarks.<side>.`` prefix, and
optional ``loop_<side>`` (L,). The schema number lives in rig.json only (rig.npz is the
arrays of the same product, read through the same reader).

Every reader validates and refuses anything else with one line naming the file: another
schema, a missing key or array, a wrong type or shape, non-finite values, indices outside
the mesh the rig belongs to. Keys it does not know are carried unchanged (``doc``, ``arrays``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io import docfile as df
from pipeline.io.atomic import write_json
from pipeline.io.blend_shapes import shapes_from_arrays
from pipeline.io.eyes_file import Eye

SCHEMA = 1
SIDES = ("left", "right")
RIG_JSON, RIG_NPZ = "rig.json", "rig.npz"
N_EYELID = 12


@dataclass
class RigArrays:
    """``rig.npz``, validated.

    Attributes
    ----------
    path : Path
    arrays : dict of str -> ndarray     every array as stored
    shapes : list of pipeline.io.blend_shapes.BlendShape   the lid shapes
    curves : dict side -> (points (12, 3) float64, list of BlendShape)   eyelid landmark curves
    """

    path: Path
    arrays: dict = field(repr=False)
    shapes: list = field(repr=False)
    curves: dict = field(repr=False)


@dataclass
class Rig:
    """The whole rig product: ``rig.json`` (``doc``, ``eyes``, ``max_pitch_deg``) and
    ``rig.npz`` (``npz``). ``eyes``: side -> :class:`pipeline.io.eyes_file.Eye`, read from
    ``rig.json["eyes"]`` (the rig's keys in ``extra``; ``model_radius`` from its surface)."""

    folder: Path
    doc: dict = field(repr=False)
    eyes: dict
    max_pitch_deg: float
    npz: RigArrays = field(repr=False)

    @property
    def json_path(self) -> Path:
        return self.folder / RIG_JSON

    @property
    def npz_path(self) -> Path:
        return self.folder / RIG_NPZ


def write_rig(folder, arrays: dict, doc: dict) -> None:
    """Write ``folder/rig.npz`` (``arrays``, uncompressed) and ``folder/rig.json`` (``doc``
    with the schema number) into an existing folder (the stage's atomic output folder)."""
    folder = Path(folder)
    with open(folder / RIG_NPZ, "wb") as fh:
        np.savez(fh, **arrays)
    write_json(folder / RIG_JSON, {"schema": SCHEMA, **doc})


def _shapes(arrays: dict, path: Path, prefix: str, n_points: int | None, against: str):
    """The blend shapes stored under ``prefix``, each array checked as stored (dtype, shape)."""
    what = "lid" if not prefix else prefix.rstrip(".")
    key = f"{prefix}shape_names"
    if key not in arrays:
        raise ScanError(path, f"missing {what} shape array {key!r}")
    names = arrays[key]
    if names.ndim != 1 or names.dtype.kind != "U":
        raise ScanError(path, f"{key} must be a (n,) array of names")
    for name in names:
        pre = f"{prefix}{name}"
        missing = [k for k in ("point_indices", "offsets", "inbetween_weights", "inbetween_offsets")
                   if f"{pre}.{k}" not in arrays]
        if missing:
            raise ScanError(path, f"missing {what} shape array '{pre}.{missing[0]}'")
        pi = df.check_array(arrays[f"{pre}.point_indices"], (None,), path, f"{pre}.point_indices", "i")
        k = len(pi)
        df.check_array(arrays[f"{pre}.offsets"], (k, 3), path, f"{pre}.offsets")
        w = df.check_array(arrays[f"{pre}.inbetween_weights"], (None,), path, f"{pre}.inbetween_weights")
        df.check_array(arrays[f"{pre}.inbetween_offsets"], (len(w), k, 3), path, f"{pre}.inbetween_offsets")
        if np.any((w <= 0) | (w >= 1)) or np.any(np.diff(w) <= 0):
            raise ScanError(path, f"{pre}.inbetween_weights must increase inside (0, 1)")
        df.indices_within(pi, n_points, path, f"shape {pre}", against)
    return shapes_from_arrays(arrays, prefix=prefix)


def read_rig_arrays(path, n_vertices: int | None = None, against: str = "the mesh") -> RigArrays:
    """``rig.npz`` (a file, or the rig folder holding it), validated.

    Parameters
    ----------
    path : str or os.PathLike
    n_vertices : int, optional
        Vertex count of the mesh the rig deforms (the snapped mesh, the asset's skin): shape,
        landmark-edge and loop indices must be below it.
    against : str
        How messages name that mesh.

    Raises
    ------
    ScanError
        One line naming the file: missing, unreadable, a missing array, a wrong shape or
        dtype, non-finite values, indices outside the mesh.
    """
    path = Path(path)
    if path.suffix != ".npz":
        path = path / RIG_NPZ
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 -- corrupt zip / npy: whatever numpy raises
        raise ScanError(path, f"cannot be read as a rig .npz ({type(exc).__name__})") from None
    shapes = _shapes(arrays, path, "", n_vertices, against)
    curves = {}
    for side in SIDES:
        pre = f"landmarks.{side}."
        if pre + "points" not in arrays:
            raise ScanError(path, f"no eyelid landmarks for the {side} eye ({pre}points)")
        pts = df.check_array(arrays[pre + "points"], (N_EYELID, 3), path, pre + "points")
        curves[side] = (pts, _shapes(arrays, path, pre, N_EYELID, "the 12 landmarks"))
        if pre + "edge" in arrays:
            edge = df.check_array(arrays[pre + "edge"], (N_EYELID, 2), path, pre + "edge", "i")
            df.indices_within(edge, n_vertices, path, pre + "edge", against)
            t = df.check_array(arrays.get(pre + "t"), (N_EYELID,), path, pre + "t")
            if np.any((t < 0) | (t > 1)):
                raise ScanError(path, f"{pre}t must lie in [0, 1]")
        if f"loop_{side}" in arrays:
            loop = df.check_array(arrays[f"loop_{side}"], (None,), path, f"loop_{side}", "i")
            if len(loop) < 3:
                raise ScanError(path, f"loop_{side} must be at least 3 vertex indices")
            df.indices_within(loop, n_vertices, path, f"loop_{side}", against)
    return RigArrays(path=path, arrays=arrays, shapes=shapes, curves=curves)


def _eye(doc: dict, side: str, path: Path) -> Eye:
    # rig.json's own checks first, so its messages name the key path (eyes.<side>.<key>);
    # Eye.from_doc then reads the entry as it reads an eyes.json one (rig's keys in ``extra``)
    pre = f"eyes.{side}"
    e = df.field(doc, pre, path, dict)
    df.array_field(doc, pre + ".center", (3,), path)
    forward = df.array_field(doc, pre + ".forward", (3,), path)
    if np.linalg.norm(forward) < 1e-9:
        raise ScanError(path, f"{pre}.forward is the zero vector")
    df.number(doc, pre + ".radius", path, low=0.0, high=100.0)
    surface = e.get("surface", "sphere")
    if isinstance(surface, dict) and "parametric_eye" in surface:
        df.number(doc, pre + ".surface.parametric_eye.r1", path, low=0.0)
    elif surface != "sphere":
        raise ScanError(path, f"{pre}.surface must be \"sphere\" or {{\"parametric_eye\": {{...}}}}")
    return Eye.from_doc(side, e, path)


def read_rig(folder, n_vertices: int | None = None, against: str = "the mesh") -> Rig:
    """The rig product in ``folder`` (``build/<scan>/rig``, or its rig.npz / rig.json),
    validated; see :func:`read_rig_arrays` for ``n_vertices`` and ``against``.

    Raises
    ------
    ScanError
        One line naming rig.json or rig.npz and the problem.
    """
    folder = Path(folder)
    if folder.suffix in (".npz", ".json"):
        folder = folder.parent
    path = folder / RIG_JSON
    doc = df.read_json_doc(path, RIG_JSON, SCHEMA, "rig")
    max_pitch = df.number(doc, "weight_rule.max_pitch_deg", path, low=0.0, high=90.0)
    eyes = {s: _eye(doc, s, path) for s in SIDES}
    npz = read_rig_arrays(folder / RIG_NPZ, n_vertices, against)
    return Rig(folder=folder, doc=doc, eyes=eyes, max_pitch_deg=max_pitch, npz=npz)
