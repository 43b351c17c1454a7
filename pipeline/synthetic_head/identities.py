"""Procedural identities: the ``synthetic_head`` keys of identity ``i`` of a seed, and the marked
blocks of ``params.yaml`` that list them (``identities:`` and ``scans:``), edited as text so
every other line and comment stays as written, and an identity's stages in ``dvc.lock``.
stages/identities.py is the command.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import ScanError

#: Marks around the lines this command owns, in ``scans:`` and in ``identities:`` (2-space indent).
BEGIN, END = "  # >>> identities", "  # <<< identities"
#: A lighter default mesh than the home head's 350k triangles: ~2x faster through the per-scan
#: stages with the same retopologised asset (docs/synthetic_head.md, "Identities").
DEFAULT_TRIANGLES = 150_000
#: 1 / golden ratio: tone i = frac(u0 + i * this) spreads any N tones evenly over [0, 1).
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def identity_name(seed: int, i: int) -> str:
    return f"ident_s{seed}_{i:03d}"


def draw_identity(seed: int, i: int, triangles: int) -> dict:
    """Identity ``i`` of ``seed``: the ``synthetic_head`` keys it sets (plain YAML scalars).

    The skin tones follow a golden-ratio sequence from a seeded start, so any first N of them
    cover [0, 1] evenly; an age-like draw sets both wrinkles (0.3-2.2) and pores (0.7-1.6)."""
    rng = np.random.default_rng([0x1D, int(seed), int(i)])
    u0 = float(np.random.default_rng([0x1D, int(seed)]).uniform())
    age = float(rng.uniform())
    return {
        "seed": int(rng.integers(0, 2**31 - 1)),
        "eye_shape": round(float(rng.uniform()), 2),          # hoodedness: 0 round .. 1 hooded
        "skin_tone": round((u0 + i * _GOLDEN) % 1.0, 3),
        "wrinkle_scale": round(0.3 + 1.9 * age, 2),
        "pore_scale": round(0.7 + 0.9 * age, 2),
        "eye_spacing_mm": round(float(np.clip(rng.normal(63.0, 3.0), 57.0, 69.0)), 1),
        "target_triangles": int(triangles),
        "asset_eye_size": "population",   # the asset keeps the globe drawn for the head (issue 29)
    }


def _flow(entry: dict) -> str:
    return "{" + ", ".join(f"{k}: {v}" for k, v in entry.items()) + "}"


def _marked(lines: list[str], top: str, source) -> tuple[int, int]:
    """(begin, end) line indices of the marks inside the top-level key ``top:``."""
    try:
        start = lines.index(f"{top}:")
    except ValueError:
        raise ScanError(source, f"has no top-level '{top}:' list") from None
    stop = next((k for k in range(start + 1, len(lines)) if lines[k] and not lines[k][0].isspace()
                 and not lines[k].startswith("#")), len(lines))
    b = next((k for k in range(start, stop) if lines[k].startswith(BEGIN)), None)
    e = next((k for k in range(start, stop) if lines[k].startswith(END)), None)
    if b is None or e is None or e < b:
        raise ScanError(source, f"'{top}:' has no '{BEGIN.strip()}' ... '{END.strip()}' marks "
                                "(add the two comment lines where the generated entries go)")
    return b, e


def _marked_entries(lines: list[str], b: int, e: int, source) -> dict:
    """{name: keys} of the ``identities:`` lines between the marks ``b`` and ``e``."""
    import yaml

    have = {}
    for ln in lines[b + 1:e]:
        if ln.strip() and not ln.strip().startswith("#"):
            one = yaml.safe_load(ln)
            if not isinstance(one, dict):
                raise ScanError(source, f"identities: cannot read the generated line {ln.strip()!r}")
            have.update(one)
    return have


def add_identities(text: str, entries: dict, source="params.yaml") -> str:
    """``text`` (params.yaml) with ``entries`` ({name: keys}) between the marks of ``scans:`` and
    ``identities:``; the entries already there are kept, those of the same names replaced.
    Every line outside the marks is unchanged."""
    lines = text.split("\n")
    b, e = _marked(lines, "identities", source)
    have = _marked_entries(lines, b, e, source)
    have.update(entries)
    lines[b + 1:e] = [f"  {n}: {_flow(have[n])}" for n in sorted(have)]
    b, e = _marked(lines, "scans", source)
    names = [ln.strip()[2:].strip() for ln in lines[b + 1:e] if ln.strip().startswith("- ")]
    names += [n for n in sorted(entries) if n not in names]
    lines[b + 1:e] = [f"  - {n}" for n in names]
    return "\n".join(lines)


def remove_identities(text: str, names, source="params.yaml") -> str:
    """``text`` (params.yaml) without the entries ``names`` between the marks of ``identities:``
    and ``scans:``; every other line is unchanged. A name not between the ``identities:`` marks
    is refused (ScanError naming ``source`` and the name): an entry written by hand, or a scan,
    is not this command's to remove."""
    lines = text.split("\n")
    b, e = _marked(lines, "identities", source)
    have = _marked_entries(lines, b, e, source)
    unknown = [n for n in names if n not in have]
    if unknown:
        raise ScanError(source, f"identities: no {', '.join(map(repr, unknown))} between the "
                                f"'{BEGIN.strip()}' marks (known: {', '.join(sorted(have)) or 'none'}); "
                                "nothing was changed")
    gone = set(names)
    lines[b + 1:e] = [f"  {n}: {_flow(have[n])}" for n in sorted(have) if n not in gone]
    b, e = _marked(lines, "scans", source)
    lines[b + 1:e] = [ln for ln in lines[b + 1:e] if ln.strip()[2:].strip() not in gone
                      or not ln.strip().startswith("- ")]
    return "\n".join(lines)


