"""Smooth ramps shared by the falloffs (bake's displacement fade) and the procedural models
(synthetic head, eyeball textures)."""

from __future__ import annotations

import numpy as np


def smoothstep(e0, e1, x):
    """C1 ramp (GLSL's ``smoothstep``): 0 at ``x <= e0``, 1 at ``x >= e1``, cubic between;
    ``e1 < e0`` ramps the other way."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
