"""Blender worker: Cycles contact sheet of a per-scan rigged asset.

    python -m pipeline.blender.asset_preview ASSET.usda RIG.npz OUT.png [--size 180] [--samples 4]
        [--hdri PATH] [--json INFO.json] [--option KEY=VALUE ...]

Imports ``rigged_assets/<scan>/<scan>.usda`` with Blender's USD importer and renders four
tiles with CPU Cycles (+ OpenImageDenoise when built in), lit by one of Blender's bundled
studio-light HDRIs:

* front views (orthographic, both eyes) at gaze pitch +25, 0 and -25 degrees, and
* a three-quarter view (35 degrees toward the subject's left, 8 degrees from above) at pitch 0.

For each pitch both eye bones are rotated by the pitch about the head X axis (positive =
looking up) and the lid shape keys are set with the rig's own pitch-to-weight rule
(:func:`pipeline.rig.lids.lid_weights`). Blender imports only the full ``lids_up`` /
``lids_down`` shapes, not the UsdSkel inbetweens, so the inbetween poses are added here from
``RIG.npz`` as extra shape keys (``<shape>_ib<j>``, offsets relative to the rest mesh) and
driven with :func:`pipeline.rig.lids.flat_shape_weights`, which reproduces the UsdSkel
inbetween evaluation exactly (``lid_max_error_mm`` in the JSON checks that against
:func:`pipeline.rig.lids.evaluate_shapes`).

Materials (:mod:`pipeline.blender.materials`): skin = Principled BSDF with subsurface
scattering, the baked colour texture and the baked displacement map as bump (signed mm along
the normal = object units); eyes = :func:`pipeline.blender.materials.setup_eyeball_materials`
with the iris / sclera textures the asset's variant selection imported. Output: one labelled PNG
(:func:`sheet_size` gives its pixel size for a tile size).

Speed (benchmarks/bench_asset_preview.py): one Blender process imports the asset once and renders
the four tiles with persistent render data, so a tile re-syncs only the posed bones, shape keys
and camera (~0.01 s). A tile's cost is its pixels x samples: path tracing ~2.6 CPU-us per
sample and pixel (Christensen-Burley subsurface, one Cycles tile; Blender's default random walk
in 64-px tiles: ~5) plus the denoiser, ~4 CPU-us per pixel; the first render also builds the
world's importance map. :data:`RENDER_OPTIONS` holds the measured choices; ``--option KEY=VALUE``
overrides one (benchmarks). The JSON reports the time of each phase (Blender start, USD import,
scene setup, per tile posing + checks and rendering, composing) and the process CPU time.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PITCHES = (25.0, 0.0, -25.0)
THREE_QUARTER_YAW_DEG = 35.0
THREE_QUARTER_ELEV_DEG = 8.0
TILE_ASPECT = 2            # tile width / height (both eyes side by side)
PAD, LABEL_H = 6, 18
BACKDROP = (46, 46, 50)
# skin: subsurface scale in world units (m)
SKIN_BSDF = {"Roughness": 0.5, "Specular IOR Level": 0.4, "Subsurface Weight": 0.25, "Subsurface Scale": 0.002,
             "Subsurface Radius": (1.0, 0.35, 0.2)}
# Cycles choices of the preview, measured by benchmarks/bench_asset_preview.py --split: a 480 x 240
# tile at 8 spp took 5.7 CPU-s with the former choices (in the comments), 2.6 with these
RENDER_OPTIONS = {
    "denoise": True,                 # OpenImageDenoise (when built in)
    "denoise_prefilter": "ACCURATE",  # albedo/normal seen through the cornea are noisy: FAST speckles the pupil
    "denoise_quality": "BALANCED",   # was HIGH: ~2.2x the denoiser time for no visible difference here
    "subsurface_method": "BURLEY",   # the render stage's; was RANDOM_WALK (Blender's default): +33 % per tile
    "world_map_resolution": 256,     # world importance map; was 0 = automatic (the HDRI's 1024 x 512): +1.2 CPU-s
    "tile_size": 2048,               # Cycles tile, px: the whole preview tile at once; was 64: +23 % per tile
    "adaptive_threshold": 0.05,      # adaptive sampling: a pixel stops below this noise level
    "adaptive_min_samples": 0,       # ... after at least this many samples (0 = Cycles' automatic)
}


def sheet_size(size: int) -> tuple[int, int]:
    """(width, height) of the contact sheet for tile height ``size``: a 2 x 2 grid of labelled tiles."""
    w = 2 * TILE_ASPECT * size + 3 * PAD
    h = 2 * (size + LABEL_H) + 3 * PAD
    return w, h


def tile_boxes(size: int) -> list[tuple[int, int, int, int]]:
    """(x, y, width, height) in the sheet of the four rendered tiles (their labels above them left
    out), row-major, for tile height ``size``."""
    w, h = TILE_ASPECT * size, size
    return [(PAD + (i % 2) * (w + PAD), PAD + (i // 2) * (h + LABEL_H + PAD) + LABEL_H, w, h) for i in range(4)]


def _views():
    """(label, pitch_deg, view) of the four tiles, row-major."""
    return [(f"front, pitch +{PITCHES[0]:.0f} deg (up)", PITCHES[0], "front"),
            ("front, pitch 0 deg", PITCHES[1], "front"),
            (f"front, pitch {PITCHES[2]:.0f} deg (down)", PITCHES[2], "front"),
            ("three-quarter (35 deg), subject's left eye, pitch 0 deg", 0.0, "three-quarter")]


def render_options(overrides: dict | None = None) -> dict:
    """:data:`RENDER_OPTIONS` with ``overrides`` (``{key: value or its string}``) applied and checked."""
    out = dict(RENDER_OPTIONS)
    for k, v in (overrides or {}).items():
        if k not in RENDER_OPTIONS:
            raise ValueError(f"unknown render option {k!r} (known: {', '.join(RENDER_OPTIONS)})")
        ref = RENDER_OPTIONS[k]
        if isinstance(v, str) and not isinstance(ref, str):
            low = v.strip().lower()
            if isinstance(ref, bool):
                if low not in ("1", "0", "true", "false", "on", "off"):
                    raise ValueError(f"render option {k}: {v!r} is not a boolean")
                v = low in ("1", "true", "on")
            else:
                v = type(ref)(v)
        out[k] = v
    return out


def _setup_scene(width: int, height: int, samples: int, hdri: Path, opts: dict):
    import bpy

    from pipeline.blender.scene import preview_scene

    scene, cam = preview_scene(height, samples, hdri)
    scene.render.resolution_x, scene.render.resolution_y = width, height
    c = scene.cycles
    c.tile_size = int(opts["tile_size"])
    c.adaptive_threshold = float(opts["adaptive_threshold"])
    c.adaptive_min_samples = int(opts["adaptive_min_samples"])
    if c.use_denoising:
        c.use_denoising = bool(opts["denoise"])
        c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        c.denoising_prefilter = opts["denoise_prefilter"]
        c.denoising_quality = opts["denoise_quality"]
    if int(opts["world_map_resolution"]) > 0:
        scene.world.cycles.sampling_method = "MANUAL"
        scene.world.cycles.sample_map_resolution = int(opts["world_map_resolution"])
    cam.data.type = "ORTHO"
    cam.data.clip_end = 10.0
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
    # rotate the HDRI so its brightest window lights the face from the upper front-left
    nt = scene.world.node_tree
    env = next(n for n in nt.nodes if n.type == "TEX_ENVIRONMENT")
    mapping = nt.nodes.new("ShaderNodeMapping")
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(200.0))
    nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    bpy.context.view_layer.update()
    return scene, cam


def _pose_eyes(arm, pitch_deg: float) -> None:
    """Rotate both eye bones by ``pitch_deg`` about the head X axis (positive = looking up)."""
    from mathutils import Quaternion, Vector

    # armature space = stage space (mm, +Y up, +Z out of the face): pitch up = rotation about -X
    axis_arm = Vector((-1.0, 0.0, 0.0))
    for pb in arm.pose.bones:
        if not pb.name.startswith("eye_"):
            continue
        axis = (pb.bone.matrix_local.to_3x3().normalized().inverted() @ axis_arm).normalized()
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = Quaternion(axis, math.radians(pitch_deg))


def _place_camera(cam, view: str, target, distance: float, ortho_scale: float):
    from mathutils import Vector

    yaw = math.radians(THREE_QUARTER_YAW_DEG if view == "three-quarter" else 0.0)
    el = math.radians(THREE_QUARTER_ELEV_DEG if view == "three-quarter" else 0.0)
    # Blender world: head +X -> +X, head +Z (out of the face) -> -Y, head +Y (up) -> +Z
    d = Vector((math.sin(yaw) * math.cos(el), -math.cos(yaw) * math.cos(el), math.sin(el)))
    cam.location = Vector(target) + d * distance
    cam.rotation_euler = (-d).to_track_quat("-Z", "Y").to_euler()
    cam.data.ortho_scale = ortho_scale


def render_sheet(asset: Path, rig_npz: Path, out_png: Path, size: int = 180, samples: int = 4,
                 hdri: Path | None = None, options: dict | None = None) -> dict:
    """Render the contact sheet; returns timings and checks (see the module docstring).

    ``options`` overrides :data:`RENDER_OPTIONS` (see :func:`render_options`).
    """
    opts = render_options(options)
    t_start = time.perf_counter()
    import bpy                                    # the first import starts Blender
    t_bpy = time.perf_counter() - t_start
    from PIL import Image, ImageDraw

    from pipeline.blender.materials import eye_region_materials, setup_eyeball_materials
    from pipeline.blender.scene import add_inbetween_keys, bundled_hdri, evaluated_vertices, find_image, import_usd
    from pipeline.io.rig_file import read_rig_arrays
    from pipeline.rig import lids

    t0 = time.perf_counter()
    shapes = read_rig_arrays(rig_npz).shapes
    objs = import_usd(asset, unit_conversion=True)
    t_import = time.perf_counter() - t0
    skin = next((o for o in objs if o.name.split(".")[0] == "EyeRegion"), None)
    if skin is None:
        raise RuntimeError(f"{asset}: no EyeRegion mesh imported")
    arm = next((o for o in bpy.context.scene.objects if o.type == "ARMATURE"), None)
    if arm is None:
        raise RuntimeError(f"{asset}: no skeleton imported")
    n_v = len(skin.data.vertices)
    for s in shapes:
        if len(s.point_indices) and int(np.max(s.point_indices)) >= n_v:
            raise RuntimeError(f"{rig_npz}: shape {s.name} indexes beyond the {n_v} asset vertices")
    rest = np.empty(n_v * 3)
    skin.data.shape_keys.reference_key.data.foreach_get("co", rest) if skin.data.shape_keys else \
        skin.data.vertices.foreach_get("co", rest)
    rest = rest.reshape(n_v, 3)
    add_inbetween_keys(skin, shapes)
    keys = skin.data.shape_keys.key_blocks

    # materials
    color = find_image([skin], "Skin", "color")
    disp = find_image([skin], "Skin", "displacement")
    eye_region_materials(skin, color, disp, displacement_method="BUMP",
                         subsurface_method=opts["subsurface_method"], **SKIN_BSDF)
    eyes = [o for o in objs if o is not skin]
    iris = find_image(eyes, "Iris", "iris_")
    sclera = find_image(eyes, "Sclera", "sclera_")
    bump = None
    if sclera is not None:
        p = Path(bpy.path.abspath(sclera.filepath)).with_name("sclera_bump.png")
        if p.is_file():
            bump = bpy.data.images.load(str(p), check_existing=True)
    if iris is None or sclera is None:
        raise RuntimeError(f"{asset}: eyeball textures (iris_*.png, sclera_*.png) not imported")
    setup_eyeball_materials(eyes, iris, sclera, (1.0, 1.0, 1.0), bump)

    # framing from the eye joints (armature space = stage mm)
    M = arm.matrix_world
    heads = {b.name: M @ b.head_local for b in arm.data.bones if b.name.startswith("eye_")}
    centres = list(heads.values())
    mid = sum(centres, type(centres[0])((0, 0, 0))) / len(centres)
    sep = (centres[0] - centres[-1]).length if len(centres) > 1 else 0.03
    radius = max(o.dimensions.x for o in eyes) / 2.0            # eyeball radius, m
    front_scale = sep + 2.8 * radius                             # tile width, m (2:1 tile)
    target = mid.copy()
    target.y -= radius          # toward the face surface (Blender -Y = out of the face)
    target.z += 0.15 * radius   # the region reaches higher (brow) than lower (cheek)
    # three-quarter (camera toward the subject's left): close-up of the near eye (subject's left,
    # +X), shifted toward the nose so the lateral end of the eye-region crop stays out of frame
    near = max(centres, key=lambda c: c.x)
    tq_target = near.copy()
    tq_target.y -= radius
    tq_target.x -= 0.7 * radius
    tq_scale = 4.0 * radius
    # the landmark curves (BasisCurves) carry no shape keys in Blender: keep them out of the renders
    for o in bpy.context.scene.objects:
        if o.type not in ("MESH", "ARMATURE", "CAMERA", "EMPTY"):
            o.hide_render = True

    # corneal apex of each eye (largest local z of the Outer mesh, the model looks down +Z)
    apex = {}
    for o in eyes:
        mats = [sl.material.name.split(".")[0] for sl in o.material_slots if sl.material is not None]
        bone = o.parent.name if o.parent is not None else ""
        if "Cornea" in mats and f"{bone}" in heads:
            z = np.empty(len(o.data.vertices) * 3)
            o.data.vertices.foreach_get("co", z)
            apex[bone] = (o, int(np.argmax(z.reshape(-1, 3)[:, 2])))

    def gaze_elevation_deg() -> dict:
        dg = bpy.context.evaluated_depsgraph_get()
        out = {}
        for bone, (o, i) in apex.items():
            oe = o.evaluated_get(dg)
            em = oe.to_mesh()
            p = oe.matrix_world @ em.vertices[i].co
            oe.to_mesh_clear()
            d = (p - heads[bone]).normalized()
            out[bone] = math.degrees(math.asin(max(-1.0, min(1.0, d.z))))   # Blender +Z = head up
        return out

    rest_elev = gaze_elevation_deg()
    w, h = TILE_ASPECT * size, size
    scene, cam = _setup_scene(w, h, samples, hdri or bundled_hdri(), opts)
    t_setup = time.perf_counter() - t0

    tiles, times, cpu_times, pose_times, lid_err, pitch_meas = [], [], [], [], {}, {}
    with tempfile.TemporaryDirectory() as td:
        for i, (label, pitch, view) in enumerate(_views()):
            t = time.perf_counter()
            _pose_eyes(arm, pitch)
            cw = lids.lid_weights(pitch)
            flat = lids.flat_shape_weights(shapes, cw)
            for kb in keys:
                if kb != skin.data.shape_keys.reference_key:
                    kb.value = flat.get(kb.name, 0.0)
            bpy.context.view_layer.update()
            pitch_meas[f"{pitch:+.0f}"] = {b: round(e - rest_elev[b], 4) for b, e in gaze_elevation_deg().items()}
            # check: the Blender shape-key mix equals the UsdSkel inbetween evaluation
            P, _ = evaluated_vertices(skin, bpy.context.evaluated_depsgraph_get())
            lid_err[f"{pitch:+.0f}"] = float(np.abs(P - lids.evaluate_shapes(rest, shapes, cw)).max())
            if view == "front":
                _place_camera(cam, view, target, 0.5, front_scale)
            else:
                _place_camera(cam, view, tq_target, 0.5, tq_scale)
            path = Path(td) / f"tile{i}.png"
            scene.render.filepath = str(path)
            pose_times.append(time.perf_counter() - t)
            t, c = time.perf_counter(), time.process_time()
            bpy.ops.render.render(write_still=True)
            times.append(time.perf_counter() - t)
            cpu_times.append(time.process_time() - c)
            tiles.append((label, Image.open(path).convert("RGBA")))

    t = time.perf_counter()
    W, H = sheet_size(size)
    sheet = Image.new("RGB", (W, H), (30, 30, 33))
    bg = Image.new("RGBA", (w, h), (*BACKDROP, 255))
    for (label, tile), (x, y, _, _) in zip(tiles, tile_boxes(size)):
        lab = Image.new("RGB", (w, LABEL_H), (30, 30, 33))   # clipped to the tile width
        ImageDraw.Draw(lab).text((2, 3), label, fill=(235, 235, 235))
        sheet.paste(lab, (x, y - LABEL_H))
        sheet.paste(Image.alpha_composite(bg, tile).convert("RGB"), (x, y))
    sheet.save(out_png)
    t_compose = time.perf_counter() - t
    return {"blender_start_s": round(t_bpy, 3), "import_s": round(t_import, 3), "setup_s": round(t_setup, 3),
            "pose_s_total": round(float(np.sum(pose_times)), 3),
            "render_s_total": round(float(np.sum(times)), 3), "render_s": [round(x, 3) for x in times],
            "render_cpu_s": [round(x, 3) for x in cpu_times],
            "render_s_per_tile_median": round(float(np.median(times)), 3), "compose_s": round(t_compose, 3),
            "sheet_s": round(time.perf_counter() - t_start, 3), "cpu_s": round(time.process_time(), 3),
            "tiles": len(times), "tile_px": [w, h], "sheet_px": [W, H], "samples": samples,
            "denoiser": bool(scene.cycles.use_denoising), "render_options": opts,
            "hdri": Path(hdri or bundled_hdri()).name,
            "shape_keys": [kb.name for kb in keys], "lid_max_error_mm": lid_err,
            "gaze_pitch_measured_deg": pitch_meas}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", type=Path)
    ap.add_argument("rig", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", type=int, default=180, help="tile height, px (tiles are 2:1)")
    ap.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel (+ the denoiser)")
    ap.add_argument("--hdri", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help=f"override a render option (benchmarks): {', '.join(RENDER_OPTIONS)}")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.size < 8 or args.samples < 1:
        print("error: --size must be >= 8 and --samples >= 1", file=sys.stderr)
        return 2
    try:
        options = render_options(dict(o.split("=", 1) for o in args.option if "=" in o))
        if any("=" not in o for o in args.option):
            raise ValueError("--option takes KEY=VALUE")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    info = render_sheet(args.asset, args.rig, args.out, args.size, args.samples, args.hdri, options)
    if args.json:
        args.json.write_text(json.dumps(info, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
