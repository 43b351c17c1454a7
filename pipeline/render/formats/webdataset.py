"""Label format ``webdataset``: the images and their files in tar shards that ``webdataset`` streams.

``shards/shard-SSSSSS.tar`` (SSSSSS = shard number from 0): shard ``s`` holds images
``s * k .. s * k + k - 1`` with ``k = render.tar_images`` (the last shard fewer). Each image ``NNNNNN``
is the webdataset sample of key ``NNNNNN`` (webdataset's key is a member's name before its
first dot, its fields what follows), members sorted by name, so a sample's files are adjacent:

* ``NNNNNN.depth.exr``: ``NNNNNN_depth.exr`` (when the render has masks)
* ``NNNNNN.json``: the eyerig label ``NNNNNN.json``
* ``NNNNNN.png``: the image
* ``NNNNNN.seg.png``: ``NNNNNN_seg.png`` (when the render has masks)

Each member's bytes are the loose file's. The tars are plain (uncompressed) POSIX ustar, written
at the end of every run from the files on disk (:func:`finish`) with fixed member headers
(mtime 0, uid/gid 0, no owner names, mode 0644): the same images give the same tar bytes
whatever the order they finished in. No webdataset import is needed to write or read them:
``tarfile`` reads them, ``webdataset.WebDataset("shards/shard-{000000..000001}.tar")`` streams
them.
"""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_file

NAME = "webdataset"
SHARD_DIR = "shards"
FILES: dict = {}
DATASET_FILES = {f"{SHARD_DIR}/shard-SSSSSS.tar": "webdataset tar shard SSSSSS: render.tar_images images, "
                                                 "each as NNNNNN.png, .json, .seg.png, .depth.exr "
                                                 "(the loose files' bytes; eyerig docs/labels.md)"}
#: tar member suffix -> the loose file name of image NNNNNN, in member (sorted) order.
MEMBERS = {".depth.exr": "{:06d}_depth.exr", ".json": "{:06d}.json", ".png": "{:06d}.png",
           ".seg.png": "{:06d}_seg.png"}
#: The loose files every image has (the others come with render.masks).
REQUIRED_MEMBERS = (".json", ".png")


def shard_name(s: int) -> str:
    """``shards/shard-SSSSSS.tar`` of shard ``s``."""
    return f"{SHARD_DIR}/shard-{int(s):06d}.tar"


def shard_ranges(n: int, k: int) -> list[range]:
    """The image indices of each shard of ``n`` images, ``k`` per shard."""
    return [range(s, min(n, s + k)) for s in range(0, n, k)]


def members(out: Path, index: int) -> list[tuple[str, Path]]:
    """``(member name, loose file)`` of image ``index`` in tar order; ScanError if a required file is missing."""
    got = []
    for suffix, loose in MEMBERS.items():
        p = Path(out) / loose.format(index)
        if p.is_file():
            got.append((f"{index:06d}{suffix}", p))
        elif suffix in REQUIRED_MEMBERS:
            raise ScanError(p, "missing: the image is not finished")
    return got


def write_tar(path: Path, files) -> None:
    """Write ``files`` (``(member name, path)``, in order) as a ustar archive with fixed headers, atomically."""
    with atomic_file(path) as tmp, tarfile.open(tmp, "w", format=tarfile.USTAR_FORMAT) as tar:
        for name, p in files:
            data = Path(p).read_bytes()
            info = tarfile.TarInfo(name)
            info.size, info.mtime, info.mode = len(data), 0, 0o644
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            tar.addfile(info, io.BytesIO(data))


def job(asset, smp) -> None:
    """Nothing: the shards are written at the end of the run."""
    return None


def write(out_dir, index: int, label: dict, job, png) -> list[Path]:
    """Nothing per image: :func:`finish` packs the finished images' files."""
    return []


def finish(out_dir, n: int, settings) -> list[Path]:
    """Write every shard of images ``0..n-1``; their paths."""
    out = Path(out_dir)
    paths = []
    for s, idx in enumerate(shard_ranges(n, settings.tar_images)):
        p = out / shard_name(s)
        p.parent.mkdir(parents=True, exist_ok=True)
        write_tar(p, [m for i in idx for m in members(out, i)])
        paths.append(p)
    return paths
