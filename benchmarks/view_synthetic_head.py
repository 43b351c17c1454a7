"""Picture of the procedural head for the README: colour front views and eye close-ups.

A point splat of the dense vertices (painter's order along +Z, Lambert shading from
vertex normals), which is enough at ~1 px per vertex and needs no renderer.

    .venv/bin/python -m benchmarks.view_synthetic_head [OUT.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.geometry.meshtopo import vertex_normals
from pipeline.synthetic_head import make_synthetic_head


def splat(head, center, half, res):
    """(res, res, 3) uint8 orthographic front view of ``head`` around ``center`` (x, y) mm."""
    V, N = head.V, vertex_normals(head.V, head.F)
    light = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    shade = np.clip(N @ light, 0, 1) * 0.85 + 0.15
    tex = head.texture
    h = tex.shape[0]
    ui = np.clip((head.UV[:, 0] * tex.shape[1]).astype(int), 0, tex.shape[1] - 1)
    vi = np.clip(((1 - head.UV[:, 1]) * h).astype(int), 0, h - 1)
    colour = tex[vi, ui] / 255.0 * shade[:, None]
    px = ((V[:, 0] - center[0] + half) / (2 * half) * res).astype(int)
    py = ((center[1] + half - V[:, 1]) / (2 * half) * res).astype(int)
    ok = (px >= 0) & (px < res) & (py >= 0) & (py < res)
    order = np.flatnonzero(ok)[np.argsort(V[ok, 2])]
    img = np.zeros((res, res, 3))
    img[py[order], px[order]] = colour[order]
    return (img * 255).astype(np.uint8)


def _upscale(img, size):
    # the close-up has ~1 vertex per px at 100 px; enlarge rather than leave gaps between points
    return np.asarray(Image.fromarray(img).resize((size, size), Image.BICUBIC))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", type=Path, default=Path("benchmarks/results/synthetic_head.png"),
                    metavar="OUT.png")
    out = ap.parse_args(argv).out
    tiles = []
    for shape in ("round", "hooded"):
        head = make_synthetic_head(seed=7, target_triangles=1_400_000, eye_shape=shape, texture_size=1024,
                                   noise_mm=0.0)
        eye = head.ground_truth["eyes"]["left"]["eyeball_sphere"]["center_mm"]
        tiles.append(np.concatenate([splat(head, (0.0, -25.0), 125.0, 360),
                                     _upscale(splat(head, (eye[0], eye[1]), 20.0, 100), 360)], axis=1))
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(tiles, axis=0)).save(out)
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
