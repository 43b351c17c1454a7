"""Persistent Blender worker: renders eye close-ups from sample specs (stage ``render``).

    python -m pipeline.blender.render_worker ASSET.usda RIG.npz [--threads N] [--tile-size PX]
        [--oidn-library PATH]

Loads ``rigged_assets/<scan>/<scan>.usda`` once with Blender's USD importer, builds the
Cycles scene and then reads one JSON sample spec per line on stdin (the spec is defined in the
render design, see ``pipeline/render``); for each it poses the scene, renders it with CPU Cycles
and writes the PNG to ``spec["png"]`` (temp name in the same folder + ``os.replace``). Replies go
to stdout, one line each, prefixed with :data:`REPLY_PREFIX` so they can be told apart from
Blender's own prints::

    @@render@@ {"ready": true, "setup_s": 2.1, "rss_mib": 400.0, "denoiser": "worker"}  (once, after loading)
    @@render@@ {"index": 17, "ok": true, "render_s": 0.21, "total_s": 0.25, "render_cpu_s": 0.4,
                "total_cpu_s": 0.45, "rss_mib": 612.0, "denoiser": "worker", "denoise_cpu_s": 0.09,
                "landmark_check_mm": 3e-6, "landmarks_measured_head_mm": [[x, y, z] * 28]}
    @@render@@ {"index": 17, "ok": false, "error": "..."}                          (and carries on)

``*_s`` = wall seconds of the render call (with the worker's film: the render, reading its
passes, denoising and writing the PNG) / of the whole sample, ``*_cpu_s`` = CPU seconds of
this process (all threads) over the same spans: robust to other processes on a shared
machine; ``denoise_*`` = the worker's OIDN call alone. stdin EOF or ``{"quit": true}`` ends the worker.

Scene (SynthesEyes paper, section 4):

* Frames. Stage (head) space = mm, +Y up, +Z out of the face. The importer puts the mm -> m
  scale and the Y-up -> Z-up rotation into the armature's world matrix ``H`` (head mm ->
  Blender world m: head +X -> +X, head +Z -> -Y, head +Y -> +Z); every head-frame quantity
  of the spec goes through ``H`` and every measurement comes back through ``H^-1``.
* Camera: ``world_to_camera`` (head mm -> camera mm, OpenGL axes, the camera looks down -Z)
  is inverted and mapped through ``H``. Orthographic: ``ortho_scale`` = ``ortho_scale_mm``
  / 1000 (horizontal extent, sensor fit AUTO with W >= H); the camera is pulled back
  along its own +Z by :data:`CAMERA_PULLBACK_M`: an orthographic image does not depend on
  the distance along the view axis, and this keeps clipping away from the face whatever
  origin the spec gives. Pinhole (spec ``K``): a perspective camera at the spec's camera
  centre, sensor fit HORIZONTAL, lens and shifts from ``K`` (:func:`pinhole_lens`).
* Eyes: each eye bone gets the head-frame quaternion ``eye_rotation[side]`` conjugated into
  the bone's rest frame (``R_b^-1 q R_b``), i.e. the eye rotates by ``q`` about its centre.
  Pupil/iris blend weights drive the Inner mesh shape keys.
* Lids: ``lid_weights`` channel weights are expanded with
  :func:`pipeline.rig.lids.flat_shape_weights` onto the full and inbetween shape keys
  (inbetweens added from RIG.npz, as in ``asset_preview``).
* Skin: Principled BSDF, baked colour map, subsurface (Christensen-Burley, red-dominant
  radius) plus a glossy specular lobe (roughness 0.45); detail from the baked displacement
  map (signed mm along the normal): ``skin_detail`` = ``"displacement"`` (Cycles true
  displacement of the mesh vertices + bump for the finer detail, method BOTH), ``"bump"``
  (bump only) or ``"none"`` (map unplugged). The bake fades the map to 0 at the eyelid
  margins, so true displacement does not move the landmarks.
* Eyeballs: :mod:`pipeline.blender.materials` (refractive cornea n = 1.376); all
  4 iris textures, 2 vein layers loaded once and switched per sample on the texture nodes,
  the sclera tint on the tint-multiply node.
* Eyelashes (:mod:`pipeline.blender.lashes`): one hair-curves object per eye (``LASHES``: 90
  upper lashes up to 9 mm, 45 lower up to 5.5 mm, 0.14 mm thick at the root, tapering), rooted
  0.5 mm in front of the posed lid margin (the ``loop_<side>`` vertices of the evaluated skin
  mesh) and curling away from the opening (up / down); rebuilt every sample so they follow the
  lids (``lash_curves``); dark glossy Principled BSDF, rendered as Cycles ribbons.
* World (:mod:`pipeline.blender.world`): one of Blender's bundled studio-light HDRIs (or an
  absolute path), loaded only when it changes (importance map 256 px); its rotation turns
  every root object and the camera instead, its strength is the exposure.
* Landmark check: the 28 landmarks of ``eye`` are measured in the posed, evaluated
  Blender scene -- eyelid landmark k = lerp of the evaluated skin vertices of
  ``landmarks.<side>.edge[k]`` at ``t[k]``; iris/pupil = evaluated Inner-mesh vertices
  ``eyerig:landmarks:iris|pupil`` of the eyeball asset -- brought back to head mm and
  compared with ``landmarks_head_mm`` (max distance, mm).

Film and denoiser (spec ``denoiser``, :data:`DENOISERS`): by default (``"worker"``) Cycles
renders without its denoiser, the worker reads the render's passes (noisy colour, denoising
albedo and normal; :mod:`pipeline.blender.film`), denoises them with OpenImageDenoise filters
it built once (:mod:`pipeline.blender.oidn`: the same filters and settings as Cycles', the same
pixels, without Cycles' per-render device and filter set-up) and writes the PNG through
Blender's Standard view transform itself. ``"cycles"``, or a worker whose OIDN library cannot
be loaded (said once on stderr, ``"denoiser": "cycles"`` in the ready reply): Cycles denoises
and Blender writes the PNG, as before.

Render settings (see benchmarks/bench_render_quality.py for the measured trade-off): CPU
Cycles, samples / denoise / seed from the spec, OpenImageDenoise with albedo + normal passes
and the ACCURATE prefilter (colour and albedo networks HIGH, the normal's FAST:
:data:`DENOISE_QUALITY`), adaptive sampling (threshold 0.02), single-scatter GGX on every
Principled BSDF, light paths limited to what the cornea needs (:data:`LIGHT_PATHS`), one
tile for the whole image, persistent render data, blue-noise sampling and no light tree
(:data:`CYCLES`). Optional spec keys (tests/benchmarks): ``denoiser``, ``lashes``, ``skin_subdivision``, ``adaptive_sampling``,
``adaptive_threshold``, ``denoise_prefilter``, ``denoise_normal_quality`` (``HIGH``: Cycles' own filters), the :data:`LIGHT_PATHS` names and ``cycles``
(``{scene.cycles property: value}`` for that image only; the defaults come back on the next).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

from pipeline.blender.film import render_passes, write_film_png
from pipeline.blender.lashes import LASHES, add_lash_objects, lash_curves
from pipeline.blender.materials import (CORNEA_IOR, eye_region_materials, eyelash_material, set_tint,
                                        setup_eyeball_materials, thin_coat)
from pipeline.blender.seg_passes import SegPasses
from pipeline.blender.scene import add_inbetween_keys, evaluated_vertices, find_image, import_usd
from pipeline.blender.world import EnvironmentWorld
from pipeline.eyeball.textures import IRIS_COLORS, SCLERA_TINTS, VEINS  # the asset's variants (no bpy)
from pipeline.render.camera import Camera, quat_to_matrix
from pipeline.render.spec import EYE_BLENDS, SIDES, RenderSpec

REPLY_PREFIX = "@@render@@ "
CAMERA_PULLBACK_M = 0.25
PINHOLE_SENSOR_MM = 36.0         # any width: Blender's lens is set from it (pinhole_lens)
ADAPTIVE_THRESHOLD = 0.02
WORLD_MAP_RESOLUTION = 256
DENOISERS = ("worker", "cycles")  # the worker's own persistent OIDN filters (default) | Cycles' per render
DENOISE_PREFILTER = "ACCURATE"   # OIDN albedo/normal prefilter: +0.7 dB at 16 spp for ~0.3 CPU-s
# OIDN quality of the colour, albedo-prefilter and normal-prefilter networks. The normal at FAST (OIDN's small
# network) gives the same PSNR on bench_render_quality's frame for ~0.03 CPU-s less per image; the albedo at
# FAST loses 0.07 dB, the colour at BALANCED 0.4 dB (issue 32, benchmarks/results/render_speed.md)
DENOISE_QUALITY = {"quality": "HIGH", "aux_quality": "HIGH", "normal_quality": "FAST"}
BSDF_DISTRIBUTION = "GGX"        # single-scatter GGX on every Principled BSDF (multi-scatter: ~1.3x time)
# Measured on bench_render_quality's frame, same 2048-spp reference (benchmarks/bench_render_split.py):
# blue-noise sample pattern = +0.5 dB after OIDN at the same samples (what lets 10 spp replace 12);
# no light tree: the world is the only light, so the tree only costs (-6 % CPU, same PSNR).
CYCLES = {"sampling_pattern": "BLUE_NOISE", "use_light_tree": False}
LIGHT_PATHS = {"max_bounces": 8, "diffuse_bounces": 1, "glossy_bounces": 2, "transmission_bounces": 6,
               "transparent_max_bounces": 8, "volume_bounces": 0}
# skin BSDF: subsurface scale is in world units (m): ~1.2 mm mean free path for red light
SKIN_BSDF = {"Roughness": 0.45, "Specular IOR Level": 0.5, "IOR": 1.4, "Subsurface Weight": 0.35,
             "Subsurface Scale": 0.0012, "Subsurface Radius": (1.0, 0.35, 0.2)}


def rss_mib() -> float:
    """Resident set size of this process, MiB (Linux /proc; 0 if unavailable)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        pass
    return 0.0


