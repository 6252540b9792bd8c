"""Two bench results compared cell by cell: the regression gate of
``sparse-brdf bench-compare OLD NEW --fail-if-worse DB [--fail-if-flip-rises X]``.

Every cell (material, model) finished in OLD and present in NEW is compared, in every
scene both rendered: each rendering-SNR form (object-only and whole-image, dB) and
HDR-FLIP; without renders, the cosine-weighted SNR. A figure is worse when an SNR drops
by more than ``worse_db`` dB (a render identical to the reference, infinite SNR, that is
no longer identical drops by an infinite amount), when HDR-FLIP rises by more than
``flip_rise``, or when the cell failed in NEW. Results of different protocols
(:data:`~sparse_brdf.benchmark.results_file.PROTOCOL_SETTINGS`) are refused.
"""

from __future__ import annotations

import math
import os

from ..errors import ConfigError
from ..params import Interval, check
from .results_file import PROTOCOL_SETTINGS, read_results

__all__ = ["PARAMETERS", "compare_results", "format_worse", "quality_of"]

#: The gate's tolerances: an SNR drop in dB, an HDR-FLIP rise (FLIP is from 0 to 1).
PARAMETERS = {"worse_db": Interval(float, 0), "flip_rise": Interval(float, 0, 1)}
#: The SNR forms compared in each rendered scene.
_SNR_FORMS = ("snr_object", "snr_whole")


def _value(x) -> float:
    """A recorded figure as a float; nan where none was recorded (None)."""
    return math.nan if x is None else float(x)


def _drop(old: float, new: float) -> float:
    """How far an SNR fell from ``old`` to ``new`` (dB): 0 when both are infinite, infinite
    when a figure was recorded before and is lost now."""
    if old == new:
        return 0.0
    if math.isnan(old):
        return 0.0  # nothing to fall from
    return math.inf if math.isnan(new) else old - new


def _figures(old: dict, new: dict) -> list[tuple[str, str, float, float]]:
    """(scene, figure, old, new) of a cell finished in both: each scene both rendered,
    else the cosine-weighted SNR."""
    ro, rn = old.get("renders") or {}, new.get("renders") or {}
    scenes = sorted(ro.keys() & rn.keys())
    if not scenes:
        return [("", "cos_snr", _value(old.get("cos_snr")), _value(new.get("cos_snr")))]
    return [(s, f, _value(ro[s].get(f)), _value(rn[s].get(f)))
            for s in scenes for f in (*_SNR_FORMS, "flip")]


def _check_protocol(old: dict, new: dict, names: tuple[str, str]) -> None:
    for key in PROTOCOL_SETTINGS:
        a, b = old["config"].get(key), new["config"].get(key)
        if a != b:
            raise ConfigError(f"{names[1]}: measured with {key} = {b!r}, {names[0]} with "
                              f"{a!r}: results of different protocols are not compared")


def compare_results(old: str | os.PathLike, new: str | os.PathLike, worse_db: float,
                    flip_rise: float | None = None) -> dict:
    """Compare two bench results cell by cell (see the module doc).

    Parameters
    ----------
    old, new : path
        ``results.json`` files or bench output folders; ``old`` is the baseline.
    worse_db : float
        Largest SNR drop (dB, >= 0) that does not count as worse.
    flip_rise : float, optional
        Largest HDR-FLIP rise (0 to 1) that does not count as worse; None: FLIP is not
        gated.

    Returns
    -------
    dict
        ``cells`` (how many were compared), ``figures`` (how many figures) and ``worse``:
        one dict per worse figure (``cell``, ``scene``, ``figure``, ``old``, ``new``), by
        cell then scene.

    Raises
    ------
    MissingFileError, ConfigError
        A file that does not exist, is not a bench's results, or of another protocol;
        results that share no finished cell.
    UsageError
        A tolerance out of its range.
    """
    check("--fail-if-worse", worse_db, PARAMETERS["worse_db"])
    if flip_rise is not None:
        check("--fail-if-flip-rises", flip_rise, PARAMETERS["flip_rise"])
    a, b = read_results(old), read_results(new)
    _check_protocol(a, b, (str(old), str(new)))
    shared = [k for k in sorted(a["cells"].keys() & b["cells"].keys())
              if a["cells"][k].get("status") == "finished"]
    if not shared:
        raise ConfigError(f"{new}: no cell finished in {old} is in it: nothing to compare")
    worse, n = [], 0
    for key in shared:
        co, cn = a["cells"][key], b["cells"][key]
        if cn.get("status") != "finished":
            worse.append({"cell": key, "scene": "", "figure": "status", "old": "finished",
                          "new": f"failed: {cn.get('error', 'no error recorded')}"})
            continue
        for scene, figure, vo, vn in _figures(co, cn):
            n += 1
            if figure == "flip":
                bad = flip_rise is not None and not math.isnan(vo) and (
                    math.isnan(vn) or vn - vo > flip_rise)
            else:
                bad = _drop(vo, vn) > worse_db
            if bad:
                worse.append({"cell": key, "scene": scene, "figure": figure, "old": vo,
                              "new": vn})
    return {"cells": len(shared), "figures": n, "worse": worse}


def quality_of(results: dict) -> dict:
    """``results`` cut down to what :func:`compare_results` reads (schema, run, config,
    provenance; each cell's status, cos-SNR and per-scene SNRs and HDR-FLIP): a small
    baseline to commit (``tests/data/ci_bench_baseline.json``); write it with
    :func:`~sparse_brdf.fileio.strict_json`."""
    keep = ("material", "model", "status", "error", "cos_snr")
    cells = {k: {**{f: c[f] for f in keep if f in c},
                 **({"renders": {s: {f: r.get(f) for f in (*_SNR_FORMS, "flip")}
                                 for s, r in c["renders"].items()}} if c.get("renders") else {})}
             for k, c in results["cells"].items()}
    return {**{k: results[k] for k in ("schema", "run", "config", "provenance")},
            "cells": cells, "noise_floor": {}, "speed": {}}


def format_worse(row: dict) -> str:
    """One worse figure as a line: the cell, the scene, the figure, old -> new and the
    change."""
    where = f"{row['cell']}" + (f" in {row['scene']}" if row["scene"] else "")
    if row["figure"] == "status":
        return f"{where}: {row['old']} -> {row['new']}"
    unit = "" if row["figure"] == "flip" else " dB"
    change = row["new"] - row["old"]
    fmt = ".4f" if row["figure"] == "flip" else ".2f"
    return (f"{where}: {row['figure']} {row['old']:{fmt}} -> {row['new']:{fmt}}{unit} "
            f"({change:+{fmt}}{unit})")
