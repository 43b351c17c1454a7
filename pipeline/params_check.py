"""The check of a whole ``params.yaml`` mapping: safe scan names, every block read by its stage's
settings class, the ``identities:`` entries (stages/check_params.py runs it before any other
stage; stages/identities.py, as :func:`check_params_text`, before it writes the file).

It names every stage package's settings class (``"module:Class"``, imported when checked), so it
sits above them all (tests/test_layers.py).
"""

from __future__ import annotations

import importlib

from pipeline.errors import ScanError
from pipeline.settings import Settings, check_scan_name

#: params.yaml block -> the settings dataclass that reads it ("module:Class").
BLOCKS = {
    "synthetic_head": "pipeline.synthetic_head:SyntheticHeadSettings",
    "eyeball": "pipeline.eyeball.geometry:EyeballSettings",
    "ingest": "pipeline.ingest.ingest:IngestSettings",
    "remove_eyeballs": "pipeline.remove_eyeballs.settings:RemoveEyeballsSettings",
    "retopo": "pipeline.retopo.retopo:RetopoSettings",
    "bake": "pipeline.bake.bake:BakeSettings",
    "snap": "pipeline.snap.snap:SnapSettings",
    "rig": "pipeline.rig.lids:RigSettings",
    "usd": "pipeline.usd.asset:UsdSettings",
    "render": "pipeline.render.settings:RenderSettings",
}
#: Top-level keys that are not a stage's block.
LISTS = ("scans", "identities")


def settings_class(block: str):
    module, name = BLOCKS[block].split(":")
    return getattr(importlib.import_module(module), name)


def check_scans(scans, source="params.yaml") -> list[str]:
    """The ``scans:`` list, every name safe and listed once (ScanError naming ``source`` otherwise)."""
    if scans is None:
        return []
    if not isinstance(scans, list):
        raise ScanError(source, "scans must be a list of scan folder names")
    seen = set()
    for name in scans:
        check_scan_name(name, source)
        if name in seen:
            raise ScanError(source, f"scans: {name!r} is listed twice")
        seen.add(name)
    return list(scans)


def check_identities(data: dict, scans: list[str], source="params.yaml") -> dict:
    """The ``identities:`` mapping read into {name: SyntheticHeadSettings} (ScanError naming
    ``source`` on a bad name, a name missing from ``scans``, an unknown key or a bad value)."""
    from pipeline.synthetic_head import identity_settings

    idents = data.get("identities")
    if idents is None:
        return {}
    if not isinstance(idents, dict):
        raise ScanError(source, "identities must be a mapping of name -> synthetic_head keys")
    out = {}
    for name in idents:
        check_scan_name(name, source, key="identities")
        if "." in name:          # dvc.yaml's params dep identities.<name> would read it as a key path
            raise ScanError(source, f"identities: {name!r} has a '.' (not allowed in an identity's name)")
        if name not in scans:
            raise ScanError(source, f"identities: {name!r} is not listed under scans (its asset would "
                                    "never be built)")
        out[name] = identity_settings(data, name, source)
    return out


def check_params(data: dict, source="params.yaml", complete: bool = False) -> dict:
    """Check a whole params mapping; returns {block: settings} (ScanError on the first problem),
    with ``identities`` -> {name: SyntheticHeadSettings}. ``complete``: every block and list must
    be there (a whole ``params.yaml``, as DVC's params deps need them); otherwise a block that is
    absent takes its defaults."""
    scans = check_scans(data.get("scans"), source)
    unknown = [k for k in data if k not in LISTS and k not in BLOCKS]
    if unknown:
        raise ScanError(source, f"{unknown[0]!r} is not a block of this pipeline (known: "
                                f"{', '.join(LISTS)}, {', '.join(BLOCKS)})")
    out = {}
    for block in BLOCKS:
        raw = data.get(block)
        if raw is not None and not isinstance(raw, dict):
            raise ScanError(source, f"{block} must be a mapping of settings")
        cls = settings_class(block)
        if issubclass(cls, Settings):
            out[block] = cls.from_params(raw, source=source, block=block)
            continue
        try:      # blocks not yet on pipeline.settings: their own from_params
            out[block] = cls.from_params(dict(raw or {}))
        except (ValueError, TypeError) as exc:
            raise ScanError(source, f"{block}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    out["identities"] = check_identities(data, scans, source)
    if complete:
        missing = [k for k in (*LISTS, *BLOCKS) if k not in data]
        if missing:
            raise ScanError(source, f"{missing[0]}: block is missing (every block of this pipeline must be "
                                    f"there; missing: {', '.join(missing)})")
    return out


def check_params_text(text: str, source="params.yaml") -> dict:
    """``text`` read as params.yaml is read (no repeated key) and checked whole
    (:func:`check_params`, ``complete``); returns the parsed mapping, ScanError otherwise."""
    from pipeline.io.strict_yaml import DuplicateKeyError, load_strict

    try:
        data = load_strict(text)       # params.yaml's rules: no repeated key
    except DuplicateKeyError as exc:
        raise ScanError(source, f"{exc}: each key may appear once") from None
    check_params(data, source=str(source), complete=True)
    return data
