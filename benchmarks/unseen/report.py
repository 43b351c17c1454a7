"""Acceptance of ``bench_unseen_scans`` (issue 21, item 4), per family and per set, and its tables.

The bounds, as the issue states them:

- assets for >= 95 % of the open-eyed cases of every family (100 % of the procedural heads);
  every blink refused as closed;
- eye centre within 1.0 mm of truth on >= 80 % of eyes and within 2.0 mm on >= 95 %; radius
  within 1.0 mm on >= 90 %;
- the placed eye (as the asset builds it) within 0.5 mm RMS of the true eye surface inside the
  true opening on >= 95 % of eyes;
- the asset's lid margin after snap within 0.5 mm (mean) of the true margin, with both canthi
  within 1.5 mm of the true corners (the issue gives no fraction: every eye). The margin counts
  as met when both the one-way mean (asset to truth) and the symmetric mean are within 0.5 mm,
  so an opening that covers only part of the fissure does not pass;
- calibration: centre error within 2 stated sigma on >= 90 % of the placed eyes (an eye that
  states no uncertainty counts as outside);
- never silent: no placed eye more than 2 mm off (centre or radius) without a doubt.

Which eyes count: every eye of an open-eyed case (``expect == "asset"``); an eye the pipeline
did not place, or did not carry to the stage a figure needs, counts as not meeting it, so refusing
a scan never helps a fraction. Calibration and silence are about what the pipeline said of the
eyes it placed, so they count placed eyes. Cases whose truth sphere is only a least-squares fit
(``ideal`` False: ICT's own eyeball) are not judged on sphere-based figures (centre, radius,
visible RMS, calibration, silence); their margin and canthi are. A figure of a stage the run
stopped before (``--stop-after``) is "not measured", neither met nor failed.
"""

from __future__ import annotations

import numpy as np

from tests.fixtures.unseen.metrics import says_closed  # noqa: F401  (bench_placement reads it here too)

SIDES = ("left", "right")
CHAIN = ("ingest", "remove_eyeballs", "retopo", "bake", "snap", "rig", "usd")

ASSET_FRACTION, SYNTHETIC_ASSET_FRACTION = 0.95, 1.0
CENTER_MM = ((1.0, 0.80), (2.0, 0.95))      # (mm, fraction of eyes)
RADIUS_MM, RADIUS_FRACTION = 1.0, 0.90
VISIBLE_RMS_MM, VISIBLE_FRACTION = 0.5, 0.95
MARGIN_MM, CANTHUS_MM, MARGIN_FRACTION = 0.5, 1.5, 1.0
CALIBRATION_FRACTION = 0.90
SILENT_MM = 2.0


def outcome(row) -> str:
    """``asset`` (every stage run passed), ``closed`` (refused as closed), ``unsure`` (a self-check
    refused it) or ``failed`` (any other refusal: no eyeball found, cut topology, a later stage)."""
    if not row["failed_stage"]:
        return "asset"
    msg = row["stages"][row["failed_stage"]]["message"]
    if says_closed(msg):
        return "closed"
    if "not sure" in msg:
        return "unsure"
    return "failed"


def eye_error(e) -> float:
    """How far off an eye is: the larger of the centre error and the radius error (mm)."""
    return max(e["center_error_mm"], abs(e["radius_error_mm"]))


def _eyes(rows, ideal_only=False):
    """(row, eye dict or None) for every eye of the open-eyed cases."""
    return [(r, r.get(s)) for r in rows if r["expect"] == "asset" and (r["ideal"] or not ideal_only)
            for s in SIDES]


def _frac(hits, n, need):
    """A bound's record: hits of n against the fraction ``need`` (None when n == 0)."""
    return {"hits": int(hits), "n": int(n), "need": need,
            "met": None if n == 0 else bool(hits >= need * n - 1e-9)}


def _measured(rows, stage) -> bool:
    """Whether the run went as far as ``stage`` (rows record the ``--stop-after`` they ran with)."""
    return any(CHAIN.index(stage) <= CHAIN.index(r.get("stop_after", "rig")) for r in rows)


