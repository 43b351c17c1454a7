"""The per-scan rigged USD asset (``rigged_assets/<scan>/<scan>.usda``).

Hierarchy (default prim ``/<scan>``, a SkelRoot with kind = component; millimetres in the
head frame, metersPerUnit 0.001, upAxis Y, +Z out of the face)::

    /<scan>                       SkelRoot; variant sets irisColor, scleraTint, veins (forwarded
                                  to both eyes); customData["eyerig"] = provenance + weight rule
        Skel                      Skeleton: joints head, head/eye_left, head/eye_right
            Anim                  SkelAnimation: rest pose; weights of lids_up, lids_down and the
                                  eyeball's pupil/iris shapes (0)
        EyeRegion                 Mesh: the eye-region skin (primvars:st, normals); bound to
                                  joint "head"; blend shapes lids_up, lids_down (with inbetweens)
        Eyes/eye_left, eye_right  Xform referencing ./eyeball/eyeball.usda, the asset folder's copy
                                  of rigged_assets/eyeball (typeName overridden
                                  from SkelRoot to Xform, kind subcomponent, its own Skel
                                  deactivated); Outer/Inner rebound rigidly to the eye joint, their
                                  points and the Inner blend shapes overridden with the eye placed
                                  at the asset's radius (customData eyerig.params: its geometry)
        Landmarks/eyelid_left,    BasisCurves (12 points, linear, periodic) with the same lid
                  eyelid_right    blend shapes and inbetweens
        Landmarks/eye_left, ...   Scope: eyerig:landmarks:iris / :pupil (Inner vertex indices,
                                  copied from the eyeball) + rel eyerig:landmarks:mesh -> Inner
        Materials/Skin            UsdPreviewSurface: diffuse = textures/color.png,
                                  displacement = textures/displacement.exr (scale 1: mm = stage units)
        Materials/Caruncle        UsdPreviewSurface, the skin map reddened (or pink): bound to the EyeRegion's GeomSubset
                                  "caruncle" (the strip closing the medial corner where the lids
                                  stand off the eye, pipeline/geometry/corners.py); absent when
                                  every corner rests on the eye; the EyeRegion's
                                  primvars:caruncleWeight (vertex, 0-1) says how much of the
                                  caruncle's colour each vertex takes (0 at the lid margin): the
                                  renderer blends skin into caruncle by it (a preview surface
                                  cannot, so USD viewers show the subset's flat colour)

Eyes and joints: UsdSkel does not move child prims of joints, so each eye's meshes are
skinned rigidly (constant ``jointIndices``/``jointWeights``) to their eye joint. The joint's
bind/rest transform is the fitted eye frame (rotation rows e_x, e_y, forward; translation =
eye's centre) and so is ``geomBindTransform`` (no scale): the eye's points are the parametric
eye placed at the eye's radius in eyes.json (the paper's 12 mm unless ``remove_eyeballs.eye_size``
says otherwise; :func:`pipeline.eyeball.geometry.placed_params`: the sclera sphere takes the
radius, cornea, iris and pupil keep their size in mm), built at the referenced
eyeball's resolution from its own parameters (customData eyerig.params and .resolution) and
authored over the reference's points, with the Inner blend shapes' offsets; the eye prim's
customData eyerig.params says which. At rest the eye sits at its centre (anchored at the scan's
limbus, pipeline/placement/human_eye.py) looking along its forward direction, and rotating the joint rotates it about its centre.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.settings import Settings, setting


@dataclass(frozen=True)
class UsdSettings(Settings):
    """The ``usd:`` block of params.yaml (the per-scan asset)."""

    block: ClassVar[str] = "usd"

    usdz: bool = True                                   # also write <scan>.usdz (self-contained)
    # the preview stage's (rigged_assets/<scan>.preview.png), not the asset's
    preview_px: int = setting(180, ge=16, le=2048)      # tile height (tiles are 2:1, both eyes)
    preview_samples: int = setting(4, ge=1, le=4096)    # + OpenImageDenoise (bench_asset_preview --quality)


SIDES = ("left", "right")
JOINTS = ("head", "head/eye_left", "head/eye_right")
DISPLACEMENT_DOC = ("textures/displacement.exr: float32, signed distance in mm (= stage units) along "
                    "the interpolated vertex normal, positive outward; UsdPreviewSurface "
                    "displacement input connected with scale 1, bias 0")


def _usd_normals(V, F) -> np.ndarray:
    """Unit area-weighted vertex normals (meshtopo.vertex_normals), +Z where a vertex has no
    area around it (USD viewers want a direction everywhere)."""
    N = meshtopo.vertex_normals(V, F)
    N[np.linalg.norm(N, axis=1) == 0] = (0.0, 0.0, 1.0)
    return N


def eye_frame_matrix(center, forward, scale: float = 1.0) -> np.ndarray:
    """(4, 4) row-vector matrix (USD convention): rows scale*e_x, scale*e_y, scale*forward, centre."""
    M = np.eye(4)
    M[:3, :3] = eye_basis(forward) * float(scale)
    M[3, :3] = np.asarray(center, np.float64)
    return M


def _gf(M):
    from pxr import Gf

    return Gf.Matrix4d(*[float(x) for x in np.asarray(M, np.float64).ravel()])


def _shape_inbetweens(shapes):
    return {s.name: list(zip(np.asarray(s.inbetween_weights, float), s.inbetween_offsets)) for s in shapes}


def _skin_material(stage, path, color_tex: str | None, disp_tex: str | None):
    from pxr import Sdf

    from pipeline.usd import stage as su

    mat, surf, _ = su.preview_material(stage, path, roughness=0.55, texture=color_tex,
                                       diffuse=(0.75, 0.6, 0.55))
    if disp_tex is not None:
        dt = su.uv_texture(stage, path, "DisplacementTexture", disp_tex, "raw", "clamp", "clamp")
        dt.CreateOutput("r", Sdf.ValueTypeNames.Float)
        dt.GetPrim().SetDocumentation(DISPLACEMENT_DOC)
        surf.CreateInput("displacement", Sdf.ValueTypeNames.Float).ConnectToSource(
            dt.ConnectableAPI(), "r")
        mat.CreateDisplacementOutput().ConnectToSource(surf.ConnectableAPI(), "displacement")
    return mat


def _caruncle_subset(stage, path: str, mesh, faces, n_faces: int, skin, color_tex=None) -> None:
    """Bind the caruncle material to the mesh faces ``faces`` and the skin to the rest: two
    GeomSubsets (family materialBind, a partition of the faces). The mesh keeps its own binding
    to the skin for viewers without subsets; Blender's importer reads only the subsets once
    there are any, so the skin gets one too. With the skin's colour map ``color_tex`` the
    caruncle is that map times ``CARUNCLE_TINT`` (the texture's ``scale``), else a flat pink."""
    from pxr import UsdGeom, UsdShade, Vt

    from pipeline.geometry.corners import CARUNCLE_DIFFUSE, CARUNCLE_ROUGHNESS, CARUNCLE_TINT
    from pipeline.usd import stage as su

    mat, _, _ = su.preview_material(stage, path, diffuse=CARUNCLE_DIFFUSE, roughness=CARUNCLE_ROUGHNESS,
                                    texture=color_tex,
                                    scale=None if color_tex is None else (*CARUNCLE_TINT, 1.0))
    api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    car = np.unique(np.asarray(faces, np.int64))
    rest = np.setdiff1d(np.arange(n_faces), car)
    for name, idx, m, doc in (("skin", rest, skin, "the skin: every face but the caruncle's"),
                              ("caruncle", car, mat, "the caruncle: faces closing the medial corner "
                                                     "between the lids and the eye "
                                                     "(pipeline/geometry/corners.py)")):
        subset = api.CreateMaterialBindSubset(name, Vt.IntArray([int(f) for f in idx]), UsdGeom.Tokens.face)
        subset.GetPrim().SetDocumentation(doc)
        su.bind_material(subset.GetPrim(), m)
    api.SetMaterialBindSubsetsFamilyType(UsdGeom.Tokens.partition)


def _nul_free(value, key: str = "eyerig") -> None:
    """Refuse (ValueError) a NUL character in any string of ``value``: USD would cut the string there."""
    if isinstance(value, str):
        if "\0" in value:
            raise ValueError(f"metadata {key} contains a NUL character (USD would cut the text there)")
    elif isinstance(value, dict):
        for k, v in value.items():
            _nul_free(k, key)
            _nul_free(v, f"{key}.{k}")
    elif isinstance(value, (list, tuple)):
        for v in value:
            _nul_free(v, key)


def _eyeball_model(prim, eyeball_ref: str):
    """(EyeballParams, Resolution) of the eyeball asset ``prim`` references (its customData
    eyerig.params / .resolution); ValueError when it has none."""
    from pipeline.eyeball import geometry as geo

    data = prim.GetCustomDataByKey("eyerig") or {}
    params, res = data.get("params"), data.get("resolution")
    if not isinstance(params, dict) or not isinstance(res, dict):
        raise ValueError(f"eyeball reference {eyeball_ref!r} carries no eyerig params/resolution "
                         "in its customData (rebuild it with the eyeball stage)")
    try:
        p = geo.EyeballParams.from_dict({k: float(v) for k, v in params.items()
                                         if k in geo.EyeballParams.__dataclass_fields__})
        r = geo.Resolution(**{k: int(v) for k, v in res.items()
                              if k in geo.Resolution.__dataclass_fields__})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"eyeball reference {eyeball_ref!r}: eyerig params: {exc}") from None
    return p, r


