"""The eyeball stage's work: build the parametric eyeball, write its asset (eyeball.usda and its
textures), validate it, and render its Cycles preview in a Blender child process.

``stages/eyeball.py`` parses its folder and settings and calls :func:`build_eyeball_asset` and
:func:`render_eyeball_preview` inside an atomic output folder. Its own module (not
pipeline/usd/eyeball.py, which every stage that reads the eyeball imports) so that only the
eyeball stage's code deps name the preview worker.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from pipeline.eyeball import geometry as geo
from pipeline.results import StageResult

ROOT = Path(__file__).resolve().parents[2]


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


#: What the preview worker reports that measures its run, not the sheet.
PREVIEW_TIMINGS = ("setup_s", "render_s_per_tile_median", "render_s_total")


def render_eyeball_preview(folder: Path, settings: geo.EyeballSettings) -> StageResult:
    """Render ``folder/preview.png`` of the asset in ``folder`` with the Blender preview worker
    (a subprocess); the sheet's facts under ``preview`` in the metrics, its times in the timings."""
    import json
    import tempfile

    from pipeline.io.png import strip_png_metadata
    from pipeline.io.scratch import run_child

    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as td:
        report = Path(td) / "preview.json"
        cmd = [sys.executable, "-m", "pipeline.blender.eyeball_preview", str(folder / "eyeball.usda"),
               str(folder / "preview.png"), "--size", str(settings.preview_px),
               "--samples", str(settings.preview_samples), "--json", str(report)]
        res = run_child(cmd, capture_output=True, text=True, cwd=ROOT)
        if res.returncode != 0:
            raise RuntimeError("preview render failed:\n" + res.stdout[-2000:] + res.stderr[-2000:])
        info = json.loads(report.read_text())
    strip_png_metadata(folder / "preview.png")     # Blender's time/text chunks: same pixels, same bytes
    sheet = {k: v for k, v in info.items() if k not in PREVIEW_TIMINGS}
    times = {k: info[k] for k in PREVIEW_TIMINGS if k in info}
    return StageResult({"preview": sheet}, {"preview": {**times, "wall_s": round(time.perf_counter() - t, 3)}})
