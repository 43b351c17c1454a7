"""Cycles materials of every Blender worker (runs inside Blender worker processes only): the
eyeball's, the skin (:func:`skin_material`), the thin sclera coat of the render worker
(:func:`thin_coat`) and the eyelashes (:func:`eyelash_material`). The functions fill the
node tree of a material they are handed (``bpy`` itself is never imported here).

Eyeball material slots are the ones the USD importer creates from the asset's
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
# the eyeball's textures (iris 512 px over 12 mm; sclera colour and bump height 1024 x 512 over the globe:
# 0.02-0.07 mm per texel) are sampled bilinearly: every preset's pixel is wider (>= 0.1 mm, near_eye at 33.5 mm),
# so bicubic gave the same image (bench frame +0.00 dB) for four times the texel reads; the coat's bump reads its
# height three times per shading point on every ray through the coat: 6 % of an image's CPU (issue 32,
# benchmarks/results/render_speed.md). The skin's displacement map stays bicubic: its texels are not
# below every preset's pixel, and its bump would show their facets.
EYE_TEXTURE_INTERPOLATION = "Linear"
SKIN_TONE = (0.75, 0.6, 0.55, 1.0)         # skin base colour where no colour map was baked


def new_tree(mat):
    """Empty ``mat``'s node tree down to a new material output; returns (node tree, output)."""
    mat.use_nodes = True
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    return nt, out


def principled(nt, **inputs):
    """A new Principled BSDF in ``nt`` with the given input values (names this Blender lacks are skipped)."""
    b = nt.nodes.new("ShaderNodeBsdfPrincipled")
    for k, v in inputs.items():
        if k in b.inputs:
            b.inputs[k].default_value = v
    return b


def _shadow_transparent(nt, shader, out) -> None:
    """Plug the ``shader`` output socket into ``out``'s surface, transparent for shadow rays (a Light
    Path "Is Shadow Ray" mix): environment light reaches what lies beneath without caustics."""
    lp = nt.nodes.new("ShaderNodeLightPath")
    transp = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(lp.outputs["Is Shadow Ray"], mix.inputs["Fac"])
    nt.links.new(shader, mix.inputs[1])
    nt.links.new(transp.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])


def _coat(mat, bump_image=None, bump_distance_mm: float = 0.16, strength: float = 1.0):
    nt, out = new_tree(mat)
    glass = principled(nt, **{"Base Color": (1, 1, 1, 1), "Roughness": 0.0, "IOR": CORNEA_IOR,
                              "Transmission Weight": 1.0, "Metallic": 0.0})
    if bump_image is not None:
        bump_image.colorspace_settings.name = "Non-Color"
        uv = nt.nodes.new("ShaderNodeUVMap")
        uv.uv_map = "st"
        img = nt.nodes.new("ShaderNodeTexImage")
        img.image = bump_image
        img.interpolation = EYE_TEXTURE_INTERPOLATION
        bump = nt.nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = strength
        # height texel 0..1 spans 8 noise amplitudes (textures.sclera_bump_maps); world units = metres
        bump.inputs["Distance"].default_value = bump_distance_mm * 1e-3
        nt.links.new(uv.outputs["UV"], img.inputs["Vector"])
        nt.links.new(img.outputs["Color"], bump.inputs["Height"])
        nt.links.new(bump.outputs["Normal"], glass.inputs["Normal"])
    _shadow_transparent(nt, glass.outputs["BSDF"], out)
    return mat


def _tinted_map(nt, image, tint, base_color_input, interpolation=None):
    """``image`` on UV map ``st`` times the colour ``tint`` into ``base_color_input``: the
    (texture, multiply) nodes."""
    uv = nt.nodes.new("ShaderNodeUVMap")
    uv.uv_map = "st"
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = image
    if interpolation:
        tex.interpolation = interpolation
    nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    mul = nt.nodes.new("ShaderNodeMix")
    mul.data_type = "RGBA"
    mul.blend_type = "MULTIPLY"
    mul.inputs["Factor"].default_value = 1.0
    mul.inputs[7].default_value = (*tint, 1.0)       # B (colour)
    nt.links.new(tex.outputs["Color"], mul.inputs[6])  # A (colour)
    nt.links.new(mul.outputs[2], base_color_input)
    return tex, mul


def _textured(mat, image, tint=(1.0, 1.0, 1.0), roughness=0.5, subsurface=0.0):
    nt, out = new_tree(mat)
    b = principled(nt, **{"Roughness": roughness, "Specular IOR Level": 0.3})
    tex, mul = _tinted_map(nt, image, tint, b.inputs["Base Color"], EYE_TEXTURE_INTERPOLATION)
    if subsurface:
        b.inputs["Subsurface Weight"].default_value = subsurface
        b.inputs["Subsurface Radius"].default_value = (1.0, 0.3, 0.2)
        b.inputs["Subsurface Scale"].default_value = 0.0005   # scene units are metres: 0.5 mm (was 0.5 m)
    nt.links.new(b.outputs["BSDF"], out.inputs["Surface"])
    return mat, tex, mul


