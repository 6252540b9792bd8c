"""Choosing and checking Mitsuba variants (``docs/method.md``, "Rendering with Mitsuba").

Mitsuba and Dr.Jit are imported inside the functions, so that importing this module (and
``sparse_brdf``) stays fast.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from .errors import MitsubaSetupError

#: The CPU vectorised variant the project renders with.
DEFAULT_VARIANT = "llvm_ad_rgb"
_MIN_LLVM = 16


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


def set_variant(variant: str = DEFAULT_VARIANT) -> str:
    """Set the Mitsuba variant (checking LLVM for llvm_* variants) and return its name."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    if variant.startswith("llvm"):
        mi.set_variant(variant)
        check_llvm()
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
