"""A training set end to end: render a mixed dataset, then read it back the ways a researcher would.

    .venv/bin/python -m benchmarks.bench_dataset --assets rigged_assets/* --n 2000 --out DIR \\
        [--preset generic] [--formats eyerig coco webdataset] [--workers N] [--name dataset]

Renders with ``stages.dataset`` (its wall time is the headline), then checks, over every image:

* background: segmentation class 0 pixels per image (``NNNNNN_seg.png``); 0 is the contract;
* COCO: ``coco.json`` read with pycocotools (a keypoint annotation per image whose ``v`` equals the
  label's visibility, and the class masks' RLE decoding to the seg mask exactly);
* shards: every ``shards/*.tar`` member equal to its loose file, every image in one shard;
* the torch example (examples/torch_dataset.py, no eyerig import): every item read lazily, shapes
  and the gaze equal to the label's;
* the card: its plots exist.

Writes ``benchmarks/results/<name>.json`` and ``.md``, and copies the card's plots and contact sheet
beside them (``<name>_*.png``) for the README.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import tarfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from PIL import Image

from tests.fixtures.assets import images_per_asset

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _torch_example():
    spec = importlib.util.spec_from_file_location("torch_dataset", ROOT / "examples" / "torch_dataset.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def background(out: Path, indices) -> dict:
    """Class-0 pixels per image over every seg mask."""
    per = np.array([int((np.asarray(Image.open(out / f"{i:06d}_seg.png")) == 0).sum()) for i in indices])
    return {"images": int(per.size), "images_with_background": int((per > 0).sum()),
            "background_px_total": int(per.sum()), "background_px_max": int(per.max(initial=0))}


def coco_check(out: Path, labels: dict) -> dict:
    from pycocotools import mask as mask_util
    from pycocotools.coco import COCO

    coco = COCO(str(out / "coco.json"))
    eye_cat = [c["id"] for c in coco.loadCats(coco.getCatIds()) if c["name"] == "eye"][0]
    wrong_v = wrong_mask = 0
    for img in coco.loadImgs(coco.getImgIds()):
        idx = int(Path(img["file_name"]).stem)
        anns = coco.loadAnns(coco.getAnnIds(imgIds=img["id"]))
        eye = [a for a in anns if a["category_id"] == eye_cat]
        vis = labels[idx]["landmarks"]["visible"]
        v = np.asarray(eye[0]["keypoints"]).reshape(-1, 3)[:, 2]
        wrong_v += int(len(eye) != 1 or not np.array_equal(v == 2, np.asarray(vis, bool)))
        seg = np.asarray(Image.open(out / f"{idx:06d}_seg.png"))
        rebuilt = np.zeros_like(seg)
        for a in anns:
            if a["category_id"] != eye_cat:
                rebuilt[mask_util.decode(a["segmentation"]).astype(bool)] = a["category_id"]
        wrong_mask += int(not np.array_equal(rebuilt, seg))
    return {"images": len(coco.getImgIds()), "annotations": len(coco.getAnnIds()),
            "keypoint_visibility_wrong": wrong_v, "masks_wrong": wrong_mask}


def shards_check(out: Path, indices) -> dict:
    seen, differ, tars = Counter(), 0, sorted((out / "shards").glob("*.tar"))
    for t in tars:
        with tarfile.open(t) as tf:
            for m in tf.getmembers():
                key, _, ext = m.name.partition(".")
                loose = out / _loose_name(key, ext)
                differ += int(tf.extractfile(m).read() != loose.read_bytes())
                seen[int(key)] += 1
    return {"tars": len(tars), "images": len(seen), "members": int(sum(seen.values())),
            "images_missing": len(set(indices) - set(seen)), "members_differing": differ}


def _loose_name(key: str, ext: str) -> str:
    """The loose file of webdataset member ``key.ext`` (``seg.png`` -> ``NNNNNN_seg.png``)."""
    stem, _, last = ext.rpartition(".")
    return f"{key}_{stem}.{last}" if stem else f"{key}.{ext}"


def torch_check(out: Path, labels: dict) -> dict:
    ds = _torch_example().EyeDataset(out)
    t0, bad = time.perf_counter(), 0
    for k in range(len(ds)):
        it = ds[k]
        lab = labels[int(it["index"])]
        h, w = lab["image"]["height"], lab["image"]["width"]
        ok = (it["image"].shape == (h, w, 3) and it["landmarks"].shape == (28, 2)
              and it["mask"].shape == (h, w) and ("depth" not in it or it["depth"].shape == (h, w))
              and np.allclose(it["gaze"], lab["gaze"]["vector_camera"], atol=1e-6))
        bad += int(not ok)
    return {"items": len(ds), "items_wrong": bad, "has_depth": bool(ds.has_depth),
            "read_s_per_item": round((time.perf_counter() - t0) / max(len(ds), 1), 5)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--assets", nargs="+", required=True)
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--out", required=True)
    ap.add_argument("--preset", default="generic")
    ap.add_argument("--formats", nargs="+", default=["eyerig", "coco", "webdataset"])
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--name", default="dataset")
    ap.add_argument("--no-render", action="store_true", help="check an existing folder only")
    a = ap.parse_args(argv)
    out = Path(a.out)
    wall = None
    if not a.no_render:
        cmd = [sys.executable, "-m", "stages.dataset", "--assets", *a.assets, "--n", str(a.n), "--out", str(out),
               "--preset", a.preset, "--set", f"label_formats=[{', '.join(a.formats)}]"]
        if (out / "config.json").is_file():
            cmd.append("--resume")                   # a killed run goes on where it stopped
        if a.workers:
            cmd += ["--workers", str(a.workers)]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT)
        wall = time.perf_counter() - t0
    info = json.loads((out / "dataset.json").read_text())
    indices = list(range(a.n))
    labels = {i: json.loads((out / f"{i:06d}.json").read_text()) for i in indices}
    res = {"n": a.n, "preset": a.preset, "formats": a.formats, "assets": len(info.get("assets", [])),
           "counts": dict(Counter(lab["scan"] for lab in labels.values())),
           "wall_s": None if wall is None else round(wall, 1),
           "background": background(out, indices)}
    if "coco" in a.formats:
        res["coco"] = coco_check(out, labels)
    if "webdataset" in a.formats:
        res["shards"] = shards_check(out, indices)
    res["torch_example"] = torch_check(out, labels)
    plots = sorted(p.name for p in (out / "card").glob("*.png"))
    res["card_plots"] = plots
    RESULTS.mkdir(parents=True, exist_ok=True)
    for p in plots:
        shutil.copyfile(out / "card" / p, RESULTS / f"{a.name}_{p}")
    if (out / "contact_sheet.png").is_file():
        shutil.copyfile(out / "contact_sheet.png", RESULTS / f"{a.name}_contact_sheet.png")
    (RESULTS / f"{a.name}.json").write_text(json.dumps(res, indent=1) + "\n")
    b = res["background"]
    md = [f"# {a.name}: {a.n} images, preset {a.preset}, {res['assets']} assets", "",
          f"`python -m benchmarks.bench_dataset --assets ... --n {a.n} --preset {a.preset} --out DIR`", "",
          "| check | result |", "|---|---|",
          f"| render wall time | {res['wall_s']} s |" if wall is not None else "| render wall time | (not rendered here) |",
          f"| images with background (class 0) | {b['images_with_background']} of {b['images']} "
          f"({b['background_px_total']} px in all) |"]
    if "coco" in res:
        c = res["coco"]
        md.append(f"| COCO (pycocotools) | {c['images']} images, {c['annotations']} annotations; "
                  f"visibility wrong {c['keypoint_visibility_wrong']}, masks wrong {c['masks_wrong']} |")
    if "shards" in res:
        s = res["shards"]
        md.append(f"| webdataset shards | {s['tars']} tars, {s['images']} images, {s['members']} members; "
                  f"missing {s['images_missing']}, differing {s['members_differing']} |")
    t = res["torch_example"]
    md.append(f"| torch example | {t['items']} items, wrong {t['items_wrong']}, depth {t['has_depth']}, "
              f"{t['read_s_per_item'] * 1000:.1f} ms per item |")
    md += ["", *images_per_asset(res["counts"], a.assets), ""]
    (RESULTS / f"{a.name}.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
