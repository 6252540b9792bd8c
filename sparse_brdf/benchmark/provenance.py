"""What a bench cell's result depends on, recorded with it so that a rerun recomputes
exactly the cells whose inputs changed.

Each finished cell of ``results.json`` holds a ``provenance``
(:func:`cell_provenance`): the model's spec and options, its source (for a
``module:Class`` model, the SHA-256 of the module's file; for a built-in model, the
package's version and, in a git checkout, its commit), the Mitsuba and Dr.Jit versions
and the machine (:func:`environment_provenance`). A resumed bench keeps a finished cell
only when its recorded provenance equals the current one (:func:`stale_cells`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from ..compared.specs import parse_spec
from .results_file import package_version

__all__ = ["cell_provenance", "environment_provenance", "git_commit", "machine",
           "source_hash", "stale_cells"]

#: The package's folder and the folder above it (a checkout's root when run from one).
_PACKAGE_DIR = Path(__file__).resolve().parents[1]


def _version(dist: str) -> str:
    """An installed distribution's version, ``"unknown"`` if it is not installed."""
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def machine() -> str:
    """The machine as results name it: its architecture and CPU model (from
    ``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f
                        if line.startswith("model name")), cpu)
    except OSError:
        pass
    return f"{platform.machine()} {cpu}".strip()


@functools.cache
def git_commit() -> str | None:
    """The commit of the git checkout the package runs from; None outside a checkout of
    this package (an installed wheel, no git, a package inside another project's
    repository). Edits not committed do not change it."""
    root = _PACKAGE_DIR.parent

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True,
                              text=True, timeout=10, check=True).stdout.strip()

    try:
        if Path(git("rev-parse", "--show-toplevel")).resolve() != root:
            return None
        return git("rev-parse", "HEAD")
    except (OSError, subprocess.SubprocessError):
        return None


def source_hash(path: str | Path) -> str | None:
    """SHA-256 of a file's bytes (hex); None if it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def environment_provenance() -> dict:
    """The renderer's versions (``mitsuba``, ``drjit``) and the ``machine``."""
    return {"mitsuba": _version("mitsuba"), "drjit": _version("drjit"), "machine": machine()}


def _model_source(spec) -> dict:
    """The source of a parsed spec's model: its module file's name and hash (an outside
    model) or the package's version and commit (a built-in one)."""
    if spec.kind != "outside":
        return {"sparse_brdf": package_version(), "commit": git_commit()}
    module = sys.modules.get(spec.kwargs["module"])
    file = getattr(module, "__file__", None)
    return {"module": spec.kwargs["module"], "file": Path(file).name if file else None,
            "sha256": source_hash(file) if file else None}


def cell_provenance(spec: str) -> dict:
    """The provenance of every cell of the model built from ``spec`` (call it after the
    model is built, so that an outside model's module is imported): ``model`` (the spec),
    ``options`` (the constructor's keyword arguments), ``source`` and the environment
    (:func:`environment_provenance`); as JSON gives it back, so that it compares equal to
    a recorded one."""
    s = parse_spec(spec)
    options = s.kwargs["options"] if s.kind == "outside" else s.kwargs
    prov = {"model": spec, "options": options, "source": _model_source(s),
            **environment_provenance()}
    return json.loads(json.dumps(prov, sort_keys=True, default=repr))


def stale_cells(cells: dict, provenance: dict[str, dict]) -> tuple[list[str], int]:
    """Which recorded cells a resumed bench drops, and how many finished ones it keeps.

    Parameters
    ----------
    cells : dict
        ``results["cells"]``: ``"material|model"`` -> the cell's record.
    provenance : dict
        Model name -> its current :func:`cell_provenance`, for every configured model.

    Returns
    -------
    stale : list of str
        Keys of the cells to drop: of a model no longer configured, or finished with
        another provenance (or none recorded). Failed cells are not listed: they run
        again anyway.
    kept : int
        Finished cells whose provenance is unchanged.
    """
    stale, kept = [], 0
    for key, cell in cells.items():
        current = provenance.get(cell.get("model"))
        if current is None:
            stale.append(key)
        elif cell.get("status") == "finished":
            if cell.get("provenance") == current:
                kept += 1
            else:
                stale.append(key)
    return stale, kept
