"""Reusable USD asset validator: ``validate_stage(path_or_stage) -> list[str]``.

Runs every registered ``pxr.UsdValidation`` validator (errors only; warnings
are returned by :func:`validate_stage_report`) and the explicit checks that
those validators miss:

- stage metadata: default prim, ``metersPerUnit`` (house value 0.001 unless
  ``meters_per_unit=None``), ``upAxis`` ``Y``;
- every UsdGeom.Mesh: ``UsdGeom.Mesh.ValidateTopology``, finite points,
  primvar element counts against their interpolation;
- every mesh with SkelBindingAPI: ``skel:blendShapes`` and
  ``skel:blendShapeTargets`` of equal length, each target a UsdSkel.BlendShape;
  ``UsdSkel.BlendShape.ValidatePointIndices`` and no duplicate indices; offsets (and every inbetween's)
  count == pointIndices count (== point count without indices); finite offsets;
- every bound material exists and has a surface output;
- every asset-valued shader input (textures) resolves to an existing file
  (for the current variant selections).

An empty list means the asset is valid.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.geometry.meshtopo import triangle_cross, turned_over_faces


def _open(path_or_stage):
    from pxr import Usd

    if isinstance(path_or_stage, Usd.Stage):
        return path_or_stage, []
    try:
        stage = Usd.Stage.Open(str(path_or_stage))
    except Exception as exc:  # pxr raises Tf.ErrorException
        return None, [f"{path_or_stage}: cannot be opened as a USD stage ({str(exc).strip()[:200]})"]
    if stage is None:
        return None, [f"{path_or_stage}: cannot be opened as a USD stage"]
    return stage, []


def usd_validation_errors(stage):
    """(errors, warnings) from every registered pxr.UsdValidation validator."""
    from pxr import UsdValidation

    reg = UsdValidation.ValidationRegistry()
    validators = reg.GetOrLoadAllValidators()
    ctx = UsdValidation.ValidationContext(validators)
    errors, warnings = [], []
    for e in ctx.Validate(stage):
        if e.HasNoError():
            continue
        msg = f"UsdValidation {e.GetName()}: {e.GetMessage()}"
        if e.GetType() == UsdValidation.ValidationErrorType.Error:
            errors.append(msg)
        else:
            warnings.append(msg)
    return errors, warnings


def _mesh_checks(mesh, errors):
    from pxr import Usd, UsdGeom

    path = mesh.GetPath()
    pts = mesh.GetPointsAttr().Get()
    counts = mesh.GetFaceVertexCountsAttr().Get()
    idx = mesh.GetFaceVertexIndicesAttr().Get()
    if pts is None or counts is None or idx is None:
        errors.append(f"{path}: mesh lacks points, faceVertexCounts or faceVertexIndices")
        return None
    P = np.asarray(pts, np.float64).reshape(-1, 3)
    n = len(P)
    ok, why = UsdGeom.Mesh.ValidateTopology(idx, counts, n)
    if not ok:
        errors.append(f"{path}: bad topology: {why}")
    if not np.all(np.isfinite(P)):
        errors.append(f"{path}: {int((~np.isfinite(P)).any(1).sum())} point(s) are not finite")
    nfaces, ncorners = len(counts), len(idx)
    expect = {UsdGeom.Tokens.vertex: n, UsdGeom.Tokens.varying: n,
              UsdGeom.Tokens.faceVarying: ncorners, UsdGeom.Tokens.uniform: nfaces,
              UsdGeom.Tokens.constant: 1}
    for pv in UsdGeom.PrimvarsAPI(mesh).GetPrimvars():
        interp = pv.GetInterpolation()
        if interp not in expect or pv.GetName().startswith("primvars:skel:"):
            continue
        val = pv.Get(Usd.TimeCode.Default())
        if val is None:
            continue
        es = max(pv.GetElementSize(), 1)
        if pv.IsIndexed():
            ind = np.asarray(pv.GetIndices(), np.int64)
            if len(ind) != expect[interp] * es:
                errors.append(f"{path}: primvar {pv.GetPrimvarName()} has {len(ind)} indices, "
                              f"{interp} needs {expect[interp] * es}")
            if len(ind) and (ind.min() < 0 or ind.max() >= len(val)):
                errors.append(f"{path}: primvar {pv.GetPrimvarName()} indices out of range")
        elif interp != UsdGeom.Tokens.constant and len(val) != expect[interp] * es:
            errors.append(f"{path}: primvar {pv.GetPrimvarName()} has {len(val)} values, "
                          f"{interp} needs {expect[interp] * es}")
    return n


def _fan_triangles(counts, idx):
    """Fan triangulation of polygons: ``(face, a, b, c)``, each (t,) int64, in face order and
    fan order within a face (the order :func:`_polygon_normals` sums in)."""
    counts = np.asarray(counts, np.int64)
    idx = np.asarray(idx, np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_tri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), n_tri)
    # k = 1 .. count-2 within each face: a running index minus where the face's run began
    first = np.cumsum(n_tri) - n_tri
    k = np.arange(len(face), dtype=np.int64) - first[face] + 1
    return face, idx[start[face]], idx[start[face] + k], idx[start[face] + k + 1]


def _polygon_normals(P, counts, idx, fan=None):
    """(nfaces, 3) area-weighted normals of polygons (fan sums; exact for planar polygons).
    ``fan``: :func:`_fan_triangles` of ``counts, idx``, when the caller reuses it."""
    face, a, b, c = _fan_triangles(counts, idx) if fan is None else fan
    T = triangle_cross(P, np.stack([a, b, c], axis=1))
    # bincount adds each face's triangles in order from 0.0, as np.add.at did: the same bits
    n = len(counts)
    return np.stack([np.bincount(face, T[:, j], minlength=n) for j in range(3)], axis=1)


def _posed_flips(P, counts, idx, point_indices, offsets_list):
    """Largest number of faces that turn over (:func:`pipeline.geometry.meshtopo.turned_over_faces`:
    turned by more than 90 degrees, and away from the way the mesh faces) when the shape is
    applied at each given offsets array (full weight and every inbetween)."""
    fan = _fan_triangles(counts, idx)
    N0 = _polygon_normals(P, counts, idx, fan)
    ok = np.linalg.norm(N0, axis=1) > 1e-20
    worst = 0
    for O in offsets_list:
        Q = P.copy()
        if point_indices is None:
            Q += O
        else:
            Q[point_indices] += O
        N1 = _polygon_normals(Q, counts, idx, fan)
        worst = max(worst, int(np.count_nonzero(turned_over_faces(N0, N1)[ok])))
    return worst


def _blend_shape_checks(stage, mesh, n_points, errors):
    from pxr import UsdGeom, UsdSkel

    prim = mesh.GetPrim()
    if not prim.HasAPI(UsdSkel.BindingAPI):
        return
    api = UsdSkel.BindingAPI(prim)
    names = api.GetBlendShapesAttr().Get() or []
    targets = api.GetBlendShapeTargetsRel().GetTargets() if api.GetBlendShapeTargetsRel() else []
    path = mesh.GetPath()
    if len(names) != len(targets):
        errors.append(f"{path}: {len(names)} skel:blendShapes but {len(targets)} skel:blendShapeTargets")
    for t in targets:
        bs = UsdSkel.BlendShape(stage.GetPrimAtPath(t))
        if not bs:
            errors.append(f"{path}: blend-shape target {t} is not a UsdSkel.BlendShape")
            continue
        offsets = bs.GetOffsetsAttr().Get()
        if offsets is None:
            errors.append(f"{t}: no offsets")
            continue
        O = np.asarray(offsets, np.float64).reshape(-1, 3)
        ind = bs.GetPointIndicesAttr().Get()
        if ind is not None and len(ind):
            ok, why = bs.ValidatePointIndices(ind, n_points)
            if not ok:
                errors.append(f"{t}: bad pointIndices: {why}")
            ia = np.asarray(ind, np.int64)
            if len(np.unique(ia)) != len(ia):
                errors.append(f"{t}: pointIndices has {len(ia) - len(np.unique(ia))} duplicate(s)")
            expect = len(ind)
        else:
            expect = n_points
        if len(O) != expect:
            errors.append(f"{t}: {len(O)} offsets but {expect} "
                          f"{'pointIndices' if ind is not None and len(ind) else 'mesh points'}")
        if not np.all(np.isfinite(O)):
            errors.append(f"{t}: offsets are not finite")
        for ib in bs.GetInbetweens():
            io = ib.GetOffsets()
            if io is None or len(io) != expect:
                errors.append(f"{t}: inbetween {ib.GetAttr().GetName()} has "
                              f"{0 if io is None else len(io)} offsets, expected {expect}")
            elif not np.all(np.isfinite(np.asarray(io, np.float64))):
                errors.append(f"{t}: inbetween {ib.GetAttr().GetName()} offsets are not finite")
            w = ib.GetWeight()
            if w is None or not math.isfinite(w):
                errors.append(f"{t}: inbetween {ib.GetAttr().GetName()} weight is not finite")
        # the rig's geometry check, on what the asset actually stores: no face turns over
        # at full weight or at any inbetween (a fold shows in every render of that pose)
        pts = mesh.GetPointsAttr().Get()
        counts, fidx = mesh.GetFaceVertexCountsAttr().Get(), mesh.GetFaceVertexIndicesAttr().Get()
        if (pts is None or counts is None or fidx is None or len(O) != expect
                or not np.all(np.isfinite(O))):
            continue
        P = np.asarray(pts, np.float64).reshape(-1, 3)
        pidx = (np.asarray(ind, np.int64) if ind is not None and len(ind) else None)
        ca = np.asarray(counts, np.int64)
        if ((pidx is not None and (pidx.min() < 0 or pidx.max() >= len(P)))
                or not UsdGeom.Mesh.ValidateTopology(fidx, counts, len(P))[0]
                or (len(ca) and ca.min() < 3) or not np.all(np.isfinite(P))):
            continue   # reported by the topology/point checks
        offs = [O] + [np.asarray(ib.GetOffsets(), np.float64).reshape(-1, 3)
                      for ib in bs.GetInbetweens()
                      if ib.GetOffsets() is not None and len(ib.GetOffsets()) == expect]
        flips = _posed_flips(P, counts, fidx, pidx, offs)
        if flips:
            errors.append(f"{t}: posing the shape flips {flips} face(s)")


def _material_checks(stage, errors):
    from pxr import UsdShade

    for prim in stage.Traverse():
        if not prim.HasAPI(UsdShade.MaterialBindingAPI):
            continue
        rel = UsdShade.MaterialBindingAPI(prim).GetDirectBindingRel()
        if not rel:
            continue
        for t in rel.GetTargets():
            mat = UsdShade.Material(stage.GetPrimAtPath(t))
            if not mat:
                errors.append(f"{prim.GetPath()}: bound material {t} does not exist")
            elif not mat.GetSurfaceOutput().HasConnectedSource():
                errors.append(f"{t}: material has no connected surface output")


def shader_asset_inputs(stage):
    """Yield ``(prim, input, asset_path)`` for every authored asset-valued shader input."""
    from pxr import Sdf, UsdShade

    for prim in stage.Traverse():
        if not prim.IsA(UsdShade.Shader):
            continue
        for inp in UsdShade.Shader(prim).GetInputs():
            if inp.GetTypeName() != Sdf.ValueTypeNames.Asset:
                continue
            val = inp.Get()
            if val is not None and val.path:
                yield prim, inp, val


def _asset_checks(stage, errors):
    import os

    for prim, inp, val in shader_asset_inputs(stage):
        if not val.resolvedPath or not os.path.isfile(val.resolvedPath):
            errors.append(f"{prim.GetPath()}: inputs:{inp.GetBaseName()} @{val.path}@ does not resolve "
                          "to an existing file")


def validate_stage_report(path_or_stage, meters_per_unit: float | None = 0.001,
                          up_axis: str | None = "Y") -> dict:
    """Full report: ``{"errors": [...], "warnings": [...], "meshes": n, "blend_shapes": n}``."""
    from pxr import UsdGeom, UsdSkel

    stage, errors = _open(path_or_stage)
    if stage is None:
        return {"errors": errors, "warnings": [], "meshes": 0, "blend_shapes": 0}
    errs, warnings = usd_validation_errors(stage)
    errors += errs
    dp = stage.GetDefaultPrim()
    if not dp:
        errors.append("stage has no default prim")
    if meters_per_unit is not None:
        mpu = UsdGeom.GetStageMetersPerUnit(stage)
        if not math.isclose(mpu, meters_per_unit, rel_tol=1e-9):
            errors.append(f"metersPerUnit is {mpu}, expected {meters_per_unit}")
    if up_axis is not None and UsdGeom.GetStageUpAxis(stage) != up_axis:
        errors.append(f"upAxis is {UsdGeom.GetStageUpAxis(stage)}, expected {up_axis}")
    n_mesh = n_bs = 0
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            n_mesh += 1
            mesh = UsdGeom.Mesh(prim)
            n = _mesh_checks(mesh, errors)
            if n is not None:
                _blend_shape_checks(stage, mesh, n, errors)
        elif prim.IsA(UsdSkel.BlendShape):
            n_bs += 1
    _material_checks(stage, errors)
    _asset_checks(stage, errors)
    return {"errors": errors, "warnings": warnings, "meshes": n_mesh, "blend_shapes": n_bs}


def validate_stage(path_or_stage, meters_per_unit: float | None = 0.001,
                   up_axis: str | None = "Y") -> list[str]:
    """Errors of a USD asset (empty list = valid). See the module docstring for the checks.

    Parameters
    ----------
    path_or_stage : str | pathlib.Path | pxr.Usd.Stage
    meters_per_unit : float or None (skip the check)
    up_axis : "Y", "Z" or None (skip the check)
    """
    return validate_stage_report(path_or_stage, meters_per_unit, up_axis)["errors"]