def _place_eye(prim, model, radius: float, eyeball_ref: str) -> None:
    """Author over the referenced eyeball under ``prim`` the eye placed at ``radius`` (mm): the
    Outer and Inner points (and extents), the Inner blend shapes, and customData eyerig.params /
    cornea_center_mm / placement. ValueError when the reference's topology differs."""
    from pxr import Gf, UsdGeom, UsdSkel, Vt

    from pipeline.eyeball import geometry as geo

    params, res = model
    placed = geo.placed_params(params, radius)
    eye = geo.build_eyeball(placed, res)
    for name, ring in (("Outer", eye.outer), ("Inner", eye.inner)):
        mesh = UsdGeom.Mesh(prim.GetChild(name))
        n = len(mesh.GetPointsAttr().Get() or [])
        if not mesh or n != len(ring.V):
            raise ValueError(f"eyeball reference {eyeball_ref!r}: {name} has {n} points, its "
                             f"parameters give {len(ring.V)}")
        pts = np.asarray(ring.V, np.float32)
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts))
        mesh.GetExtentAttr().Set([Gf.Vec3f(*map(float, pts.min(0))), Gf.Vec3f(*map(float, pts.max(0)))])
    inner = prim.GetChild("Inner")
    for s in eye.shapes:
        bs = UsdSkel.BlendShape(inner.GetChild(s.name))
        if not bs:
            raise ValueError(f"eyeball reference {eyeball_ref!r}: Inner has no blend shape {s.name}")
        bs.GetOffsetsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(s.offsets, np.float32)))
        bs.GetPointIndicesAttr().Set(Vt.IntArray.FromNumpy(np.asarray(s.point_indices, np.int32)))
    prim.SetCustomDataByKey("eyerig:params",
                            {k: float(getattr(placed, k)) for k in placed.__dataclass_fields__})
    prim.SetCustomDataByKey("eyerig:cornea_center_mm", Gf.Vec3d(0, 0, placed.cornea_center_z))
    prim.SetCustomDataByKey("eyerig:placement",
                            "pipeline.eyeball.geometry.placed_params: the eyeball sphere r1 = the "
                            "eye's radius (eyes.json); r2, apex - r1, iris, pupil, gap in mm as in the "
                            "referenced eyeball (not scaled)")