def _pupil(mat):
    nt, out = new_tree(mat)
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


def skin_material(mat, color_image, disp_image, displacement_method=None, subsurface_method=None,
                  **bsdf_inputs) -> dict:
    """Skin: Principled BSDF (``bsdf_inputs``) with the baked colour map on UV map ``st`` (a flat
    :data:`SKIN_TONE` without one) and the baked displacement map (signed mm along the normal)
    feeding a Displacement node in object space (object units = stage mm = the map's units).

    ``displacement_method`` (``"BUMP"``, ``"BOTH"``, ...): plug the displacement into the output
    and set the material's method; None leaves it unplugged (the caller switches it per render).
    ``subsurface_method``: the BSDF's subsurface method where this Blender has it.

    Returns
    -------
    dict
        ``mat``, ``nt`` (node tree), ``out`` (material output), ``disp`` (Displacement node or None).
    """
    nt, out = new_tree(mat)
    b = principled(nt, **bsdf_inputs)
    if subsurface_method is not None:
        try:
            b.subsurface_method = subsurface_method
        except (AttributeError, TypeError):
            pass
    uv = nt.nodes.new("ShaderNodeUVMap")
    uv.uv_map = "st"
    if color_image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = color_image
        nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], b.inputs["Base Color"])
    else:
        b.inputs["Base Color"].default_value = SKIN_TONE
    d = None
    if disp_image is not None:
        disp_image.colorspace_settings.name = "Non-Color"
        dtex = nt.nodes.new("ShaderNodeTexImage")
        dtex.image = disp_image
        dtex.interpolation = "Cubic"
        nt.links.new(uv.outputs["UV"], dtex.inputs["Vector"])
        d = nt.nodes.new("ShaderNodeDisplacement")
        d.space = "OBJECT"                      # object units = stage mm = the map's units
        d.inputs["Midlevel"].default_value = 0.0
        d.inputs["Scale"].default_value = 1.0
        nt.links.new(dtex.outputs["Color"], d.inputs["Height"])
        if displacement_method is not None:
            nt.links.new(d.outputs["Displacement"], out.inputs["Displacement"])
            try:
                mat.displacement_method = displacement_method
            except AttributeError:
                mat.cycles.displacement_method = displacement_method
    nt.links.new(b.outputs["BSDF"], out.inputs["Surface"])
    return {"mat": mat, "nt": nt, "disp": d, "out": out}


#: The EyeRegion's vertex attribute (USD ``primvars:caruncleWeight``) with each vertex's share of
#: the caruncle's colour and gloss; a mesh without it gets the caruncle's colour on all its faces.
CARUNCLE_WEIGHT_ATTRIBUTE = "caruncleWeight"


def caruncle_material(mat, subsurface_method=None, color_image=None, weight_attribute=None,
                      **bsdf_inputs) -> dict:
    """Caruncle: moist tissue in the medial corner, glossier than the skin, with the skin's
    subsurface scattering (``bsdf_inputs``, e.g. the render worker's ``SKIN_BSDF``), no
    displacement. Its colour is the skin's colour map (UV map ``st``) times
    ``pipeline.geometry.corners.CARUNCLE_TINT``, so it keeps the subject's tone and never
    outshines the skin; without a map the asset's pink (``CARUNCLE_DIFFUSE``). With
    ``weight_attribute`` (the mesh's :data:`CARUNCLE_WEIGHT_ATTRIBUTE`) the colour and the
    roughness are the skin's where the weight is 0 (the lid margin) and the caruncle's where it
    is 1 (the mound), so the tissue grows out of the lids instead of ending in a painted edge.
    Returns the dict of :func:`skin_material`."""
    from pipeline.geometry.corners import CARUNCLE_DIFFUSE, CARUNCLE_ROUGHNESS, CARUNCLE_TINT

    nt, out = new_tree(mat)
    b = principled(nt, **{**bsdf_inputs, "Base Color": (*CARUNCLE_DIFFUSE, 1.0),
                          "Roughness": CARUNCLE_ROUGHNESS})
    tex = mul = None
    if color_image is not None:
        tex, mul = _tinted_map(nt, color_image, CARUNCLE_TINT, b.inputs["Base Color"])
    if weight_attribute is not None:
        attr = nt.nodes.new("ShaderNodeAttribute")
        attr.attribute_type = "GEOMETRY"
        attr.attribute_name = weight_attribute
        mix = nt.nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        nt.links.new(attr.outputs["Fac"], mix.inputs["Factor"])
        if mul is not None:
            nt.links.new(tex.outputs["Color"], mix.inputs[6])          # A: the skin's map
            nt.links.new(mul.outputs[2], mix.inputs[7])                # B: reddened
        else:
            mix.inputs[6].default_value = SKIN_TONE
            mix.inputs[7].default_value = (*CARUNCLE_DIFFUSE, 1.0)
        nt.links.new(mix.outputs[2], b.inputs["Base Color"])
        rough = nt.nodes.new("ShaderNodeMix")
        rough.data_type = "FLOAT"
        nt.links.new(attr.outputs["Fac"], rough.inputs["Factor"])
        rough.inputs[2].default_value = float(bsdf_inputs.get("Roughness", 0.5))   # A: skin
        rough.inputs[3].default_value = CARUNCLE_ROUGHNESS                          # B
        nt.links.new(rough.outputs[0], b.inputs["Roughness"])
    if subsurface_method is not None:
        try:
            b.subsurface_method = subsurface_method
        except (AttributeError, TypeError):
            pass
    nt.links.new(b.outputs["BSDF"], out.inputs["Surface"])
    return {"mat": mat, "nt": nt, "disp": None, "out": out}


