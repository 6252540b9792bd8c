"""Choosing and checking Mitsuba variants (``docs/method.md``, "Rendering with Mitsuba"),
and reading a scene file as Mitsuba reads it (its ``<include>`` elements resolved).

Mitsuba and Dr.Jit are imported inside the functions, so that importing this module (and
``sparse_brdf``) stays fast.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Iterator

from .errors import MitsubaSetupError
from .params import check_choice

#: The CPU vectorised variant the project renders with.
DEFAULT_VARIANT = "llvm_ad_rgb"
#: The variants of Mitsuba 3.9's wheel that run on the CPU (every one tested, also from
#: the command line, ``render --variant``), and those that need an NVIDIA GPU (untested).
CPU_VARIANTS: tuple[str, ...] = (
    "scalar_rgb", "scalar_spectral", "scalar_spectral_polarized", "llvm_ad_rgb",
    "llvm_ad_mono", "llvm_ad_mono_polarized", "llvm_ad_spectral",
    "llvm_ad_spectral_polarized")
CUDA_VARIANTS: tuple[str, ...] = tuple(v.replace("llvm", "cuda") for v in CPU_VARIANTS
                                       if v.startswith("llvm"))
#: Every variant a render may ask for.
VARIANTS: tuple[str, ...] = CPU_VARIANTS + CUDA_VARIANTS
_MIN_LLVM = 16

#: The environment variable that makes Dr.Jit's LLVM backend compile for another CPU
#: (:func:`set_llvm_target`): a name of :data:`LLVM_TARGETS` or ``CPU:FEATURES:WIDTH``.
LLVM_TARGET_ENV = "SPARSE_BRDF_LLVM_TARGET"

#: The vector widths Dr.Jit's LLVM backend compiles for (float32 lanes), as written.
LLVM_WIDTHS: tuple[str, ...] = ("4", "8", "16")

_X86_V3 = "+sse4.1,+sse4.2,+ssse3,+popcnt,+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+movbe"
#: Named CPUs for :func:`set_llvm_target`: (LLVM CPU name, LLVM target features, vector
#: width in float32 lanes). ``haswell``: an AVX2 machine, 8 lanes; ``skylake-avx512``:
#: an Intel Xeon with AVX-512, 16 lanes.
LLVM_TARGETS: dict[str, tuple[str, str, int]] = {
    "haswell": ("haswell", _X86_V3, 8),
    "skylake-avx512": ("skylake-avx512",
                       _X86_V3 + ",+avx512f,+avx512dq,+avx512cd,+avx512bw,+avx512vl", 16),
}


def check_llvm() -> tuple[int, ...]:
    """Return Dr.Jit's LLVM version, raising a clear error if LLVM is absent or too old.

    With Debian's stock libLLVM 15 the first render aborts the process ("Cannot select
    ... fminimum"), which Python cannot catch; so refuse before that happens.
    """
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)

    try:
        version = tuple(dr.detail.llvm_version())
    except Exception as exc:  # noqa: BLE001 - drjit raises plain RuntimeError here
        raise MitsubaSetupError(
            "Dr.Jit found no LLVM library: install Debian's libllvm19 "
            "(`apt-get install libllvm19`, done by `make setup`)"
        ) from exc
    if version[0] < _MIN_LLVM:
        raise MitsubaSetupError(
            f"Dr.Jit loaded LLVM {'.'.join(map(str, version))}, too old for Mitsuba's LLVM "
            "variant (renders abort with 'Cannot select ... fminimum'): install Debian's "
            "libllvm19 (`apt-get install libllvm19`, done by `make setup`)"
        )
    return version


def _drjit_core() -> ctypes.CDLL:
    """Dr.Jit's core library, already loaded by ``import drjit``."""
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)

    return ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))


def _core_function(name: str, mangled: str, restype, argtypes=()):
    """A C++ function of Dr.Jit's core library, which its Python module does not expose."""
    fn = getattr(_drjit_core(), mangled, None)
    if fn is None:
        raise MitsubaSetupError(f"${LLVM_TARGET_ENV}: this Dr.Jit's core library has no "
                                f"{name}(); unset the variable")
    fn.restype, fn.argtypes = restype, list(argtypes)
    return fn


def llvm_target() -> tuple[str, int]:
    """The CPU Dr.Jit's LLVM backend compiles for: (LLVM CPU name, vector width in
    float32 lanes), e.g. ("znver4", 16)."""
    cpu = _core_function("jit_llvm_target_cpu", "_Z19jit_llvm_target_cpuv", ctypes.c_char_p)
    width = _core_function("jit_llvm_vector_width", "_Z21jit_llvm_vector_widthv",
                           ctypes.c_uint32)
    return cpu().decode(), int(width())


def set_llvm_target(spec: str) -> tuple[str, int]:
    """Make Dr.Jit's LLVM backend compile for another CPU than this one.

    Kernels compiled afterwards use that CPU's instructions and vector width, so they
    round as that CPU's would (a render on an AVX2 machine, say, imitated on an AVX-512
    one). The CPU must be one this machine can run: an older or narrower one.

    Parameters
    ----------
    spec : str
        A name of :data:`LLVM_TARGETS`, or ``CPU:FEATURES:WIDTH`` in LLVM's terms (e.g.
        ``"haswell:+avx2,+fma:8"``).

    Returns
    -------
    tuple
        :func:`llvm_target` after the change.

    Raises
    ------
    UsageError
        For a spec that is neither, or a width other than 4, 8 or 16.
    """
    parts = LLVM_TARGETS.get(spec) or tuple(spec.split(":"))
    if len(parts) != 3:
        check_choice(f"${LLVM_TARGET_ENV}", spec, tuple(LLVM_TARGETS) + ("CPU:FEATURES:WIDTH",))
    check_choice(f"${LLVM_TARGET_ENV} vector width", str(parts[2]), LLVM_WIDTHS)
    cpu, features, width = parts
    if llvm_target() == (cpu, int(width)):
        return llvm_target()  # already: setting it again would drop compiled kernels
    set_target = _core_function("jit_llvm_set_target", "_Z19jit_llvm_set_targetPKcS0_j",
                                None, (ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32))
    set_target(cpu.encode(), features.encode(), int(width))
    return llvm_target()


def set_variant(variant: str = DEFAULT_VARIANT) -> str:
    """Set the Mitsuba variant (one of :data:`VARIANTS`; checking LLVM for llvm_*
    variants) and return its name.

    For an llvm_* variant, ``$SPARSE_BRDF_LLVM_TARGET`` (when set) chooses the CPU its
    kernels are compiled for (:func:`set_llvm_target`).
    """
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    check_choice("variant", variant, VARIANTS)
    if variant not in mi.variants():
        raise MitsubaSetupError(f"variant {variant}: not in this Mitsuba build (it has "
                                f"{', '.join(mi.variants())})")
    if variant.startswith("llvm"):
        mi.set_variant(variant)
        check_llvm()
        if os.environ.get(LLVM_TARGET_ENV):
            set_llvm_target(os.environ[LLVM_TARGET_ENV])
    else:
        mi.set_variant(variant)
    return variant


@contextlib.contextmanager
def variant(name: str = DEFAULT_VARIANT) -> Iterator[str]:
    """Temporarily switch to ``name``, restoring the previous variant afterwards."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    before = mi.variant()
    set_variant(name)
    try:
        yield name
    finally:
        if before is not None and before != name:
            mi.set_variant(before)
