"""One settings base for every ``params.yaml`` block: defaults in one place, values checked.

A block is a dataclass that inherits :class:`Settings`. Its field defaults are THE defaults
(``params.yaml`` may repeat them for documentation); each field's type annotation says what
is accepted, and :func:`setting` adds ranges and choices::

    @dataclass(frozen=True)            # frozen or not, both work
    class BakeSettings(Settings):
        block: ClassVar[str] = "bake"
        resolution: int = setting(2048, ge=16, le=16384)
        max_distance_mm: float = setting(4.0, gt=0, le=100)
        size_mm: tuple[float, float] = setting((40.0, 1000.0), gt=0, ordered=True)

        def validate(self):             # optional cross-field checks
            if ...:
                raise SettingError("falloff_mm", "must be <= max_distance_mm")

    s = BakeSettings.from_params(load_params("bake"))   # stages: unknown keys refused

Accepted types: ``bool`` (a YAML true/false only), ``int`` (an integral number),
``float`` (finite; NaN and inf are refused), ``str``, ``Literal[...]`` (choices),
``tuple[T, ...]`` / ``tuple[T, T]`` (from a YAML list; ``ordered=True`` for lo <= hi ranges),
``X | None``, unions of those (dispatched on the value's type), a nested :class:`Settings`
subclass (from a mapping, e.g. ``eyeball.geometry``) and ``dict[str, <Settings subclass>]``
(e.g. ``render.presets``). Numbers written as YAML 1.2 text (``1e9``, which PyYAML reads as
a string) are read as numbers, like DVC reads them.

Every refusal is a :class:`SettingError` (a ``ValueError`` naming the key). Through
:meth:`Settings.from_params` it becomes a :class:`SettingsError`, which is also a
:class:`pipeline.errors.ScanError`, so a stage ends with one line and exit 2::

    error: params.yaml: bake.max_distance_mm must be > 0 (got -4)

Constructing a block directly (``BakeSettings(resolution=512)``) runs the same checks.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from typing import Any, ClassVar, Literal

from pipeline.errors import ScanError

__all__ = ["Settings", "SettingError", "SettingsError", "setting", "boundaries", "check_scan_name",
           "SAFE_NAME"]

_MISSING = dataclasses.MISSING
# YAML 1.2 core-schema numbers that YAML 1.1 (PyYAML) reads as text: 1e9, 3.45e1, +12, .5
_NUMBER_TEXT = re.compile(r"^[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?$")


class SettingError(ValueError):
    """A bad value (or unknown key) in a settings block; ``key`` is dotted within the block."""

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"{key} {problem}" if key else problem)


class SettingsError(ScanError, ValueError):
    """A :class:`SettingError` placed in its file and block: ``params.yaml: bake.key problem``."""

    def __init__(self, source, block: str, key: str, problem: str):
        self.block, self.key = block, key
        where = ".".join(p for p in (block, key) if p)
        super().__init__(source, f"{where} {problem}" if where else problem)


def setting(default=_MISSING, *, default_factory=_MISSING, gt=None, ge=None, lt=None, le=None,
            ordered: bool = False, min_len: int | None = None, max_len: int | None = None,
            choices=None, doc: str = ""):
    """A dataclass field with checks: numeric bounds (on a number or on every element of a
    tuple), ``ordered`` (tuple elements non-decreasing), tuple length, extra ``choices``."""
    meta = {"gt": gt, "ge": ge, "lt": lt, "le": le, "ordered": ordered, "min_len": min_len,
            "max_len": max_len, "choices": tuple(choices) if choices is not None else None, "doc": doc}
    if default_factory is not _MISSING:
        return dataclasses.field(default_factory=default_factory, metadata={"check": meta})
    if isinstance(default, (list, dict, set)):
        raise TypeError("mutable setting defaults need default_factory")
    return dataclasses.field(default=default, metadata={"check": meta})


def _show(v) -> str:
    if isinstance(v, str):
        return repr(v if len(v) <= 40 else v[:37] + "...")
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (list, tuple)):
        s = repr(list(v))
        return s if len(s) <= 60 else s[:57] + "..."
    if isinstance(v, dict):
        return "a mapping"
    return repr(v)


def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if tp is bool:
        return "true or false"
    if tp is int:
        return "an integer"
    if tp is float:
        return "a number"
    if tp is str:
        return "a string"
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return "a list"
    if isinstance(tp, type) and issubclass(tp, Settings):
        return "a mapping"
    if origin is dict:
        return "a mapping"
    if tp is type(None):
        return "null"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp))


def _number(v):
    if isinstance(v, str) and _NUMBER_TEXT.match(v.strip()):
        return float(v)
    return v


def _coerce(tp, v, key: str):
    """``v`` converted to the annotated type ``tp`` (SettingError when it is not one)."""
    origin = typing.get_origin(tp)
    if tp is Any:
        return v
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(typing.get_args(tp), v, key)
    if tp is type(None):
        if v is None:
            return None
    elif tp is bool:
        if isinstance(v, bool):
            return v
    elif tp is int:
        n = _number(v)
        if isinstance(n, bool):
            pass
        elif isinstance(n, int):
            return n
        elif isinstance(n, float) and math.isfinite(n) and n.is_integer():
            return int(n)
        elif isinstance(n, float):
            raise SettingError(key, f"must be an integer (got {_show(v)})")
    elif tp is float:
        n = _number(v)
        if isinstance(n, (int, float)) and not isinstance(n, bool):
            n = float(n)
            if not math.isfinite(n):
                raise SettingError(key, f"must be a finite number (got {_show(v)})")
            return n
    elif tp is str:
        if isinstance(v, str):
            return v
    elif origin is Literal:
        if isinstance(v, str) and v in typing.get_args(tp):
            return v
        raise SettingError(key, f"must be {_type_name(tp)} (got {_show(v)})")
    elif origin is tuple:
        if isinstance(v, (list, tuple)):
            args = typing.get_args(tp)
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(_coerce(args[0], x, f"{key}[{i}]") for i, x in enumerate(v))
            if len(v) != len(args):
                raise SettingError(key, f"must be a list of {len(args)} values (got {_show(v)})")
            return tuple(_coerce(a, x, f"{key}[{i}]") for i, (a, x) in enumerate(zip(args, v)))
    elif origin is dict:
        if isinstance(v, dict):
            kt, vt = typing.get_args(tp)
            return {_coerce(kt, k, key): _coerce(vt, x, f"{key}.{k}") for k, x in v.items()}
    elif isinstance(tp, type) and issubclass(tp, Settings):
        if isinstance(v, tp):
            return v
        if isinstance(v, dict):
            return tp._build(v, prefix=key)
    elif isinstance(tp, type):
        if isinstance(v, tp):
            return v
    raise SettingError(key, f"must be {_type_name(tp)} (got {_show(v)})")


def _coerce_union(args, v, key: str):
    """Pick the union member that matches the value's kind, then coerce to it."""
    def kind(t):
        o = typing.get_origin(t)
        if t is type(None):
            return "null"
        if t is bool:
            return "bool"
        if t in (int, float):
            return "number"
        if t is str or o is Literal:
            return "str"
        if o is tuple:
            return "list"
        if o is dict or (isinstance(t, type) and issubclass(t, Settings)):
            return "map"
        return "other"

    n = _number(v)
    vk = ("null" if v is None else "bool" if isinstance(v, bool) else
          "number" if isinstance(n, (int, float)) else "str" if isinstance(v, str) else
          "list" if isinstance(v, (list, tuple)) else "map" if isinstance(v, dict) else "other")
    cands = [a for a in args if kind(a) == vk]
    if isinstance(v, str) and not cands:          # numeric text for a number member
        cands = [a for a in args if kind(a) == "number"]
    if vk == "other":
        cands = [a for a in args if isinstance(a, type) and isinstance(v, a)]
    if not cands:
        raise SettingError(key, f"must be {_type_name(typing.Union[tuple(args)])} (got {_show(v)})")
    err = None
    for a in cands:
        try:
            return _coerce(a, v, key)
        except SettingError as exc:
            err = err or exc
    raise err


