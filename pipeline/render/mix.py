"""Which asset each image of a dataset comes from: exact counts by weight, mixed by a seed.

:func:`allocate` splits ``n`` images over the assets by largest remainder (Hamilton's
method): asset ``a`` gets ``floor(n w_a / W)`` images, and the images left over go one each
to the assets with the largest fractional parts (ties: the earlier asset). Every count is
within one image of its quota ``n w_a / W`` and the counts sum to ``n`` exactly; there is no
sampling error to tolerate.

:func:`assign` turns the counts into the asset of every global index ``0..n-1``: the list
``[0] * c_0 + [1] * c_1 + ...`` permuted by ``numpy.random.default_rng([seed, MIX_TAG])``,
so the assets are interleaved over the indices (any slice of the dataset holds a mix) and the
assignment is a pure function of ``(n, weights, seed)``.

The images themselves are drawn with ``default_rng([seed, index, attempt])``
(pipeline/render/sampling.py) over the global index, so no two images of a dataset, of the
same or of different assets, share a random stream; the mixing stream's key ``[seed,
MIX_TAG]`` cannot equal an image's key either (its second word is larger than any index).
"""

from __future__ import annotations

import math

import numpy as np

#: Second word of the mixing stream's key (the bytes of ``"mix"`` + 2**31: above any image index).
MIX_TAG = 2**31 + 0x6D6978


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
    """Images per asset by largest remainder.

    Parameters
    ----------
    n : int               images in the dataset (>= 0)
    weights : sequence    one positive weight per asset

    Returns
    -------
    (k,) int64  counts, summing to ``n``, each within 1 of ``n * w / sum(w)``.
    """
    w = np.asarray(weights, np.float64)
    quota = n * w / w.sum()
    counts = np.floor(quota).astype(np.int64)
    left = int(n - counts.sum())
    frac = quota - counts
    # largest fractional part first, the earlier asset on ties (stable sort of -frac)
    counts[np.argsort(-frac, kind="stable")[:left]] += 1
    return counts


def assign(n: int, weights, seed: int) -> np.ndarray:
    """(n,) int32 asset position of every global image index (see the module docstring)."""
    counts = allocate(n, weights)
    ids = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
    return np.random.default_rng([int(seed), MIX_TAG]).permutation(ids)