def _reply(obj: dict) -> None:
    sys.stdout.write(REPLY_PREFIX + json.dumps(obj) + "\n")
    sys.stdout.flush()


# ----------------------------------------------------------------------------- pure numpy helpers

def camera_to_head(world_to_camera) -> np.ndarray:
    """(4, 4) camera -> head rigid transform from the spec's world_to_camera (orthonormalised)."""
    M = np.asarray(world_to_camera, float)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise ValueError("camera.world_to_camera must be a finite 4x4 matrix")
    R = M[:3, :3]
    U, S, Vt = np.linalg.svd(R)
    if np.abs(S - 1).max() > 1e-3 or np.linalg.det(R) <= 0:
        raise ValueError("camera.world_to_camera is not a rigid transform (rotation + translation)")
    R = U @ Vt
    C = np.eye(4)
    C[:3, :3] = R.T
    C[:3, 3] = -R.T @ M[:3, 3]
    return C


def pinhole_lens(K, width: int, height: int) -> dict:
    """Blender perspective-camera values of pinhole intrinsics ``K`` (pixel centres at +0.5) for a
    ``width`` x ``height`` image, with ``sensor_fit = HORIZONTAL`` and ``sensor_width =``
    :data:`PINHOLE_SENSOR_MM`: ``lens = f * sensor_width / width`` (horizontal fit: the sensor
    width spans the image width); Blender's shifts are in units of the fitted dimension (the
    width), shift_x moving the view right and shift_y up: ``shift_x = (width / 2 - cx) / width``,
    ``shift_y = (cy - height / 2) / width``.
    """
    K = np.asarray(K, float)
    f, cx, cy = float(K[0, 0]), float(K[0, 2]), float(K[1, 2])
    lens = f * PINHOLE_SENSOR_MM / width
    if lens < 1.0:                               # Blender's smallest lens
        raise ValueError(f"camera.K focal length {f:g} px is too short for a {width} px wide image "
                         f"(horizontal field of view over {2 * np.degrees(np.arctan(width / (2 * f))):.0f} deg)")
    return {"lens": lens, "shift_x": (width / 2.0 - cx) / width, "shift_y": (cy - height / 2.0) / width}


