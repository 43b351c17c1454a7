"""The pipeline's own mesh container: one ``.npz`` of named arrays.

Stages hand meshes to each other as ``mesh.npz`` files. Arrays and their names
are the same everywhere (one name across code, tests and docs):

``V``   (n, 3) float64   vertex positions, mm, head frame
``F``   (m, 3) int64     triangles, counter-clockwise seen from outside
``UV``  (k, 2) float64   texture coordinates, origin bottom-left (OBJ/USD convention)
``FUV`` (m, 3) int64     per-corner indices into ``UV`` (UV seams allowed)
``VC``  (n, 3) uint8     per-vertex sRGB colour, when the scan has no texture

Polygon meshes (quad-dominant retopology) add ``poly_counts`` (p,) int64 and
``poly_indices`` (sum(poly_counts),) int64 in USD's faceVertexCounts/Indices
layout; ``F`` is then their fan triangulation. Any other array is kept as is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.io.atomic import atomic_file

_DTYPES = {
    "V": np.float64,
    "F": np.int64,
    "UV": np.float64,
    "FUV": np.int64,
    "VC": np.uint8,
    "poly_counts": np.int64,
    "poly_indices": np.int64,
}


def save_mesh(path, **arrays) -> None:
    """Atomically write named arrays to ``path`` (an uncompressed ``.npz``).

    Parameters
    ----------
    path : str or os.PathLike
    **arrays : numpy.ndarray
        At least ``V`` and ``F``; standard names are cast to their dtype.
    """
    if "V" not in arrays or "F" not in arrays:
        raise ValueError("save_mesh needs at least V and F")
    out = {k: np.ascontiguousarray(v, dtype=_DTYPES.get(k)) for k, v in arrays.items()}
    with atomic_file(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **out)


def load_mesh(path) -> dict[str, np.ndarray]:
    """Read a mesh written by :func:`save_mesh` into a dict of arrays."""
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def read_stage_mesh(path, required=("V", "F")) -> dict[str, np.ndarray]:
    """:func:`load_mesh` for a stage's input: missing, unreadable or incomplete is a ScanError.

    Parameters
    ----------
    path : str or os.PathLike
    required : tuple of str
        Array names that must be present.
    """
    from pipeline.errors import ScanError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        mesh = load_mesh(path)
    except Exception as exc:  # corrupt zip / npy: whatever numpy raises
        raise ScanError(path, f"cannot be read as a mesh .npz ({type(exc).__name__})") from None
    missing = [k for k in required if k not in mesh]
    if missing:
        raise ScanError(path, f"needs arrays {' and '.join(required)} (missing {', '.join(missing)})")
    return mesh
