"""The placement's settings: the fields of the ``remove_eyeballs:`` block that say how an eye
is placed, how sure it must be and when it is doubted.

The stage's block is :class:`pipeline.remove_eyeballs.settings.RemoveEyeballsSettings`, which
extends these with the cut's (hole filling, the margin's lift-off): one block in params.yaml,
read by one class, while the placement names only what it reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pipeline.settings import Settings, setting


@dataclass
class PlacementSettings(Settings):
    """How both eyes of a scan are placed (:func:`pipeline.placement.place.place_pair`) and
    judged (:func:`pipeline.placement.place.judge_pair`); the defaults are here."""

    patch_radius_mm: float = setting(22.0, gt=0, le=100)       # surface considered around a hint
    radius_range_mm: tuple[float, float] = setting((10.0, 21.0), gt=0, le=100, ordered=True)  # the scan sphere (a diagnostic)
    radius_prior_mm: float = setting(12.0, gt=0, le=100)
    radius_prior_sigma_mm: float = setting(3.0, gt=0, le=100)
    min_crease_deg: float = setting(12.0, ge=0, le=180)        # lid fold around the eye surface; below = closed
    texture_fallback: bool = True
    texture_min_contrast: float = setting(3.0, gt=0, le=1000)
    texture_fissure_min_share: float = setting(0.8, gt=0, le=1)  # a texture-placed opening narrower than this share of the texture's fissure is doubted
    seed: int = setting(0, ge=0)
    # the joint placement (pipeline.placement.fit)
    place_patch_mm: float = setting(20.0, gt=5, le=60)          # surface the eye model explains around a hint
    prior_front_sigma_mm: float = setting(4.0, gt=0, le=100)     # the eye-region prior's say on the front of the globe
    uncertainty_temperature: float = setting(5.0, gt=0, le=1e6)  # energy scale of a rival local optimum's weight
    uncertainty_scale: float = setting(3.0, gt=0, le=100)        # Laplace sigma x this (calibrated on unseen heads)
    # the asset's eye (pipeline.placement.human_eye): the parametric eyeball (eyeball.geometry)
    # anchored at the scan's limbus; its size: the paper's r1, a population size, or the scan's sphere
    eye_size: Literal["human", "population", "fitted"] = "human"
    limbus_fit: Literal["iris_plane", "model"] = "iris_plane"   # the scan's limbus: refit with the iris plane, or the eye model's
    population_radius_mm: tuple[float, float] = setting((11.7, 0.45), gt=0, le=100, min_len=2, max_len=2)
    min_iris_visible: float = setting(0.05, ge=0, le=1)          # less of the iris inside the opening at rest: placed from the opening
    doubt_limbus_sigma_mm: float = setting(0.5, gt=0, le=100)    # a limbus centre less sure than this is published with a doubt
    doubt_axis_sigma_deg: float = setting(2.0, gt=0, le=90)      # ... an axis less sure than this
    min_open_area_mm2: float = setting(6.0, ge=0, le=1000)       # less visible eye than this: the eye is closed
    fill_face_ratio: float = setting(12.0, gt=1, le=1e6)         # faces this many times the median area: a scanner's flat fill
    min_eye_vertices: int = setting(40, ge=0, le=100000)         # fewer scan vertices on the eye surface: too coarse to place from geometry
