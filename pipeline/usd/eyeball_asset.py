"""The eyeball stage's work: build the parametric eyeball, write its asset (eyeball.usda and its
textures) and validate it. No Blender: its contact sheet is the eyeball_preview stage's
(pipeline/preview/eyeball.py).

``stages/eyeball.py`` parses its folder and settings and calls :func:`build_eyeball_asset`
inside an atomic output folder. Its own module, apart from pipeline/usd/eyeball.py (which every
stage that reads the eyeball imports), so that the textures and checks are the eyeball stage's
code deps only.
"""

from __future__ import annotations

import time
from pathlib import Path

from pipeline.eyeball import geometry as geo
from pipeline.results import StageResult


def build_eyeball_asset(folder: Path, settings: geo.EyeballSettings) -> StageResult:
    """Write eyeball.usda + textures into ``folder``, validated (no preview).

    ``settings``: the ``eyeball:`` block (EyeballSettings or its raw mapping)."""
    if not isinstance(settings, geo.EyeballSettings):
        settings = geo.EyeballSettings.from_params(settings)
    from PIL import Image

    from pipeline.eyeball import textures as tex
    from pipeline.eyeball.checks import seam_dihedral_report
    from pipeline.usd.eyeball import write_eyeball_usd
    from pipeline.usd.validate import validate_stage_report

    t0 = time.perf_counter()
    p = settings.geometry
    eye = geo.build_eyeball(p, settings.resolution)
    t_geo = time.perf_counter() - t0
    t1 = time.perf_counter()
    (folder / "textures").mkdir(parents=True, exist_ok=True)
    images = tex.texture_set(settings.texture_seed, settings.iris_texture_px, settings.sclera_texture_px,
                             p, eye.resolution)
    for name, img in images.items():
        Image.fromarray(img).save(folder / "textures" / name, optimize=False, compress_level=3)
    t_tex = time.perf_counter() - t1
    t2 = time.perf_counter()
    usda = write_eyeball_usd(eye, folder / "eyeball.usda")
    t_usd = time.perf_counter() - t2
    t3 = time.perf_counter()
    report = validate_stage_report(usda)
    t_val = time.perf_counter() - t3
    if report["errors"]:
        raise RuntimeError("eyeball asset failed validation:\n  " + "\n  ".join(report["errors"]))
    seam = seam_dihedral_report(p, eye.resolution)
    metrics = {"resolution": eye.resolution.__dict__, **eye.stats(), "validation_errors": len(report["errors"]),
               "validation_warnings": len(report["warnings"]),
               "seam_dihedral_deg": round(seam["seam_max_deg"], 3),
               "max_dihedral_elsewhere_deg": round(max(seam["cornea_max_deg"], seam["sclera_max_deg"]), 3)}
    return StageResult(metrics, {"geometry_s": round(t_geo, 4), "textures_s": round(t_tex, 4),
                                 "usd_write_s": round(t_usd, 4), "validate_s": round(t_val, 4)})