def write_scan_asset(path, *, name: str, V, F, UV, FUV, shapes, landmark_curves: dict, eyes: dict,
                     eyeball_ref: str, color_tex: str | None = "./textures/color.png",
                     disp_tex: str | None = "./textures/displacement.exr",
                     metadata: dict | None = None, caruncle_faces=None, caruncle_weight=None) -> Path:
    """Write the per-scan asset's root layer to ``path`` (textures and the eyeball must exist).

    Parameters
    ----------
    path : str | Path        ``rigged_assets/<scan>/<scan>.usda``
    name : str               default prim name (made a valid identifier)
    V : (n, 3) float64 mm ; F : (m, 3) int64 ; UV : (k, 2) ; FUV : (m, 3) per-corner UV indices
    shapes : list of pipeline.rig.lids.BlendShape (lids_up, lids_down with inbetweens)
    landmark_curves : dict side -> (points (12, 3) mm, list of BlendShape on points 0..11)
    eyes : dict side -> pipeline.io.eyes_file.Eye (center, radius, forward); the eye is placed
                             at the fitted radius (eyes.json; see the module docstring)
    eyeball_ref : str        asset path of eyeball.usda relative to this layer (``./eyeball/eyeball.usda``)
    metadata : dict          stored as customData["eyerig"] on the default prim
    caruncle_faces : (k,) int, optional  faces of F given the caruncle material (none: no subset)
    caruncle_weight : (n,) float, optional  each vertex's share of the caruncle's colour, written
                             as the EyeRegion's ``primvars:caruncleWeight`` (vertex)

    Returns
    -------
    Path of the written layer.
    """
    from pxr import Gf, Kind, Sdf, Tf, Usd, UsdGeom, UsdSkel, Vt

    from pipeline.usd import stage as su

    path = Path(path)
    root_name = Tf.MakeValidIdentifier(name)
    stage, root = su.new_stage(path, root_name, root_type="SkelRoot",
                               doc=f"Rigged eye region of scan '{name}', generated by eyerig "
                                   "pipeline/usd/asset.py. Millimetres, head frame (+Y up, +Z out "
                                   "of the face, +X = subject's left).")
    rp = "/" + root_name

    # eyeball: its variant sets, landmark indices and blend-shape names (composed through the reference)
    eye_prims = {}
    for side in SIDES:
        p = stage.DefinePrim(f"{rp}/Eyes/eye_{side}", "Xform")
        p.GetReferences().AddReference(eyeball_ref)
        eye_prims[side] = p
    UsdGeom.Xform.Define(stage, rp + "/Eyes")
    probe = eye_prims["left"]
    if not probe.GetChild("Inner"):
        raise ValueError(f"eyeball reference {eyeball_ref!r} does not resolve to an eyeball asset "
                         "with an Inner mesh")
    eye_shape_names = list(UsdSkel.BindingAPI(probe.GetChild("Inner")).GetBlendShapesAttr().Get() or [])
    vsets = {vs: probe.GetVariantSets().GetVariantSet(vs).GetVariantNames()
             for vs in probe.GetVariantSets().GetNames()}
    vsel = {vs: probe.GetVariantSets().GetVariantSet(vs).GetVariantSelection() for vs in vsets}

    # skeleton: head + one joint per eye
    skel = UsdSkel.Skeleton.Define(stage, rp + "/Skel")
    skel.CreateJointsAttr(list(JOINTS))
    J = {s: eye_frame_matrix(eyes[s].center, eyes[s].forward) for s in SIDES}
    world = [np.eye(4), J["left"], J["right"]]
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([_gf(M) for M in world]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([_gf(M) for M in world]))   # parent = identity
    anim = UsdSkel.Animation.Define(stage, rp + "/Skel/Anim")
    anim.CreateJointsAttr(list(JOINTS))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, M[3, :3])) for M in world]))
    anim.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(_gf(M).ExtractRotationQuat()) for M in world]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1)] * len(JOINTS)))
    channel_names = [s.name for s in shapes] + eye_shape_names
    anim.CreateBlendShapesAttr(channel_names)
    anim.CreateBlendShapeWeightsAttr(Vt.FloatArray([0.0] * len(channel_names)))
    UsdSkel.BindingAPI.Apply(root).CreateSkeletonRel().SetTargets([skel.GetPath()])
    UsdSkel.BindingAPI(root).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])

    # skin mesh
    F = np.asarray(F, np.int64)
    mesh = su.write_mesh(stage, rp + "/EyeRegion", V, np.full(len(F), 3, np.int32), F.ravel(),
                         UV=UV, uv_indices=None if FUV is None else np.asarray(FUV).ravel())
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(_usd_normals(V, F).astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    su.bind_rigid(mesh, skel, 0)
    su.write_blend_shapes(mesh, shapes, _shape_inbetweens(shapes))
    skin = _skin_material(stage, rp + "/Materials/Skin", color_tex, disp_tex)
    su.bind_material(mesh.GetPrim(), skin)
    if caruncle_faces is not None and len(caruncle_faces):
        _caruncle_subset(stage, rp + "/Materials/Caruncle", mesh, caruncle_faces, len(F), skin, color_tex)
        if caruncle_weight is not None:
            pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("caruncleWeight", Sdf.ValueTypeNames.FloatArray,
                                                          UsdGeom.Tokens.vertex)
            pv.Set(Vt.FloatArray.FromNumpy(np.asarray(caruncle_weight, np.float32)))

    # eyes: placed at their radius, rigid skinning to their joints
    model = _eyeball_model(probe, eyeball_ref)
    for j, side in enumerate(SIDES, start=1):
        p = eye_prims[side]
        Usd.ModelAPI(p).SetKind(Kind.Tokens.subcomponent)
        p.GetChild("Skel").SetActive(False)
        _place_eye(p, model, float(eyes[side].radius), eyeball_ref)
        G = _gf(eye_frame_matrix(eyes[side].center, eyes[side].forward))
        for child in p.GetChildren():
            if child.IsA(UsdGeom.Mesh):
                api = UsdSkel.BindingAPI.Apply(child)
                api.CreateSkeletonRel().SetTargets([skel.GetPath()])
                api.CreateJointIndicesPrimvar(True, 1).Set([j])
                api.CreateJointWeightsPrimvar(True, 1).Set([1.0])
                api.CreateGeomBindTransformAttr().Set(G)
        p.SetDocumentation(f"Subject's {side} eye: {eyeball_ref} placed at radius "
                           f"{float(eyes[side].radius):.4f} mm (sclera; cornea, iris and pupil "
                           f"keep their size) and rigidly skinned to joint {JOINTS[j]} (centre "
                           f"{list(map(float, eyes[side].center))} mm)")

    # landmarks
    UsdGeom.Scope.Define(stage, rp + "/Landmarks")
    for side in SIDES:
        pts, lshapes = landmark_curves[side]
        pts = np.asarray(pts, np.float32)
        crv = UsdGeom.BasisCurves.Define(stage, f"{rp}/Landmarks/eyelid_{side}")
        crv.CreateTypeAttr(UsdGeom.Tokens.linear)
        crv.CreateWrapAttr(UsdGeom.Tokens.periodic)
        crv.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
        crv.CreateCurveVertexCountsAttr([len(pts)])
        crv.CreateWidthsAttr([0.15])
        crv.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        crv.CreateExtentAttr([Gf.Vec3f(*map(float, pts.min(0) - 0.1)), Gf.Vec3f(*map(float, pts.max(0) + 0.1))])
        crv.GetPrim().SetDocumentation("12 eyelid landmarks, closed curve in order: "
                                       "0 medial canthus, 1-5 upper lid medial->lateral, 6 lateral "
                                       "canthus, 7-11 lower lid lateral->medial")
        su.bind_rigid(crv, skel, 0)
        su.write_blend_shapes(crv, lshapes, _shape_inbetweens(lshapes))
        sc = UsdGeom.Scope.Define(stage, f"{rp}/Landmarks/eye_{side}").GetPrim()
        inner = eye_prims[side].GetChild("Inner")
        sc.CreateRelationship("eyerig:landmarks:mesh", custom=True).SetTargets([inner.GetPath()])
        for key in ("iris", "pupil"):
            src = inner.GetAttribute(f"eyerig:landmarks:{key}")
            a = sc.CreateAttribute(f"eyerig:landmarks:{key}", Sdf.ValueTypeNames.IntArray, custom=True)
            a.Set(src.Get() if src else Vt.IntArray())
            a.SetDocumentation(f"8 {key} landmarks: vertex indices of eyerig:landmarks:mesh "
                               f"(copied from the eyeball asset; {src.GetDocumentation() if src else ''})")

    # variant sets forwarded to both eyes
    for vs_name, names in vsets.items():
        vs = root.GetVariantSets().AddVariantSet(vs_name)
        for v in names:
            vs.AddVariant(v)
            vs.SetVariantSelection(v)
            with vs.GetVariantEditContext():
                for side in SIDES:
                    over = stage.OverridePrim(eye_prims[side].GetPath())
                    over.GetVariantSets().GetVariantSet(vs_name).SetVariantSelection(v)
        vs.SetVariantSelection(vsel[vs_name] or names[0])

    if metadata:
        _nul_free(metadata)
        root.SetCustomDataByKey("eyerig", metadata)
    stage.GetRootLayer().Save()
    return path


#: The asset folder's copy of the eyeball asset (its eyes reference ``./eyeball/eyeball.usda``).
EYEBALL_DIR = "eyeball"


def copy_eyeball(src, asset_dir) -> str:
    """Copy the eyeball asset folder ``src`` (``eyeball.usda`` and every file of ``textures/``:
    the renderer also reads ``sclera_bump.png``, which no USD attribute names; not its preview)
    into ``asset_dir/eyeball/``. Returns the reference relative to a layer in ``asset_dir``
    (``eyeball/eyeball.usda``). Bytes and file modes as in ``src``, whatever its location."""
    import shutil

    src, dst = Path(src), Path(asset_dir) / EYEBALL_DIR
    (dst / "textures").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src / "eyeball.usda", dst / "eyeball.usda")
    if (src / "textures").is_dir():
        for f in sorted((src / "textures").iterdir()):
            if f.is_file():
                shutil.copyfile(f, dst / "textures" / f.name)
    return f"{EYEBALL_DIR}/eyeball.usda"


