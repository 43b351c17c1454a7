"""What the Blender workers share besides their materials (:mod:`pipeline.blender.materials`):
importing a USD asset, Blender's bundled HDRIs, the previews' Cycles scene, finding the textures the
importer brought in, and the rig's inbetween poses as shape keys. ``bpy`` is imported inside the
functions only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def import_usd(path: str, unit_conversion: bool = False):
    """Import ``path`` into an empty scene; returns the list of mesh objects."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=str(path), import_blendshapes=True, import_skeletons=True,
                          import_materials=True, import_usd_preview=True,
                          apply_unit_conversion_scale=unit_conversion, scale=1.0)
    return [o for o in bpy.context.scene.objects if o.type == "MESH"]


def bundled_hdri(name: str = "interior.exr") -> Path:
    """One of the studio-light HDRIs Blender ships (``datafiles/studiolights/world``)."""
    import bpy

    base = Path(bpy.utils.system_resource("DATAFILES")) / "studiolights" / "world"
    return base / name


def preview_scene(size: int, samples: int, hdri: Path):
    """The previews' Cycles scene: CPU, denoised, transparent film, ``hdri`` as the world
    (strength 1.2), a perspective camera (165 mm lens); returns (scene, camera)."""
    import bpy

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = True
    scene.cycles.max_bounces = 6
    scene.cycles.transmission_bounces = 6
    scene.cycles.glossy_bounces = 2
    scene.cycles.diffuse_bounces = 1
    scene.cycles.transparent_max_bounces = 8
    scene.cycles.caustics_reflective = False
    scene.cycles.caustics_refractive = False
    try:
        scene.cycles.use_denoising = True
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    except Exception:  # denoiser not built in
        scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.render.threads_mode = "AUTO"
    scene.render.use_persistent_data = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    world = bpy.data.worlds.new("PreviewWorld")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(str(hdri), check_existing=True)
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = 1.2
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    cam_data = bpy.data.cameras.new("PreviewCam")
    cam_data.lens = 165.0
    cam_data.sensor_width = 36.0
    cam_data.clip_start = 0.001
    cam = bpy.data.objects.new("PreviewCam", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene, cam


def evaluated_vertices(obj, depsgraph):
    """Vertices of ``obj`` as evaluated in ``depsgraph`` (shape keys, armature, modifiers): (n, 3)
    object-local points and the evaluated object's (4, 4) world matrix."""
    oe = obj.evaluated_get(depsgraph)
    em = oe.to_mesh()
    P = np.empty(len(em.vertices) * 3)
    em.vertices.foreach_get("co", P)
    oe.to_mesh_clear()
    return P.reshape(-1, 3), np.array(oe.matrix_world)


def images_of(mat) -> list:
    """The images of a material's image-texture nodes."""
    if mat is None or mat.node_tree is None:
        return []
    return [n.image for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image is not None]


def find_image(objs, material: str, stem_prefix: str):
    """The first image whose file name starts with ``stem_prefix`` in material ``material`` of ``objs``."""
    for o in objs:
        for slot in o.material_slots:
            if slot.material is not None and slot.material.name.split(".")[0] == material:
                for im in images_of(slot.material):
                    if Path(im.filepath).name.startswith(stem_prefix):
                        return im
    return None


def add_inbetween_keys(obj, shapes) -> list[str]:
    """Add one shape key per stored inbetween pose (rest + offsets, object-local = stage mm).

    Full shapes missing from the import are added too. Returns the names added.
    """
    me = obj.data
    if me.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    basis = me.shape_keys.reference_key
    n = len(me.vertices)
    rest = np.empty(n * 3)
    basis.data.foreach_get("co", rest)
    rest = rest.reshape(n, 3)
    added = []
    for s in shapes:
        idx = np.asarray(s.point_indices, np.int64)
        poses = list(zip(s.inbetween_names(), np.asarray(s.inbetween_offsets, float).reshape(-1, len(idx), 3)))
        if me.shape_keys.key_blocks.get(s.name) is None:
            poses.append((s.name, np.asarray(s.offsets, float)))
        for name, off in poses:
            kb = obj.shape_key_add(name=name, from_mix=False)
            P = rest.copy()
            P[idx] += off
            kb.data.foreach_set("co", P.ravel())
            kb.slider_min, kb.slider_max = 0.0, 1.0
            added.append(name)
    if me.shape_keys.animation_data is not None:   # imported weight animation would override values
        me.shape_keys.animation_data_clear()
    return added
