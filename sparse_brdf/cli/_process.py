"""A command's process settings: numpy's huge-page requests off and glibc's malloc keeping
freed memory (docs/benchmarks.md, "Whole commands after cutting fixed costs"). Only the
command line applies them: a program that imports the library keeps its own."""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Mapping

import numpy as np


def no_madvised_hugepages() -> None:
    """Stop numpy asking the kernel for transparent huge pages for its large arrays, unless
    ``NUMPY_MADVISE_HUGEPAGE`` says otherwise (numpy's own switch, read at its import).

    A command is a short process whose large arrays are all freshly mapped memory; where
    the kernel compacts memory to serve huge pages on request (``defrag`` of ``madvise``,
    a common default) those first touches stall. On the 2-core benchmark machine this
    made a whole ``encode`` 2-8 % slower (docs/benchmarks.md, "Whole commands after
    cutting fixed costs"). Only the
    command line does this: a program that imports the library keeps numpy's setting."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return
    setter = getattr(getattr(np, "_core", None), "multiarray", None)
    setter = getattr(setter, "_set_madvise_hugepage", None)
    if setter is not None:
        setter(False)


#: glibc ``mallopt`` settings of a command: (parameter number, value, the environment
#: variables that set it instead). Freed arrays below 32 MB stay in the heap, and the heap
#: is not returned to the system below 1 GB of free space at its top, so a command's
#: large arrays reuse memory already touched instead of mapping fresh pages each time.
MALLOC_SETTINGS = ((-3, 32 << 20, "MALLOC_MMAP_THRESHOLD_"),  # M_MMAP_THRESHOLD
                   (-1, 1 << 30, "MALLOC_TRIM_THRESHOLD_"))   # M_TRIM_THRESHOLD


def malloc_settings(environ: Mapping[str, str]) -> list[tuple[int, int]]:
    """The :data:`MALLOC_SETTINGS` to apply: none where the user tunes glibc's malloc
    (``GLIBC_TUNABLES`` naming ``glibc.malloc``), else each one its own variable does not
    set."""
    if "glibc.malloc" in environ.get("GLIBC_TUNABLES", ""):
        return []
    return [(param, value) for param, value, var in MALLOC_SETTINGS if var not in environ]


def keep_freed_memory() -> None:
    """Apply :func:`malloc_settings` through glibc's ``mallopt`` (Linux with glibc; a
    no-op elsewhere). On the 2-core benchmark machine this made a whole ``encode`` 4-7 %
    faster (docs/benchmarks.md, "Whole commands after cutting fixed costs")."""
    if not sys.platform.startswith("linux"):
        return
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    for param, value in malloc_settings(os.environ):
        mallopt(ctypes.c_int(param), ctypes.c_int(value))
