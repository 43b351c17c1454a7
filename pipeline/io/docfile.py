"""What the typed readers of stage products share: a schema-numbered JSON document read and
checked with one-line errors, and checked fields and arrays inside it.

Every check raises :class:`pipeline.errors.ScanError` naming the file and the problem (the
dotted key, what it must be, what it is), so a bad product ends a stage as one line.
Used by ``rig_file`` (rig.json / rig.npz), ``bake_file`` (bake.json and the maps) and
``labels_file`` (the render labels and index).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError

_MISSING = object()


def read_json_doc(path, kind: str, schema: int | None, writer: str) -> dict:
    """The JSON mapping in ``path``, of schema ``schema`` (None: no schema field).

    Parameters
    ----------
    path : str or os.PathLike
    kind : str
        What the file is, for messages (``"rig.json"``).
    schema : int or None
        The ``"schema"`` value this eyerig reads.
    writer : str
        The stage that writes the file (the message says to rebuild with it).

    Raises
    ------
    ScanError
        Missing, unreadable, not JSON, not a mapping, or another schema.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ScanError(path, f"is not valid JSON ({exc.__class__.__name__})") from None
    if not isinstance(doc, dict):
        raise ScanError(path, f"is not a {kind} (not a mapping)")
    if schema is not None and doc.get("schema") != schema:
        raise ScanError(path, f"has schema {doc.get('schema')!r}, this eyerig reads schema {schema} "
                              f"(rebuild it with the {writer} stage)")
    return doc


def field(doc: dict, key: str, path, types=None, what: str | None = None, default=_MISSING):
    """``doc[a][b]...`` for the dotted ``key`` ``"a.b..."``.

    Parameters
    ----------
    types : type or tuple of types, optional
        What the value must be an instance of (bool never counts as a number).
    what : str, optional
        How the message names the expected type (``"a number"``).
    default : optional
        Returned when the key is absent (without it a missing key is an error).
    """
    v = doc
    for part in key.split("."):
        if not isinstance(v, dict) or part not in v:
            if default is not _MISSING:
                return default
            raise ScanError(path, f"has no {key}")
        v = v[part]
    if types is None:
        return v
    types = types if isinstance(types, tuple) else (types,)
    if not isinstance(v, types) or (isinstance(v, bool) and bool not in types):
        raise ScanError(path, f"{key} must be {what or _type_words(types)} (got {type(v).__name__})")
    return v


def _type_words(types: tuple) -> str:
    names = {dict: "a mapping", str: "a string", int: "an integer", float: "a number", list: "a list"}
    return " or ".join(names.get(t, t.__name__) for t in types)


def number(doc: dict, key: str, path, low=None, high=None, default=_MISSING) -> float:
    """A finite number at ``key`` (``low < value <= high`` where given)."""
    v = field(doc, key, path, (int, float), "a number", default=default)
    if v is default:
        return v
    v = float(v)
    if not np.isfinite(v):
        raise ScanError(path, f"{key} must be finite (got {v})")
    if (low is not None and not v > low) or (high is not None and not v <= high):
        bound = (f"in ({low:g}, {high:g}]" if low is not None and high is not None
                 else f"> {low:g}" if low is not None else f"<= {high:g}")
        raise ScanError(path, f"{key} must be {bound} (got {v:g})")
    return v


def _shape_text(shape) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def check_array(a, shape, path, name: str, kind: str = "f", finite: bool = True) -> np.ndarray:
    """``a`` as a float64 (``kind="f"``) or int64 (``"i"``) array of ``shape`` (None = any length).

    Raises
    ------
    ScanError
        ``name must be a (n, 3) array of numbers (got ...)`` or non-finite values.
    """
    words = "numbers" if kind == "f" else "integers"
    try:
        arr = np.asarray(a)
        ok_kind = arr.dtype.kind in ("iu" if kind == "i" else "iuf")
    except (TypeError, ValueError):
        ok_kind, arr = False, None
    if (not ok_kind or arr.ndim != len(shape)
            or any(s is not None and s != d for s, d in zip(shape, arr.shape))):
        got = f"shape {tuple(arr.shape)} of {arr.dtype}" if arr is not None else "no array"
        raise ScanError(path, f"{name} must be a {_shape_text(shape)} array of {words} (got {got})")
    arr = arr.astype(np.int64 if kind == "i" else np.float64)
    if finite and kind == "f" and not np.isfinite(arr).all():
        raise ScanError(path, f"{name} has non-finite values")
    return arr


def array_field(doc: dict, key: str, shape, path, kind: str = "f") -> np.ndarray:
    """:func:`check_array` of the list at the dotted ``key`` of a JSON document."""
    v = field(doc, key, path)
    if isinstance(v, (str, bytes, dict)) or v is None:
        raise ScanError(path, f"{key} must be a {_shape_text(shape)} array of numbers "
                              f"(got {type(v).__name__})")
    return check_array(v, shape, path, key, kind)


def indices_within(a: np.ndarray, n: int | None, path, name: str, against: str = "the mesh") -> None:
    """Refuse indices of ``a`` outside ``[0, n)`` (no bound when ``n`` is None)."""
    if a.size and (a.min() < 0 or (n is not None and a.max() >= n)):
        raise ScanError(path, f"{name} indexes vertices outside {against}"
                              + (f" ({n} vertices)" if n is not None else ""))


def plain_name(doc: dict, key: str, path, folder: Path) -> Path:
    """The file named at ``key``: a plain name (no folder part) of an existing file in ``folder``."""
    name = field(doc, key, path, str)
    if not name or Path(name).name != name or name in (".", ".."):
        raise ScanError(path, f"{key} must be a file name in the same folder (got {name!r})")
    p = Path(folder) / name
    if not p.is_file():
        raise ScanError(p, f"not found (named by {Path(path).name} {key})")
    return p
