"""The eye-region prior's data file (``pipeline/placement/data/eye_region_prior.npz``): one
writer, one reader.

Derived once from the UnityEyes shape model (MIT; ``pipeline/placement/data/README.md``
names the source files and ``benchmarks/derive_eye_prior.py`` derives it) and shipped with the
package. An uncompressed ``.npz`` of float64 / int64 arrays (``np.savez`` writes its zip entries
with a fixed date, so the same arrays give the same bytes)::

    schema          ()        int64   SCHEMA
    mean_mm         (229, 3)  float64 the mean eye region, mm, model frame (origin at the eyeball
                                      centre, -y forward, +z up, +x lateral; one left eye)
    components_mm   (687, k)  float64 the first k principal components, mm; row 3*i + c =
                                      coordinate c of vertex i
    coef_mean       (k,)      float64 mean of each component's coefficient over the scans
    coef_sd         (k,)      float64 its standard deviation
    faces           (414, 3)  int64   the region's triangles over the 229 vertices (tests, pictures)

:func:`read_eye_prior` refuses a missing, unreadable, incomplete or non-finite file with a
:class:`~pipeline.errors.ScanError` whose one line names the file.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_file

SCHEMA = 1
N_VERTICES = 229
KEYS = ("schema", "mean_mm", "components_mm", "coef_mean", "coef_sd", "faces")


@dataclass
class EyePriorArrays:
    """The arrays of an eye-region prior file (shapes in the module docstring)."""

    mean_mm: np.ndarray
    components_mm: np.ndarray
    coef_mean: np.ndarray
    coef_sd: np.ndarray
    faces: np.ndarray


def write_eye_prior(path, prior: EyePriorArrays) -> None:
    """Atomically write ``prior`` to ``path`` (checked as :func:`read_eye_prior` checks it)."""
    arrays = {"schema": np.asarray(SCHEMA, dtype=np.int64),
              "mean_mm": np.ascontiguousarray(prior.mean_mm, dtype=np.float64),
              "components_mm": np.ascontiguousarray(prior.components_mm, dtype=np.float64),
              "coef_mean": np.ascontiguousarray(prior.coef_mean, dtype=np.float64),
              "coef_sd": np.ascontiguousarray(prior.coef_sd, dtype=np.float64),
              "faces": np.ascontiguousarray(prior.faces, dtype=np.int64)}
    problem = _problem(arrays)
    if problem:
        raise ValueError(f"eye-region prior {problem}")
    with atomic_file(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def read_eye_prior(path) -> EyePriorArrays:
    """The prior in ``path``.

    Raises
    ------
    ScanError  the file is missing, not an ``.npz`` of these arrays, of another schema, or holds
               non-finite numbers (one line naming ``path``).
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "the eye-region prior file is missing (it ships with eyerig: "
                              "restore it from git, or re-derive it with benchmarks/derive_eye_prior.py)")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ScanError(path, f"is not a readable eye-region prior file ({type(exc).__name__}: "
                              f"{str(exc).splitlines()[0] if str(exc) else 'unreadable'})") from None
    problem = _problem(arrays)
    if problem:
        raise ScanError(path, f"is not an eye-region prior file: {problem}")
    return EyePriorArrays(arrays["mean_mm"], arrays["components_mm"], arrays["coef_mean"],
                          arrays["coef_sd"], arrays["faces"])


def _problem(a: dict) -> str | None:
    """What is wrong with the arrays ``a`` (None: nothing)."""
    missing = [k for k in KEYS if k not in a]
    if missing:
        return f"lacks {', '.join(missing)}"
    if a["schema"].shape != () or a["schema"].dtype.kind != "i" or int(a["schema"]) != SCHEMA:
        return f"schema is {a['schema'].tolist()}, not {SCHEMA}"
    floats = ("mean_mm", "components_mm", "coef_mean", "coef_sd")
    if any(a[k].dtype != np.float64 for k in floats) or a["faces"].dtype.kind not in "iu":
        return "holds arrays of the wrong type"
    mean, comp, mu, sd, F = (a[k] for k in floats + ("faces",))
    k = comp.shape[1] if comp.ndim == 2 else -1
    if mean.shape != (N_VERTICES, 3) or comp.shape != (3 * N_VERTICES, k) or k < 1 \
            or mu.shape != (k,) or sd.shape != (k,) or F.ndim != 2 or F.shape[1:] != (3,):
        return (f"shapes {mean.shape}, {comp.shape}, {mu.shape}, {sd.shape}, {F.shape} are not "
                f"the 229-vertex eye-region model's")
    if not all(np.isfinite(x).all() for x in (mean, comp, mu, sd)):
        return "holds non-finite numbers"
    if len(F) and (F.min() < 0 or F.max() >= N_VERTICES):
        return "has faces outside its 229 vertices"
    return None
