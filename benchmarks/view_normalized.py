"""Picture of rendered images beside their normalised eye crops (docs/datasets.md figure).

    python -m benchmarks.view_normalized DIR benchmarks/results/dataset_lab_normalized.png [--images 2 5] [--scale 3]

Each row: the image with its 28 landmarks (eyelid green, iris cyan, pupil yellow) and the eye
centre the normalisation is taken about (white ring); ETH-XGaze's 128 x 128 crop (1800 px, 600 mm)
with the landmarks its warp carries there and the principal point (white cross); MPIIGaze's 60 x 36
crop (960 px, 600 mm) likewise. The crops are computed here with pipeline/render/normalize.py from
the image and its label (the ``normalized`` format writes the first one into DIR/normalized/).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pipeline.render import normalize as nz

COLOURS = [(60, 230, 90)] * 12 + [(60, 220, 255)] * 8 + [(255, 230, 40)] * 8


def _panel(rgb: np.ndarray, px, centre, scale: int, caption: str):
    from PIL import Image, ImageDraw

    h, w = rgb.shape[:2]
    img = Image.fromarray(rgb).resize((w * scale, h * scale), Image.NEAREST)
    d = ImageDraw.Draw(img)
    for (x, y), c in zip(np.asarray(px) * scale, COLOURS):
        d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=c)
    cx, cy = np.asarray(centre) * scale
    d.ellipse([cx - 5, cy - 5, cx + 5, cy + 5], outline=(255, 255, 255))
    d.line([cx - 8, cy, cx + 8, cy], fill=(255, 255, 255))
    d.line([cx, cy - 8, cx, cy + 8], fill=(255, 255, 255))
    out = Image.new("RGB", (img.width, img.height + 18), (255, 255, 255))
    out.paste(img, (0, 0))
    ImageDraw.Draw(out).text((3, img.height + 3), caption, fill=(0, 0, 0))
    return out


def main(argv=None) -> int:
    from PIL import Image

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--images", type=int, nargs="+", default=[2])
    ap.add_argument("--scale", type=int, default=3)
    args = ap.parse_args(argv)
    rows = []
    for i in args.images:
        lab = json.loads((args.folder / f"{i:06d}.json").read_text())
        with Image.open(args.folder / f"{i:06d}.png") as im:
            rgb = np.asarray(im.convert("RGB"))
        e_px = lab["eyes"][lab["gaze"]["eye"]]["center_px"]
        panels = [_panel(rgb, lab["landmarks"]["px"], e_px, args.scale,
                         f"#{i} {lab['asset']['name']} {rgb.shape[1]}x{rgb.shape[0]}")]
        for name, prof in nz.PROFILES.items():
            n = nz.normalization(lab, prof["size_px"], prof["focal_px"], prof["distance_mm"])
            crop = nz.warp_image(rgb, n["warp_opencv"], n["size_px"])
            doc = nz.normalized_label(lab, n)
            p, y = np.degrees(doc["gaze"]["pitchyaw_rad"])
            panels.append(_panel(crop, doc["landmarks"]["px"], doc["center"]["px"], args.scale,
                                 f"{name} {n['size_px'][0]}x{n['size_px'][1]} gaze {p:+.0f},{y:+.0f} deg"))
        W = sum(p.width for p in panels) + 8 * (len(panels) - 1)
        row = Image.new("RGB", (W, max(p.height for p in panels)), (255, 255, 255))
        x = 0
        for p in panels:
            row.paste(p, (x, 0))
            x += p.width + 8
        rows.append(row)
    sheet = Image.new("RGB", (max(r.width for r in rows), sum(r.height + 8 for r in rows)), (255, 255, 255))
    y = 0
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.height + 8
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
