"""The doubts of a placed eye: sentences saying why an eye that is published may be wrong.

Only what cannot be an asset is refused (:mod:`pipeline.placement.place`: a closed eye); every
other failing is a doubt, which the stage prints as a ``warning:`` line and ``eyes.json``
records: a failed self-check (:mod:`pipeline.placement.checks`, :func:`check_doubts`), a
texture-placed opening narrower than the fissure its texture shows (:func:`fissure_doubts`),
and the asset's eye's own (:func:`pipeline.placement.human_eye.asset_eyes`: little evidence on
the limbus or the axis, an iris outside the opening).
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry.frame import eye_basis
from pipeline.placement import checks as eye_checks
from pipeline.placement.settings import PlacementSettings
from pipeline.placement.texture import texture_fissure


def check_doubts(checks: dict) -> list:
    """Sentences for every failed self-check of the scan's sphere (``checks``: name -> check, as
    :func:`pipeline.placement.checks.check_eye` returns them). The eye is still published."""
    return ["self-check " + k + ": " + eye_checks.describe(k, checks[k])
            for k in eye_checks.failed(checks)]


def fissure_doubts(V, F, mesh_arrays, texture, hint, fit, loop_points, st: PlacementSettings):
    """A texture-placed eye's opening against the fissure its texture shows.

    Returns ``(record, doubts)``: the fissure's and the loop's widths along the eye (mm) and a
    list holding one sentence when the loop spans less than ``texture_fissure_min_share`` of
    the fissure (its canthi, eyelid landmarks 0 and 6, then lie far inside the true corners)."""
    fis = texture_fissure(V, F, mesh_arrays["UV"], mesh_arrays["FUV"], texture, hint, fit.forward,
                          radius_mm=st.patch_radius_mm, min_contrast=st.texture_min_contrast)
    x = (np.asarray(loop_points, float) - fit.center) @ eye_basis(fit.forward)[0]
    record = {"width_mm": fis["width_mm"], "height_mm": fis["height_mm"],
              "loop_width_mm": float(x.max() - x.min()), "min_share": st.texture_fissure_min_share}
    doubts = []
    if record["loop_width_mm"] < st.texture_fissure_min_share * fis["width_mm"]:
        doubts.append(f"opening {record['loop_width_mm']:.1f} mm wide where the texture's fissure is "
                      f"{fis['width_mm']:.1f} mm: the canthi (eyelid landmarks 0 and 6) lie too close "
                      f"together; the scan is too coarse for its eye opening")
    return record, doubts