def is_caruncle(mat) -> bool:
    """Whether a material of the EyeRegion mesh is the asset's caruncle (``Materials/Caruncle``)."""
    return mat is not None and mat.name.split(".")[0] == "Caruncle"


def eye_region_materials(skin_obj, color_image, disp_image, displacement_method=None,
                         subsurface_method=None, **bsdf_inputs) -> list:
    """Set up every material slot of the EyeRegion mesh: the caruncle subset's with
    :func:`caruncle_material`, the others with :func:`skin_material`; returns their dicts."""
    out = []
    weight = (CARUNCLE_WEIGHT_ATTRIBUTE if skin_obj.data.attributes.get(CARUNCLE_WEIGHT_ATTRIBUTE) is not None
              else None)
    for slot in skin_obj.material_slots:
        if slot.material is None:
            continue
        if is_caruncle(slot.material):
            out.append(caruncle_material(slot.material, subsurface_method, color_image, weight,
                                         **bsdf_inputs))
        else:
            out.append(skin_material(slot.material, color_image, disp_image, displacement_method,
                                     subsurface_method, **bsdf_inputs))
    return out


def thin_coat(mat) -> None:
    """Sclera tear film as a thin clear coat: Fresnel mix of a sharp glossy reflection and
    straight transmission (no refraction), keeping the bump of the asset's coat.

    The asset's coat is a refracting glass shell 0.5 mm above the sclera that joins the
    cornea: at oblique views rays refracted into that shell are piped along it into the
    cornea and smear a dark/doubled iris over the sclera. A real sclera has no such
    layer (the tear film is microns thick), so it is rendered as a thin coat; shadow rays
    pass it (as in :func:`setup_eyeball_materials`).
    """
    nt = mat.node_tree
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output)
    bump = next((n for n in nt.nodes if n.type == "BUMP"), None)
    keep = {out, bump} | {n for n in nt.nodes if n.type in ("TEX_IMAGE", "UVMAP")}
    for n in list(nt.nodes):
        if n not in keep:
            nt.nodes.remove(n)
    gloss = nt.nodes.new("ShaderNodeBsdfGlossy")
    gloss.distribution = "GGX"
    gloss.inputs["Roughness"].default_value = 0.03
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    fres = nt.nodes.new("ShaderNodeFresnel")
    fres.inputs["IOR"].default_value = CORNEA_IOR
    coat = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(fres.outputs["Fac"], coat.inputs["Fac"])
    nt.links.new(clear.outputs["BSDF"], coat.inputs[1])
    nt.links.new(gloss.outputs["BSDF"], coat.inputs[2])
    if bump is not None:
        nt.links.new(bump.outputs["Normal"], gloss.inputs["Normal"])
        nt.links.new(bump.outputs["Normal"], fres.inputs["Normal"])
    _shadow_transparent(nt, coat.outputs["Shader"], out)


def eyelash_material(mat):
    """Eyelashes: dark glossy Principled BSDF (rendered on Cycles hair ribbons)."""
    nt, out = new_tree(mat)
    b = principled(nt, **{"Base Color": (0.012, 0.009, 0.007, 1.0), "Roughness": 0.35,
                          "Specular IOR Level": 0.5, "Coat Weight": 0.0})
    nt.links.new(b.outputs["BSDF"], out.inputs["Surface"])
    return mat
