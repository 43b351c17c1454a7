"""The scan folder's sidecar ``scan.yaml``: schema, validation and safe paths.

Everything in a scan folder is untrusted. :func:`read_sidecar` refuses, with a
:class:`pipeline.errors.ScanError` naming the file and the problem, anything
that is not exactly what the scan folder contract (DESIGN.md) describes:

``mesh``          str, relative path inside the folder (OBJ, PLY, STL or GLB)
``texture``       optional str, relative path inside the folder
``units``         ``mm`` | ``cm`` | ``m``
``up_axis``       one of ``+X -X +Y -Y +Z -Z``
``forward_axis``  one of the same, not parallel to ``up_axis``
``eyes``          ``{left: {hint: [x, y, z]}, right: {hint: [x, y, z]}}`` finite numbers,
                  scan coordinates and units; optional ``open: true`` on an eye: the subject's
                  eye is open (where the scan shows too little of it to tell, it is placed
                  behind the opening the skin outlines, doubted, not refused as closed)
``licence``       non-empty str
``eye_size``      optional: ``human`` | ``population`` | ``fitted``, this scan's asset eye
                  (over ``remove_eyeballs.eye_size``; procedural identities say ``population``)

Unknown top-level keys are tolerated (and listed in :attr:`ScanSpec.unknown_keys`
so a stage can report them) unless they look like a misspelling of a known key
(``textrue:``), which is refused: a silently ignored typo would drop the texture.

The YAML is read with :class:`SidecarLoader`, a ``yaml.SafeLoader`` that refuses
duplicate mapping keys (a silent "last one wins" hides mistakes) and reads YAML 1.2
floats such as ``3.45e1`` as numbers (YAML 1.1 needs a dot: ``3.45e+1``).
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np
import yaml

from pipeline.errors import ScanError
from pipeline.io.strict_yaml import DuplicateKeyError, SidecarLoader, StrictLoader  # noqa: F401 (re-exported)

SIDECAR_NAME = "scan.yaml"
UNITS_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
AXES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")
KNOWN_KEYS = ("mesh", "texture", "units", "up_axis", "forward_axis", "eyes", "licence", "eye_size")
EYE_SIZES = ("human", "population", "fitted")
FREE_FORM_KEYS = ("source", "notes", "description", "name", "comment")
EYE_SIDES = ("left", "right")
EYE_KEYS = ("hint", "open")
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb")
TEXTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")   # PNG, JPEG, TIFF: pipeline.io.formats.image
DEFAULT_MAX_YAML_BYTES = 65536
_URI = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]+:")


@dataclass(frozen=True)
class ScanSpec:
    """A validated ``scan.yaml``.

    Attributes
    ----------
    folder : pathlib.Path
        The scan folder, resolved.
    sidecar : pathlib.Path
        Path of ``scan.yaml``.
    mesh : pathlib.Path
        Resolved mesh path, a regular file inside ``folder``.
    texture : pathlib.Path or None
        Resolved texture path from the sidecar (overrides one named by the mesh file).
    units : str
        ``"mm"``, ``"cm"`` or ``"m"``.
    up_axis, forward_axis : str
        Signed scan axes, e.g. ``"+Y"``.
    hints : dict[str, numpy.ndarray]
        ``{"left": (3,), "right": (3,)}`` float64 eye hints in scan coordinates and units.
    licence : str
    eye_size : str or None
        This scan's asset eye size (:data:`EYE_SIZES`), over the project's
        ``remove_eyeballs.eye_size``; None: the project's.
    unknown_keys : tuple of str
        Top-level keys that are neither known nor free-form (tolerated, reported).
    open_eyes : tuple of str
        The sides whose ``eyes.<side>.open`` is true: declared open by the user.
    """

    folder: Path
    sidecar: Path
    mesh: Path
    texture: Path | None
    units: str
    up_axis: str
    forward_axis: str
    hints: dict = field(default_factory=dict)
    licence: str = ""
    unknown_keys: tuple = ()
    eye_size: str | None = None
    open_eyes: tuple = ()

    @property
    def scale_to_mm(self) -> float:
        """Factor taking scan units to millimetres."""
        return UNITS_TO_MM[self.units]


def one_line(text) -> str:
    """Collapse ``text`` to one line (error messages must be one line)."""
    return " ".join(str(text).split())


def short_repr(value) -> str:
    """A bounded one-line repr of an untrusted value (YAML aliases can make huge nested structures)."""
    import reprlib

    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxtuple, r.maxdict, r.maxstring, r.maxother = 2, 4, 4, 4, 40, 40
    return one_line(r.repr(value))[:80]


def control_characters(text: str) -> list:
    """Control characters in ``text`` other than newline and tab (C0, DEL, C1), in order."""
    return [ch for ch in text if (ord(ch) < 32 and ch not in "\n\t") or 127 <= ord(ch) < 160]


def safe_path(folder, value, sidecar, key: str, suffixes=None) -> Path:
    """Resolve a relative path from an untrusted file and check it stays inside ``folder``.

    Parameters
    ----------
    folder : pathlib.Path
        The scan folder (resolved).
    value : object
        The untrusted value (must be a non-empty str).
    sidecar : pathlib.Path
        The file the value came from (named in errors).
    key : str
        What the value is (``"mesh"``, ``"texture"``, ``"map_Kd"``), named in errors.
    suffixes : tuple of str, optional
        Allowed lower-case file suffixes.

    Returns
    -------
    pathlib.Path
        The resolved path of an existing regular file inside ``folder``.
    """
    if not isinstance(value, str) or not value.strip():
        raise ScanError(sidecar, f"{key} must be a non-empty string, got {_type_name(value)}")
    value = value.strip()
    if any(ord(ch) < 32 or ord(ch) == 127 for ch in value):
        raise ScanError(sidecar, f"{key} path {value!r} contains control characters")
    if _URI.match(value):
        scheme = value.split(":", 1)[0]
        raise ScanError(sidecar, f"{key} is a {scheme}: URI, not a file; give a path relative to the scan folder")
    posix, win = PurePosixPath(value), PureWindowsPath(value)
    if posix.is_absolute() or win.is_absolute() or win.drive or value.startswith(("/", "\\", "~")):
        raise ScanError(sidecar, f"{key} path {value!r} is absolute; give a path relative to the scan folder")
    if ".." in posix.parts or ".." in win.parts:
        raise ScanError(sidecar, f"{key} path {value!r} leaves the scan folder ('..')")
    folder = Path(folder).resolve()
    candidate = folder / value
    try:
        resolved = candidate.resolve(strict=False)
    except (OSError, RuntimeError) as exc:  # symlink loop
        raise ScanError(sidecar, f"{key} path {value!r} cannot be resolved: {one_line(exc)}") from None
    if resolved != folder and folder not in resolved.parents:
        raise ScanError(sidecar, f"{key} path {value!r} resolves outside the scan folder (symlink?)")
    try:
        exists, regular = resolved.exists(), resolved.is_file()
    except OSError as exc:                       # e.g. a name too long for the file system
        raise ScanError(sidecar, f"{key} path {value[:60]!r} cannot be used: {one_line(exc.strerror)}") from None
    if not exists:
        raise ScanError(candidate, f"{key} file does not exist (named in {Path(sidecar).name})")
    if not regular:
        raise ScanError(candidate, f"{key} is not a regular file")
    if suffixes is not None and resolved.suffix.lower() not in suffixes:
        raise ScanError(candidate, f"{key} has unsupported file type {resolved.suffix or '(none)'!r}; "
                                   f"expected one of {', '.join(suffixes)}")
    return resolved


def _type_name(value) -> str:
    return "nothing" if value is None else type(value).__name__


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _hint(eyes, side: str, sidecar: Path) -> np.ndarray:
    entry = eyes.get(side)
    if entry is None:
        raise ScanError(sidecar, f"eyes.{side} is missing (need eyes.{side}.hint: [x, y, z])")
    if not isinstance(entry, dict) or "hint" not in entry:
        raise ScanError(sidecar, f"eyes.{side} must be a mapping with a 'hint' key")
    hint = entry["hint"]
    if not isinstance(hint, (list, tuple)) or len(hint) != 3 or not all(_is_number(x) for x in hint):
        raise ScanError(sidecar, f"eyes.{side}.hint must be three numbers [x, y, z], got {short_repr(hint)}")
    try:
        finite = all(math.isfinite(float(x)) for x in hint)
    except OverflowError:                        # an integer too large for a float
        finite = False
    if not finite:
        raise ScanError(sidecar, f"eyes.{side}.hint {short_repr(hint)} is not finite")
    return np.array(hint, dtype=np.float64)


def _declared_open(eyes, side: str, sidecar: Path) -> bool:
    """``eyes.<side>.open`` (absent: False); a misspelt key beside ``hint`` is refused, since
    a silently ignored ``opne: true`` would refuse an open eye as closed after all."""
    entry = eyes[side]
    for key in entry:
        if key in EYE_KEYS or not isinstance(key, str):
            continue
        close = difflib.get_close_matches(key, EYE_KEYS, n=1, cutoff=0.6)
        if close:
            raise ScanError(sidecar, f"unknown key eyes.{side}.{key} (did you mean {close[0]!r}?)")
    value = entry.get("open", False)
    if not isinstance(value, bool):
        raise ScanError(sidecar, f"eyes.{side}.open must be true or false, got {short_repr(value)}")
    return value


def parse_sidecar(data, folder, sidecar) -> ScanSpec:
    """Validate an already-parsed sidecar mapping.

    Parameters
    ----------
    data : object
        What ``yaml.safe_load`` returned.
    folder : pathlib.Path
        The scan folder.
    sidecar : pathlib.Path
        The sidecar path (named in errors).

    Returns
    -------
    ScanSpec
    """
    folder = Path(folder).resolve()
    if not isinstance(data, dict):
        raise ScanError(sidecar, f"must be a YAML mapping of keys to values, got {_type_name(data)}")
    for key in data:
        if not isinstance(key, str):
            raise ScanError(sidecar, f"keys must be strings, got {short_repr(key)}")
    unknown = []
    for key in data:
        if key in KNOWN_KEYS or key in FREE_FORM_KEYS:
            continue
        close = difflib.get_close_matches(key, KNOWN_KEYS, n=1, cutoff=0.75)
        if close:
            raise ScanError(sidecar, f"unknown key {key!r} (did you mean {close[0]!r}?)")
        unknown.append(key)
    for key in ("mesh", "units", "up_axis", "forward_axis", "eyes", "licence"):
        if key not in data:
            raise ScanError(sidecar, f"required key {key!r} is missing")
    units = data["units"]
    if not isinstance(units, str) or units not in UNITS_TO_MM:
        raise ScanError(sidecar, f"units must be one of mm, cm, m; got {short_repr(units)}")
    axes = {}
    for key in ("up_axis", "forward_axis"):
        value = data[key]
        if not isinstance(value, str) or value.strip().upper() not in AXES:
            raise ScanError(sidecar, f"{key} must be one of {', '.join(AXES)}; got {short_repr(value)}")
        axes[key] = value.strip().upper()
    if axes["up_axis"][1] == axes["forward_axis"][1]:
        raise ScanError(sidecar, f"up_axis {axes['up_axis']} and forward_axis {axes['forward_axis']} "
                                 "are parallel; they must be different axes")
    licence = data["licence"]
    if not isinstance(licence, str) or not licence.strip():
        raise ScanError(sidecar, f"licence must be a non-empty string, got {_type_name(licence)}")
    bad = control_characters(licence)
    if bad:
        raise ScanError(sidecar, f"licence contains a control character (U+{ord(bad[0]):04X}); "
                                 "only printable text, newlines and tabs are allowed")
    eyes = data["eyes"]
    if not isinstance(eyes, dict):
        raise ScanError(sidecar, f"eyes must be a mapping with left and right, got {_type_name(eyes)}")
    hints = {side: _hint(eyes, side, sidecar) for side in EYE_SIDES}
    open_eyes = tuple(side for side in EYE_SIDES if _declared_open(eyes, side, sidecar))
    mesh = safe_path(folder, data["mesh"], sidecar, "mesh", MESH_SUFFIXES)
    texture = None
    if data.get("texture") is not None:
        texture = safe_path(folder, data["texture"], sidecar, "texture", TEXTURE_SUFFIXES)
    eye_size = data.get("eye_size")
    if eye_size is not None and eye_size not in EYE_SIZES:
        raise ScanError(sidecar, f"eye_size must be one of {', '.join(EYE_SIZES)}, got {short_repr(eye_size)}")
    return ScanSpec(folder=folder, sidecar=Path(sidecar), mesh=mesh, texture=texture, units=units,
                    up_axis=axes["up_axis"], forward_axis=axes["forward_axis"], hints=hints,
                    licence=licence.strip(), unknown_keys=tuple(unknown), eye_size=eye_size,
                    open_eyes=open_eyes)


def read_sidecar(folder, max_yaml_bytes: int = DEFAULT_MAX_YAML_BYTES) -> ScanSpec:
    """Read and validate ``<folder>/scan.yaml`` (safe loading only, size-capped, duplicate keys refused).

    Parameters
    ----------
    folder : str or os.PathLike
        The scan folder.
    max_yaml_bytes : int
        Refuse a sidecar larger than this.

    Returns
    -------
    ScanSpec
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ScanError(folder, "scan folder does not exist or is not a folder")
    sidecar = folder / SIDECAR_NAME
    if not sidecar.exists():
        raise ScanError(sidecar, "missing: every scan folder needs a scan.yaml sidecar")
    real = sidecar.resolve()
    if sidecar.is_symlink() and folder.resolve() not in real.parents:
        raise ScanError(sidecar, "is a symlink to outside the scan folder")
    if not real.is_file():
        raise ScanError(sidecar, "is not a regular file")
    size = real.stat().st_size
    if size > max_yaml_bytes:
        raise ScanError(sidecar, f"is {size} bytes, over the limit of {max_yaml_bytes} bytes")
    raw = real.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScanError(sidecar, f"is not UTF-8 text ({one_line(exc)})") from None
    loader = SidecarLoader(text)      # a SafeLoader subclass (duplicate keys, YAML 1.2 numbers)
    try:
        data = loader.get_single_data()
    except DuplicateKeyError as exc:
        raise ScanError(sidecar, f"{exc}: each key may appear once") from None
    except yaml.YAMLError as exc:
        raise ScanError(sidecar, f"YAML error: {one_line(exc)[:200]}") from None
    except RecursionError:
        raise ScanError(sidecar, "YAML error: nesting too deep") from None
    except (ValueError, TypeError, OverflowError) as exc:   # a bad explicit tag value ("!!int mm", "!!binary x")
        raise ScanError(sidecar, f"YAML error: a tagged value cannot be read ({one_line(exc)[:120]})") from None
    finally:
        loader.dispose()
    return parse_sidecar(data, folder, sidecar)