def package_usdz(usda, usdz, folder_name: str | None = None) -> list[str]:
    """Package ``usda`` with every dependency (textures, the referenced eyeball) into ``usdz``.

    The archive mirrors the asset folder's parent: the root layer is ``<folder>/<scan>.usda`` (the
    first file, so it is the package's root layer), its textures under ``<folder>/textures/``, the
    eyeball's copy under ``<folder>/eyeball/`` (a dependency in a sibling folder goes under its
    own name; one farther out is refused). Every authored relative path
    (``./eyeball/eyeball.usda``, ``./textures/...``) therefore stays valid inside the package unchanged (UsdUtils'
    CreateNewUsdzPackage renames dependencies outside the folder and breaks the eyeball's own
    texture paths, so it is not used).

    Parameters
    ----------
    folder_name : str, optional
        Name of the asset folder inside the archive (default: the folder holding ``usda``).

    Returns
    -------
    list of archive member names.
    """
    import os

    from pxr import Sdf, UsdUtils

    usda = Path(usda).resolve()
    folder = usda.parent
    base = folder.parent
    folder_name = folder_name or folder.name
    layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(usda)))
    if unresolved:
        raise ValueError(f"{usda}: unresolved dependencies {list(unresolved)[:3]}")
    files = [Path(lay.realPath).resolve() for lay in layers] + [Path(a).resolve() for a in assets]
    members, seen = [], set()
    with Sdf.ZipFileWriter.CreateNew(str(usdz)) as zw:
        for f in files:
            if f in seen:
                continue
            seen.add(f)
            try:
                rel = f.relative_to(folder)
                arc = f"{folder_name}/{rel.as_posix()}"
            except ValueError:
                rel = Path(os.path.relpath(f, base))
                if rel.parts and rel.parts[0] == "..":
                    raise ValueError(f"{f}: dependency outside {base}, cannot be packaged") from None
                arc = rel.as_posix()
            zw.AddFile(str(f), arc)
            members.append(arc)
    fix_zip_times(usdz)
    return members