def _check(meta: dict, v, key: str) -> None:
    if v is None:
        return
    if meta.get("choices") is not None and v not in meta["choices"]:
        raise SettingError(key, f"must be one of {', '.join(map(repr, meta['choices']))} (got {_show(v)})")
    if isinstance(v, tuple):
        n = len(v)
        if meta.get("min_len") is not None and n < meta["min_len"]:
            raise SettingError(key, f"needs at least {meta['min_len']} value(s) (got {n})")
        if meta.get("max_len") is not None and n > meta["max_len"]:
            raise SettingError(key, f"takes at most {meta['max_len']} value(s) (got {n})")
        for x in v:
            _bounds(meta, x, key, shown=v)
        if meta.get("ordered") and any(a > b for a, b in zip(v, v[1:])):
            raise SettingError(key, f"must be in increasing order [low, high] (got {_show(v)})")
        return
    _bounds(meta, v, key, shown=v)


def _bounds(meta: dict, x, key: str, shown) -> None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return
    for op, ok in (("gt", lambda a, b: a > b), ("ge", lambda a, b: a >= b),
                   ("lt", lambda a, b: a < b), ("le", lambda a, b: a <= b)):
        b = meta.get(op)
        if b is not None and not ok(x, b):
            sym = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}[op]
            what = "every value " if isinstance(shown, tuple) else ""
            bound = str(b) if isinstance(b, int) else f"{b:g}"
            raise SettingError(key, f"{what}must be {sym} {bound} (got {_show(shown)})")