def acceptance(rows) -> dict:
    """Every bound of the module docstring for ``rows`` (one family, one set, or all)."""
    out = {}
    wanted = [r for r in rows if r["expect"] == "asset"]
    if wanted:
        synth = all(r["family"] == "synthetic" for r in wanted)
        out["assets"] = _frac(sum(outcome(r) == "asset" for r in wanted), len(wanted),
                              SYNTHETIC_ASSET_FRACTION if synth else ASSET_FRACTION)
    closed = [r for r in rows if r["expect"] == "closed"]
    if closed:
        out["blinks_refused_as_closed"] = _frac(sum(outcome(r) == "closed" for r in closed),
                                                len(closed), 1.0)
    ideal = _eyes(rows, ideal_only=True)
    if ideal:
        for mm, need in CENTER_MM:
            out[f"center_within_{mm:g}mm"] = _frac(
                sum(e is not None and e["center_error_mm"] <= mm for _, e in ideal), len(ideal), need)
        out[f"radius_within_{RADIUS_MM:g}mm"] = _frac(
            sum(e is not None and abs(e["radius_error_mm"]) <= RADIUS_MM for _, e in ideal),
            len(ideal), RADIUS_FRACTION)
        out[f"visible_rms_within_{VISIBLE_RMS_MM:g}mm"] = _frac(
            sum(e is not None and e.get("visible_rms_mm") is not None
                and e["visible_rms_mm"] <= VISIBLE_RMS_MM for _, e in ideal), len(ideal), VISIBLE_FRACTION)
        placed = [e for _, e in ideal if e is not None]
        out["calibration_within_2sigma"] = _frac(sum(bool(e.get("within_2sigma")) for e in placed),
                                                 len(placed), CALIBRATION_FRACTION)
        silent = sum(eye_error(e) > SILENT_MM and not e["doubted"] for e in placed)
        out[f"silent_over_{SILENT_MM:g}mm"] = {"hits": silent, "n": len(placed), "need": 0,
                                               "met": silent == 0}
    eyes = _eyes(rows)
    if eyes:
        if _measured(rows, "snap"):
            out[f"margin_within_{MARGIN_MM:g}mm"] = _frac(
                sum(e is not None and "margin_mean_mm" in e and e["margin_mean_mm"] <= MARGIN_MM
                    and e["margin_symmetric_mm"] <= MARGIN_MM for _, e in eyes), len(eyes), MARGIN_FRACTION)
        if _measured(rows, "rig"):
            out[f"canthi_within_{CANTHUS_MM:g}mm"] = _frac(
                sum(e is not None and "canthus_medial_mm" in e
                    and max(e["canthus_medial_mm"], e["canthus_lateral_mm"]) <= CANTHUS_MM
                    for _, e in eyes), len(eyes), MARGIN_FRACTION)
    return out


def families(rows, order) -> list:
    """The families present in ``rows``, in ``order``."""
    present = {r["family"] for r in rows}
    return [f for f in order if f in present]


def summary(rows, order) -> dict:
    """Per set (and ``all``): the acceptance over the set and per family, and whether every bound
    of every family is met (the issue's "done when")."""
    out = {}
    for set_name in ("dev", "heldout", "fresh", "all"):
        rs = [r for r in rows if set_name in ("all", r["set"])]
        if not rs:
            continue
        fams = {f: acceptance([r for r in rs if r["family"] == f]) for f in families(rs, order)}
        every = [b["met"] for acc in fams.values() for b in acc.values() if b["met"] is not None]
        out[set_name] = {"cases": len(rs), "chain_to": sorted({r.get("stop_after", "rig") for r in rs}),
                         "overall": acceptance(rs), "families": fams,
                         "every_family_meets_every_bound": bool(every) and all(every)}
    return out


def _cell(b):
    if b is None:
        return "–"
    return f"{b['hits']}/{b['n']}"


SHORT = {"assets": "assets", "blinks_refused_as_closed": "closed", "center_within_1mm": "c<=1",
         "center_within_2mm": "c<=2", "radius_within_1mm": "r<=1", "visible_rms_within_0.5mm": "vis",
         "calibration_within_2sigma": "2sig", "silent_over_2mm": "silent",
         "margin_within_0.5mm": "margin", "canthi_within_1.5mm": "canthi"}


