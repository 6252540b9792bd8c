"""Print the environment that puts numpy, OpenBLAS and Dr.Jit on kernels other than the
ones they pick on this machine (docs/testing.md, "Another CPU at home").

``make test-other-cpu`` runs ``env $(python tests/other_cpu.py) pytest -m numerics``.
Each choice is one this CPU can run: numpy and OpenBLAS fall back to narrower kernels,
and Dr.Jit compiles for AVX2 with half the vector width it would use here.

``python tests/other_cpu.py --pinned`` prints the opposite: the kernels every x86-64 CPU
with AVX2 and FMA runs alike (:func:`pinned_cpu`), under which the CI-sized bench's
stored figures are computed and checked (docs/bench-guide.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

from threadpoolctl import threadpool_info

from sparse_brdf.mitsuba_env import LLVM_TARGETS, llvm_target, set_variant


def cpu_flags() -> set[str]:
    """The flags of this machine's first CPU (Linux's /proc/cpuinfo; empty elsewhere)."""
    path = Path("/proc/cpuinfo")
    for line in path.read_text().splitlines() if path.exists() else ():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def other_cpu() -> dict[str, str]:
    """The environment variables, {name: value}."""
    flags = cpu_flags()
    env = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}  # numpy: AVX2 at most
    native = {i.get("architecture") for i in threadpool_info()
              if i.get("internal_api") == "openblas"}
    if native:  # an Intel Xeon's kernels where this CPU runs them and does not pick them
        env["OPENBLAS_CORETYPE"] = ("SkylakeX" if "avx512f" in flags and "SkylakeX" not in
                                    native else "Sandybridge")
    if {"avx2", "fma"} <= flags:
        set_variant("llvm_ad_rgb")
        cpu, features, _ = LLVM_TARGETS["haswell"]
        width = 8 if llvm_target()[1] == 16 else 4
        env["SPARSE_BRDF_LLVM_TARGET"] = f"{cpu}:{features}:{width}"
    return env


def pinned_cpu() -> dict[str, str] | None:
    """The environment variables, {name: value}, that give every x86-64 CPU with AVX2 and
    FMA the same kernels, so the same rounding: numpy's AVX2 kernels at most, OpenBLAS's
    Haswell kernels, Dr.Jit compiled for Haswell at 8 lanes. None on a CPU without them
    (another architecture, or an x86-64 CPU older than Haswell)."""
    if not {"avx2", "fma"} <= cpu_flags():
        return None
    cpu, features, width = LLVM_TARGETS["haswell"]
    return {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
            "OPENBLAS_CORETYPE": "Haswell",
            "SPARSE_BRDF_LLVM_TARGET": f"{cpu}:{features}:{width}"}


def as_env_words(env: dict[str, str]) -> str:
    """``env`` as ``NAME=VALUE`` words for ``env $(...)`` (spaces in values as commas,
    which numpy and the LLVM target both read)."""
    return " ".join(f"{k}={v.replace(' ', ',')}" for k, v in env.items())


if __name__ == "__main__":
    if sys.argv[1:] == ["--pinned"]:
        pinned = pinned_cpu()
        if pinned is None:
            sys.exit("other_cpu.py: this CPU has no AVX2 and FMA: no kernels to pin")
        print(as_env_words(pinned))
    else:
        print(as_env_words(other_cpu()))