def drop_lock_stages(text: str, names, source="dvc.lock") -> tuple[str, list[str]]:
    """``text`` (dvc.lock) without the stages ``<stage>@<name>`` of ``names``, and the stage names
    dropped. Edited as text, one block per stage of the ``stages:`` mapping, so every other stage
    keeps its bytes (a load and dump would rewrap dvc's long ``cmd`` lines); the result must load
    as the same mapping less those stages, else ScanError naming ``source`` (nothing written)."""
    from pipeline.io.strict_yaml import load_strict

    lines = text.splitlines(keepends=True)
    old = load_strict(text) if text.strip() else {}
    if not isinstance(old, dict):
        raise ScanError(source, "is not a YAML mapping (not a dvc.lock); nothing was changed")
    if not any(isinstance(k, str) and k.rpartition("@")[2] in set(names) and "@" in k
               for k in old.get("stages") or {}):
        return text, []
    if not isinstance(old["stages"], dict):
        raise ScanError(source, "'stages:' is not a mapping of stage names; nothing was changed")
    top = next((k for k, ln in enumerate(lines) if ln.rstrip() == "stages:"), None)
    if top is None:
        raise ScanError(source, "has no 'stages:' line at the start of a line (not as dvc writes it); "
                                "nothing was changed")
    end = next((k for k in range(top + 1, len(lines)) if lines[k].strip() and not lines[k][0].isspace()),
               len(lines))
    starts = [k for k in range(top + 1, end) if lines[k].startswith("  ") and lines[k][2:3] not in (" ", "#", "\n", "")]
    gone = set(names)
    keep, dropped = lines[:top + 1], []
    keep += lines[top + 1:starts[0]] if starts else lines[top + 1:end]
    for k, nxt in zip(starts, [*starts[1:], end]):
        one = load_strict(lines[k])
        key = next(iter(one)) if isinstance(one, dict) and len(one) == 1 else None
        if isinstance(key, str) and "@" in key and key.rpartition("@")[2] in gone:
            dropped.append(key)
        else:
            keep += lines[k:nxt]
    keep += lines[end:]
    out = "".join(keep)
    want = dict(old, stages={k: v for k, v in old["stages"].items() if k not in dropped})
    if load_strict(out) != want:
        raise ScanError(source, "its 'stages:' blocks are not laid out as dvc writes them (cannot cut "
                                f"{', '.join(dropped) or 'the stages'} out as text); nothing was changed")
    return out, dropped