def print_summary(summ) -> None:
    """Each bound with met / not met, per set: the set's totals, then one line per family."""
    word = {True: "met", False: "NOT MET", None: "n/a"}
    for set_name, s in summ.items():
        print(f"== {set_name}: {s['cases']} cases, chain to {'/'.join(s['chain_to'])}; "
              f"every family meets every bound: "
              f"{'yes' if s['every_family_meets_every_bound'] else 'no'}")
        for k, b in s["overall"].items():
            need = (f"== {b['need']}" if k.startswith("silent") else f">= {b['need']:.0%}")
            print(f"   {k:<32} {b['hits']:>4}/{b['n']:<4} (need {need}): {word[b['met']]}")
        for f, acc in s["families"].items():    # one line: each bound, short, * = not met
            print(f"   {f:<18} " + "  ".join(
                f"{SHORT[k]} {b['hits']}/{b['n']}{'*' if b['met'] is False else ''}"
                for k, b in acc.items()))
        print("   (* not met; n/a where no eye was placed)")


def _median(vals):
    vals = [v for v in vals if v is not None]
    return f"{np.median(vals):.2f}" if vals else "–"


def markdown(rows, order, oracle: dict | None = None) -> str:
    """The README tables: one per set, a row per family and one for the set, with two bars beside:
    the oracle (eyes a fit to the perfectly segmented sclera puts within 0.5 / 1.0 mm) and the
    visible RMS of the asset's eye placed exactly at the truth (what its eye model allows)."""
    head = ("| family | cases | assets | closed refused | centre ≤1 / ≤2 mm | radius ≤1 mm | "
            "visible RMS ≤0.5 mm (median) | same, eye at truth | margin ≤0.5 mm (median) | "
            "canthi ≤1.5 mm | calibration ≤2σ | silent >2 mm | oracle ≤0.5 / ≤1 mm |")
    out = []
    for set_name in ("dev", "heldout", "fresh"):
        rs = [r for r in rows if r["set"] == set_name]
        if not rs:
            continue
        out += [f"**{set_name}**", "", head, "|" + "---|" * 13]
        for f in families(rs, order) + ["all"]:
            sub = rs if f == "all" else [r for r in rs if r["family"] == f]
            a = acceptance(sub)
            eyes = [e for _, e in _eyes(sub) if e is not None]
            orc = _oracle_cell(oracle, [r["case"] for r in sub])
            vis = _median(e.get("visible_rms_mm") for e in eyes)
            floor = [r.get("visible_rms_floor_mm", {}).get(s) for r in sub if r["expect"] == "asset"
                     and r["ideal"] for s in SIDES]
            floor = [f for f in floor if f is not None]
            floor_cell = (f"{sum(f <= VISIBLE_RMS_MM for f in floor)}/{len(floor)} ({_median(floor)})"
                          if floor else "–")
            mar = _median(e.get("margin_symmetric_mm") for e in eyes)
            out.append(
                f"| {f if f != 'all' else '**all**'} | {len(sub)} | {_cell(a.get('assets'))} | "
                f"{_cell(a.get('blinks_refused_as_closed'))} | "
                f"{_cell(a.get('center_within_1mm'))} / {_cell(a.get('center_within_2mm'))} | "
                f"{_cell(a.get('radius_within_1mm'))} | "
                f"{_cell(a.get('visible_rms_within_0.5mm'))} ({vis}) | {floor_cell} | "
                f"{_cell(a.get('margin_within_0.5mm'))} ({mar}) | "
                f"{_cell(a.get('canthi_within_1.5mm'))} | {_cell(a.get('calibration_within_2sigma'))} | "
                f"{a['silent_over_2mm']['hits'] if 'silent_over_2mm' in a else '–'} | {orc} |")
        out.append("")
    return "\n".join(out)


def _oracle_cell(oracle, names, key="margin_0mm"):
    """Eyes of ``names`` the oracle puts within 0.5 / 1.0 mm (``k/n · k/n``), or – ."""
    if not oracle:
        return "–"
    errs = []
    for n in names:
        c = oracle.get("cases", {}).get(n)
        if not c:
            continue
        for s in SIDES:
            e = c[s][key]
            errs.append(np.inf if e["center_error_mm"] is None
                        else max(e["center_error_mm"], abs(e["radius_error_mm"])))
    if not errs:
        return "–"
    errs = np.array(errs)
    return f"{(errs <= 0.5).sum()}/{len(errs)} · {(errs <= 1.0).sum()}/{len(errs)}"
