"""Label format ``eyerig``: our own label, ``NNNNNN.json`` (pipeline/render/labels.py builds it,
pipeline/io/labels_file.py writes and reads it; fields in docs/labels.md).

Always written, and written last: an image is done when its label exists, so every other format
of the image is on disk before it.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.io.labels_file import label_name, write_label

NAME = "eyerig"
FILES = {"NNNNNN.json": "its label (see the label schema below); written last, it marks the image done"}


def job(asset, smp) -> None:
    """Nothing beyond the label."""
    return None


def write(out_dir, index: int, label: dict, job, png) -> list[Path]:
    """Write ``NNNNNN.json`` of image ``index`` into ``out_dir``; its path."""
    p = Path(out_dir) / label_name(index)
    write_label(p, label)
    return [p]
