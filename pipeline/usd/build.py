"""The usd stage's work: load and check the stage products an asset needs, write and validate
the USD asset (and its usdz). No Blender: the asset's contact sheet is the preview stage's
(pipeline/preview/asset.py).

``read_inputs`` -> ``build``; ``stages/usd.py`` only parses its paths and settings, calls them
inside an atomic output folder and returns the metrics.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import pipeline
from pipeline.errors import ScanError
from pipeline.io.bake_file import read_bake
from pipeline.io.meshfile import read_stage_mesh
from pipeline.io.rig_file import read_rig
from pipeline.io.scan_file import ScanRecord, read_scan_record
from pipeline.results import StageResult
from pipeline.rig import lids
from pipeline.rig.yaw_shapes import yaw_rule


def _need(path: Path) -> Path:
    if not path.is_file():
        raise ScanError(path, "not found")
    return path


@dataclass
class UsdInputs:
    """Everything the scan's asset is made of, read and checked (:func:`read_inputs`).

    Attributes
    ----------
    V : (n, 3) float64, F : (m, 3) int64
        The sealed eye-region mesh (snap), head frame mm.
    UV : (k, 2) float64, FUV : (m, 3) int64
        Its atlas (bake).
    shapes : list of BlendShape
        The lid blend shapes (rig).
    curves : dict side -> ((12, 3) float64, list of BlendShape)
        The eyelid landmark curves and their shapes (rig).
    max_pitch_deg : float
        The pitch-to-weight rule's limit (rig).
    eyes : dict side -> pipeline.io.eyes_file.Eye
        The rig's eyes as stored (the asset's metadata repeats their centre, radius, forward
        and doubts).
    scan : ScanRecord
        ingest's record: name, source hash, licence.
    color, displacement : Path
        The baked maps.
    eyeball : Path
        ``rigged_assets/eyeball/eyeball.usda``, copied into the asset, which references the copy.
    caruncle : (c,) int64
        Faces of ``F`` that take the caruncle material (snap's corner strips; may be empty).
    caruncle_weight : (n,) float64 or None
        Each vertex's share of the caruncle's colour (snap's ``caruncle_weight``; None without
        a caruncle): the asset's ``primvars:caruncleWeight``.
    band : dict side -> (R + 1, S) int64, optional
        The grid of rings and spokes round each opening (retopo's ``band_<side>``), when the
        mesh has one.
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    FUV: np.ndarray
    shapes: list
    curves: dict
    max_pitch_deg: float
    eyes: dict
    scan: ScanRecord
    color: Path
    displacement: Path
    eyeball: Path
    caruncle: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    band: dict | None = None
    caruncle_weight: np.ndarray | None = None


def band_record(band: dict | None, n_vertices: int) -> dict | None:
    """The asset's ``customData eyerig.band``: how the rings and spokes round each opening are
    numbered, so that a user can put any two assets into correspondence there (docs/retopo.md).

    None when the mesh has no band or its ids do not follow the one rule (the older ``march``
    band): then the asset claims no correspondence.
    """
    if not band or set(band) != {"left", "right"}:
        return None
    L, R = (np.asarray(band[s]) for s in ("left", "right"))
    if L.ndim != 2 or L.shape != R.shape:
        return None
    rings, spokes = L.shape
    n = rings * spokes
    if not (np.array_equal(L.ravel(), np.arange(n)) and np.array_equal(R.ravel(), np.arange(n, 2 * n))
            and 2 * n <= n_vertices):
        return None
    return {"rings": int(rings), "spokes": int(spokes),
            "vertex_id": "eye * rings * spokes + ring * spokes + spoke (eye 0 left, 1 right); ring 0 "
                         "is the eyelid margin, spoke 0 its medial canthus, upper lid first",
            "lateral_canthus_spoke": int(spokes // 2),
            "left_vertex_ids": [0, int(n - 1)], "right_vertex_ids": [int(n), int(2 * n - 1)]}


def read_inputs(snap: Path, bake: Path, rig: Path, ingest: Path, eyeball: Path) -> UsdInputs:
    """Load and check everything the asset needs (ScanError on a missing/inconsistent input)."""
    mesh_path = snap / "mesh.npz"
    mesh = read_stage_mesh(mesh_path)
    for k in ("UV", "FUV"):
        if k not in mesh:
            raise ScanError(mesh_path, f"has no {k} array (the asset needs UVs from bake)")
    V, F = np.asarray(mesh.V, np.float64), np.asarray(mesh.F, np.int64)
    if not np.all(np.isfinite(V)):
        raise ScanError(mesh_path, "has non-finite vertex coordinates")
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        raise ScanError(mesh_path, "face indices out of range")
    caruncle = mesh.caruncle_faces
    caruncle = np.zeros(0, np.int64) if caruncle is None else np.asarray(caruncle)
    if caruncle.ndim != 1 or caruncle.dtype.kind not in "iu" or \
            (caruncle.size and (caruncle.min() < 0 or caruncle.max() >= len(F))):
        raise ScanError(mesh_path, "caruncle_faces must be face indices of F")
    cw = mesh.extra.get("caruncle_weight")
    if cw is not None:
        cw = np.asarray(cw, np.float64)
        if cw.shape != (len(V),) or not np.all((cw >= 0) & (cw <= 1)):
            raise ScanError(mesh_path, "caruncle_weight must hold one weight in [0, 1] per vertex")
    r = read_rig(rig, n_vertices=len(V), against=str(mesh_path))
    maps = read_bake(bake)
    scan = read_scan_record(ingest)
    return UsdInputs(V=V, F=F, UV=mesh.UV, FUV=mesh.FUV, shapes=r.npz.shapes, curves=r.npz.curves,
                     max_pitch_deg=r.max_pitch_deg, eyes=r.eyes, scan=scan, color=maps.color,
                     displacement=maps.displacement, eyeball=_need(eyeball / "eyeball.usda"),
                     caruncle=caruncle.astype(np.int64), caruncle_weight=cw,
                     band=({"left": mesh.band_left, "right": mesh.band_right}
                           if mesh.band_left is not None and mesh.band_right is not None else None))


def build(inp: UsdInputs, out_dir: Path, name: str, all_params: dict, package: bool = True) -> StageResult:
    """Write the asset into ``out_dir`` (an empty folder, anywhere), with a copy of the eyeball
    asset in ``out_dir/eyeball/``, validate it and package it."""
    from pipeline.usd.asset import DISPLACEMENT_DOC, check_package, copy_eyeball, package_usdz, write_scan_asset
    from pipeline.usd.validate import validate_stage

    (out_dir / "textures").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(inp.color, out_dir / "textures" / "color.png")
    shutil.copyfile(inp.displacement, out_dir / "textures" / "displacement.exr")
    # the eyeball travels inside the asset folder (a copied or moved folder keeps its eyes; the
    # asset publishes anywhere): ~3 MB beside a ~35 MB asset
    ref = "./" + copy_eyeball(inp.eyeball.parent, out_dir)
    meta = {
        "scan": inp.scan.name if inp.scan.name is not None else name,
        "source_sha256": inp.scan.source_sha256,
        "licence": inp.scan.licence,
        "pipeline_version": pipeline.__version__,
        "units": "mm", "frame": "head frame: +Y up, +Z out of the face, +X subject's left",
        "weight_rule": lids.weight_rule(inp.max_pitch_deg),
        **({"yaw_rule": yaw_rule()} if any(s.name.startswith("lids_look_") for s in inp.shapes) else {}),
        "eyes": {s: {"joint": f"head/eye_{s}", "center_mm": list(map(float, e.center)),
                     "radius_mm": float(e.radius), "forward": list(map(float, e.forward)),
                     # USD cannot type an empty list: no key means nothing doubted
                     **({"doubts": list(e.doubts)} if e.doubts else {})}
                 for s, e in inp.eyes.items()},
        "displacement": DISPLACEMENT_DOC,
        "params": json.loads(json.dumps(all_params)),
    }
    band = band_record(inp.band, len(inp.V))
    if band is not None:
        meta["band"] = band
    t0 = time.perf_counter()
    try:
        usda = write_scan_asset(out_dir / f"{name}.usda", name=name, V=inp.V, F=inp.F, UV=inp.UV,
                                FUV=inp.FUV, shapes=inp.shapes, landmark_curves=inp.curves,
                                eyes=inp.eyes, eyeball_ref=ref, metadata=meta,
                                caruncle_faces=inp.caruncle, caruncle_weight=inp.caruncle_weight)
    except ValueError as exc:
        raise ScanError(inp.eyeball, str(exc)) from None
    t_write = time.perf_counter() - t0
    t0 = time.perf_counter()
    errors = validate_stage(usda)
    t_val = time.perf_counter() - t0
    if errors:
        raise ScanError(usda, f"fails validation ({len(errors)} error(s)): {errors[0]}")
    t_pkg = 0.0
    if package:
        t0 = time.perf_counter()
        usdz = out_dir / f"{name}.usdz"
        try:
            package_usdz(usda, usdz, folder_name=name)
        except ValueError as exc:
            raise ScanError(usdz, f"cannot be packaged: {exc}") from None
        bad = check_package(usdz)
        if bad:
            raise ScanError(usdz, f"package is incomplete ({len(bad)} error(s)): {bad[0]}")
        t_pkg = time.perf_counter() - t0
    return StageResult({"n_vertices": int(len(inp.V)), "n_faces": int(len(inp.F)),
                        "caruncle_faces": int(len(inp.caruncle)), "n_shapes": len(inp.shapes),
                        "validation_errors": 0},
                       {"write_s": round(t_write, 4), "validate_s": round(t_val, 4), "usdz_s": round(t_pkg, 4)})
