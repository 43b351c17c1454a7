"""Same bytes on any CPU: the whole chain under different numpy / OpenBLAS kernel dispatch.

    .venv/bin/python -m benchmarks.bench_dispatch [--settings native,npy_no_avx2 ...] [--keep DIR]

For each dispatch setting, clones this repository's HEAD into a fresh folder (``.venv`` linked
from here), runs ``dvc repro`` there as ``make run`` does, and records the sha256 of every file
under ``raw_scans/synthetic_head``, ``build/``, ``rigged_assets/`` and ``renders/`` (each run's
``*.timings.json`` left out: wall times, not tracked) and ``git status --porcelain`` (a rewritten
``dvc.lock`` shows here). Every setting is compared with the first, and the first with the
committed ``dvc.lock``. Writes benchmarks/results/dispatch.json and dispatch.md.

Settings (numpy 1.26 names; a feature the CPU lacks is ignored):

* ``native``: what numpy and OpenBLAS pick on this CPU.
* ``npy_no_avx2``: ``NPY_DISABLE_CPU_FEATURES`` with every AVX512 group and AVX2 off, so numpy's
  dispatched loops take their AVX / SSE4 versions (an AVX2-less or AVX512-less machine).
* ``npy_sse3``: everything above the x86-64 baseline off (SSE3 kernels only).
* ``blas_haswell`` / ``blas_prescott``: ``OPENBLAS_CORETYPE`` (numpy's and scipy's OpenBLAS
  both read it): AVX2 kernels, and SSE3 kernels of 2004.
* ``libm_no_fma``: glibc's non-FMA libm (a CPU without FMA) and one OpenBLAS thread (a
  one-core machine).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_AVX512 = "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"
SETTINGS = {
    "native": {},
    "npy_no_avx2": {"NPY_DISABLE_CPU_FEATURES": f"{_AVX512} AVX2"},
    "npy_sse3": {"NPY_DISABLE_CPU_FEATURES": f"{_AVX512} AVX2 FMA3 F16C AVX SSE42 POPCNT SSE41 SSSE3"},
    "blas_haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "blas_prescott": {"OPENBLAS_CORETYPE": "Prescott"},
    "libm_no_fma": {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-FMA,-AVX2", "OPENBLAS_NUM_THREADS": "1"},
}
OUTPUTS = ("raw_scans/synthetic_head", "build", "rigged_assets", "renders")


def output_hashes(clone: Path) -> dict[str, str]:
    """Repository-relative path -> sha256 of every output file of a run (timings left out)."""
    out = {}
    for top in OUTPUTS:
        for p in sorted((clone / top).rglob("*")):
            if p.is_file() and not p.name.endswith(".timings.json"):
                out[p.relative_to(clone).as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def run_setting(name: str, env_extra: dict, work: Path, commit: str) -> dict:
    """Clone ``commit`` into ``work/name``, ``dvc repro`` there under ``env_extra``; hashes and status."""
    clone = work / name
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "checkout", "-q", "-B", "bench", commit], cwd=clone, check=True)
    (clone / ".venv").symlink_to((ROOT / ".venv").resolve())
    env = {k: v for k, v in os.environ.items()
           if k not in ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "GLIBC_TUNABLES")}
    env.update(env_extra)
    env["PATH"] = f"{clone / '.venv' / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env.pop("PYTHONPATH", None)
    t0 = time.perf_counter()
    r = subprocess.run([str(clone / ".venv" / "bin" / "dvc"), "repro"], cwd=clone, env=env,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{name}: dvc repro failed ({r.returncode})\n{(r.stdout + r.stderr)[-3000:]}")
    status = subprocess.run(["git", "status", "--porcelain"], cwd=clone, capture_output=True,
                            text=True, check=True).stdout.split("\n")
    # the linked .venv is a symlink, which .gitignore's "/.venv/" (a folder) does not cover
    status = [s for s in status if s and s != "?? .venv"]
    lock = hashlib.sha256((clone / "dvc.lock").read_bytes()).hexdigest()
    return {"env": env_extra, "wall_s": round(wall, 1), "git_status": status, "dvc_lock_sha256": lock,
            "hashes": output_hashes(clone)}


def compare(runs: dict) -> dict:
    """Setting -> files whose bytes differ from the first setting's (or exist in one only)."""
    names = list(runs)
    ref = runs[names[0]]["hashes"]
    diff = {}
    for n in names[1:]:
        h = runs[n]["hashes"]
        diff[n] = sorted(p for p in set(ref) | set(h) if ref.get(p) != h.get(p))
    return diff


def write_page(runs: dict, diff: dict, head: str, out: Path) -> None:
    lines = ["# Same bytes under every numpy / OpenBLAS dispatch setting", "",
             f"`python -m benchmarks.bench_dispatch` at {head[:10]}: a fresh clone's `dvc repro` "
             "(as `make run`) under each setting; every file under raw_scans/synthetic_head, build/, "
             "rigged_assets/ and renders/ compared by sha256 with the first setting's.", "",
             "| setting | environment | files | differ from first | dvc.lock (sha256) | git status | wall s |",
             "|---|---|---|---|---|---|---|"]
    first = next(iter(runs))
    for n, r in runs.items():
        env = " ".join(f"{k}=\"{v}\"" for k, v in r["env"].items()) or "(none)"
        nd = "-" if n == first else str(len(diff[n]))
        st = "clean" if not r["git_status"] else "; ".join(r["git_status"])
        lines.append(f"| {n} | `{env}` | {len(r['hashes'])} | {nd} | {r['dvc_lock_sha256'][:12]} | {st} "
                     f"| {r['wall_s']} |")
    for n, files in diff.items():
        if files:
            lines += ["", f"## {n}: {len(files)} file(s) differ", ""] + [f"- `{p}`" for p in files[:60]]
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--settings", default=",".join(SETTINGS),
                    help=f"comma-separated, the first is the reference (known: {', '.join(SETTINGS)})")
    ap.add_argument("--keep", type=Path, help="leave the clones in this folder (default: a temp folder, removed)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "dispatch")
    args = ap.parse_args(argv)
    names = [s for s in args.settings.split(",") if s]
    bad = [s for s in names if s not in SETTINGS]
    if bad or not names:
        raise SystemExit(f"error: --settings: unknown {bad} (known: {', '.join(SETTINGS)})")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="bench_dispatch_") as tmp:
        work = args.keep if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        runs = {}
        for n in names:
            runs[n] = run_setting(n, SETTINGS[n], work, head)
            print(f"{n}: {len(runs[n]['hashes'])} files, {runs[n]['wall_s']} s, "
                  f"git status {'clean' if not runs[n]['git_status'] else runs[n]['git_status']}", file=sys.stderr)
    diff = compare(runs)
    for n, files in diff.items():
        print(f"{n}: {len(files)} file(s) differ from {names[0]}", file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    result = {"head": head, "settings": {n: {k: v for k, v in r.items() if k != "hashes"} for n, r in runs.items()},
              "differ": diff, "hashes": {n: r["hashes"] for n, r in runs.items()}}
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    write_page(runs, diff, head, args.out.with_suffix(".md"))
    return 1 if any(diff.values()) or any(r["git_status"] for r in runs.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
