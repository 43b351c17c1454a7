"""Cross-sections through the eye openings of benchmark scans, against their ground truth.

    .venv/bin/python -m benchmarks.view_eye_sections [--work benchmarks/out/unseen]
        [--cases id42_down:left:x id37_up:left:x ...] [--out benchmarks/results/unseen_eye_sections.png]

Each panel is a 1.2 mm slab through the true opening centre (``x``: a vertical section,
``y``: a horizontal one; forward is to the right): scan vertices labelled eyeball by scanify's
``--write-labels`` in green, everything else red, the true eyeball sphere in dark blue and the
corneal sphere in light blue. It shows what the eye fit has to work with: in most openings the
visible eye is cornea (or the iris seen through it), and the sclera shows only towards the
canthi. Run ``bench_unseen_scans`` first (it makes the scans).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["id42_down:left:x", "id37_up:left:x", "id18_dome:left:x", "id11_neutral:left:y"]
SIZE, SCALE = 420, 18.0      # panel px, px per mm


def panel(folder: Path, side: str, axis: str) -> Image.Image:
    import trimesh

    V = np.asarray(trimesh.load(folder / "scan.ply", process=False).vertices, dtype=np.float64)
    lab = np.load(folder / "scan_labels.npy")
    g = json.loads((folder / "ground_truth.json").read_text())["eyes"][side]
    o = np.array(g["eye_opening_center_mm"])
    ax = 0 if axis == "x" else 1
    up = 1 - ax
    m = (np.abs(V[:, ax] - o[ax]) < 0.6) & (np.linalg.norm(V - o, axis=1) < 12.0)
    img = Image.new("RGB", (SIZE, SIZE), "white")
    d = ImageDraw.Draw(img)

    def px(u, z):
        return (SIZE / 2 + (z - o[2]) * SCALE, SIZE / 2 - (u - o[up]) * SCALE)

    t = np.linspace(0, 2 * np.pi, 400)
    for key, col in (("eyeball_sphere", (0, 0, 200)), ("cornea_sphere", (140, 140, 255))):
        c, r = np.array(g[key]["center_mm"]), g[key]["radius_mm"]
        d.line([px(c[up] + r * np.cos(a), c[2] + r * np.sin(a)) for a in t], fill=col, width=2)
    eye = {"left": 1, "right": 2}[side]
    for p, lb in zip(V[m], lab[m]):
        x, y = px(p[up], p[2])
        d.ellipse([x - 3, y - 3, x + 3, y + 3], fill=(0, 160, 0) if lb == eye else (200, 0, 0))
    d.text((6, 6), f"{folder.name} {side} ({'vertical' if axis == 'x' else 'horizontal'})",
           fill=(0, 0, 0))
    d.line([(SIZE - 6 - SCALE * 5, SIZE - 10), (SIZE - 6, SIZE - 10)], fill=(0, 0, 0), width=2)
    d.text((SIZE - 6 - SCALE * 5, SIZE - 24), "5 mm", fill=(0, 0, 0))
    return img


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--work", default=str(ROOT / "benchmarks" / "out" / "unseen"))
    ap.add_argument("--cases", nargs="*", default=DEFAULT, help="NAME:SIDE:AXIS (axis x or y)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "unseen_eye_sections.png"))
    args = ap.parse_args()
    panels = [panel(Path(args.work) / "scans" / n, s, a) for n, s, a in (c.split(":") for c in args.cases)]
    sheet = Image.new("RGB", (SIZE * len(panels), SIZE), "white")
    for i, p in enumerate(panels):
        sheet.paste(p, (SIZE * i, 0))
    sheet.save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
