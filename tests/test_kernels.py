"""pipeline/kernels.py: a pipeline program gives the same bits whatever numeric kernels the CPU
offers (numpy's SIMD dispatch, OpenBLAS's core type and threads, glibc's FMA libm)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pipeline import kernels

ROOT = Path(__file__).resolve().parents[1]
_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"
#: the dispatch settings of issue 22, and glibc's non-FMA libm
SETTINGS = [{}, {"NPY_DISABLE_CPU_FEATURES": f"{_AVX512} AVX2"}, {"OPENBLAS_CORETYPE": "Haswell"},
            {"OPENBLAS_CORETYPE": "Prescott"}, {"OPENBLAS_NUM_THREADS": "2"},
            {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-FMA"}]
#: the operations whose last bits follow those kernels (measured: each differs under one of them)
PROBE = """
import hashlib, numpy as np, scipy.linalg
x = np.random.default_rng(0).uniform(0.01, 10, 100000)
A = x[:90000].reshape(300, 300)
r = [np.exp(x), np.log(x), np.sin(x), np.arctan2(x, x[::-1]), np.power(x, 1.3), A @ A,
     np.linalg.solve(A[:50, :50], x[:50]), scipy.linalg.lstsq(A[:, :10], x[:300])[0]]
print(hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in r)).hexdigest())
"""

pytestmark = pytest.mark.skipif(not kernels.applies({}), reason="the pin is for x86-64 POSIX")


def _env(extra: dict, **more) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in kernels.PINNED and k != kernels.OPT_OUT}
    return {**env, "PYTHONPATH": str(ROOT), **extra, **more}


def _probe(extra: dict, pin: bool) -> str:
    code = ("import pipeline.kernels as k; k.pin_process()\n" if pin else "") + PROBE
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_env(extra), capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.strip()


@pytest.mark.slow
def test_pinned_kernels_give_the_same_bits_under_every_dispatch_setting():
    pinned = {_probe(s, pin=True) for s in SETTINGS}
    assert len(pinned) == 1, pinned
    # the control: on a CPU with AVX2 or FMA the unpinned bits do move (else the test tests nothing)
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").is_file() else ""
    if " avx2" in flags or " fma" in flags:
        assert len({_probe(s, pin=False) for s in SETTINGS}) > 1


@pytest.mark.slow
def test_a_stage_pins_itself_and_writes_the_same_bytes_under_every_setting(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"synthetic_head": {"target_triangles": 20_000, "texture_size": 64}}))
    digests = set()
    for i, extra in enumerate(SETTINGS[:3]):
        out = tmp_path / f"head{i}"
        r = subprocess.run([sys.executable, "-m", "stages.synthetic_head", str(out), "--params", str(params),
                            "--metrics", str(tmp_path / f"m{i}.json")], cwd=ROOT, env=_env(extra),
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        digests.add(hashlib.sha256(b"".join((out / n).read_bytes() for n in
                                            ("scan.ply", "texture.png", "ground_truth.json"))).hexdigest())
    assert len(digests) == 1


def test_pinned_environment_keeps_other_tunables_and_opts_out():
    env = kernels.pinned_env({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2:glibc.cpu.hwcaps=-AVX512F"})
    assert env["GLIBC_TUNABLES"].startswith("glibc.malloc.arena_max=2:glibc.cpu.hwcaps=-AVX,")
    assert "-AVX512F" not in env["GLIBC_TUNABLES"] and kernels.is_pinned(env)
    assert env["OPENBLAS_NUM_THREADS"] == "1" and not kernels.is_pinned({})
    assert not kernels.applies({kernels.OPT_OUT: "1"}) and kernels.applies({kernels.OPT_OUT: "0"})


def test_importing_the_package_pins_nothing():
    """Only ``python -m pipeline.*`` / ``stages.*`` programs re-exec; a library user's process is
    left as it is (this one imported pipeline without being restarted)."""
    r = subprocess.run([sys.executable, "-c", "import os, pipeline, numpy; print(os.environ.get('OPENBLAS_CORETYPE'))"],
                       cwd=ROOT, env=_env({}), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "None"


def test_a_pipeline_program_runs_without_numpys_huge_page_advice():
    # a `python -m stages.*` program: pipeline/__init__.py sees argv[0] == "-m"
    code = ("import sys; sys.argv = ['-m']; import pipeline; import numpy.core.multiarray as m; "
            "print(m._set_madvise_hugepage(False))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"})
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"      # the advice was already off when numpy loaded
