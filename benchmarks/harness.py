"""The benchmarks' shared harness: common options, a machine-and-date header, JSON output.

A benchmark script in this folder builds its options with :func:`parser` (the script's
docstring as ``--help``, plus ``--json PATH``), prints :func:`header` above its table and,
when ``--json`` is given, writes its results with :func:`write_json`: the results under a
record of the machine (host, CPU, cores, load average, UTC date and time, commit), the
command line and the options, so that every figure keeps its provenance::

    from harness import header, parser, write_json

    def main() -> None:
        p = parser(__doc__)
        p.add_argument("--n", type=int, default=8, help="materials per corpus")
        args = p.parse_args()
        rows = ...                         # measure
        print(header())
        print(table(rows))
        if args.json:
            write_json(args.json, rows, args)

Scripts run as ``.venv/bin/python benchmarks/NAME.py`` (the folder is then on the import
path); a script no guide cites is removed (git keeps it; ``benchmarks/README.md``).
The machine is shared and its speed drifts: timings are only comparable within one run,
which is why the header names the load average beside the date.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from sparse_brdf.fileio import atomic_write

ROOT = Path(__file__).resolve().parents[1]


def parser(doc: str | None, *, json_option: bool = True) -> argparse.ArgumentParser:
    """An argument parser with the script's docstring as its help text.

    Parameters
    ----------
    doc : str or None
        The description shown by ``--help`` (the script's ``__doc__``), kept as written.
    json_option : bool
        Whether to add ``--json PATH`` (results as JSON, see :func:`write_json`).

    Returns
    -------
    argparse.ArgumentParser
        The parser; the script adds its own options.
    """
    p = argparse.ArgumentParser(description=doc,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    if json_option:
        p.add_argument("--json", type=Path, default=None, metavar="PATH",
                       help="also write the results here as JSON, under a record of the "
                            "machine, its load average, the date and the commit")
    return p


def _cpu() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else what the platform reports."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def _cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _commit() -> str:
    """The checkout's commit (``git describe --always --dirty``), or ``unknown``."""
    try:
        run = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty",
                              "--abbrev=10"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return run.stdout.strip() or "unknown"


def machine() -> dict[str, Any]:
    """Where and when a benchmark runs.

    Returns
    -------
    dict
        ``host``, ``cpu`` (model name), ``cores`` (usable by this process),
        ``load_average`` (1, 5 and 15 minutes, as ``uptime`` shows them), ``date`` (UTC,
        ``YYYY-MM-DD HH:MM UTC``), ``commit`` (``git describe --always --dirty``) and
        ``python`` (version).
    """
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not available on this platform
        load = [float("nan")] * 3
    return {"host": platform.node(), "cpu": _cpu(), "cores": _cores(), "load_average": load,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": _commit(),
            "python": platform.python_version()}


def header(info: dict[str, Any] | None = None) -> str:
    """One line naming the machine, its load, the date and the commit.

    Parameters
    ----------
    info : dict, optional
        A record from :func:`machine`; by default, taken now.

    Returns
    -------
    str
        e.g. ``host, CPU model, 2 cores, load average 1.90 / 2.05 / 2.10 (1 / 5 / 15 min),
        2026-12-02 07:40 UTC, commit 6bac7a3f1e``.
    """
    m = machine() if info is None else info
    one, five, fifteen = m["load_average"]
    return (f"{m['host']}, {m['cpu']}, {m['cores']} cores, load average {one:.2f} / "
            f"{five:.2f} / {fifteen:.2f} (1 / 5 / 15 min), {m['date']}, "
            f"commit {m['commit']}")


def _plain(value: Any) -> Any:
    """An option's value as JSON can hold it (paths as strings)."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def write_json(path: str | os.PathLike, results: Any,
               args: argparse.Namespace | None = None,
               info: dict[str, Any] | None = None) -> Path:
    """Write ``results`` as JSON with their provenance, atomically.

    Parameters
    ----------
    path : str or path-like
        The file to write (its folder is created).
    results : JSON-serialisable
        The benchmark's numbers (rows, a dict, ...), written under ``"results"``.
    args : argparse.Namespace, optional
        The parsed options, written under ``"args"``.
    info : dict, optional
        A record from :func:`machine` (e.g. taken when the timing started); by default,
        taken now.

    Returns
    -------
    pathlib.Path
        The file written. Its keys: ``machine``, ``command`` (the command line),
        ``args`` and ``results``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"machine": machine() if info is None else info,
              "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
              "args": {k: _plain(v) for k, v in vars(args).items()} if args else {},
              "results": results}
    with atomic_write(path, "w") as f:
        json.dump(record, f, indent=1)
        f.write("\n")
    return path
