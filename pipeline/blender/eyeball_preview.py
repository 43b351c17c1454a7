"""Blender worker: Cycles contact sheet of the eyeball asset.

    python -m pipeline.blender.eyeball_preview ASSET.usda OUT.png [--size 160] [--samples 16]
        [--hdri PATH] [--json TIMINGS.json]

Imports the asset with Blender's USD importer, swaps in the Cycles materials
(pipeline/blender/materials.py), lights it with one of Blender's
bundled HDRIs and renders one tile per (iris colour x view x pupil): rows =
amber, blue, brown, grey; columns = front/constricted, front/dilated,
three-quarter/constricted, three-quarter/dilated. CPU Cycles, OpenImageDenoise
when available. Writes the sheet as one PNG with labels.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

from pipeline.eyeball.textures import IRIS_COLORS

COLUMNS = (("front", "pupil_constrict"), ("front", "pupil_dilate"),
           ("three-quarter", "pupil_constrict"), ("three-quarter", "pupil_dilate"))


def _place_camera(cam, view: str, distance_m: float = 0.125):
    """Aim at the eye centre (origin). The imported eye looks down Blender -Y (USD +Z)."""
    from mathutils import Vector

    yaw = 0.0 if view == "front" else math.radians(40.0)
    pitch = math.radians(0.0 if view == "front" else 12.0)
    d = Vector((math.sin(yaw) * math.cos(pitch), -math.cos(yaw) * math.cos(pitch), math.sin(pitch)))
    cam.location = d * distance_m
    cam.rotation_euler = (-d).to_track_quat("-Z", "Y").to_euler()


def render_sheet(asset: Path, out_png: Path, size: int = 160, samples: int = 16,
                 hdri: Path | None = None, tint=(1.0, 1.0, 1.0), veins: str = "clear") -> dict:
    """Render the contact sheet; returns timings."""
    import bpy
    import numpy as np
    from PIL import Image, ImageDraw

    from pipeline.blender.materials import setup_eyeball_materials
    from pipeline.blender.scene import bundled_hdri, import_usd, preview_scene

    t0 = time.perf_counter()
    objs = import_usd(asset, unit_conversion=True)
    scene, cam = preview_scene(size, samples, hdri or bundled_hdri())
    tex_dir = asset.parent / "textures"
    iris_imgs = {c: bpy.data.images.load(str(tex_dir / f"iris_{c}.png")) for c in IRIS_COLORS}
    sclera_img = bpy.data.images.load(str(tex_dir / f"sclera_{veins}.png"))
    bump_img = bpy.data.images.load(str(tex_dir / "sclera_bump.png"))
    for im in (*iris_imgs.values(), sclera_img, bump_img):
        im.use_fake_user = True  # survive the orphan purge between renders
    handles = setup_eyeball_materials(objs, iris_imgs["brown"], sclera_img, tint, bump_img)
    inner = next(o for o in objs if o.name.startswith("Inner"))
    keys = inner.data.shape_keys.key_blocks
    t_setup = time.perf_counter() - t0

    tiles, times = {}, []
    with tempfile.TemporaryDirectory() as td:
        for color in IRIS_COLORS:
            handles["iris_tex"].image = iris_imgs[color]
            for ci, (view, shape) in enumerate(COLUMNS):
                for kb in keys:
                    if kb.name != keys[0].name:
                        kb.value = 1.0 if kb.name == shape else 0.0
                _place_camera(cam, view)
                path = Path(td) / f"{color}_{ci}.png"
                scene.render.filepath = str(path)
                t = time.perf_counter()
                bpy.ops.render.render(write_still=True)
                times.append(time.perf_counter() - t)
                tiles[(color, ci)] = np.asarray(Image.open(path).convert("RGBA"))
                bpy.data.orphans_purge(do_recursive=True)
    # sheet: grey backdrop, labels
    pad, label_h = 4, 16
    W = 4 * size + 5 * pad + 60
    H = 4 * size + 5 * pad + label_h
    sheet = Image.new("RGB", (W, H), (46, 46, 50))
    draw = ImageDraw.Draw(sheet)
    names = ["front, constricted", "front, dilated", "3/4, constricted", "3/4, dilated"]
    for ci, nm in enumerate(names):
        draw.text((60 + pad + ci * (size + pad) + 4, 2), nm, fill=(230, 230, 230))
    bg = Image.new("RGBA", (size, size), (46, 46, 50, 255))
    for ri, color in enumerate(IRIS_COLORS):
        y = label_h + pad + ri * (size + pad)
        draw.text((4, y + size // 2 - 6), color, fill=(230, 230, 230))
        for ci in range(4):
            tile = Image.alpha_composite(bg, Image.fromarray(tiles[(color, ci)]))
            sheet.paste(tile.convert("RGB"), (60 + pad + ci * (size + pad), y))
    sheet.save(out_png)
    return {"setup_s": round(t_setup, 3), "render_s_per_tile_median": round(float(np.median(times)), 3),
            "render_s_total": round(float(np.sum(times)), 3), "tiles": len(times), "size": size,
            "samples": samples, "denoiser": bool(scene.cycles.use_denoising),
            "hdri": Path(hdri or bundled_hdri()).name}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--hdri", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    info = render_sheet(args.asset, args.out, args.size, args.samples, args.hdri)
    if args.json:
        args.json.write_text(json.dumps(info, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
