"""The eyeball_preview stage's work: the Cycles contact sheet of the eyeball asset, rendered by
the Blender worker ``pipeline.blender.eyeball_preview`` through the door
(pipeline/blender/launch.py)."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from pipeline.blender import launch
from pipeline.io.png import strip_png_metadata
from pipeline.results import StageResult

WORKER = "pipeline.blender.eyeball_preview"
#: What the preview worker reports that measures its run, not the sheet.
PREVIEW_TIMINGS = ("setup_s", "render_s_per_tile_median", "render_s_total")


def render_eyeball_preview(usda: Path, out_png: Path, size: int, samples: int) -> StageResult:
    """Render the sheet of the eyeball asset ``usda`` to ``out_png``: the sheet's facts in the
    metrics, its times in the timings."""
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as td:
        report = Path(td) / "preview.json"
        res = launch.run(WORKER, [usda, out_png, "--size", int(size), "--samples", int(samples),
                                  "--json", report])
        if res.returncode != 0:
            raise RuntimeError("preview render failed:\n" + res.stdout[-2000:] + res.stderr[-2000:])
        info = json.loads(report.read_text())
    strip_png_metadata(out_png)          # Blender's time/text chunks: same pixels, same bytes
    sheet = {k: v for k, v in info.items() if k not in PREVIEW_TIMINGS}
    times = {k: info[k] for k in PREVIEW_TIMINGS if k in info}
    return StageResult(sheet, {**times, "wall_s": round(time.perf_counter() - t, 3)})
