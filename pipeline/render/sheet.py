"""Contact sheet of rendered images with their labels drawn on (PIL only).

Each tile: the image upscaled ``scale`` times (nearest neighbour, so pixels stay honest),
the eyelid polygon (12 landmarks, green, canthi larger), the iris (cyan) and pupil (yellow)
landmarks (straight projection, circles) and where they appear through the cornea (magenta
dots, ``apparent_px``), and the gaze direction in the camera frame as a red line from the pupil centre
(length proportional to the gaze's in-image component). Caption: index, eye, gaze
pitch/yaw in the camera frame.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

PAD, CAPTION_H = 4, 14


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
    return img


def contact_sheet(items, out_png, scale: int = 2, columns: int = 4) -> tuple[int, int]:
    """Write a grid of ``(png_path, label_dict)`` tiles to ``out_png``; returns its (w, h)."""
    from PIL import Image, ImageDraw

    items = list(items)
    if not items:
        raise ValueError("no images for the contact sheet")
    tiles = [(_tile(Path(p), lab, scale), lab) for p, lab in items]
    tw = max(t.size[0] for t, _ in tiles)
    th = max(t.size[1] for t, _ in tiles)
    cols = min(columns, len(tiles))
    rows = math.ceil(len(tiles) / cols)
    W = cols * (tw + PAD) + PAD
    H = rows * (th + CAPTION_H + PAD) + PAD
    sheet = Image.new("RGB", (W, H), (28, 28, 31))
    draw = ImageDraw.Draw(sheet)
    for k, (t, lab) in enumerate(tiles):
        x = PAD + (k % cols) * (tw + PAD)
        y = PAD + (k // cols) * (th + CAPTION_H + PAD)
        gc = lab["gaze"]["camera"]
        draw.text((x + 1, y + 1), f"#{lab['index']} {lab['gaze']['eye']}, gaze {gc['pitch_deg']:+.0f}/"
                                  f"{gc['yaw_deg']:+.0f}", fill=(225, 225, 225))
        sheet.paste(t, (x, y + CAPTION_H))
    out_png = Path(out_png)
    tmp = out_png.with_name(f".{out_png.stem}.tmp{out_png.suffix}")
    sheet.save(tmp)
    tmp.replace(out_png)
    return W, H