_HINTS: dict = {}


def _hints(cls) -> dict:
    h = _HINTS.get(cls)
    if h is None:
        h = _HINTS[cls] = typing.get_type_hints(cls)
    return h


class Settings:
    """Base of every settings block (use with ``@dataclass``, frozen or not); see the module doc.

    Class attribute ``block``: the ``params.yaml`` block name (``""`` for nested blocks).
    Override :meth:`validate` for checks across fields (raise :class:`SettingError`), and
    :meth:`prepare` to rewrite the raw mapping before it is read (e.g. presets).
    """

    block: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs):
        """A subclass's own ``__post_init__`` runs after the checks, never instead of them."""
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("__post_init__")
        if own is not None and not getattr(own, "_after_checks", False):
            def __post_init__(self, _own=own):
                Settings.__post_init__(self)
                _own(self)
            __post_init__._after_checks = True
            cls.__post_init__ = __post_init__

    def __post_init__(self):
        hints = _hints(type(self))
        for f in dataclasses.fields(self):
            if not f.init:
                continue
            v = getattr(self, f.name)
            v2 = _coerce(hints[f.name], v, f.name)
            _check(f.metadata.get("check", {}), v2, f.name)
            if v2 is not v:
                object.__setattr__(self, f.name, v2)
        self.validate()

    def validate(self) -> None:
        """Cross-field checks; raise ``SettingError(key, problem)``."""

    @classmethod
    def prepare(cls, params: dict) -> dict:
        """Rewrite the raw block before it is read (default: as is)."""
        return params

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls) if f.init]

    @classmethod
    def _build(cls, params, prefix: str = ""):
        if params is None:
            params = {}
        if not isinstance(params, dict):
            raise SettingError(prefix, f"must be a mapping of settings (got {_show(params)})")
        params = cls.prepare(dict(params))
        known = set(cls.keys())
        for k in params:
            if not isinstance(k, str) or k not in known:
                key = f"{prefix}.{k}" if prefix else str(k)
                raise SettingError(key, f"is an unknown key (known: {', '.join(cls.keys())})")
        try:
            return cls(**params)
        except SettingError as exc:
            if prefix:
                raise SettingError(f"{prefix}.{exc.key}" if exc.key else prefix, exc.problem) from None
            raise

    @classmethod
    def from_params(cls, params: dict | None = None, source="params.yaml", block: str | None = None):
        """The block from its raw ``params.yaml`` mapping (None or absent = all defaults).

        Raises
        ------
        SettingsError
            (a ScanError and a ValueError) one line: ``<source>: <block>.<key> <problem>``.
        """
        block = cls.block if block is None else block
        try:
            return cls._build(params)
        except SettingError as exc:
            raise SettingsError(source, block, exc.key, exc.problem) from None

    def to_dict(self) -> dict:
        """Plain data (tuples as lists, nested blocks as dicts), e.g. for metadata."""
        def plain(v):
            if isinstance(v, Settings):
                return v.to_dict()
            if isinstance(v, (tuple, list)):
                return [plain(x) for x in v]
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            return v
        return {k: plain(getattr(self, k)) for k in self.keys()}


