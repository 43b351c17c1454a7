"""Which asset each image of a dataset comes from: a sequence that only grows, counts by weight.

:func:`assign` gives the asset of every global index ``0..n-1`` as the first ``n`` terms of one
infinite sequence of ``(weights, seed)``: Balinski and Young's quota method (1975), the
sequential apportionment that stays within quota at every size. Term ``t`` (1-based) goes to the
asset with the largest ``w_a / (c_a + 1)`` among those still below their upper quota
(``c_a < t w_a / W``), ``c_a`` its images among the first ``t - 1``; ties go to the asset first
in a seeded order (``numpy.random.default_rng([seed, MIX_TAG]).permutation``), so the seed, not
the order of ``--assets``, says which asset opens the dataset. Because the sequence does not
depend on ``n``:

* image ``i``'s asset depends only on the weights, the seed and ``i``; growing a dataset from
  ``n`` to ``m`` adds images ``n..m-1`` and changes no earlier one, shrinking removes the tail;
* every prefix (any ``n``) holds ``floor(n w_a / W)`` or ``ceil(n w_a / W)`` images of asset
  ``a``: within one image of its quota (the quota property; exact when the quota is whole, e.g.
  10,000 at 2:1:1 is 5,000 / 2,500 / 2,500), and the assets are interleaved over the indices.

Weights are taken exactly (each float's own binary fraction, scaled to integers), so the quota
comparisons have no rounding. :func:`assign_legacy` is the mix of datasets planned before this
sequence (largest remainder counts permuted by the seed, which reshuffled every index when ``n``
changed); plans record which one they used (pipeline/render/plan.py).

The images themselves are drawn with ``default_rng([seed, index, attempt])``
(pipeline/render/sampling.py) over the global index, so no two images of a dataset, of the
same or of different assets, share a random stream; the mixing stream's key ``[seed,
MIX_TAG]`` cannot equal an image's key either (its second word is larger than any index).
"""

from __future__ import annotations

import math
from fractions import Fraction
from functools import lru_cache

import numpy as np

#: Second word of the mixing stream's key (the bytes of ``"mix"`` + 2**31: above any image index).
MIX_TAG = 2**31 + 0x6D6978
#: The mix a plan records (``config.json``: ``dataset.mix``); plans without it used :func:`assign_legacy`.
MIX = "quota"


def check_weights(weights, n_assets: int) -> list[float]:
    """``weights`` as floats (None: equal weights); ValueError naming the problem.

    Each weight must be a finite number > 0, one per asset.
    """
    if weights is None:
        return [1.0] * int(n_assets)
    w = list(weights)
    if len(w) != n_assets:
        raise ValueError(f"{len(w)} weight(s) for {n_assets} asset(s): give one weight per asset")
    out = []
    for k, x in enumerate(w):
        try:
            v = float(x)
        except (TypeError, ValueError):
            raise ValueError(f"weight {k + 1} ({x!r}) is not a number") from None
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"weight {k + 1} must be a finite number > 0 (got {x!r})")
        out.append(v)
    return out


def allocate(n: int, weights) -> np.ndarray:
    """Images per asset among the first ``n`` of :func:`assign` (seed-independent: ties only
    reorder); each within 1 of ``n * w / sum(w)``, summing to ``n``."""
    return np.bincount(assign(n, weights, 0), minlength=len(list(weights))).astype(np.int64)


def _integer_weights(weights) -> list[int]:
    """The weights as integers in the same exact proportions (each float's binary fraction)."""
    fr = [Fraction(float(w)) for w in weights]
    den = 1
    for f in fr:
        den = den * f.denominator // math.gcd(den, f.denominator)
    return [int(f * den) for f in fr]


@lru_cache(maxsize=8)
def _sequence(weights: tuple, seed: int, n: int) -> np.ndarray:
    w = _integer_weights(weights)
    k, W = len(w), sum(w)
    rank = np.random.default_rng([int(seed), MIX_TAG]).permutation(k).tolist()   # tie order
    order = sorted(range(k), key=lambda a: rank[a])
    c = [0] * k
    out = np.empty(n, np.int32)
    for t in range(1, n + 1):
        best = -1
        for a in order:                  # the seeded order: a later asset wins only strictly
            if c[a] * W < t * w[a] and (best < 0 or w[a] * (c[best] + 1) > w[best] * (c[a] + 1)):
                best = a
        c[best] += 1
        out[t - 1] = best
    return out


def assign(n: int, weights, seed: int) -> np.ndarray:
    """(n,) int32 asset position of every global image index (see the module docstring); the
    first ``n`` terms of a sequence that does not depend on ``n``."""
    seq = _sequence(tuple(float(x) for x in weights), int(seed), int(n))
    return seq.copy()


def _largest_remainder(n: int, weights) -> np.ndarray:
    w = np.asarray(weights, np.float64)
    quota = n * w / w.sum()
    counts = np.floor(quota).astype(np.int64)
    left = int(n - counts.sum())
    frac = quota - counts
    # largest fractional part first, the earlier asset on ties (stable sort of -frac)
    counts[np.argsort(-frac, kind="stable")[:left]] += 1
    return counts


def assign_legacy(n: int, weights, seed: int) -> np.ndarray:
    """The mix of plans recorded before :data:`MIX`: largest-remainder counts permuted by
    ``default_rng([seed, MIX_TAG])`` (a function of ``n``: read old folders with it only)."""
    counts = _largest_remainder(n, weights)
    ids = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
    return np.random.default_rng([int(seed), MIX_TAG]).permutation(ids)