#: DOS date/time stamped on every usdz member: 1980-01-01 00:00:00, the format's epoch.
ZIP_DOS_DATE, ZIP_DOS_TIME = (0 << 9) | (1 << 5) | 1, 0


def fix_zip_times(path) -> int:
    """Set every member's modification time in the zip at ``path`` to 1980-01-01 00:00 (in the
    local headers and the central directory), in place, so the same files always give the same
    archive bytes (Sdf.ZipFileWriter stamps each member with its file's mtime). Sizes, offsets
    and the usdz 64-byte data alignment are unchanged. Returns the number of members."""
    import struct
    import zipfile

    with open(path, "r+b") as fh:
        with zipfile.ZipFile(fh) as zf:
            infos = zf.infolist()
            start_dir = zf.start_dir
        for info in infos:
            fh.seek(info.header_offset)
            if fh.read(4) != b"PK\x03\x04":
                raise ValueError(f"{path}: bad local header for {info.filename}")
            fh.seek(info.header_offset + 10)
            fh.write(struct.pack("<HH", ZIP_DOS_TIME, ZIP_DOS_DATE))
        pos = start_dir
        for _ in infos:
            fh.seek(pos)
            head = fh.read(46)
            if head[:4] != b"PK\x01\x02":
                raise ValueError(f"{path}: bad central directory entry")
            n, m, k = struct.unpack("<HHH", head[28:34])
            fh.seek(pos + 12)
            fh.write(struct.pack("<HH", ZIP_DOS_TIME, ZIP_DOS_DATE))
            pos += 46 + n + m + k
    return len(infos)


def check_package(usdz) -> list[str]:
    """Problems of a packaged asset: it must open, have a default prim, and every asset-valued
    shader input (current variant selections) must resolve to a readable member of the package."""
    from pxr import Ar, Usd

    try:
        stage = Usd.Stage.Open(str(usdz))
    except Exception as exc:  # Tf.ErrorException
        return [f"{usdz}: cannot be opened ({str(exc).strip()[:200]})"]
    if stage is None or not stage.GetDefaultPrim():
        return [f"{usdz}: no default prim"]
    from pipeline.usd.validate import shader_asset_inputs

    errors = []
    for prim, inp, val in shader_asset_inputs(stage):
        rp = val.resolvedPath
        if not rp or Ar.GetResolver().OpenAsset(Ar.ResolvedPath(rp)) is None:
            errors.append(f"{prim.GetPath()}: inputs:{inp.GetBaseName()} @{val.path}@ is not in the package")
    return errors
