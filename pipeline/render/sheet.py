"""Contact sheet of rendered images with their labels drawn on (PIL only).

Each tile: the image upscaled ``scale`` times (nearest neighbour, so pixels stay honest),
the eyelid polygon (12 landmarks, green, canthi larger), the iris (cyan) and pupil (yellow)
landmarks (straight projection, circles) and where they appear through the cornea (magenta
dots, ``apparent_px``), and the gaze direction in the camera frame as a red line from the pupil centre
(length proportional to the gaze's in-image component). With ``render.masks`` the label names
a seg mask: the tile then shows the mask (its palette, pipeline/io/seg_file.py) beside the image,
and each landmark is drawn where it is seen (through the cornea for iris and pupil) as a filled
dot when visible or a red cross when occluded (``landmarks.visible``). Caption, two lines: the
asset the image shows (``asset.name`` of a dataset label, else ``scan``), then the index, eye and
gaze pitch/yaw in the camera frame; a column is widened to its longest caption so names stay whole.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

PAD, CAPTION_H = 4, 28
NAME_PT, INFO_PT = 12, 10        # Pillow's bundled font (FreeType), pixel sizes of the two caption lines


def _tile(png: Path, label: dict, scale: int):
    from PIL import Image, ImageDraw

    img = Image.open(png).convert("RGB")
    w, h = img.size
    img = img.resize((w * scale, h * scale), Image.NEAREST)
    d = ImageDraw.Draw(img)
    px = np.asarray(label["landmarks"]["px"], float) * scale
    lid = [tuple(p) for p in px[:12]]
    d.line(lid + [lid[0]], fill=(60, 230, 90), width=1)
    r = max(1.5, scale * 0.6)
    for k, (x, y) in enumerate(px):
        col = (60, 230, 90) if k < 12 else (60, 220, 255) if k < 20 else (255, 230, 40)
        rr = 1.6 * r if k in (0, 6) else r
        d.ellipse([x - rr, y - rr, x + rr, y + rr], outline=col)
    for q in label["landmarks"].get("apparent_px") or []:    # seen through the cornea
        if q is not None:
            x, y = q[0] * scale, q[1] * scale
            d.ellipse([x - 1, y - 1, x + 1, y + 1], fill=(255, 60, 255))
    pc = np.asarray(label["landmarks"]["pupil_center_px"], float) * scale
    g = np.asarray(label["gaze"]["vector_camera"], float)
    L = 0.35 * h * scale
    tip = pc + L * np.array([g[0], -g[1]])
    d.line([tuple(pc), tuple(tip)], fill=(255, 60, 60), width=2)
    seg = label.get("seg", {}).get("file") if isinstance(label.get("seg"), dict) else None
    if seg is None or label["landmarks"].get("visible") is None:
        return img
    return _with_mask(img, Path(png).with_name(seg), label, scale)


def _with_mask(img, seg_png: Path, label: dict, scale: int):
    """The tile beside its seg mask, both with every landmark marked visible (dot) or not (cross)."""
    from PIL import Image, ImageDraw

    from pipeline.render.visibility import positions

    w, h = img.size
    mask = Image.open(seg_png).convert("RGB").resize((w, h), Image.NEAREST)
    both = Image.new("RGB", (2 * w + PAD, h), (28, 28, 31))
    both.paste(img, (0, 0))
    both.paste(mask, (w + PAD, 0))
    d = ImageDraw.Draw(both)
    P = positions(label["landmarks"]["px"], label["landmarks"].get("apparent_px")) * scale
    r = max(1.5, scale * 0.6)
    for x0 in (0, w + PAD):
        for (x, y), vis in zip(P, label["landmarks"]["visible"]):
            x += x0
            if vis:
                d.ellipse([x - r, y - r, x + r, y + r], fill=(255, 255, 255), outline=(0, 0, 0))
            else:
                d.line([(x - r, y - r), (x + r, y + r)], fill=(255, 40, 40), width=2)
                d.line([(x - r, y + r), (x + r, y - r)], fill=(255, 40, 40), width=2)
    return both


def asset_name(label: dict) -> str:
    """The asset an image shows: ``asset.name`` (a dataset's label), else ``scan`` (a render's)."""
    a = label.get("asset")
    return str(a["name"]) if isinstance(a, dict) and a.get("name") else str(label.get("scan", "?"))


def _caption(label: dict) -> tuple[str, str]:
    gc = label["gaze"]["camera"]
    return (asset_name(label),
            f"#{label['index']} {label['gaze']['eye']}, gaze {gc['pitch_deg']:+.0f}/{gc['yaw_deg']:+.0f}")


def contact_sheet(items, out_png, scale: int = 2, columns: int | None = None) -> tuple[int, int]:
    """Write a grid of ``(png_path, label_dict)`` tiles to ``out_png``; returns its (w, h).

    ``columns`` defaults to 4 (2 when the tiles carry their masks, which doubles their width)."""
    from PIL import Image, ImageDraw, ImageFont

    items = list(items)
    if not items:
        raise ValueError("no images for the contact sheet")
    tiles = [(_tile(Path(p), lab, scale), lab) for p, lab in items]
    name_font, info_font = ImageFont.load_default(NAME_PT), ImageFont.load_default(INFO_PT)
    captions = [_caption(lab) for _, lab in tiles]
    tw = max(max(t.size[0] for t, _ in tiles),
             max(max(name_font.getlength(a), info_font.getlength(b)) for a, b in captions) + 2)
    tw = int(math.ceil(tw))
    th = max(t.size[1] for t, _ in tiles)
    if columns is None:
        columns = 2 if any("seg" in lab for _, lab in tiles) else 4
    cols = min(columns, len(tiles))
    rows = math.ceil(len(tiles) / cols)
    W = cols * (tw + PAD) + PAD
    H = rows * (th + CAPTION_H + PAD) + PAD
    sheet = Image.new("RGB", (W, H), (28, 28, 31))
    draw = ImageDraw.Draw(sheet)
    for k, (t, lab) in enumerate(tiles):
        x = PAD + (k % cols) * (tw + PAD)
        y = PAD + (k // cols) * (th + CAPTION_H + PAD)
        name, info = captions[k]
        draw.text((x + 1, y + 1), name, fill=(255, 255, 255), font=name_font)
        draw.text((x + 1, y + 2 + NAME_PT), info, fill=(200, 200, 200), font=info_font)
        sheet.paste(t, (x, y + CAPTION_H))
    out_png = Path(out_png)
    tmp = out_png.with_name(f".{out_png.stem}.tmp{out_png.suffix}")
    sheet.save(tmp)
    tmp.replace(out_png)
    return W, H
