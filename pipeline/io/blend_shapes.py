"""Blend shapes in UsdSkel layout, and their array layout in ``rig.npz``: the container every
reader of the rig product shares (rig stage, usd, render, the Blender workers).

:class:`BlendShape` holds one channel with its inbetweens; :func:`shapes_to_arrays` /
:func:`shapes_from_arrays` are the pure conversions to and from the named arrays of
``rig.npz`` (pipeline/io/rig_file.py reads and writes the file). How the shapes are evaluated
and built is the rig's (pipeline/rig/lids.py, lid_shapes.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class BlendShape:
    """One blend-shape channel in UsdSkel layout.

    Attributes
    ----------
    name : str
    point_indices : (k,) int64
        Mesh vertices the shape moves.
    offsets : (k, 3) float64
        Offsets at weight 1, mm.
    inbetween_weights : (j,) float64
        Weights in (0, 1) of the inbetween shapes, increasing.
    inbetween_offsets : (j, k, 3) float64
        Offsets of each inbetween (same ``point_indices``).
    """

    name: str
    point_indices: np.ndarray
    offsets: np.ndarray
    inbetween_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inbetween_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))

    def knots(self):
        """(weights (j+2,), offsets (j+2, k, 3)) including the implicit 0 and the full shape."""
        k = len(self.point_indices)
        w = np.concatenate([[0.0], np.asarray(self.inbetween_weights, float), [1.0]])
        o = np.concatenate([np.zeros((1, k, 3)),
                            np.asarray(self.inbetween_offsets, float).reshape(-1, k, 3),
                            np.asarray(self.offsets, float)[None]])
        return w, o

    def inbetween_names(self) -> list[str]:
        """Names for the inbetweens: ``<name>_ib<j>`` (j = 1 .. number of inbetweens)."""
        return [f"{self.name}_ib{j + 1}" for j in range(len(self.inbetween_weights))]


def shapes_to_arrays(shapes, prefix: str = "") -> dict[str, np.ndarray]:
    """Flatten blend shapes into named arrays (the rig.npz layout).

    Keys per shape ``<prefix><name>.point_indices`` (k,) int64, ``.offsets`` (k, 3),
    ``.inbetween_weights`` (j,), ``.inbetween_offsets`` (j, k, 3); plus
    ``<prefix>shape_names`` (s,) str.
    """
    out = {f"{prefix}shape_names": np.array([s.name for s in shapes], dtype=str)}
    for s in shapes:
        k = len(s.point_indices)
        out[f"{prefix}{s.name}.point_indices"] = np.asarray(s.point_indices, np.int64)
        out[f"{prefix}{s.name}.offsets"] = np.asarray(s.offsets, np.float64).reshape(k, 3)
        out[f"{prefix}{s.name}.inbetween_weights"] = np.asarray(s.inbetween_weights, np.float64)
        out[f"{prefix}{s.name}.inbetween_offsets"] = np.asarray(
            s.inbetween_offsets, np.float64).reshape(-1, k, 3)
    return out


def shapes_from_arrays(arrays, prefix: str = "") -> list[BlendShape]:
    """Inverse of :func:`shapes_to_arrays` (accepts a dict or an open ``np.load`` file)."""
    names = [str(n) for n in arrays[f"{prefix}shape_names"]]
    return [BlendShape(name=n,
                       point_indices=np.asarray(arrays[f"{prefix}{n}.point_indices"], np.int64),
                       offsets=np.asarray(arrays[f"{prefix}{n}.offsets"], np.float64),
                       inbetween_weights=np.asarray(arrays[f"{prefix}{n}.inbetween_weights"],
                                                    np.float64),
                       inbetween_offsets=np.asarray(arrays[f"{prefix}{n}.inbetween_offsets"],
                                                    np.float64))
            for n in names]
