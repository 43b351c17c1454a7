"""``build/<scan>/ingest/scan.json``: the ingested scan's record, one writer and one reader.

Written by ``ingest``, read by ``remove_eyeballs`` (the eye hints, and the scan folder a refusal
names) and ``usd`` (name, source hash and licence for the asset's metadata). Layout (head frame,
mm)::

    {"name": "james", "source_sha256": "...", "licence": "...",
     "eyes": {"left": {"hint": [x, y, z]}, "right": {"hint": [x, y, z]}},
     "texture": "texture.png" | null,
     "units_in": "mm", "up_axis_in": "+Y", "forward_axis_in": "+Z",
     "folder": "raw_scans/james"}

Only the hints are required (a hand-written record for a test may hold nothing else); every
other key is optional and keys the reader does not know are carried unchanged (``doc``). The
file has no schema number: adding one would change every ingest output's bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_json
from pipeline.io.scan import EYE_SIZES

SIDES = ("left", "right")
SCAN_JSON = "scan.json"


@dataclass(frozen=True)
class ScanRecord:
    """``scan.json``, validated.

    Attributes
    ----------
    path : Path
    name : str or None
        The scan folder's name (None in a record that does not say it).
    hints : dict side -> (3,) float64
        The eye hints in the head frame, mm.
    source_sha256, licence : str
        ``""`` where the record does not say.
    folder : str or None
        The scan folder as ingest was given it: what a later refusal names.
    doc : dict
        The whole document as stored.
    eye_size : str or None
        The scan's own asset eye size (scan.yaml ``eye_size``), None where it leaves it to
        ``remove_eyeballs.eye_size``.
    open_eyes : tuple of str
        The sides the user declared open (scan.yaml ``eyes.<side>.open``).
    """

    path: Path
    name: str | None
    hints: dict
    source_sha256: str
    licence: str
    folder: str | None
    doc: dict = field(repr=False)
    eye_size: str | None = None
    open_eyes: tuple = ()


def write_scan_record(path, scan: dict, folder) -> None:
    """Write ingest's ``scan`` mapping with the scan ``folder`` (a later stage names it, not
    ``build/``, when the scan is at fault), atomically."""
    write_json(path, {**scan, "folder": str(folder)})


def read_scan_record(path) -> ScanRecord:
    """``scan.json`` (a file, or the ingest folder holding it), validated.

    Raises
    ------
    ScanError
        One line naming the file: missing, not a JSON mapping, no valid eye hints (3 finite
        numbers for each eye).
    """
    from pipeline.io.docfile import read_json_doc

    path = Path(path)
    if path.is_dir():
        path = path / SCAN_JSON
    doc = read_json_doc(path, SCAN_JSON, None, "ingest")
    try:
        hints = {s: np.asarray(doc["eyes"][s]["hint"], dtype=np.float64).reshape(3) for s in SIDES}
    except (ValueError, KeyError, TypeError) as exc:
        raise ScanError(path, f"has no valid eye hints ({type(exc).__name__})") from None
    if not all(np.isfinite(h).all() for h in hints.values()):
        raise ScanError(path, "eye hints are not finite")

    def text(key):
        v = doc.get(key)
        return v if isinstance(v, str) else None

    eye_size = doc.get("eye_size")
    if eye_size is not None and eye_size not in EYE_SIZES:
        raise ScanError(path, f"eye_size must be one of {', '.join(EYE_SIZES)}, got {eye_size!r:.40}")
    open_eyes = tuple(s for s in SIDES if doc["eyes"][s].get("open", False) is True)
    return ScanRecord(path=path, name=text("name"), hints=hints, source_sha256=str(doc.get("source_sha256", "")),
                      licence=str(doc.get("licence", "")), folder=text("folder"), doc=doc, eye_size=eye_size,
                      open_eyes=open_eyes)
