"""Same bytes on any x86-64 CPU: every pipeline program runs the same numeric kernels.

numpy, OpenBLAS and glibc's libm each pick machine code for the CPU they start on, and the
choices round differently in the last bits:

* numpy dispatches its loops (``np.exp``, ``np.log``, ``np.power``, ``np.arctan2``, ``np.tan``,
  the float32 ``sin`` / ``cos`` ...) to AVX512 (SVML), AVX2 or baseline code;
* OpenBLAS picks a kernel per CPU model (``matmul``, ``lstsq``, ``solve``, ``svd``, in numpy and
  in scipy, which ships its own), and splits work by its thread count, so results depend on the
  number of cores too;
* glibc's ``sin``, ``cos``, ``exp``, ``log``, ``pow``, ``atan`` ... have FMA builds chosen on FMA
  CPUs (numpy's baseline loops call them).

Measured on one machine (benchmarks/bench_dispatch.py): with AVX512 and AVX2 off, 7 of the
synthetic head's 527k float32 coordinates moved by one step and every product downstream of
them differed; with OPENBLAS_CORETYPE=Haswell the fits, meshes and renders differed. A
difference in the last bit is far below every accuracy figure but changes the bytes, so
``dvc.lock`` would depend on the machine, and a RANSAC draw or a decimation order can turn
it into a visible one.

So a pipeline program pins all three before numpy is loaded: numpy's baseline (SSE3) loops,
OpenBLAS's Prescott kernels on one thread, and glibc's non-FMA libm (:data:`PINNED`). The
environment is read only when a process starts, so :func:`pin_process` sets it and starts the
program again in place (``os.execve``, same process id) when it differs; child processes (the
Blender workers, Dask workers) inherit it. ``python -m stages.<stage>`` and ``python -m
pipeline.<module>`` do this on their own (``pipeline/__init__.py``); importing the package from
other code changes nothing. Cost, measured on the 2-core machine: the whole chain took 95-106 CPU
seconds pinned (three runs) and 96 s on the CPU's own kernels; the render stage 19-22 s against
17 s, the other stages within run-to-run noise (the chain's BLAS work is small matrices).

``EYERIG_NATIVE_KERNELS=1`` opts out: the CPU's own kernels, faster on big BLAS work, with
bytes that may differ between machines. Other architectures run as they are (the names below
are x86-64's), and so do libraries with their own CPU dispatch (Embree's ray casts in bake,
Cycles and OpenImageDenoise in the previews and renders): see README, Guarantees.
"""

from __future__ import annotations

import os
import platform
import sys

__all__ = ["PINNED", "OPT_OUT", "applies", "pinned_env", "is_pinned", "pin_process"]

#: numpy 1.26's x86-64 dispatch targets above its SSE3 baseline (naming a feature the CPU
#: lacks is allowed; naming a baseline one is an import error, so none is listed).
_NUMPY_DISPATCH = ("SSSE3 SSE41 POPCNT SSE42 AVX F16C FMA3 AVX2 AVX512F AVX512CD AVX512_KNL AVX512_KNM "
                   "AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL")
#: glibc's libm chooses its FMA / FMA4 / AVX2 builds from these; glibc 2.33+ spells them plain,
#: 2.26-2.32 with ``_Usable`` (an unknown name is ignored)
_GLIBC_HWCAPS = "glibc.cpu.hwcaps=" + ",".join(
    f"-{f}{s}" for s in ("", "_Usable") for f in ("AVX", "AVX2", "FMA", "FMA4"))

#: environment variable -> the value every pipeline process runs with
PINNED = {
    "NPY_DISABLE_CPU_FEATURES": _NUMPY_DISPATCH,
    "OPENBLAS_CORETYPE": "Prescott",
    "OPENBLAS_NUM_THREADS": "1",
    "GLIBC_TUNABLES": _GLIBC_HWCAPS,
}
#: set to 1 to run on the CPU's own kernels
OPT_OUT = "EYERIG_NATIVE_KERNELS"


def applies(env=None) -> bool:
    """Whether the pin is used here: x86-64 POSIX, not opted out."""
    env = os.environ if env is None else env
    return (platform.machine().lower() in ("x86_64", "amd64") and os.name == "posix"
            and env.get(OPT_OUT, "") in ("", "0"))


def _tunables(current: str) -> str:
    """``GLIBC_TUNABLES`` with the hwcaps mask in place of any other hwcaps entry (other
    tunables kept)."""
    keep = [t for t in current.split(":") if t and not t.startswith("glibc.cpu.hwcaps=")]
    return ":".join(keep + [_GLIBC_HWCAPS])


def pinned_env(env=None) -> dict:
    """A copy of ``env`` (default: this process's) with :data:`PINNED` set."""
    out = dict(os.environ if env is None else env)
    out.update(PINNED)
    out["GLIBC_TUNABLES"] = _tunables((os.environ if env is None else env).get("GLIBC_TUNABLES", ""))
    return out


def is_pinned(env=None) -> bool:
    env = os.environ if env is None else env
    return all(env.get(k) == v for k, v in pinned_env(env).items() if k in PINNED)


def pin_process() -> None:
    """Make this program run on the pinned kernels: when :func:`applies` and the environment
    is not pinned yet, set it and start the same command line again in this process
    (``os.execve``; never returns then). Call it before numpy is imported, from an entry point."""
    if not applies() or is_pinned():
        return
    args = list(getattr(sys, "orig_argv", []) or [])
    if not args or not sys.executable:
        return
    env = pinned_env()
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, *args[1:]], env)
