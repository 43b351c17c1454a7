"""Benchmark: building the eyeball asset per resolution setting.

    .venv/bin/python -m benchmarks.bench_eyeball [--repeats 5]

For every resolution preset: median wall time of geometry (meshes, blend
shapes, landmarks), USD authoring (eyeball.usda) and validation, vertex and
polygon counts; plus the procedural textures (4 iris at 512 px, 2 sclera at
1024x512). Target: geometry + USD for the full resolution <= 2 s. Writes
benchmarks/results/eyeball.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from pipeline.eyeball import geometry as geo
from pipeline.eyeball import textures as tex

OUT = Path(__file__).resolve().parent / "results" / "eyeball.json"


def _median_time(fn, repeats):
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main(argv=None) -> int:
    from pipeline.usd.eyeball import write_eyeball_usd
    from pipeline.usd.validate import validate_stage

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as td:
        from PIL import Image

        (Path(td) / "textures").mkdir()
        for fname, img in tex.texture_set(0, 64, (64, 32)).items():  # referenced files must exist
            Image.fromarray(img).save(Path(td) / "textures" / fname)
        write_eyeball_usd(geo.build_eyeball(resolution="low"), Path(td) / "warm.usda")  # pxr import
        for name in geo.RESOLUTION_PRESETS:
            eye = geo.build_eyeball(resolution=name)
            t_geo = _median_time(lambda: geo.build_eyeball(resolution=name), args.repeats)
            path = Path(td) / f"{name}.usda"
            t_usd = _median_time(lambda: write_eyeball_usd(eye, path), args.repeats)
            t_val = _median_time(lambda: validate_stage(path), args.repeats)
            t_all = _median_time(lambda: write_eyeball_usd(geo.build_eyeball(resolution=name), path),
                                 args.repeats)
            rows.append({"resolution": name, **geo.Resolution.preset(name).__dict__, **eye.stats(),
                         "geometry_s": round(t_geo, 4), "usd_write_s": round(t_usd, 4),
                         "validate_s": round(t_val, 4), "build_total_s": round(t_all, 4),
                         "usda_bytes": path.stat().st_size})
    t_tex = _median_time(lambda: tex.texture_set(0), max(1, args.repeats // 2))
    # The whole asset as the stage writes it (geometry, textures, USD, validation; no preview).
    from pipeline.usd.eyeball_asset import build_eyeball_asset

    def whole():
        with tempfile.TemporaryDirectory() as td:
            build_eyeball_asset(Path(td), {"resolution": "full"})

    t_whole = _median_time(whole, max(3, args.repeats // 2))
    result = {"repeats": args.repeats, "target_build_full_s": 2.0, "resolutions": rows,
              "textures_s": round(t_tex, 3), "asset_full_with_textures_s": round(t_whole, 3),
              "command": ".venv/bin/python -m benchmarks.bench_eyeball"}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{'res':8s} {'around':>6s} {'outer V':>8s} {'inner V':>8s} {'polys':>7s} "
          f"{'geom s':>7s} {'usd s':>7s} {'valid s':>7s} {'build s':>7s}")
    for r in rows:
        print(f"{r['resolution']:8s} {r['n_around']:6d} {r['outer_vertices']:8d} {r['inner_vertices']:8d} "
              f"{r['outer_polygons'] + r['inner_polygons']:7d} {r['geometry_s']:7.3f} {r['usd_write_s']:7.3f} "
              f"{r['validate_s']:7.3f} {r['build_total_s']:7.3f}")
    print(f"textures (4 iris 512 px + 2 sclera 1024x512): {t_tex:.2f} s")
    print(f"whole asset at full resolution (geometry + textures + USD + validation): {t_whole:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
