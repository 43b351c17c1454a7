"""The settings of stage remove_eyeballs (``remove_eyeballs:`` block of params.yaml)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.placement.settings import PlacementSettings
from pipeline.settings import setting


@dataclass
class RemoveEyeballsSettings(PlacementSettings):
    """Parameters of eye finding and removal (``remove_eyeballs:`` block of params.yaml): the
    placement's (:class:`PlacementSettings`) and the cut's; the defaults are here, values are
    checked by pipeline.settings."""

    block: ClassVar[str] = "remove_eyeballs"

    sample_radius_mm: float = setting(13.0, gt=0, le=100)      # holes within this of a hint are closed for the fit
    max_hole_perimeter_mm: float = setting(60.0, ge=0, le=1000)  # holes near the hints (an unmeasured pupil) closed for the fit
    margin_lift_mm: float = setting(0.6, ge=0, le=20)          # 0 = loop left on the cut
    margin_max_turn_deg: float = setting(60.0, gt=0, le=180)
    margin_on_eye_mm: float = setting(0.3, ge=0, le=20)
