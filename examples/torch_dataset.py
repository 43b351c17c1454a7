"""A lazy PyTorch ``Dataset`` over an eyerig dataset (or render) folder, with no eyerig import.

    python examples/torch_dataset.py DIR [--batch 8]

Needs numpy and Pillow; OpenEXR (``pip install OpenEXR``, >= 3) for the depth maps: without it
items carry no ``depth`` (and ``EyeDataset.has_depth`` is False). torch is optional: with it,
:class:`EyeDataset` is a ``torch.utils.data.Dataset`` (a ``DataLoader`` batches its items; numpy
arrays become tensors), without it the same class with ``__len__`` / ``__getitem__`` on
``object``. Nothing is read until an item is asked for: the constructor reads ``index.jsonl``
only. Copy this file anywhere.

Item ``k`` (the k-th line of DIR/index.jsonl) is a dict of numpy arrays (schema in DIR/README.md
and docs/labels.md of eyerig):

* ``image``: (H, W, 3) uint8 RGB, row 0 at the top.
* ``landmarks``: (28, 2) float32 pixels, x right, y down, origin at the top-left pixel *corner*
  (pixel centres at +0.5); 0-11 eyelid, 12-19 iris boundary, 20-27 pupil boundary.
* ``visibility``: (28,) bool, the label's ``landmarks.visible`` (seen in the image: not hidden by
  a lid, lashes or skin, not outside); all True when the render had no masks (then unknown).
* ``gaze``: (3,) float32 unit gaze vector of the imaged eye in the camera frame (+X image right,
  +Y image up, +Z toward the viewer: the camera looks down -Z).
* ``gaze_pitch_yaw``: (2,) float32 degrees, ``(pitch, yaw)`` of ``gaze``: pitch up positive, yaw
  toward image right positive (``gaze.camera``). ETH-XGaze / GazeML use the same pitch and the
  opposite yaw (eyerig README, conventions).
* ``head_rotation``: (3, 3) float32, head frame -> camera frame (``head_pose.rotation_head_to_camera``).
* ``head_pitch_yaw``: (2,) float32 degrees, the direction from the head toward the camera in the
  head frame (``head_pose.camera_pitch_deg``, ``camera_yaw_deg``).
* ``mask``: (H, W) uint8 class ids (``NNNNNN_seg.png``: 0 background, 1 skin, 2 sclera, 3 iris,
  4 pupil, 5 eyelashes, 6 caruncle), when the render has masks.
* ``depth``: (H, W) float32 camera mm, inf where nothing is seen (``NNNNNN_depth.exr``), when the
  render has masks and OpenEXR is installed.
* ``index`` (int), ``eye`` (``"left"``/``"right"``, the subject's), ``asset`` (str).

The same folder's ``shards/shard-SSSSSS.tar`` (label format ``webdataset``) stream through
:class:`EyeShards` (``tarfile`` only; an ``IterableDataset`` with torch): each sample a dict of
``image`` (H, W, 3) uint8, ``mask`` (H, W) uint8 class ids, ``label`` (the JSON) and ``key``.

**Masks and webdataset's decoders**: ``seg.png`` is an indexed PNG whose *index* is the class
id. Every image decoder of ``webdataset.WebDataset(...).decode(...)`` converts first:
``decode("l8")`` gives the palette colours' luminance and ``decode("pil")`` / ``"rgb8"`` their
RGB, not the class ids (no error, wrong labels). Put :func:`seg_ids` before them::

    wds.WebDataset(urls).decode(seg_ids, "rgb8")      # seg.png -> class ids, png -> RGB
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tarfile
from pathlib import Path

import numpy as np
from PIL import Image

try:
    from torch.utils.data import Dataset as _Base
    from torch.utils.data import IterableDataset as _IterBase
except ImportError:                         # torch absent: the same class, indexable by hand
    _Base = _IterBase = object

try:
    import OpenEXR
except ImportError:
    OpenEXR = None


def read_depth(path) -> np.ndarray:
    """(H, W) float32 channel ``Z`` of a depth EXR (OpenEXR >= 3)."""
    with OpenEXR.File(str(path)) as f:
        return np.array(f.channels()["Z"].pixels, dtype=np.float32)


class EyeDataset(_Base):
    """The images of ``root`` (a folder with ``index.jsonl``), one dict per item (module doc).

    Parameters
    ----------
    root : path
    transform : callable, optional    applied to each item dict before it is returned
    depth : bool                       read the depth maps (needs OpenEXR)
    """

    def __init__(self, root, transform=None, depth: bool = True):
        self.root = Path(root)
        index = self.root / "index.jsonl"
        if not index.is_file():
            raise FileNotFoundError(f"{index}: missing (not an eyerig dataset or render folder)")
        self.rows = [json.loads(line) for line in index.read_text(encoding="utf-8").splitlines() if line.strip()]
        self.transform = transform
        self.has_depth = bool(depth) and OpenEXR is not None

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, k: int) -> dict:
        if not -len(self.rows) <= k < len(self.rows):
            raise IndexError(f"item {k} of {len(self.rows)}")
        row = self.rows[k]
        label = json.loads((self.root / row["json"]).read_text(encoding="utf-8"))
        with Image.open(self.root / row["png"]) as im:
            image = np.asarray(im.convert("RGB"))
        lm, gaze, head = label["landmarks"], label["gaze"], label["head_pose"]
        item = {
            "index": int(label["index"]),
            "eye": gaze["eye"],
            "asset": (label.get("asset") or {}).get("name", label.get("scan", "")),
            "image": image,
            "landmarks": np.asarray(lm["px"], np.float32),
            "visibility": np.asarray(lm.get("visible", [True] * len(lm["px"])), bool),
            "gaze": np.asarray(gaze["vector_camera"], np.float32),
            "gaze_pitch_yaw": np.asarray([gaze["camera"]["pitch_deg"], gaze["camera"]["yaw_deg"]], np.float32),
            "head_rotation": np.asarray(head["rotation_head_to_camera"], np.float32),
            "head_pitch_yaw": np.asarray([head["camera_pitch_deg"], head["camera_yaw_deg"]], np.float32),
        }
        if label.get("seg"):
            with Image.open(self.root / label["seg"]["file"]) as im:
                item["mask"] = np.asarray(im)          # indexed PNG: the index is the class id
        if self.has_depth and label.get("depth"):
            item["depth"] = read_depth(self.root / label["depth"]["file"])
        return self.transform(item) if self.transform is not None else item


def seg_ids(key: str, data: bytes):
    """A webdataset decoder for ``seg.png``: the (H, W) uint8 class ids (the PNG's palette
    indices, read without converting); None for any other key, so the next decoder takes it."""
    if not key.lower().endswith("seg.png"):
        return None
    with Image.open(io.BytesIO(data)) as im:
        if im.mode != "P":
            raise ValueError(f"{key}: a seg mask is an indexed PNG (mode P), got mode {im.mode}")
        return np.asarray(im)


def decode_member(suffix: str, data: bytes):
    """One shard member by its suffix: ``seg.png`` class ids, ``png`` RGB, ``json`` a dict, else bytes."""
    ids = seg_ids(suffix, data)
    if ids is not None:
        return ids
    if suffix == "png":
        with Image.open(io.BytesIO(data)) as im:
            return np.asarray(im.convert("RGB"))
    if suffix == "json":
        return json.loads(data.decode("utf-8"))
    return data


class EyeShards(_IterBase):
    """The samples of ``root/shards/shard-*.tar`` in order, one dict each (module doc); members
    of one key are adjacent in our shards, as webdataset expects."""

    FIELDS = {"png": "image", "seg.png": "mask", "json": "label", "depth.exr": "depth_exr"}

    def __init__(self, root, transform=None):
        self.shards = sorted((Path(root) / "shards").glob("shard-*.tar"))
        if not self.shards:
            raise FileNotFoundError(f"{root}/shards: no shard-*.tar (label format webdataset)")
        self.transform = transform

    def __iter__(self):
        for shard in self.shards:
            with tarfile.open(shard) as tar:
                sample, key = {}, None
                for m in tar:
                    k, _, suffix = m.name.partition(".")
                    if key is not None and k != key:
                        yield self._done(key, sample)
                        sample = {}
                    key = k
                    sample[self.FIELDS.get(suffix, suffix)] = decode_member(suffix, tar.extractfile(m).read())
                if key is not None:
                    yield self._done(key, sample)

    def _done(self, key, sample):
        sample["key"] = key
        return self.transform(sample) if self.transform is not None else sample


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="the dataset folder")
    ap.add_argument("--batch", type=int, default=8, help="batch size of the DataLoader (with torch)")
    args = ap.parse_args(argv)
    ds = EyeDataset(args.root)
    print(f"{len(ds)} items, depth {'read' if ds.has_depth else 'not read (OpenEXR missing)'}; torch "
          f"{'present' if _Base is not object else 'absent'}")
    if _Base is not object and len(ds):
        from torch.utils.data import DataLoader

        batch = next(iter(DataLoader(ds, batch_size=args.batch)))
    elif len(ds):
        batch = {k: np.stack([ds[i][k] for i in range(min(args.batch, len(ds)))])
                 for k, v in ds[0].items() if isinstance(v, np.ndarray)}
    else:
        return 0
    for key, v in batch.items():
        if hasattr(v, "shape"):
            print(f"{key:15s} {tuple(v.shape)} {v.dtype}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
