"""On-disk cache of tabulated BRDFs, keyed by a content hash of their source.

The key is the content only: a caller that reads a file sets the name and path of the
BRDF it returns to those of the file it was asked for (a byte-identical copy is the same
entry, but keeps its own name).

Folder: ``$SPARSE_BRDF_CACHE`` if set, else ``$XDG_CACHE_HOME/sparse-brdf``, else
``~/.cache/sparse-brdf``. Entries are ``<sha256>.npz`` files written atomically (temporary
name, then rename), so concurrent runs that compute the same entry never see a partial
file; the last writer wins with identical content. Delete the folder to clear it.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..fileio import atomic_write

CACHE_VERSION = 1


def cache_dir() -> Path:
    """The cache folder (created on first write)."""
    if os.environ.get("SPARSE_BRDF_CACHE"):
        return Path(os.environ["SPARSE_BRDF_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sparse-brdf"


def content_key(*parts: bytes | str | dict | tuple | list) -> str:
    """sha256 over the given parts (bytes as-is, other values as canonical JSON)."""
    h = hashlib.sha256(f"v{CACHE_VERSION}".encode())
    for p in parts:
        h.update(p if isinstance(p, bytes) else json.dumps(p, sort_keys=True).encode())
        h.update(b"\0")
    return h.hexdigest()


def cached_brdf(key: str, compute: Callable[[], BRDF], enabled: bool = True) -> BRDF:
    """Return the cached BRDF for ``key``, computing and storing it on a miss.

    A corrupt entry (e.g. from a full disk) is recomputed and overwritten.
    """
    if not enabled or os.environ.get("SPARSE_BRDF_NO_CACHE"):
        return compute()
    path = cache_dir() / f"{key}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                return BRDF(values=z["values"], valid=z["valid"], name=str(z["name"]),
                            source=str(z["source"]))
        except (OSError, KeyError, ValueError, zipfile.BadZipFile):
            pass
    brdf = compute()
    try:
        with atomic_write(path) as f:
            np.savez(f, values=brdf.values, valid=brdf.valid, name=brdf.name, source=brdf.source)
    except OSError:
        pass  # a read-only or full cache folder only costs time
    return brdf
