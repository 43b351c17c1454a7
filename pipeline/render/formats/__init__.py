"""The label writers: one module per format, the only place a format is named.

A format module in this folder defines

* ``NAME``: the word ``render.label_formats`` lists;
* ``FILES``: ``{file name with NNNNNN for the index: what it holds}``, every file it writes per
  image (relative to the render or dataset folder);
* ``job(asset, smp)``: what its writer needs beyond the label, computed when the sample is drawn
  (``None``: nothing); ``job(asset, smp, settings)`` with ``READS_SETTINGS = True``;
* optionally ``accepts(asset, smp)``: False for a drawn sample the format cannot write right
  (the sampler draws again, as for the pupil and background rules: :func:`accepts`);
* ``write(out_dir, index, label, job, png)``: writes image ``index``'s files and returns their
  paths.

and may define (a format of one file per dataset, or one per group of images)

* ``DATASET_FILES``: ``{file name with SSSSSS for a 6-digit number: what it holds}``, the files it
  writes per render or dataset folder (``FILES`` may then be empty);
* ``finish(out_dir, n, settings)``: writes them from the finished images ``0..n-1`` (and whatever
  ``write`` left per image) at the end of every run, and returns their paths. A run removes them
  first (:func:`dataset_files`, pipeline/render/run.py ``doomed_files``), so a killed run leaves
  none stale, and they are rebuilt from files on disk, so they do not depend on the order the
  images finished in;
* ``NEEDS_MASKS = True``: it reads the segmentation masks and visibility (``render.masks``).

Everything else derives from :data:`FORMATS`: the formats ``render.label_formats`` accepts
(pipeline/render/settings.py), the file table of the dataset card (:func:`describe`), the files a
resumed or re-planned render may remove (:func:`image_files`, :func:`dataset_files`), what a finished
image writes (:func:`write_formats`) and what a finished run writes (:func:`finish_formats`).
Adding a format is adding its module here. ``eyerig`` is required and written last: its label
marks an image done.

The modules are found by listing this folder (:func:`_discover`), and pipeline/sources.py counts
every module of it in the code of whatever imports the package (dvc deps, render fingerprint).
"""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path

#: The format every render writes, last.
REQUIRED = "eyerig"
#: Per-image files that belong to no format: the image, and the masks (``render.masks``,
#: written by the Blender worker; pipeline/io/seg_file.py).
IMAGE_FILES = {
    "NNNNNN.png": "image NNNNNN (global index, 6 digits), 8-bit RGB",
    "NNNNNN_seg.png": "segmentation mask: 8-bit indexed PNG, one class id per pixel (classes below)",
    "NNNNNN_depth.exr": "z-depth in camera mm, float32 EXR channel Z (inf where nothing is seen)",
}
INDEX = "NNNNNN"
#: The number in a dataset-level file name (a shard's, pipeline/render/formats/webdataset.py).
NUMBER = "SSSSSS"


def _discover() -> dict:
    """``{NAME: module}`` of every module in this folder: ``eyerig`` first, then by name."""
    mods = {}
    for info in pkgutil.iter_modules(__path__):
        if not info.name.startswith("_"):
            m = importlib.import_module(f"{__name__}.{info.name}")
            mods[m.NAME] = m
    return {k: mods[k] for k in sorted(mods, key=lambda k: (k != REQUIRED, k))}


FORMATS = _discover()
NAMES = tuple(FORMATS)


def file_table() -> dict:
    """Every per-image file a render may write (any format) -> what it holds."""
    out = dict(IMAGE_FILES)
    for m in FORMATS.values():
        out.update(m.FILES)
    return out


def dataset_file_table() -> dict:
    """Every dataset-level file a render may write (any format) -> what it holds."""
    out = {}
    for m in FORMATS.values():
        out.update(getattr(m, "DATASET_FILES", {}))
    return out


def _matches(name: str, pattern: str) -> bool:
    """Is ``name`` the file name ``pattern`` with six digits for ``SSSSSS``?"""
    if NUMBER not in pattern:
        return name == pattern
    pre, _, post = pattern.partition(NUMBER)
    return (len(name) == len(pre) + 6 + len(post) and name.startswith(pre) and name.endswith(post)
            and name[len(pre):len(pre) + 6].isdigit())


