"""Several benches' results in one ranked table (``sparse-brdf bench-merge``).

Results from different machines, runs and models (e.g. the shipped models' ``standard``
run and a user's own model run with ``--model``) are set side by side when they measured
the same protocol: the config settings of
:data:`~sparse_brdf.benchmark.results_file.PROTOCOL_SETTINGS` agree. Each model is one
row: its mean over its finished cells of each scene's object-only and whole-image SNR
and HDR-FLIP, and the mean over the scenes; its bytes per material and evaluations per
second (as measured on the machine its file names). Rows are ranked by one of
:data:`RANK_BY`, over the materials that every ranked model finished: a model that did
not finish every material of the protocol is listed apart, unranked, with its count of
finished materials. The same run given twice is refused, and so are runs whose speeds
were measured differently (:data:`~sparse_brdf.benchmark.results_file.SPEED_SETTINGS`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..fileio import atomic_write
from ..params import check_choice
from .report import nan_last, scenes_of
from .results_file import PROTOCOL_SETTINGS, SPEED_SETTINGS, read_results

__all__ = ["RANK_BY", "merge_results", "ranking_csv", "ranking_markdown", "write_ranking"]

#: What rows can be ranked by, and whether higher is better.
RANK_BY = {"snr_object": True, "snr_whole": True, "flip": False}
_LABELS = {"snr_object": "object-only SNR (dB)", "snr_whole": "whole-image SNR (dB)",
           "flip": "HDR-FLIP"}


def _mean(xs) -> float:
    f = [float(x) for x in xs if x is not None and math.isfinite(float(x))]
    if xs and not f and all(x is not None and float(x) == math.inf for x in xs):
        return math.inf  # identical to the reference in every cell
    return float(np.mean(f)) if f else math.nan


def _check_same_protocol(runs: list[tuple[str, dict]]) -> None:
    """:class:`ConfigError` naming the first setting where two results files differ: a
    protocol setting, or a speed setting between two files that both measured speeds."""
    first, base = runs[0]
    for name, data in runs[1:]:
        timed = base["config"].get("speed", True) and data["config"].get("speed", True)
        for key in PROTOCOL_SETTINGS + SPEED_SETTINGS[:1 + bool(timed)]:
            a, b = base["config"].get(key), data["config"].get(key)
            if a != b:
                what = ("speeds measured", "evaluations per second") \
                    if key in SPEED_SETTINGS else ("measured", "results")
                raise ConfigError(f"{name}: {what[0]} with {key} = {b!r}, {first} with "
                                  f"{a!r}: {what[1]} of different protocols are not ranked "
                                  "together")


def _check_distinct_runs(paths: list, runs: list[tuple[str, dict]]) -> None:
    """:class:`ConfigError` when one results file, or one run, is given twice: its models
    would be listed twice."""
    seen: dict = {}
    for p, (name, data) in zip(paths, runs, strict=True):
        q = Path(p)
        q = (q / "results.json" if q.is_dir() else q).resolve()
        ids = [("file", q)]
        if data.get("run"):
            ids.append(("run", data["run"]))
        if data["cells"]:
            ids.append(("cells", json.dumps(data["cells"], sort_keys=True)))
        for i in ids:
            if i in seen:
                what = "the same results file" if i[0] == "file" else "the same run"
                raise ConfigError(f"{name}: {what} as {seen[i]}: give each run once")
            seen[i] = name


def _rows_of(label: str, data: dict, scenes: list[str]) -> list[dict]:
    """One row per model of one results file; ``finished``: the materials it finished."""
    by_model: dict[str, list[dict]] = {}
    for cell in data["cells"].values():
        by_model.setdefault(cell["model"], []).append(cell)
    env = data.get("environment") or {}
    rows = []
    for model, cells in by_model.items():
        ok = [c for c in cells if c.get("status") == "finished"]
        speed = data["speed"].get(model) if ok else None
        row = {"model": model, "source": label, "machine": env.get("platform", ""),
               "finished": {c["material"] for c in ok},
               "materials": len(ok), "failed": len(cells) - len(ok),
               "bytes": _mean([c["bytes"] for c in ok]),
               "evals_per_s": math.nan if speed is None else float(speed)}
        for key in RANK_BY:
            per_scene = []
            for scene in scenes:
                v = _mean([(c.get("renders") or {}).get(scene, {}).get(key) for c in ok])
                row[f"{key}@{scene}"] = v
                per_scene.append(v)
            row[key] = _mean(per_scene)
        rows.append(row)
    return rows


def merge_results(paths: list[str | os.PathLike], by: str = "snr_object") -> dict:
    """Read several results files and rank every model in them.

    Parameters
    ----------
    paths : list of path
        ``results.json`` files or bench output folders, at least one.
    by : {"snr_object", "snr_whole", "flip"}
        The mean over the scenes that ranks the rows (higher SNR, lower FLIP first).

    Returns
    -------
    dict
        ``rows`` (ranked, each with ``rank``: the models that finished every material
        of ``materials``), ``unranked`` (the others, each with ``materials``, its count
        of finished materials, and ``failed``), ``materials`` (every material any file
        holds a cell of, sorted), ``scenes`` (every scene of the protocol), ``by``,
        ``protocol`` (the settings shared) and ``sources``.

    Raises
    ------
    ConfigError
        A file that is not a bench's results, results of different protocols or speed
        settings, or one file or run given twice.
    """
    check_choice("ranking", by, tuple(RANK_BY))
    if not paths:
        raise ConfigError("give at least one results file")
    runs = [(str(p), read_results(p)) for p in paths]
    _check_distinct_runs(paths, runs)
    _check_same_protocol(runs)
    scenes = list(dict.fromkeys(s for _, d in runs for s in scenes_of(d)))
    materials = sorted({c["material"] for _, d in runs for c in d["cells"].values()})
    rows = [r for name, d in runs for r in _rows_of(name, d, scenes)]
    ranked = [r for r in rows if r["finished"] >= set(materials)]
    unranked = sorted((r for r in rows if r not in ranked),
                      key=lambda r: (-r["materials"], r["model"], r["source"]))
    ranked.sort(key=lambda r: nan_last(r[by], RANK_BY[by]))
    for i, r in enumerate(ranked, 1):
        r["rank"] = i
    for r in rows:
        del r["finished"]
    protocol = {k: runs[0][1]["config"].get(k) for k in PROTOCOL_SETTINGS}
    return {"rows": ranked, "unranked": unranked, "materials": materials, "scenes": scenes,
            "by": by, "protocol": protocol, "sources": [name for name, _ in runs]}


def _fmt(x, fmt: str) -> str:
    if isinstance(x, str):
        return x
    return "-" if x is None or math.isnan(x) else format(x, fmt)


_FORMATS = {"snr_object": ".1f", "snr_whole": ".1f", "flip": ".3f"}


def ranking_markdown(merged: dict) -> str:
    """The ranked table as Markdown: rank, model, source, bytes, evals/s, the means over
    the scenes, then each scene's three figures."""
    p = merged["protocol"]
    head = ["rank", "model", "source", "materials", "failed", "bytes", "evals/s",
            *(f"mean {_LABELS[k]}" for k in RANK_BY),
            *(f"{k} @{s}" for s in merged["scenes"] for k in RANK_BY)]
    lines = [f"# Ranked by mean {_LABELS[merged['by']]} over the scenes", "",
             f"Protocol: corpora {', '.join(p['corpora'])} ({p['split']} split), "
             f"{p['res']}x{p['res']}, {p['spp']} spp, seed {p['seed']}; scenes "
             f"{', '.join(merged['scenes'])}. Sources: {', '.join(merged['sources'])}.", "",
             "| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for r in merged["rows"]:
        cells = [str(r["rank"]), r["model"], r["source"], str(r["materials"]), str(r["failed"]),
                 _fmt(r["bytes"], ".0f"), _fmt(r["evals_per_s"], ".3g"),
                 *(_fmt(r[k], _FORMATS[k]) for k in RANK_BY),
                 *(_fmt(r[f"{k}@{s}"], _FORMATS[k]) for s in merged["scenes"] for k in RANK_BY)]
        lines.append("| " + " | ".join(cells) + " |")
    n = len(merged["materials"])
    lines[2] += f" Ranked over the {n} materials every ranked model finished."
    if merged["unranked"]:
        lines += ["", "## Not ranked: did not finish every material", "",
                  f"Their figures would be over fewer materials than the ranking's {n}, so "
                  "they are not set beside it.", "",
                  "| model | source | materials finished | failed |", "|---|---|---|---|"]
        lines += [f"| {r['model']} | {r['source']} | {r['materials']} of {n} | {r['failed']} |"
                  for r in merged["unranked"]]
    return "\n".join(lines) + "\n"


def ranking_csv(merged: dict) -> str:
    """The ranked table as CSV, one row per model, every figure in full precision; then
    the unranked models with an empty rank, their counts of finished and failed
    materials, and no figures."""
    keys = ["rank", "model", "source", "machine", "materials", "failed", "bytes",
            "evals_per_s", *RANK_BY, *(f"{k}@{s}" for s in merged["scenes"] for k in RANK_BY)]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    w.writerows(merged["rows"])
    # the unranked models: an empty rank, their counts, no figures
    w.writerows({k: r[k] for k in ("model", "source", "machine", "materials", "failed")}
                for r in merged["unranked"])
    return buf.getvalue()


def write_ranking(merged: dict, out: str | os.PathLike) -> list[Path]:
    """``ranking.md`` and ``ranking.csv`` in the folder ``out`` (made if absent)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in (("ranking.md", ranking_markdown(merged)),
                       ("ranking.csv", ranking_csv(merged))):
        with atomic_write(out / name, "w") as f:
            f.write(text)
        paths.append(out / name)
    return paths