def _eyeball_landmark_indices(asset: Path) -> dict:
    """Inner-mesh landmark vertex indices from the eyeball asset the per-scan asset references."""
    text = asset.read_text(errors="replace")
    m = re.search(r"references\s*=\s*@([^@]*eyeball\.usda)@", text)
    if m is None:
        raise RuntimeError(f"{asset}: no reference to an eyeball.usda")
    eb = (asset.parent / m.group(1)).resolve()
    etext = eb.read_text(errors="replace")
    out = {}
    for k in ("iris", "pupil"):
        mm = re.search(r"eyerig:landmarks:" + k + r"\s*=\s*\[([^\]]*)\]", etext)
        if mm is None:
            raise RuntimeError(f"{eb}: no eyerig:landmarks:{k}")
        out[k] = np.array([int(v) for v in mm.group(1).split(",")], np.int64)
    return out, eb


# ----------------------------------------------------------------------------- Blender side

class Worker:
    """The loaded scene; :meth:`render` renders one spec."""

    def __init__(self, asset: Path, rig_npz: Path, threads: int = 0, tile_size: int = 2048,
                 thin_sclera_coat: bool = True, oidn_library: Path | None = None):
        import bpy

        from pipeline.io.rig_file import read_rig_arrays
        from pipeline.rig import lids

        t0 = time.perf_counter()
        self.bpy = bpy
        self.lids = lids
        asset, rig_npz = Path(asset), Path(rig_npz)
        rig = read_rig_arrays(rig_npz)
        self.rig, self.shapes = rig.arrays, rig.shapes
        self.eb_landmarks, eb_path = _eyeball_landmark_indices(asset)
        objs = import_usd(asset, unit_conversion=True)
        scene = bpy.context.scene
        self.scene = scene
        self.skin = next((o for o in objs if o.name.split(".")[0] == "EyeRegion"), None)
        self.arm = next((o for o in scene.objects if o.type == "ARMATURE"), None)
        if self.skin is None or self.arm is None:
            raise RuntimeError(f"{asset}: no EyeRegion mesh / skeleton imported")
        n_v = len(self.skin.data.vertices)
        for s in self.shapes:
            if len(s.point_indices) and int(np.max(s.point_indices)) >= n_v:
                raise RuntimeError(f"{rig_npz}: shape {s.name} indexes beyond the {n_v} asset vertices")
        add_inbetween_keys(self.skin, self.shapes)
        self.skin_keys = [kb for kb in self.skin.data.shape_keys.key_blocks
                          if kb != self.skin.data.shape_keys.reference_key]
        for o in scene.objects:        # landmark curves carry no shape keys in Blender: not rendered
            if o.type not in ("MESH", "ARMATURE", "CAMERA", "EMPTY"):
                o.hide_render = True
                o.hide_viewport = True

        # head mm -> Blender world
        self.H = np.array(self.arm.matrix_world)
        self.Hinv = np.linalg.inv(self.H)
        self.h_scale = float(np.cbrt(np.linalg.det(self.H[:3, :3])))
        self.H_rot = self.H[:3, :3] / self.h_scale

        # eyes per side: bone, Outer, Inner
        self.eyes = {}
        for side in SIDES:
            bone = f"eye_{side}"
            mine = [o for o in objs if o is not self.skin and o.parent is not None and o.parent.name == bone]
            inner = next((o for o in mine if o.data.shape_keys is not None
                          and "Iris" in [sl.material.name.split(".")[0] for sl in o.material_slots
                                         if sl.material]), None)
            outer = next((o for o in mine if o is not inner), None)
            pb = self.arm.pose.bones.get(bone)
            if inner is None or outer is None or pb is None:
                raise RuntimeError(f"{asset}: eye {side} (bone {bone}, Outer, Inner) not imported")
            pb.rotation_mode = "QUATERNION"
            Rb = np.array(pb.bone.matrix_local)[:3, :3]
            Rb = Rb / np.cbrt(np.linalg.det(Rb))
            n_in = len(inner.data.vertices)
            for k, idx in self.eb_landmarks.items():
                if idx.max() >= n_in:
                    raise RuntimeError(f"{eb_path}: {k} landmark index beyond the {n_in} Inner vertices")
            self.eyes[side] = {"bone": pb, "Rb": Rb, "inner": inner, "outer": outer,
                               "keys": {kb.name: kb for kb in inner.data.shape_keys.key_blocks}}
            for b in EYE_BLENDS:
                if b not in self.eyes[side]["keys"]:
                    raise RuntimeError(f"{asset}: Inner mesh of eye {side} has no shape key {b}")
            # rest forward (head frame) = bone rest local +Z mapped to armature space
            self.eyes[side]["forward"] = Rb[:, 2] / np.linalg.norm(Rb[:, 2])
            self.eyes[side]["center"] = np.array(pb.bone.head_local)
            loop = self.rig.get(f"loop_{side}")
            edge = self.rig.get(f"landmarks.{side}.edge")
            if loop is None or edge is None:
                raise RuntimeError(f"{rig_npz}: loop_{side} / landmarks.{side}.edge missing")
            lat = np.flatnonzero(np.asarray(loop) == int(edge[6, 0]))
            if len(lat) != 1:
                raise RuntimeError(f"{rig_npz}: lateral canthus of {side} not on loop_{side}")
            self.eyes[side]["loop"] = np.asarray(loop, np.int64)
            self.eyes[side]["lateral"] = int(lat[0])
            self.eyes[side]["edge"] = np.asarray(edge, np.int64)
            self.eyes[side]["t"] = np.asarray(self.rig[f"landmarks.{side}.t"], float)

        # materials: skin
        color = find_image([self.skin], "Skin", "color")
        disp = find_image([self.skin], "Skin", "displacement")
        self.skin_mats = eye_region_materials(self.skin, color, disp, subsurface_method="BURLEY", **SKIN_BSDF)
        self.skin_detail = None
        # materials: eyes (textures of all variants loaded once)
        tex_dir = eb_path.parent / "textures"
        self.iris_images = {c: self._load_image(tex_dir / f"iris_{c}.png") for c in IRIS_COLORS}
        self.sclera_images = {v: self._load_image(tex_dir / f"sclera_{v}.png") for v in VEINS}
        bump = self._load_image(tex_dir / "sclera_bump.png")
        for side in SIDES:
            e = self.eyes[side]
            e["handles"] = setup_eyeball_materials([e["outer"], e["inner"]], self.iris_images["brown"],
                                                   self.sclera_images["clear"], (1.0, 1.0, 1.0), bump)
            if not {"iris_tex", "sclera_tex", "tint"} <= set(e["handles"]):
                raise RuntimeError(f"{asset}: eye {side} lacks Iris/Sclera material slots")
        if thin_sclera_coat:
            for m in {sl.material for e in self.eyes.values() for sl in e["outer"].material_slots
                      if sl.material is not None and sl.material.name.split(".")[0] == "ScleraCoat"}:
                thin_coat(m)
        self.eye_variant = {}
        self.cycles_saved = {}

        self._setup_render(threads, tile_size)
        self._setup_oidn(oidn_library, threads)
        self._setup_lashes()
        self.seg = SegPasses(self, not thin_sclera_coat, CORNEA_IOR, CAMERA_PULLBACK_M)   # set up on first use
        for m in self.bpy.data.materials:
            for n in (m.node_tree.nodes if m.node_tree else ()):
                if n.type == "BSDF_PRINCIPLED":
                    n.distribution = BSDF_DISTRIBUTION
        # root objects (armature, skin/eye parents, lashes) and their head-aligned world matrices;
        # the environment rotation is applied by rotating these (see _set_hdri)
        self.roots = {o: np.array(o.matrix_world) for o in scene.objects
                      if o.parent is None and o is not self.cam}
        self.Rw = np.eye(4)
        self.Rw_inv = np.eye(4)
        self.setup_s = time.perf_counter() - t0

    # -- setup helpers
    def _load_image(self, path: Path):
        if not path.is_file():
            raise RuntimeError(f"{path}: eyeball texture missing")
        im = self.bpy.data.images.load(str(path), check_existing=True)
        im.use_fake_user = True      # survives the orphan purges
        return im

    def _set_skin_detail(self, mode: str) -> None:
        if mode == self.skin_detail:
            return
        for m in self.skin_mats:
            nt, d, out = m["nt"], m["disp"], m["out"]
            for link in list(out.inputs["Displacement"].links):
                nt.links.remove(link)
            if d is not None and mode != "none":
                nt.links.new(d.outputs["Displacement"], out.inputs["Displacement"])
                m["mat"].displacement_method = "BOTH" if mode == "displacement" else "BUMP"
        self.skin_detail = mode

    def _set_skin_subdivision(self, levels: int) -> None:
        """Benchmarks only (render time against polygon count): Catmull-Clark subdivide the skin
        ``levels`` times (4x the polygons per level) after the rig's deformation; 0 = as imported.
        The smoothing moves the lid margin off the labels: the landmark check fails there."""
        if not 0 <= levels <= 3:
            raise ValueError(f"skin_subdivision {levels} outside 0..3")
        mod = self.skin.modifiers.get("BenchSubdivision")
        if mod is None and levels > 0:
            mod = self.skin.modifiers.new("BenchSubdivision", "SUBSURF")
        if mod is not None:
            mod.levels = mod.render_levels = levels
            mod.show_viewport = mod.show_render = levels > 0

    def _setup_render(self, threads: int, tile_size: int) -> None:
        bpy = self.bpy
        scene = self.scene
        scene.render.engine = "CYCLES"
        c = scene.cycles
        c.device = "CPU"
        c.use_adaptive_sampling = True
        c.adaptive_threshold = ADAPTIVE_THRESHOLD
        for k, v in LIGHT_PATHS.items():
            setattr(c, k, v)
        c.caustics_reflective = False
        c.caustics_refractive = False
        for k, v in CYCLES.items():
            setattr(c, k, v)
        c.use_auto_tile = True
        c.tile_size = int(tile_size)
        try:
            c.denoiser = "OPENIMAGEDENOISE"
            c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
            c.denoising_prefilter = DENOISE_PREFILTER
            self.has_denoiser = True
        except TypeError:
            self.has_denoiser = False
        scene.cycles_curves.shape = "RIBBONS"
        scene.cycles_curves.subdivisions = 2
        r = scene.render
        r.resolution_percentage = 100
        r.film_transparent = False
        r.use_persistent_data = True
        if threads > 0:
            r.threads_mode = "FIXED"
            r.threads = int(threads)
        else:
            r.threads_mode = "AUTO"
        r.image_settings.file_format = "PNG"
        r.image_settings.color_mode = "RGB"
        r.image_settings.color_depth = "8"
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        self.world = EnvironmentWorld(bpy, scene, WORLD_MAP_RESOLUTION)
        cam_data = bpy.data.cameras.new("RenderCam")
        cam_data.type = "ORTHO"
        cam_data.sensor_fit = "AUTO"
        cam_data.clip_start = 1e-3
        cam_data.clip_end = CAMERA_PULLBACK_M + 1.0
        cam_data.shift_x = cam_data.shift_y = 0.0
        self.cam = bpy.data.objects.new("RenderCam", cam_data)
        scene.collection.objects.link(self.cam)
        scene.camera = self.cam

    def _setup_oidn(self, library, threads: int) -> None:
        """The worker's own OIDN denoiser (:mod:`pipeline.blender.oidn`), built once; without the
        library the images keep Cycles' denoiser (said once on stderr)."""
        from pipeline.blender.oidn import Denoiser, OidnUnavailable

        try:
            self.oidn = Denoiser(library, threads=threads, **DENOISE_QUALITY)
        except OidnUnavailable as exc:
            self.oidn = None
            print(f"render_worker: {exc}; denoising with Cycles' own denoiser", file=sys.stderr, flush=True)
            return
        # the noisy colour's guides: albedo and normal passes, written whether or not Cycles denoises
        self.scene.view_layers[0].cycles.denoising_store_passes = True

    def _setup_lashes(self) -> None:
        rng = np.random.default_rng(12345)
        self.lash_rng = {side: {k: rng.random((v["count"], 4)) for k, v in LASHES.items()} for side in SIDES}
        mat = eyelash_material(self.bpy.data.materials.new("Eyelash"))
        self.lashes = add_lash_objects(self.bpy, self.scene, SIDES, mat)

    # -- per sample
    def _set_hdri(self, light: dict) -> None:
        """The spec's environment map, its rotation (everything else turned by ``Rw``) and its
        strength (exposure): :mod:`pipeline.blender.world`."""
        self.Rw, exposure = self.world.set(light)
        self.Rw_inv = self.Rw.T.copy()
        self._apply_world_rotation()
        self.scene.view_settings.exposure = exposure

    def _apply_world_rotation(self) -> None:
        from mathutils import Matrix

        for o, base in self.roots.items():
            o.matrix_world = Matrix((self.Rw @ base).tolist())

    def _set_eyes(self, spec: RenderSpec) -> None:
        from mathutils import Matrix

        rot, eb = spec.eye_rotation, spec.eyeball
        blend = eb.blend
        for side in SIDES:
            e = self.eyes[side]
            q = quat_to_matrix(rot[side])
            local = e["Rb"].T @ q @ e["Rb"]
            e["bone"].rotation_quaternion = Matrix(local.tolist()).to_quaternion()
            for k in EYE_BLENDS:
                e["keys"][k].value = float(blend.get(k, 0.0))
            variant = (eb.iris_color, eb.sclera_tint, eb.veins)
            if self.eye_variant.get(side) != variant:
                h = e["handles"]
                h["iris_tex"].image = self.iris_images[eb.iris_color]
                h["sclera_tex"].image = self.sclera_images[eb.veins]
                set_tint(h, SCLERA_TINTS[eb.sclera_tint])
                self.eye_variant[side] = variant

    def _set_lids(self, cw: dict) -> None:
        bad = set(cw) - {s.name for s in self.shapes}       # the values were checked with the spec
        if bad:
            raise ValueError(f"lid_weights: unknown channels {sorted(bad)}")
        flat = self.lids.flat_shape_weights(self.shapes, {k: float(v) for k, v in cw.items()})
        for kb in self.skin_keys:
            kb.value = flat.get(kb.name, 0.0)

    def _set_camera(self, cam: Camera, width: int, height: int) -> None:
        from mathutils import Matrix

        C = camera_to_head(cam.world_to_camera)
        R = self.H_rot @ C[:3, :3]
        pullback = CAMERA_PULLBACK_M if cam.K is None else 0.0   # a pinhole camera stays where it is
        loc = self.H[:3, :3] @ C[:3, 3] + self.H[:3, 3] + R[:, 2] * pullback
        Mw = np.eye(4)
        Mw[:3, :3] = R
        Mw[:3, 3] = loc
        self.cam_base = Mw
        self.cam.matrix_world = Matrix((self.Rw @ Mw).tolist())
        data = self.cam.data
        if cam.K is None:
            scale = float(cam.ortho_scale_mm)
            if data.type != "ORTHO":             # back from a pinhole image: the set-up's values
                data.type, data.sensor_fit, data.shift_x, data.shift_y = "ORTHO", "AUTO", 0.0, 0.0
                data.clip_start, data.clip_end = 1e-3, CAMERA_PULLBACK_M + 1.0
            data.ortho_scale = scale * self.h_scale if width >= height else scale * self.h_scale * height / width
        else:
            lens = pinhole_lens(cam.K, width, height)
            data.type, data.sensor_fit, data.sensor_width = "PERSP", "HORIZONTAL", PINHOLE_SENSOR_MM
            data.lens, data.shift_x, data.shift_y = lens["lens"], lens["shift_x"], lens["shift_y"]
            data.clip_start = 0.1 * self.h_scale
            data.clip_end = float(np.linalg.norm(C[:3, 3]) + 1000.0) * self.h_scale
        self.seg.pullback_m = pullback            # the depth map is measured from the spec's camera
        self.scene.render.resolution_x, self.scene.render.resolution_y = int(width), int(height)

    def _evaluated_head_mm(self, obj, dg) -> np.ndarray:
        P, Mw = evaluated_vertices(obj, dg)
        M = self.Hinv @ self.Rw_inv @ Mw
        return P @ M[:3, :3].T + M[:3, 3]

    def _lashes_and_landmarks(self, side: str, spec_lashes: bool) -> np.ndarray:
        """Rebuild both eyes' lashes from the posed margins; return the 28 measured landmarks of ``side``."""
        dg = self.bpy.context.evaluated_depsgraph_get()
        S = self._evaluated_head_mm(self.skin, dg)
        for sd in SIDES:
            obj, curves, rad = self.lashes[sd]
            obj.hide_render = not spec_lashes
            if not spec_lashes:
                continue
            e = self.eyes[sd]
            pts, r = lash_curves(S[e["loop"]], e["lateral"], e["forward"], self.lash_rng[sd])
            W = pts @ self.H[:3, :3].T + self.H[:3, 3]
            curves.position_data.foreach_set("vector", W.astype(np.float32).ravel())
            rad.data.foreach_set("value", (r * self.h_scale).astype(np.float32))
            curves.update_tag()
        e = self.eyes[side]
        lid = (1.0 - e["t"])[:, None] * S[e["edge"][:, 0]] + e["t"][:, None] * S[e["edge"][:, 1]]
        inner = self._evaluated_head_mm(e["inner"], dg)
        return np.concatenate([lid, inner[self.eb_landmarks["iris"]], inner[self.eb_landmarks["pupil"]]])

    def render(self, spec: RenderSpec) -> dict:
        bpy = self.bpy
        t0, c0 = time.perf_counter(), time.process_time()
        png = Path(spec.png)                # the values were checked when the spec was read
        outs = {k: Path(p) for k, p in (("seg_png", spec.seg_png), ("depth_exr", spec.depth_exr)) if p}
        if any(not p.parent.is_dir() for p in [png, *outs.values()]):
            raise ValueError(f"png / seg_png / depth_exr {str(png)!r}: the folder does not exist")
        width, height, side = spec.width, spec.height, spec.eye
        lm_in = np.asarray(spec.landmarks_head_mm, float)
        over = spec.quality.overrides         # tests and benchmarks: this image only
        t_in = time.perf_counter()
        self._set_hdri(asdict(spec.lighting))
        self._set_eyes(spec)
        self._set_lids(spec.lid_weights)
        self._set_camera(spec.camera, width, height)
        self._set_skin_detail(spec.quality.skin_detail)
        self._set_skin_subdivision(int(over.get("skin_subdivision", 0)))
        c = self.scene.cycles
        c.samples = spec.quality.samples
        denoise = spec.quality.denoise
        denoiser = over.get("denoiser", "worker")
        if denoiser not in DENOISERS:
            raise ValueError(f"denoiser {denoiser!r} not in {DENOISERS}")
        own = denoiser == "worker" and self.oidn is not None     # the worker's film and OIDN, else Blender's
        prefilter = str(over.get("denoise_prefilter", DENOISE_PREFILTER))
        c.use_denoising = denoise and self.has_denoiser and not own
        c.seed = spec.quality.cycles_seed & 0x7FFFFFFF
        c.use_adaptive_sampling = bool(over.get("adaptive_sampling", True))
        c.adaptive_threshold = float(over.get("adaptive_threshold", ADAPTIVE_THRESHOLD))
        for k, v in LIGHT_PATHS.items():
            setattr(c, k, int(over.get(k, v)))
        c.denoising_prefilter = prefilter
        cycles = over.get("cycles", {})
        for k, v in cycles.items():       # benchmarks: any scene.cycles property, this image only
            if k not in self.cycles_saved:
                self.cycles_saved[k] = getattr(c, k)
            setattr(c, k, v)
        for k in [k for k in self.cycles_saved if k not in cycles]:
            setattr(c, k, self.cycles_saved.pop(k))
        self.bpy.context.view_layer.update()
        polygons = (len(self.skin.evaluated_get(self.bpy.context.evaluated_depsgraph_get()).data.polygons)
                    if "skin_subdivision" in over else None)
        t_pose = time.perf_counter()
        measured = self._lashes_and_landmarks(side, bool(over.get("lashes", True)))
        check = float(np.linalg.norm(measured - lm_in, axis=1).max())
        t_lash = time.perf_counter()
        if outs:
            self.seg.before_render(self.bpy.context.evaluated_depsgraph_get())
        tmp = png.with_name(f".{png.stem}.tmp{os.getpid()}.png")
        self.scene.render.filepath = str(tmp)
        t1, c1 = time.perf_counter(), time.process_time()
        bpy.ops.render.render(write_still=not own)
        passes, t_den, c_den = None, 0.0, 0.0
        if own or outs:
            passes = render_passes(bpy, self.scene, png.with_name(f".{png.stem}.passes{os.getpid()}.exr"))
        if own:
            t_den, c_den = write_film_png(tmp, passes, self.scene.view_settings.exposure,
                                          self.oidn if denoise else None, prefilter,
                                          over.get("denoise_normal_quality"))
        t_render, c_render = time.perf_counter() - t1, time.process_time() - c1
        if not tmp.is_file():
            raise RuntimeError("Blender wrote no image")
        os.replace(tmp, png)
        t2 = time.perf_counter()
        if outs:
            self.seg.after_render(outs.get("seg_png"), outs.get("depth_exr"), passes)
        passes_s = time.perf_counter() - t2
        return {"index": spec.index, "ok": True, "render_s": round(t_render, 4),
                "render_cpu_s": round(c_render, 4), "total_s": round(time.perf_counter() - t0, 4),
                "total_cpu_s": round(time.process_time() - c0, 4), "rss_mib": rss_mib(),
                "passes_s": round(passes_s, 4), "denoise_s": round(t_den, 4), "denoise_cpu_s": round(c_den, 4),
                "denoiser": ("worker" if own else "cycles") if denoise else None, "check_s": round(t_in - t0, 4), "pose_s": round(t_pose - t_in, 4),
                "lashes_s": round(t_lash - t_pose, 4), "seg_setup_s": round(t1 - t_lash, 4),
                "landmark_check_mm": check, "landmarks_measured_head_mm": measured.round(6).tolist(),
                **({"skin_polygons": polygons} if polygons is not None else {})}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", type=Path)
    ap.add_argument("rig", type=Path)
    ap.add_argument("--threads", type=int, default=0, help="render threads (0 = all cores)")
    ap.add_argument("--tile-size", type=int, default=2048, help="Cycles tile size, px")
    ap.add_argument("--oidn-library", type=Path, default=None,
                    help="OpenImageDenoise library for the worker's denoiser (default: the bpy wheel's)")
    ap.add_argument("--refractive-sclera-coat", action="store_true",
                    help="keep the asset's refracting sclera coat shell (default: thin clear coat)")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        w = Worker(args.asset, args.rig, args.threads, args.tile_size, not args.refractive_sclera_coat,
                   args.oidn_library)
    except Exception as exc:  # noqa: BLE001 -- any unloadable asset/rig: one line, exit 2
        _reply({"ready": False, "error": f"{type(exc).__name__}: {exc}"})
        return 2
    _reply({"ready": True, "setup_s": round(w.setup_s, 3), "rss_mib": rss_mib(),
            "denoiser": "worker" if w.oidn is not None else "cycles"})
    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        index = None
        try:
            doc = json.loads(line)
            if isinstance(doc, dict) and doc.get("quit"):
                break
            index = doc.get("index") if isinstance(doc, dict) else None
            _reply(w.render(RenderSpec.from_dict(doc)))
        except Exception as exc:  # noqa: BLE001 -- any bad spec: report it and carry on
            _reply({"index": index, "ok": False, "error": f"{type(exc).__name__}: {exc}"})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
