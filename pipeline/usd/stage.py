"""Shared USD authoring helpers (pxr imported lazily; never bpy).

Used by the eyeball asset (pipeline/usd/eyeball.py) and the per-scan asset:
stage setup with the house metadata, meshes (float32 points, face-varying
``st``), material-bind subsets, UsdSkel blend shapes with SkelBindingAPI, a
one-joint skeleton, and UsdPreviewSurface materials.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def new_stage(path, root_name: str, root_type: str = "Xform", kind: str = "component",
              meters_per_unit: float = 0.001, up_axis: str = "Y", doc: str | None = None):
    """Create a stage at ``path`` with a default prim (``kind``), metersPerUnit and upAxis.

    Returns
    -------
    (Usd.Stage, Usd.Prim) the stage and its default prim.
    """
    from pxr import Kind, Sdf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis.upper() == "Y" else UsdGeom.Tokens.z)
    prim = stage.DefinePrim(Sdf.Path("/" + root_name), root_type)
    stage.SetDefaultPrim(prim)
    Usd.ModelAPI(prim).SetKind(getattr(Kind.Tokens, kind))
    if doc:
        stage.GetRootLayer().documentation = doc
    return stage, prim


def write_mesh(stage, path: str, V, poly_counts, poly_indices, *, UV=None, uv_indices=None,
               origin=(0.0, 0.0, 0.0), subdivision: str = "none", double_sided: bool = False):
    """Define a UsdGeom.Mesh.

    Parameters
    ----------
    V : (n, 3) float64 mm; written as float32 after subtracting ``origin`` (re-centring).
    poly_counts : (p,) int ; poly_indices : (sum(poly_counts),) int
    UV : (k, 2) float, optional; uv_indices : (sum(poly_counts),) int, optional
        Face-varying indexed ``primvars:st`` (origin bottom-left).
    """
    from pxr import Gf, Sdf, UsdGeom, Vt

    V = np.asarray(V, np.float64) - np.asarray(origin, np.float64)
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = V.astype(np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(poly_counts, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(poly_indices, np.int32)))
    mesh.CreateSubdivisionSchemeAttr(subdivision)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateDoubleSidedAttr(bool(double_sided))
    lo, hi = pts.min(0), pts.max(0)
    mesh.CreateExtentAttr([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])
    if UV is not None:
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                      UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray.FromNumpy(np.asarray(UV, np.float32)))
        if uv_indices is not None:
            pv.SetIndices(Vt.IntArray.FromNumpy(np.asarray(uv_indices, np.int32)))
    return mesh


def add_material_subsets(mesh, subsets: dict, materials: dict):
    """Partition the mesh faces into ``materialBind`` subsets and bind a material to each.

    Parameters
    ----------
    subsets : dict name -> (q,) int face indices (together a partition of the faces)
    materials : dict name -> UsdShade.Material
    """
    from pxr import UsdGeom, UsdShade, Vt

    api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    out = {}
    for name, idx in subsets.items():
        sub = api.CreateMaterialBindSubset(name, Vt.IntArray.FromNumpy(np.asarray(idx, np.int32)),
                                           UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(sub.GetPrim()).Bind(materials[name])
        out[name] = sub
    api.SetMaterialBindSubsetsFamilyType(UsdGeom.Tokens.partition)
    return out


def bind_material(prim, material):
    """Bind ``material`` to ``prim`` (applies MaterialBindingAPI)."""
    from pxr import UsdShade

    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def define_skeleton(stage, path: str, joints=("root",), blend_shapes=()):
    """A skeleton with identity bind/rest transforms and a SkelAnimation source.

    The animation holds the joints' rest pose and zero weights for ``blend_shapes``
    (renderers override weights; order is the mesh's ``skel:blendShapes``).
    """
    from pxr import Gf, UsdSkel, Vt

    skel = UsdSkel.Skeleton.Define(stage, path)
    skel.CreateJointsAttr(list(joints))
    ident = Vt.Matrix4dArray([Gf.Matrix4d(1.0)] * len(joints))
    skel.CreateBindTransformsAttr(ident)
    skel.CreateRestTransformsAttr(ident)
    anim = UsdSkel.Animation.Define(stage, path + "/Anim")
    anim.CreateJointsAttr(list(joints))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(0)] * len(joints)))
    anim.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(1)] * len(joints)))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1)] * len(joints)))
    if blend_shapes:
        anim.CreateBlendShapesAttr(list(blend_shapes))
        anim.CreateBlendShapeWeightsAttr(Vt.FloatArray([0.0] * len(blend_shapes)))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    return skel


def bind_rigid(mesh, skeleton, joint_index: int = 0):
    """Bind ``mesh`` to ``skeleton`` rigidly to one joint (constant joint influence)."""
    from pxr import UsdSkel

    api = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    api.CreateSkeletonRel().SetTargets([skeleton.GetPath()])
    api.CreateJointIndicesPrimvar(True, 1).Set([int(joint_index)])
    api.CreateJointWeightsPrimvar(True, 1).Set([1.0])
    return api


def write_blend_shapes(mesh, shapes, inbetweens: dict | None = None):
    """Author UsdSkel blend shapes under ``mesh`` and bind them (SkelBindingAPI).

    Parameters
    ----------
    shapes : iterable of objects with ``name``, ``point_indices`` (k,), ``offsets`` (k, 3) mm
    inbetweens : dict name -> list of (weight, offsets (k, 3)), optional

    Returns
    -------
    list of UsdSkel.BlendShape
    """
    from pxr import Sdf, UsdSkel, Vt

    api = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    names, targets, out = [], [], []
    for s in shapes:
        bs = UsdSkel.BlendShape.Define(mesh.GetPrim().GetStage(), mesh.GetPath().AppendChild(s.name))
        bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(s.offsets, np.float32)))
        bs.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(s.point_indices, np.int32)))
        for w, off in (inbetweens or {}).get(s.name, []):
            ib = bs.CreateInbetween(f"ib{int(round(w * 1000)):04d}")
            ib.SetWeight(float(w))
            ib.SetOffsets(Vt.Vec3fArray.FromNumpy(np.asarray(off, np.float32)))
        names.append(s.name)
        targets.append(Sdf.Path(bs.GetPath()))
        out.append(bs)
    api.CreateBlendShapesAttr(names)
    api.CreateBlendShapeTargetsRel().SetTargets(targets)
    return out


def preview_material(stage, path: str, *, diffuse=(0.8, 0.8, 0.8), roughness: float = 0.5,
                     metallic: float = 0.0, opacity: float = 1.0, ior: float = 1.5,
                     specular=None, clearcoat: float = 0.0, texture: str | None = None,
                     texture_variants: bool = False, scale=None, normal_texture: str | None = None):
    """A UsdPreviewSurface material, optionally with a ``st``-mapped diffuse texture.

    Parameters
    ----------
    texture : str, optional
        Asset path of the diffuse texture (sRGB). With ``texture_variants=True``
        the ``inputs:file`` is left unauthored so variants can set it.
    scale : (4,) float, optional
        UsdUVTexture ``scale`` (colour multiplier); variants may set it instead.
    normal_texture : str, optional
        Asset path of a tangent-space normal map (raw, encoded n/2 + 0.5) for ``inputs:normal``.

    Returns
    -------
    (UsdShade.Material, UsdShade.Shader surface, UsdShade.Shader texture or None)
    """
    from pxr import Gf, Sdf, UsdShade

    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, path + "/PreviewSurface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(roughness))
    surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(metallic))
    surf.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(opacity))
    surf.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(float(ior))
    if clearcoat:
        surf.CreateInput("clearcoat", Sdf.ValueTypeNames.Float).Set(float(clearcoat))
        surf.CreateInput("clearcoatRoughness", Sdf.ValueTypeNames.Float).Set(0.0)
    if specular is not None:
        surf.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        surf.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*specular))
    tex = None
    if texture is not None or texture_variants:
        extra = [("scale", Sdf.ValueTypeNames.Float4, Gf.Vec4f(*scale))] if scale is not None else []
        tex = uv_texture(stage, path, "DiffuseTexture", texture, "sRGB", "repeat", "clamp", extra)
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            tex.ConnectableAPI(), "rgb")
    else:
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if normal_texture is not None:
        nt = uv_texture(stage, path, "NormalTexture", normal_texture, "raw", "repeat", "clamp",
                        [("scale", Sdf.ValueTypeNames.Float4, Gf.Vec4f(2, 2, 2, 1)),
                         ("bias", Sdf.ValueTypeNames.Float4, Gf.Vec4f(-1, -1, -1, 0))])
        nt.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surf.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(nt.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    return mat, surf, tex


def uv_texture(stage, path: str, name: str, file: str | None, color_space: str, wrap_s: str, wrap_t: str,
               inputs=()):
    """A ``UsdUVTexture`` shader ``<path>/<name>`` reading ``file`` through the material's ``st``
    primvar reader (``<path>/stReader``, defined on first use); the caller adds its outputs.

    ``file`` None leaves ``inputs:file`` unauthored (variants set it); ``inputs``: further
    ``(name, Sdf value type, value)`` inputs (``scale``, ``bias``), authored before ``st``.
    """
    from pxr import Sdf, UsdShade

    reader = UsdShade.Shader.Get(stage, path + "/stReader")
    if not reader:
        reader = UsdShade.Shader.Define(stage, path + "/stReader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex = UsdShade.Shader.Define(stage, f"{path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    if file is not None:
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(file))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap_s)
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap_t)
    for input_name, value_type, value in inputs:
        tex.CreateInput(input_name, value_type).Set(value)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    return tex


def relpath(path, start) -> str:
    """``./``-prefixed relative asset path (USD anchors it to the layer)."""
    rel = Path(path).resolve().relative_to(Path(start).resolve())
    return "./" + rel.as_posix()
