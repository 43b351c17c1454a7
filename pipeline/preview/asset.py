"""The preview stage's work: the Cycles contact sheet of a scan's rigged asset (front views at
pitch +25/0/-25 deg and a three-quarter view), rendered by the Blender worker
``pipeline.blender.asset_preview`` through the door (pipeline/blender/launch.py)."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from pipeline.blender import launch
from pipeline.errors import ScanError
from pipeline.io.png import strip_png_metadata
from pipeline.results import StageResult

WORKER = "pipeline.blender.asset_preview"


def render_preview(usda: Path, rig_npz: Path, out_png: Path, size: int, samples: int) -> StageResult:
    """Render the sheet of ``usda`` (posed with ``rig_npz``'s lid shapes) to ``out_png``; the
    worker's report (sheet size, samples, lid and gaze checks) and how long it took."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as td:
        info_path = Path(td) / "preview.json"
        res = launch.run(WORKER, [usda, rig_npz, out_png, "--size", int(size), "--samples", int(samples),
                                  "--json", info_path])
        if res.returncode != 0 or not out_png.is_file() or out_png.stat().st_size == 0:
            last = (res.stderr or res.stdout or "").strip().splitlines()[-1:] or ["no output"]
            raise ScanError(usda, f"the asset preview render failed ({last[0][:200]})")
        strip_png_metadata(out_png)          # Blender's time/text chunks: same pixels, same bytes
        info = json.loads(info_path.read_text(encoding="utf-8"))
    return StageResult({"preview_px": info.get("sheet_px"), "preview_samples": info.get("samples"),
                        "preview_lid_max_error_mm": max(info.get("lid_max_error_mm", {0: 0.0}).values()),
                        "preview_gaze_pitch_deg": info.get("gaze_pitch_measured_deg")},
                       {"preview_s": round(time.perf_counter() - t0, 3), "preview_render_s": info.get("render_s_total")})
