"""The eye-region prior: the UnityEyes shape model registered to the skin around an eye.

Wood et al. built a PCA model of the eye region (229 vertices, lids, canthi, caruncle and the
skin out to brow and cheek) from the SynthesEyes head scans, every scan in the frame of its own
eyeball (``../shared/reference/unityeyes_eye_region``, MIT; its README gives the frame: origin
at the eyeball centre, metres, -y forward, +z up, x medial to lateral, one (left) eye). Fitted
to a scan's skin, it says where the front of that person's globe lies and along which axis:
the lids wrap the front of the eye, so the model's globe front (its centre plus its 12.05 mm
sclera along its forward axis) is what transfers between heads, not its centre (an eye 3 mm
larger sits 3 mm deeper behind the same lids).

The data are not part of eyerig: :meth:`EyeRegionPrior.load` reads them from a folder and
returns None when they are absent, and placement then goes without this cue.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError

FILES = ("mesh_mean.txt", "pca_components.txt", "transformed_mean.txt", "transformed_std.txt")
N_VERTICES = 229
SCLERA_RADIUS_MM = 12.05      # the UnityEyes eyeball the model was registered to
MARGIN = (12, 13, 14, 15, 16, 17, 18, 132, 131, 130, 6, 2, 1, 7, 8, 0)
CARUNCLE = (28, 27, 25, 32, 31, 30, 33)


def to_head(P, side):
    """Model coordinates (mm; -y forward, +z up, +x lateral for a left eye) to the head frame
    (+Y up, +Z forward, +X toward the subject's left); the right eye is the mirror image."""
    P = np.asarray(P, dtype=np.float64)
    X = P[..., 0] if side == "left" else -P[..., 0]
    return np.stack([X, P[..., 2], -P[..., 1]], axis=-1)


@dataclass
class EyeRegionPrior:
    """The shape model: mean (229, 3) mm, components (687, k), coefficient mean and sd (k,)."""

    mean: np.ndarray
    components: np.ndarray
    coef_mean: np.ndarray
    coef_sd: np.ndarray
    modes: int = 10

    @classmethod
    def load(cls, folder, modes: int = 10):
        """The model from ``folder``, or None when the folder or its files are absent; a file
        of the wrong shape is a ScanError naming it."""
        if folder is None:
            return None
        folder = Path(folder)
        if not all((folder / f).is_file() for f in FILES):
            return None
        arrays = {}
        for f in FILES:
            try:
                arrays[f] = np.loadtxt(folder / f, dtype=np.float64, ndmin=1)
            except ValueError as exc:
                raise ScanError(folder / f, f"is not a table of numbers ({exc})") from None
        mean, comp = arrays["mesh_mean.txt"], arrays["pca_components.txt"]
        mu, sd = arrays["transformed_mean.txt"], arrays["transformed_std.txt"]
        if mean.shape != (N_VERTICES, 3) or comp.ndim != 2 or comp.shape[0] != 3 * N_VERTICES \
                or mu.shape != (comp.shape[1],) or sd.shape != mu.shape:
            raise ScanError(folder, f"is not the 229-vertex UnityEyes eye-region model "
                                    f"(shapes {mean.shape}, {comp.shape}, {mu.shape}, {sd.shape})")
        if not all(np.isfinite(a).all() for a in arrays.values()):
            raise ScanError(folder, "holds non-finite numbers")
        k = int(min(modes, comp.shape[1]))
        return cls(mean * 1000.0, comp[:, :k] * 1000.0, mu[:k], sd[:k], k)

    def shape(self, z):
        """Model vertices (229, 3) mm for standardised coefficients ``z`` (k,)."""
        coef = self.coef_mean + np.asarray(z, float) * self.coef_sd
        return self.mean + (self.components @ coef).reshape(-1, 3)

    def skin_vertices(self):
        """Indices fitted to a scan: the skin around the opening (not the interior margin or the
        caruncle, which a scan hides or rounds, and not the far brow and cheek)."""
        r = np.linalg.norm(self.mean, axis=1)
        skip = set(MARGIN) | set(CARUNCLE)
        return np.array([i for i in range(N_VERTICES) if i not in skip and 13.5 < r[i] < 35.0])

    def register(self, V, F, hint, side, iterations=6):
        """Fit a similarity transform and the coefficients to the surface ``V, F`` around
        ``hint`` (point-to-plane, robust); returns ``{"front": (3,), "axis": (3,), "scale",
        "rms_mm", "margin": (16, 3)}`` in the head frame."""
        from scipy.optimize import least_squares
        from scipy.spatial import cKDTree
        from scipy.spatial.transform import Rotation

        from pipeline.geometry.meshtopo import vertex_normals

        V = np.asarray(V, dtype=np.float64)
        hint = np.asarray(hint, dtype=np.float64)
        near = np.flatnonzero(np.linalg.norm(V - hint, axis=1) < 45.0)
        if len(near) < 50:
            raise ValueError("too little surface around the hint")
        N = vertex_normals(V, F)[near]
        tree = cKDTree(V[near])
        use = self.skin_vertices()
        k = self.modes

        def xf(x, idx):
            S = to_head(self.shape(x[7:])[idx], side)
            return np.exp(x[6]) * Rotation.from_rotvec(x[3:6]).apply(S) + x[:3]

        x = np.r_[hint - np.array([0.0, 0.0, SCLERA_RADIUS_MM]), np.zeros(3), 0.0, np.zeros(k)]
        dist = np.zeros(1)
        for _ in range(iterations):
            dist, j = tree.query(xf(x, use))
            Q, Nq = V[near][j], N[j]

            def f(x):
                r = ((xf(x, use) - Q) * Nq).sum(axis=1)
                # coefficients stay near the population; rotation and scale modest
                return np.r_[r, x[7:], 5.0 * x[3:6], 2.0 * x[6]]
            x = least_squares(f, x, loss="soft_l1", f_scale=0.5).x
        s = float(np.exp(x[6]))
        axis = Rotation.from_rotvec(x[3:6]).apply(np.array([0.0, 0.0, 1.0]))
        front = x[:3] + SCLERA_RADIUS_MM * s * axis
        return {"front": front, "axis": axis / np.linalg.norm(axis), "scale": s,
                "rms_mm": float(np.sqrt(np.mean(dist ** 2))), "margin": xf(x, list(MARGIN))}
