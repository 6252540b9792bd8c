"""Print the environment that puts numpy, OpenBLAS and Dr.Jit on kernels other than the
ones they pick on this machine (docs/testing.md, "Another CPU at home").

``make test-other-cpu`` runs ``env $(python tests/other_cpu.py) pytest -m numerics``.
Each choice is one this CPU can run: numpy and OpenBLAS fall back to narrower kernels,
and Dr.Jit compiles for AVX2 with half the vector width it would use here.
"""

from __future__ import annotations

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


if __name__ == "__main__":
    print(" ".join(f"{k}={v.replace(' ', ',')}" for k, v in other_cpu().items()))
