"""Cycles materials of the eyeball (runs inside Blender worker processes only).

Material slots are the ones the USD importer creates from the asset's
material-bind subsets: ``Cornea`` and ``ScleraCoat`` on the outer mesh,
``Pupil``, ``Iris`` and ``Sclera`` on the inner mesh.

- Cornea: Principled BSDF, transmission 1, roughness 0, IOR 1.376 (refracts and
  reflects by Fresnel); for shadow rays it is transparent (Light Path "Is
  Shadow Ray" mix), the usual eye-shading shortcut that lets environment light
  reach the iris without refractive caustics (otherwise Cycles leaves the iris
  dark and noisy at low sample counts).
- ScleraCoat: the same clear coat plus bumps from smoothed solid noise: the
  asset's ``sclera_bump.png`` height map (pipeline/eyeball/textures.py, the
  same field as the USD normal map) through a Bump node.
- Iris: Principled BSDF with the iris texture (UV map ``st``), roughness 0.55.
- Pupil: near-black diffuse.
- Sclera: sclera texture (veins layer) x tint colour (tint layer), roughness 0.4,
  a little subsurface.
"""

from __future__ import annotations

CORNEA_IOR = 1.376


def _new_tree(mat):
    mat.use_nodes = True
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    return nt, out


def _principled(nt, **inputs):
    b = nt.nodes.new("ShaderNodeBsdfPrincipled")
    for k, v in inputs.items():
        if k in b.inputs:
            b.inputs[k].default_value = v
    return b


def _coat(mat, bump_image=None, bump_distance_mm: float = 0.16, strength: float = 1.0):
    nt, out = _new_tree(mat)
    glass = _principled(nt, **{"Base Color": (1, 1, 1, 1), "Roughness": 0.0, "IOR": CORNEA_IOR,
                               "Transmission Weight": 1.0, "Metallic": 0.0})
    if bump_image is not None:
        bump_image.colorspace_settings.name = "Non-Color"
        uv = nt.nodes.new("ShaderNodeUVMap")
        uv.uv_map = "st"
        img = nt.nodes.new("ShaderNodeTexImage")
        img.image = bump_image
        img.interpolation = "Cubic"
        bump = nt.nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = strength
        # height texel 0..1 spans 8 noise amplitudes (textures.sclera_bump_maps); world units = metres
        bump.inputs["Distance"].default_value = bump_distance_mm * 1e-3
        nt.links.new(uv.outputs["UV"], img.inputs["Vector"])
        nt.links.new(img.outputs["Color"], bump.inputs["Height"])
        nt.links.new(bump.outputs["Normal"], glass.inputs["Normal"])
    lp = nt.nodes.new("ShaderNodeLightPath")
    transp = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(lp.outputs["Is Shadow Ray"], mix.inputs["Fac"])
    nt.links.new(glass.outputs["BSDF"], mix.inputs[1])
    nt.links.new(transp.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def _textured(mat, image, tint=(1.0, 1.0, 1.0), roughness=0.5, subsurface=0.0):
    nt, out = _new_tree(mat)
    b = _principled(nt, **{"Roughness": roughness, "Specular IOR Level": 0.3})
    uv = nt.nodes.new("ShaderNodeUVMap")
    uv.uv_map = "st"
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Cubic"
    nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    mul = nt.nodes.new("ShaderNodeMix")
    mul.data_type = "RGBA"
    mul.blend_type = "MULTIPLY"
    mul.inputs["Factor"].default_value = 1.0
    mul.inputs[7].default_value = (*tint, 1.0)       # B (colour)
    nt.links.new(tex.outputs["Color"], mul.inputs[6])  # A (colour)
    nt.links.new(mul.outputs[2], b.inputs["Base Color"])
    if subsurface:
        b.inputs["Subsurface Weight"].default_value = subsurface
        b.inputs["Subsurface Radius"].default_value = (1.0, 0.3, 0.2)
        b.inputs["Subsurface Scale"].default_value = 0.5
    nt.links.new(b.outputs["BSDF"], out.inputs["Surface"])
    return mat, tex, mul


def _pupil(mat):
    nt, out = _new_tree(mat)
    d = nt.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (0.003, 0.003, 0.003, 1)
    nt.links.new(d.outputs["BSDF"], out.inputs["Surface"])
    return mat


def setup_eyeball_materials(objects, iris_image, sclera_image, tint=(1.0, 1.0, 1.0),
                            bump_image=None) -> dict:
    """Replace the imported preview materials with the Cycles eyeball materials.

    Parameters
    ----------
    objects : iterable of bpy mesh objects (the imported Outer and Inner)
    iris_image, sclera_image : bpy.types.Image
    tint : (3,) sclera tint colour
    bump_image : bpy.types.Image, optional   the asset's ``sclera_bump.png`` (height)

    Returns
    -------
    dict with the iris and sclera image texture nodes and the tint mix node
    (``"iris_tex"``, ``"sclera_tex"``, ``"tint"``) so callers can switch variants.
    """
    handles = {}
    for o in objects:
        for slot in o.material_slots:
            m = slot.material
            if m is None:
                continue
            name = m.name.split(".")[0]
            if name == "Cornea":
                _coat(m)
            elif name == "ScleraCoat":
                _coat(m, bump_image=bump_image)
            elif name == "Pupil":
                _pupil(m)
            elif name == "Iris":
                _, handles["iris_tex"], _ = _textured(m, iris_image, roughness=0.55)
            elif name == "Sclera":
                _, handles["sclera_tex"], handles["tint"] = _textured(m, sclera_image, tint, 0.4, 0.05)
    return handles


def set_tint(handles: dict, tint) -> None:
    """Switch the sclera tint layer."""
    handles["tint"].inputs[7].default_value = (*tint, 1.0)
