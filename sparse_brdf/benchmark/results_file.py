"""A bench's ``results.json``: its schema's version, and reading one back with checks.

The schema is documented in ``docs/bench-guide.md`` ("results.json"); :data:`SCHEMA`
names its version and changes whenever a field changes meaning or goes. The file is
strict JSON (:func:`~sparse_brdf.fileio.strict_json`: non-finite numbers as null). A bench resumes
only results of its own schema, config and provenance; :func:`read_results` is how any
other reader (``sparse-brdf bench-merge``) gets one, checked.
"""

from __future__ import annotations

import json
import os
import platform
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

from ..errors import ConfigError
from ..fileio import parse_strict_json, require_file

__all__ = ["PROTOCOL_SETTINGS", "READ_SCHEMAS", "SCHEMA", "SPEED_SETTINGS", "environment",
           "package_version", "read_results"]

#: The version of the results.json schema written (docs/bench-guide.md). Version 2 is
#: strict JSON: a non-finite number is written null and listed in ``non_finite``.
SCHEMA = "sparse-brdf-bench/2"
#: The versions read: version 1 wrote non-finite numbers as ``Infinity``/``NaN``.
READ_SCHEMAS = ("sparse-brdf-bench/1", SCHEMA)
#: The config settings that fix what a result measures: two results files are comparable
#: (``bench-merge``) only when these agree.
PROTOCOL_SETTINGS = ("corpora", "split", "max_materials", "scenes", "spp", "res", "seed")
#: The config settings of the speed measurement: evaluations per second of two results
#: files are compared (``bench-merge``) only when these agree.
SPEED_SETTINGS = ("speed", "speed_evals")
#: The top-level keys every results file of :data:`SCHEMA` holds.
_REQUIRED = ("schema", "config", "provenance", "cells", "noise_floor", "speed")
#: Largest results file read (a full bench's is a few MB).
_MAX_BYTES = 1 << 30


def package_version() -> str:
    """The installed package's version ("unknown" when run from an uninstalled tree)."""
    try:
        return metadata.version("sparse-brdf")
    except metadata.PackageNotFoundError:
        return "unknown"


def environment() -> dict:
    """Where and when results were computed: ``platform``, ``machine`` (the CPU
    architecture), ``cpus``, ``python``, ``sparse_brdf`` (the package's version) and
    ``date`` (UTC, ISO 8601)."""
    return {"platform": platform.platform(), "machine": platform.machine(),
            "cpus": os.cpu_count(), "python": platform.python_version(),
            "sparse_brdf": package_version(),
            "date": datetime.now(UTC).isoformat(timespec="seconds")}


def read_results(path: str | os.PathLike) -> dict:
    """A bench's results: ``path`` is a ``results.json`` or the bench's output folder.

    Raises
    ------
    MissingFileError
        No such file (nor ``results.json`` in the folder).
    ConfigError
        Not JSON, not a bench's results, or of another schema version; one line naming
        the file.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "results.json"
    p = require_file(p, "bench results file")
    if p.stat().st_size > _MAX_BYTES:
        raise ConfigError(f"{p}: {p.stat().st_size} bytes: too large for a bench results file")
    try:
        data = parse_strict_json(p.read_bytes().decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not a JSON file: {exc}") from None
    if not isinstance(data, dict) or "cells" not in data or "config" not in data:
        raise ConfigError(f"{p}: not a sparse-brdf bench results file (no cells, no config)")
    if data.get("schema") not in READ_SCHEMAS:
        raise ConfigError(f"{p}: results of schema {data.get('schema', 'before versioning')!r}"
                          f"; this version reads {' and '.join(map(repr, READ_SCHEMAS))} "
                          "(rerun the bench to rewrite it)")
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise ConfigError(f"{p}: a bench results file without {', '.join(missing)}")
    return data
