"""The render labels (``renders/<scan>/NNNNNN.json``) and their index (``index.jsonl``):
one writer, one reader each.

Written by the ``render`` stage (labels by the dask task that finishes an image,
pipeline/render/shard.py; the index at the end of the run, pipeline/render/run.py); read by
the stage itself (index, contact sheet, metrics), tests and benchmarks. The label's content is
built by :func:`pipeline.render.labels.make_label` (frames and conventions in its docstring);
this module owns the file: ``{"schema": 1, "index": i, "scan": ..., "image": {...},
"camera": {...}, "gaze": {...}, "landmarks": {...}, "seed": {...}, "lighting": {...},
"render": {...}, ...}``.

:func:`read_label` validates the schema and every field a consumer relies on (index, image
size, camera matrices, gaze, the 28 landmarks in pixels / camera mm / head mm, attempts,
lighting map, skin detail; each eye's rotation centre, radius and centre-to-iris-plane distance
in ``eyes.<side>``, when present) and refuses anything else with one line naming the file. Labels
rendered with ``render.masks`` (schema 1 extended; labels without these fields still read) also
carry ``"seg": {"file": "NNNNNN_seg.png", ...}``, ``"depth": {"file": "NNNNNN_depth.exr", ...}``
(files beside the label, pipeline/io/seg_file.py) and per landmark ``landmarks.visible`` (28
booleans) and ``landmarks.occlusion`` (null where visible, else ``lid``, ``lashes``, ``eye`` or
``outside``; pipeline/render/visibility.py), checked when present. Each
``index.jsonl`` line is ``{"index", "png", "json", "eye", "gaze_camera_deg",
"landmark_check_mm"}`` (plus ``"asset"`` and ``"asset_id"`` for the images of a dataset,
whose labels carry ``"asset": {"name", "id"}``); :func:`read_index` checks every line and
that each index appears once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io import docfile as df
from pipeline.io.atomic import write_json

SCHEMA = 1
N_LANDMARKS = 28
SIDES = ("left", "right")


def label_name(index: int) -> str:
    """``NNNNNN.json``: the label file of image ``index``."""
    return f"{int(index):06d}.json"


@dataclass
class Label:
    """One label file, validated.

    Attributes
    ----------
    path : Path
    index : int
    width, height : int                  image size, px
    eye : str                            the imaged eye
    projection : (3, 4) float64          camera mm -> pixels (homogeneous)
    world_to_camera : (4, 4) float64     head mm -> camera mm
    px : (28, 2) float64                 landmarks, pixels (origin top-left, centres at +0.5)
    camera_mm : (28, 3) float64          landmarks, camera frame
    head_mm : (28, 3) float64            landmarks, head frame
    doc : dict                           the whole label as stored
    """

    path: Path
    index: int
    width: int
    height: int
    eye: str
    projection: np.ndarray
    world_to_camera: np.ndarray
    px: np.ndarray
    camera_mm: np.ndarray
    head_mm: np.ndarray
    doc: dict = field(repr=False)
    visible: np.ndarray | None = None    # (28,) bool, with render.masks (else None)
    occlusion: list | None = None        # 28 of None | "lid" | "lashes" | "eye" | "outside"


def write_label(path, label: dict) -> None:
    """Write one label (a :func:`pipeline.render.labels.make_label` dict) with the schema
    number, atomically."""
    write_json(path, {"schema": SCHEMA, **label})


def read_label(path) -> Label:
    """The label file ``path``, validated.

    Raises
    ------
    ScanError
        One line naming the file: missing, not JSON, another schema, a missing key, a wrong
        type or shape.
    """
    path = Path(path)
    doc = df.read_json_doc(path, "render label", SCHEMA, "render")
    index = df.field(doc, "index", path, int)
    w, h = df.field(doc, "image.width", path, int), df.field(doc, "image.height", path, int)
    if index < 0 or w <= 0 or h <= 0:
        raise ScanError(path, f"index, image.width and image.height must be >= 0, > 0, > 0 "
                              f"(got {index}, {w}, {h})")
    eye = df.field(doc, "gaze.eye", path, str)
    if eye not in SIDES:
        raise ScanError(path, f"gaze.eye must be 'left' or 'right' (got {eye!r})")
    df.array_field(doc, "gaze.vector_camera", (3,), path)
    for k in ("pitch_deg", "yaw_deg"):
        df.number(doc, f"gaze.camera.{k}", path)
    df.field(doc, "seed.attempts", path, int)
    df.field(doc, "lighting.hdri", path, str)
    df.field(doc, "render.skin_detail", path, str)
    if "asset" in doc:                  # dataset images name their asset
        df.field(doc, "asset.name", path, str)
        if df.field(doc, "asset.id", path, int) < 0:
            raise ScanError(path, f"asset.id must be >= 0 (got {doc['asset']['id']})")
    check = df.field(doc, "landmark_check_mm", path, default=None)
    if check is not None:
        df.number(doc, "landmark_check_mm", path)
    _eye_geometry(doc, path)
    visible, occlusion = _visibility(doc, path)
    return Label(path=path, index=index, width=w, height=h, eye=eye,
                 projection=df.array_field(doc, "camera.projection", (3, 4), path),
                 world_to_camera=df.array_field(doc, "camera.world_to_camera", (4, 4), path),
                 px=df.array_field(doc, "landmarks.px", (N_LANDMARKS, 2), path),
                 camera_mm=df.array_field(doc, "landmarks.camera_mm", (N_LANDMARKS, 3), path),
                 head_mm=df.array_field(doc, "landmarks.head_mm", (N_LANDMARKS, 3), path),
                 doc=doc, visible=visible, occlusion=occlusion)


OCCLUSIONS = ("lid", "lashes", "eye", "outside")


def _eye_geometry(doc: dict, path) -> None:
    """Each eye's rotation centre (head mm, camera mm, px: null behind a pinhole camera), radius and
    centre-to-iris-plane distance (``eyes.<side>``), checked when the label has them (labels
    written before they were added have none)."""
    for side in SIDES:
        if "center_head_mm" not in ((doc.get("eyes") or {}).get(side) or {}):
            continue
        pre = f"eyes.{side}."
        df.array_field(doc, pre + "center_head_mm", (3,), path)
        df.array_field(doc, pre + "center_camera_mm", (3,), path)
        if df.field(doc, pre + "center_px", path) is not None:
            df.array_field(doc, pre + "center_px", (2,), path)
        df.number(doc, pre + "radius_mm", path, low=0.0)
        df.number(doc, pre + "center_to_iris_plane_mm", path)


def _visibility(doc: dict, path):
    """``landmarks.visible`` / ``occlusion`` and the ``seg`` / ``depth`` file names, checked when
    the label has them (render.masks; labels written without masks have none of them)."""
    if not any(k in doc for k in ("seg", "depth")) and not any(
            k in doc.get("landmarks", {}) for k in ("visible", "occlusion")):
        return None, None
    for k in ("seg.file", "depth.file"):
        df.plain_name(doc, k, path, Path(path).parent)
    vis = df.field(doc, "landmarks.visible", path, list)
    occ = df.field(doc, "landmarks.occlusion", path, list)
    if len(vis) != N_LANDMARKS or not all(isinstance(v, bool) for v in vis):
        raise ScanError(path, f"landmarks.visible must be {N_LANDMARKS} true/false values")
    if len(occ) != N_LANDMARKS or any((o is None) != v or (o is not None and o not in OCCLUSIONS)
                                      for v, o in zip(vis, occ)):
        raise ScanError(path, f"landmarks.occlusion must be {N_LANDMARKS} entries: null where visible, else one "
                              f"of {', '.join(OCCLUSIONS)}")
    return np.array(vis, bool), list(occ)


def index_row(label: Label) -> dict:
    """The ``index.jsonl`` line of one label."""
    d = label.doc
    row = {"index": label.index, "png": f"{label.index:06d}.png", "json": label_name(label.index),
           "eye": label.eye, "gaze_camera_deg": [d["gaze"]["camera"]["pitch_deg"],
                                                 d["gaze"]["camera"]["yaw_deg"]],
           "landmark_check_mm": d.get("landmark_check_mm")}
    if "asset" in d:                    # a dataset image (pipeline/render/dataset.py)
        row.update(asset=d["asset"]["name"], asset_id=d["asset"]["id"])
    return row


def index_line(label: Label) -> str:
    """:func:`index_row` as the text of its line (newline included)."""
    return json.dumps(index_row(label)) + "\n"


def read_index(path) -> list[dict]:
    """The rows of an ``index.jsonl``, validated: one JSON mapping per line with an integer
    ``index`` (each once), ``png``/``json`` file names and the imaged ``eye``.

    Raises
    ------
    ScanError
        One line naming the file and the line number.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    rows, seen = [], set()
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ScanError(path, f"cannot be read ({type(exc).__name__})") from None
    for n, line in enumerate(lines, 1):
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            raise ScanError(path, f"line {n} is not valid JSON") from None
        where = f"line {n}"
        if not isinstance(row, dict):
            raise ScanError(path, f"{where} is not a mapping")
        i = row.get("index")
        if not isinstance(i, int) or isinstance(i, bool) or i < 0:
            raise ScanError(path, f"{where}: index must be an integer >= 0 (got {i!r})")
        if i in seen:
            raise ScanError(path, f"{where}: index {i} is listed twice")
        seen.add(i)
        for k in ("png", "json"):
            if not isinstance(row.get(k), str):
                raise ScanError(path, f"{where}: {k} must be a file name (got {row.get(k)!r})")
        if row.get("eye") not in SIDES:
            raise ScanError(path, f"{where}: eye must be 'left' or 'right' (got {row.get('eye')!r})")
        rows.append(row)
    return rows
