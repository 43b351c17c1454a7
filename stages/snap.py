"""Stage ``snap``: move the eyelid margin (and a smooth falloff zone) onto the placed eyeballs.

    python -m stages.snap build/<scan>/bake build/<scan>/remove_eyeballs rigged_assets/eyeball \
        build/<scan>/snap --metrics build/<scan>/snap.metrics.json

Reads ``bake/mesh.npz`` (V, F, loop_left, loop_right, UV/FUV...), ``remove_eyeballs/eyes.json``
(centre, radius, forward per eye) and the eyeball geometry settings from
``eyeball/eyeball.usda`` (customData eyerig.params: r1, r2, apex, seam_blend_mm). Writes
``snap/mesh.npz`` (same arrays, V snapped) and ``snap/eyes.json`` (carried over; the loop
fields re-point at the snapped mesh's loops). See pipeline/geometry/snap.py.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry import snap as sn
from pipeline.io.atomic import atomic_dir, write_json
from pipeline.io.meshfile import read_stage_mesh, save_mesh
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser

SIDES = ("left", "right")


def read_eyeball_params(folder: Path):
    """EyeballParams from ``eyeball.usda``'s customData (defaults when the folder has none)."""
    from pipeline.eyeball.geometry import EyeballParams

    usda = folder / "eyeball.usda"
    if not usda.is_file():
        raise ScanError(usda, "not found (run the eyeball stage first)")
    text = usda.read_text(encoding="utf-8", errors="replace")[:200_000]
    m = re.search(r"dictionary params = \{(.*?)\}", text, re.S)
    if not m:
        raise ScanError(usda, "has no eyerig params dictionary in its customData")
    vals = dict(re.findall(r"double (\w+) = ([-+0-9.eE]+)", m.group(1)))
    keep = {k: float(v) for k, v in vals.items() if k in EyeballParams.__dataclass_fields__}
    try:
        return EyeballParams.from_dict(keep)
    except ValueError as exc:
        raise ScanError(usda, str(exc)) from None


def _eyes(path: Path):
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        out = {}
        for s in SIDES:
            e = doc[s]
            c = np.asarray(e["center"], float).reshape(3)
            f = np.asarray(e["forward"], float).reshape(3)
            r = float(e["radius"])
            if not (np.isfinite(c).all() and np.isfinite(f).all() and np.isfinite(r) and r > 0
                    and np.linalg.norm(f) > 0):
                raise ValueError("non-finite")
            out[s] = (c, r, f / np.linalg.norm(f))
    except (ValueError, KeyError, TypeError) as exc:
        raise ScanError(path, f"is not a valid eyes.json ({type(exc).__name__}: {exc})") from None
    return doc, out


def snap_mesh(mesh: dict, eyes: dict, params, st: sn.SnapSettings, source="mesh.npz"):
    """Snap both loops; returns (new mesh arrays, per-eye reports, metrics)."""
    V = np.asarray(mesh["V"], float)
    F = np.asarray(mesh["F"], np.int64)
    V2 = V.copy()
    G = sn._edge_graph(V, F)
    metrics, reports = {}, {}
    for s in SIDES:
        key = f"loop_{s}"
        if key not in mesh:
            raise ScanError(source, f"missing array {key}")
        loop = np.asarray(mesh[key], np.int64)
        if loop.ndim != 1 or len(loop) < 3 or loop.min() < 0 or loop.max() >= len(V):
            raise ScanError(source, f"{key} is not a list of >= 3 vertex indices")
        c, r, f = eyes[s]
        eye = sn.PlacedEye(c, r, f, params)
        Vs, info = sn.snap_loop(V2, F, loop, eye, st, graph=G)
        far = info["falloff_distance"] > st.falloff_mm
        moved_far = int((np.linalg.norm(Vs - V2, axis=1)[far] > 0).sum())
        V2 = Vs
        rep = sn.margin_report(V2, loop, eye, st)
        d_zone = eye.signed_distance(V2[info["moved"]])
        reports[s] = rep
        metrics[s] = {"loop_length": int(len(loop)), "moved_vertices": int(len(info["moved"])),
                      "grazing_fallbacks": info["grazing"], "pushed_out": info["pushed_out"],
                      "relax_iterations": info["relax_iterations"],
                      "moved_outside_falloff": moved_far,
                      "zone_inside_max_mm": float(max(0.0, -d_zone.min())),
                      "max_move_mm": float(np.linalg.norm(V2[info["moved"]] - V[info["moved"]],
                                                          axis=1).max()),
                      **rep}
    out = dict(mesh)
    out["V"] = V2
    metrics["flipped_faces"] = sn.flipped_faces(V, V2, F)
    metrics["edge_manifold"] = meshtopo.is_edge_manifold(F)
    metrics["gap_max_mm"] = max(metrics[s]["gap_max_mm"] for s in SIDES)
    metrics["inside_max_mm"] = max(max(metrics[s]["inside_max_mm"], metrics[s]["zone_inside_max_mm"])
                                   for s in SIDES)
    return out, reports, metrics


def main(argv) -> dict:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("bake", type=Path, help="build/<scan>/bake (mesh.npz with loop_left/right)")
    parser.add_argument("remove_eyeballs", type=Path, help="build/<scan>/remove_eyeballs (eyes.json)")
    parser.add_argument("eyeball", type=Path, help="rigged_assets/eyeball (eyeball.usda)")
    parser.add_argument("out", type=Path, help="build/<scan>/snap")
    args = parser.parse_args(argv)
    st = load_settings(sn.SnapSettings, args.params)
    mesh_path = args.bake / "mesh.npz"
    mesh = read_stage_mesh(mesh_path)
    doc, eyes = _eyes(args.remove_eyeballs / "eyes.json")
    params = read_eyeball_params(args.eyeball)
    out, reports, metrics = snap_mesh(mesh, eyes, params, st, source=str(mesh_path))
    from pipeline.geometry.frame import eye_basis

    for s in SIDES:  # loop fields now refer to the snapped mesh
        loop = np.asarray(out[f"loop_{s}"], np.int64)
        c, r, f = eyes[s]
        sign = 1.0 if s == "left" else -1.0
        x = ((out["V"][loop] - c) @ eye_basis(f)[0]) * sign
        doc[s] = {**doc[s], "loop_indices": loop.tolist(), "loop_points": out["V"][loop].tolist(),
                  "lateral_canthus_index": int(np.argmax(x)),
                  "snap": {k: v for k, v in reports[s].items()}}
    with atomic_dir(args.out) as tmp:
        save_mesh(tmp / "mesh.npz", **out)
        write_json(tmp / "eyes.json", doc)
    return {"_path": args.metrics or default_metrics_path(args.out), **metrics}


if __name__ == "__main__":
    stage_exit(main)