def dataset_files(out: Path):
    """``(pattern, path)`` of every dataset-level file of any format in the folder ``out``
    (names of :func:`dataset_file_table` with six digits for ``SSSSSS``), nothing else."""
    out = Path(out)
    for pattern in sorted(dataset_file_table()):
        folder, _, base = pattern.rpartition("/")
        d = out / folder if folder else out
        if d.is_dir():
            for p in sorted(d.iterdir()):
                if p.is_file() and _matches(p.name, base):
                    yield pattern, p


def dataset_table(out: Path) -> dict:
    """``{pattern: what it holds}`` of the dataset-level files present in ``out`` (the card)."""
    table = dataset_file_table()
    return {k: table[k] for k in sorted({k for k, _ in dataset_files(out)})}


def needs_masks(formats) -> list[str]:
    """The formats of ``formats`` that read the masks (``NEEDS_MASKS``)."""
    return [f for f in formats if getattr(FORMATS[f], "NEEDS_MASKS", False)]


def finish_formats(out_dir, n: int, settings) -> list:
    """Write the dataset-level files of every format ``settings.label_formats`` lists that has a
    ``finish``, from the finished images ``0..n-1`` of ``out_dir``. Returns the paths."""
    written = []
    for f in settings.label_formats:
        finish = getattr(FORMATS[f], "finish", None)
        if finish is not None:
            written += finish(Path(out_dir), int(n), settings)
    return written


def describe(name: str) -> str:
    """What the file ``name`` (``NNNNNN`` for the index, ``SSSSSS`` for a number) holds."""
    return {**dataset_file_table(), **file_table()}.get(
        name, "a per-image file of another label format (render.label_formats)")


def image_files(out: Path):
    """``(index, path)`` of every file of a numbered image in the render folder ``out``, of any
    format (a folder may hold files of an earlier run with other formats): the names of
    :func:`file_table` with six digits for ``NNNNNN``, nothing else."""
    out = Path(out)
    by_folder: dict = {}
    for name in file_table():
        folder, _, base = name.rpartition("/")
        pre, _, post = base.partition(INDEX)
        by_folder.setdefault(folder, set()).add((pre, post))
    for folder, forms in sorted(by_folder.items()):
        d = out / folder if folder else out
        if not d.is_dir():
            continue
        for p in d.iterdir():
            for pre, post in forms:
                if p.name.startswith(pre) and p.name.endswith(post):
                    stem = p.name[len(pre):len(p.name) - len(post)]
                    if len(stem) == 6 and stem.isdigit():
                        yield int(stem), p
                        break


def format_job(asset, smp, formats, settings=None) -> dict | None:
    """What :func:`write_formats` needs beyond the label for ``formats`` (None when only the
    required label is written); a format with ``READS_SETTINGS`` gets the render settings too."""
    extra = [f for f in formats if f != REQUIRED]
    if not extra:
        return None
    job = {"formats": extra}
    for f in extra:
        m = FORMATS[f]
        j = m.job(asset, smp, settings) if getattr(m, "READS_SETTINGS", False) else m.job(asset, smp)
        if j is not None:
            job[f] = j
    return job


def accepts(asset, smp, formats) -> bool:
    """Whether every format of ``formats`` can write the drawn sample ``smp`` right (a format
    without ``accepts`` takes any)."""
    return all(getattr(FORMATS[f], "accepts", None) is None or FORMATS[f].accepts(asset, smp) for f in formats)


def write_formats(out_dir, index: int, label: dict, job: dict | None, png) -> list:
    """Write every format of image ``index``: the others in the order the settings list them,
    then the required label (it marks the image done). Returns the paths."""
    written = []
    for f in (job or {}).get("formats", ()):
        written += FORMATS[f].write(out_dir, index, label, (job or {}).get(f), png)
    return written + FORMATS[REQUIRED].write(out_dir, index, label, None, png)