# ---------------------------------------------------------------------------- boundaries

def _scalar(tp):
    """The number type a field's values are checked as (int / float), through ``X | None`` and
    tuples; None for anything else."""
    origin = typing.get_origin(tp)
    if tp in (int, float):
        return tp
    if origin in (typing.Union, types.UnionType):
        nums = [a for a in map(_scalar, typing.get_args(tp)) if a is not None]
        return nums[0] if len(nums) == 1 else None
    if origin is tuple:
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return _scalar(args[0]) if args and all(a == args[0] for a in args) else None
    return None


def _step(tp, x, direction: int):
    """``x`` (direction 0) or its neighbouring integer / float above (+1) or below (-1)."""
    if tp is int:
        return int(x) + direction
    return math.nextafter(float(x), math.copysign(math.inf, direction)) if direction else float(x)


#: bound kind -> (direction of the last accepted value, of the first refused one) from the bound
_EDGES = {"ge": (0, -1), "gt": (1, 0), "le": (0, 1), "lt": (-1, 0)}


def boundaries(cls, prefix: tuple = ()) -> list[tuple[tuple, object, bool]]:
    """``(key path, value, accepted)`` at the limits of every field of a :class:`Settings` class.

    For each numeric field (and each numeric tuple field, every element set to the value): its
    bounds as accepted (``ge`` / ``le`` the bound itself, ``gt`` / ``lt`` the next number inside)
    and the next number outside as refused; NaN and infinity refused for a float; every choice of
    a ``Literal`` accepted and another word refused; both booleans accepted. Nested blocks are
    walked (``("geometry", "r1")``). A value accepted field by field may still be refused by a
    block's cross-field :meth:`Settings.validate` with the other fields at their defaults.
    """
    out = []
    hints = _hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        key, tp = prefix + (f.name,), hints[f.name]
        if isinstance(tp, type) and issubclass(tp, Settings):
            out += boundaries(tp, key)
            continue
        meta = f.metadata.get("check", {})
        args = typing.get_args(tp)
        num = _scalar(tp)
        default = f.default if f.default is not _MISSING else None
        width = len(default) if isinstance(default, tuple) else None

        def shaped(x):
            return x if width is None else [x] * width

        if num is not None:
            for op, (inside, outside) in _EDGES.items():
                b = meta.get(op)
                if b is not None:
                    out += [(key, shaped(_step(num, b, inside)), True),
                            (key, shaped(_step(num, b, outside)), False)]
            if num is float:
                out += [(key, shaped(math.nan), False), (key, shaped(math.inf), False)]
        if tp is bool:
            out += [(key, True, True), (key, False, True), (key, "maybe", False)]
        lits = [a for a in (args if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,))
                if typing.get_origin(a) is Literal]
        for lit in lits:
            out += [(key, c, True) for c in typing.get_args(lit)] + [(key, "no-such-choice", False)]
    return out


# ---------------------------------------------------------------------------- scan names

SAFE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}")


def check_scan_name(name, source="params.yaml", key: str | None = "scans") -> str:
    """``name`` if it is a safe scan name, else ScanError naming ``source`` (and ``key``, the
    params key it is listed under; None for a folder's name) and the name.

    Safe: 1-128 characters from letters, digits, ``.``, ``_`` and ``-``, not starting with a
    dot (so never ``.``, ``..`` or a hidden folder). Scan names become folder names and
    command-line words in ``dvc.yaml``; anything else could reach a shell or leave the repository.
    The rule is for the scan's own name only: the folders above it are ordinary paths.
    """
    if isinstance(name, str) and SAFE_NAME.fullmatch(name) and name not in (".", ".."):
        return name
    shown = repr(name) if isinstance(name, str) else f"{name!r} ({type(name).__name__})"
    if isinstance(name, str) and len(name) > 60:
        shown = repr(name[:57] + "...")
    where = f"{key}: " if key else ""
    raise ScanError(source, f"{where}{shown} is not a safe scan name (use 1-128 letters, digits, "
                            "'.', '_' or '-', not starting with '.')")
