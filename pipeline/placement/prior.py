"""The eye-region prior: the UnityEyes shape model registered to the skin around an eye.

Wood et al. built a PCA model of the eye region (229 vertices, lids, canthi, caruncle and the
skin out to brow and cheek) from the SynthesEyes head scans, every scan in the frame of its own
eyeball (UnityEyes, MIT; the frame: origin at the eyeball centre, -y forward, +z up, x medial
to lateral, one (left) eye). Fitted to a scan's skin, it says where the front of that person's
globe lies and along which axis: the lids wrap the front of the eye, so the model's globe front
(its centre plus its 12.05 mm sclera along its forward axis) is what transfers between heads, not
its centre (an eye 3 mm larger sits 3 mm deeper behind the same lids).

The model ships with eyerig: :data:`PRIOR_FILE` (``data/eye_region_prior.npz`` beside this
module, read by pipeline/io/eye_prior_file.py) holds what the placement uses, derived from the
UnityEyes text files by benchmarks/derive_eye_prior.py (``data/README.md``; the MIT licence is
``data/LICENSE-unityeyes.txt``). :meth:`EyeRegionPrior.load` reads it; a missing or corrupt file is
a ScanError naming it, never a placement without the cue.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.io.eye_prior_file import N_VERTICES, read_eye_prior

#: The eye-region prior eyerig ships (pipeline/placement/data/README.md).
PRIOR_FILE = Path(__file__).resolve().parent / "data" / "eye_region_prior.npz"
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
    """The shape model: mean (229, 3) mm, components (687, k), coefficient mean and sd (k,);
    ``faces`` (414, 3) the region's triangles (tests and pictures; the fit uses none)."""

    mean: np.ndarray
    components: np.ndarray
    coef_mean: np.ndarray
    coef_sd: np.ndarray
    modes: int = 10
    faces: np.ndarray | None = None

    @classmethod
    def load(cls, path=PRIOR_FILE, modes: int = 10):
        """The model in ``path`` (default :data:`PRIOR_FILE`), its first ``modes`` components.

        Raises
        ------
        ScanError  the file is missing or is not an eye-region prior file (one line naming it).
        """
        a = read_eye_prior(path)
        k = int(min(modes, a.components_mm.shape[1]))
        return cls(a.mean_mm, np.ascontiguousarray(a.components_mm[:, :k]), a.coef_mean[:k].copy(),
                   a.coef_sd[:k].copy(), k, a.faces)

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
        "rms_mm", "margin": (16, 3)}`` in the head frame.

        A fit from the hint that ends on a scale no eye region has (outside :data:`SCALE_RANGE`)
        has shrunk into a local optimum: it is fitted again from the hint moved
        :data:`RESTART_MM` along each head axis across the face, and the fit with the lowest cost
        plus the scale's prior (:data:`SCALE_SD`) is kept."""
        from scipy.spatial import cKDTree
        from scipy.spatial.transform import Rotation

        from pipeline.geometry.meshtopo import vertex_normals

        V = np.asarray(V, dtype=np.float64)
        hint = np.asarray(hint, dtype=np.float64)
        near = np.flatnonzero(np.linalg.norm(V - hint, axis=1) < 45.0)
        if len(near) < 50:
            raise ValueError("too little surface around the hint")
        surface = (V[near], vertex_normals(V, F)[near], cKDTree(V[near]))
        best = self._fit(surface, hint, side, iterations)
        if not SCALE_RANGE[0] <= float(np.exp(best[0][6])) <= SCALE_RANGE[1]:
            for d in ((RESTART_MM, 0.0), (-RESTART_MM, 0.0), (0.0, RESTART_MM), (0.0, -RESTART_MM)):
                got = self._fit(surface, hint + np.array([d[0], d[1], 0.0]), side, iterations)
                if _with_scale_prior(got) < _with_scale_prior(best):
                    best = got
        x, _, dist = best
        s = float(np.exp(x[6]))
        axis = Rotation.from_rotvec(x[3:6]).apply(np.array([0.0, 0.0, 1.0]))
        front = x[:3] + SCLERA_RADIUS_MM * s * axis
        return {"front": front, "axis": axis / np.linalg.norm(axis), "scale": s,
                "rms_mm": float(np.sqrt(np.mean(dist ** 2))), "margin": self._placed(x, list(MARGIN), side)}

    def _placed(self, x, idx, side):
        """Model vertices ``idx`` under the fit's parameters ``x`` (translation, rotation vector,
        log scale, coefficients), in the head frame."""
        from scipy.spatial.transform import Rotation

        S = to_head(self.shape(x[7:])[idx], side)
        return np.exp(x[6]) * Rotation.from_rotvec(x[3:6]).apply(S) + x[:3]

    def _fit(self, surface, start, side, iterations):
        """One registration from the model's globe front at ``start``: ``(x, cost, dist)``, the
        parameters, the robust cost of the last round and the fitted vertices' distances."""
        from scipy.optimize import least_squares

        P, N, tree = surface
        use = self.skin_vertices()
        x = np.r_[start - np.array([0.0, 0.0, SCLERA_RADIUS_MM]), np.zeros(3), 0.0, np.zeros(self.modes)]
        dist, cost = np.zeros(1), 0.0
        for _ in range(iterations):
            dist, j = tree.query(self._placed(x, use, side))
            Q, Nq = P[j], N[j]

            def f(x):
                r = ((self._placed(x, use, side) - Q) * Nq).sum(axis=1)
                # coefficients stay near the population; rotation and scale modest
                return np.r_[r, x[7:], 5.0 * x[3:6], 2.0 * x[6]]
            res = least_squares(f, x, loss="soft_l1", f_scale=0.5)
            x, cost = res.x, float(res.cost)
        return x, cost, dist


#: A registration's scale outside this range is no eye region's (over the 218 eyes of the cached
#: unseen heads the fits from the hint lay at 0.80-1.28 but for seven at 0.58-0.75, each the model
#: shrunk onto part of the region: `n1306_dome_wide_hint4`'s wide left eye at 0.60 gave a margin
#: 14.5 x 4.7 mm, and the cut behind it refused the head as narrow).
SCALE_RANGE = (0.78, 1.35)
#: How far the restarts move the hint (mm), and the spread of an eye region's scale that ranks them.
RESTART_MM = 3.0
SCALE_SD = 0.1


def _with_scale_prior(fit) -> float:
    """A registration's cost with the scale's prior: fits of different scales compared."""
    x, cost, _ = fit
    return cost + 0.5 * (float(x[6]) / SCALE_SD) ** 2
