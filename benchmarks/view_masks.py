"""Picture of rendered images beside their masks, depth maps and labels (README figure).

    python -m benchmarks.view_masks renders/<scan> benchmarks/results/masks_<scan>.png [--images 0 1 2] [--scale 3]

Each row: the image with its 28 landmarks (eyelid green, iris cyan, pupil yellow; iris and pupil
drawn where they are seen through the cornea; a filled dot = visible, a red cross = occluded,
with the reason's initial: l = lid, a = lashes, e = eye, o = outside), the seg mask in its palette
(pipeline/render/seg.py) with the same landmarks, and the depth map (near = light, far = dark,
range of the image's finite depths). A legend of the classes is drawn below.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.io.labels_file import read_label
from pipeline.io import seg_file as sf
from pipeline.io.seg_file import read_depth, read_seg
from pipeline.render.visibility import positions

COLOURS = [(60, 230, 90)] * 12 + [(60, 220, 255)] * 8 + [(255, 230, 40)] * 8


def _marks(img, lab, scale: int):
    from PIL import ImageDraw

    d = ImageDraw.Draw(img)
    P = positions(lab.px, lab.doc["landmarks"].get("apparent_px")) * scale
    for k, (x, y) in enumerate(P):
        if not np.all(np.isfinite([x, y])):
            continue
        if lab.visible is None or lab.visible[k]:
            d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=COLOURS[k], outline=(0, 0, 0))
        else:
            d.line([x - 3, y - 3, x + 3, y + 3], fill=(255, 30, 30), width=2)
            d.line([x - 3, y + 3, x + 3, y - 3], fill=(255, 30, 30), width=2)
            d.text((x + 3, y - 10), {"lashes": "a"}.get(lab.occlusion[k], lab.occlusion[k][0]), fill=(255, 30, 30))


def row(folder: Path, index: int, scale: int):
    from PIL import Image

    lab = read_label(folder / f"{index:06d}.json")
    size = (lab.width, lab.height)
    big = (lab.width * scale, lab.height * scale)
    img = Image.open(folder / lab.doc["image"]["file"]).convert("RGB").resize(big, Image.NEAREST)
    seg = read_seg(folder / lab.doc["seg"]["file"], size)
    segimg = Image.fromarray(seg, "P")
    segimg.putpalette(sf.palette())
    segimg = segimg.convert("RGB").resize(big, Image.NEAREST)
    depth = read_depth(folder / lab.doc["depth"]["file"], size)
    fin = np.isfinite(depth)
    lo, hi = (float(depth[fin].min()), float(depth[fin].max())) if fin.any() else (0.0, 1.0)
    g = np.where(fin, 255 * (hi - depth) / max(hi - lo, 1e-6), 0).clip(0, 255).astype(np.uint8)
    dimg = Image.fromarray(g, "L").convert("RGB").resize(big, Image.NEAREST)
    _marks(img, lab, scale)
    _marks(segimg, lab, scale)
    return [img, segimg, dimg], (lo, hi)


def main(argv=None) -> int:
    from PIL import Image, ImageDraw

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--images", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--scale", type=int, default=3)
    args = ap.parse_args(argv)
    rows = [row(args.folder, i, args.scale) for i in args.images]
    w, h = rows[0][0][0].size
    pad, cap, legend = 4, 14, 18
    sheet = Image.new("RGB", (3 * w + 4 * pad, len(rows) * (h + cap + pad) + pad + legend), (40, 40, 40))
    d = ImageDraw.Draw(sheet)
    for r, ((tiles, (lo, hi)), i) in enumerate(zip(rows, args.images)):
        y = pad + r * (h + cap + pad)
        for c, (t, name) in enumerate(zip(tiles, ("image + landmarks", "seg + visibility",
                                                  f"depth {lo:.0f}-{hi:.0f} mm"))):
            x = pad + c * (w + pad)
            sheet.paste(t, (x, y + cap))
            d.text((x, y), f"{i:06d} {name}", fill=(230, 230, 230))
    x, y = pad, sheet.size[1] - legend + 2
    for k, (name, rgb) in sf.CLASSES.items():
        d.rectangle([x, y + 2, x + 10, y + 12], fill=rgb, outline=(200, 200, 200))
        d.text((x + 14, y + 1), f"{k} {name}", fill=(230, 230, 230))
        x += 14 + 7 * len(f"{k} {name}") + 10
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.out)
    print(args.out, sheet.size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
