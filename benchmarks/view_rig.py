"""Front view of a rigged eye region at pitch +25 / 0 / -25 deg (visual check of the lid shapes).

    .venv/bin/python -m benchmarks.view_rig build/<scan>/snap build/<scan>/rig out.png [--side left]

Flat-shaded painter's-algorithm render with PIL (no Blender): the skin around one
eye posed with the stored blend shapes and the pitch-to-weight rule, the eyeball
disc with an iris that rotates with the pitch, and the eyelid margin in green.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.geometry.frame import eye_basis
from pipeline.io.eyes_file import read_eyes
from pipeline.io.meshfile import load_mesh
from pipeline.io.rig_file import read_rig
from pipeline.rig import lids

ROOT = Path(__file__).resolve().parents[1]


def panel(P, F, loop, eye: dict, pitch: float, size=400):
    from PIL import Image, ImageDraw

    c, r = np.asarray(eye["center"], float), float(eye["radius"])
    B = eye_basis(eye["forward"])
    sel = np.linalg.norm(P[F].mean(1) - c, axis=1) < 2.2 * r
    Fs = F[sel]
    n = np.cross(P[Fs[:, 1]] - P[Fs[:, 0]], P[Fs[:, 2]] - P[Fs[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    shade = np.clip(n @ (B.T @ np.array([0.3, 0.4, 0.87])), 0, 1)
    Q = (P - c) @ B.T                                        # eye frame: x right-ish, y up, z fwd
    order = np.argsort(Q[Fs].mean(1)[:, 2])
    sc = size / (4.4 * r)
    img = Image.new("RGB", (size, size), (20, 30, 60))
    d = ImageDraw.Draw(img)
    cx = cy = size / 2
    d.ellipse([cx - r * sc, cy - r * sc, cx + r * sc, cy + r * sc], fill=(235, 235, 230))
    gy, gz = np.sin(np.radians(pitch)), np.cos(np.radians(pitch))
    iris = 0.45 * r
    d.ellipse([cx - iris * sc, cy - gy * r * sc - iris * gz * sc,
               cx + iris * sc, cy - gy * r * sc + iris * gz * sc], fill=(90, 60, 30))
    for i in order:
        xy = [(cx + x * sc, cy - y * sc) for x, y, _ in Q[Fs[i]]]
        v = int(60 + 170 * shade[i])
        d.polygon(xy, fill=(v, int(v * 0.8), int(v * 0.7)))
    xy = [(cx + x * sc, cy - y * sc) for x, y, _ in Q[loop]]
    d.line(xy + xy[:1], fill=(0, 255, 0), width=1)
    d.text((5, 5), f"pitch {pitch:+.0f} deg", fill=(255, 255, 0))
    return img


def main(argv=None) -> int:
    from PIL import Image

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("snap", type=Path)
    ap.add_argument("rig", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--side", default="left", choices=("left", "right"))
    a = ap.parse_args(argv)
    m = load_mesh(a.snap / "mesh.npz")
    eyes = {s: e.to_doc() for s, e in read_eyes(a.snap / "eyes.json", len(m["V"])).items()}
    rig = read_rig(a.rig, n_vertices=len(m["V"]))
    shapes, max_pitch = rig.npz.shapes, rig.max_pitch_deg
    loop = np.asarray(rig.npz.arrays[f"loop_{a.side}"])
    imgs = [panel(lids.evaluate_shapes(m["V"], shapes, lids.lid_weights(p, max_pitch)), m["F"],
                  loop, eyes[a.side], p) for p in (max_pitch, 0.0, -max_pitch)]
    out = Image.new("RGB", (sum(i.width for i in imgs), imgs[0].height))
    for k, im in enumerate(imgs):
        out.paste(im, (k * im.width, 0))
    out.save(a.out)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
