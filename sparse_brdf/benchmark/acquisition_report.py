"""The acquisition bench's report: curves of rendering SNR against the sample count (mean
over materials, a band over the sample seeds), fit times, the noisy and bin-placed
samples beside the full-table encoding, and the goals checked (``report.md``,
``acquisition-<scene>.png``, ``results.csv``)."""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..fileio import atomic_write
from .charts import FORMS, pyplot

#: The scene the goals are checked in when it ran (the paper's), else the first one.
GOAL_SCENE = "paper_sphere"
#: Goal thresholds (dB, dB, dB, s): sparse above PCA by this from GOAL_FROM_N samples;
#: within this of the full-table encoding at GOAL_BINS_N bin-placed samples; fit time.
GOAL_MARGIN, GOAL_FROM_N, GOAL_FULL_GAP, GOAL_BINS_N, GOAL_FIT_S = 6.0, 1000, 3.0, 10000, 10.0


def _finite(xs) -> list[float]:
    return [float(x) for x in xs if x is not None and math.isfinite(x)]


def _value(row: dict, scene: str, form: str) -> float | None:
    return row.get("renders", {}).get(scene, {}).get(form)


def scenes_of(results: dict) -> list[str]:
    """The scenes the results were rendered in, in the config's order."""
    seen: dict[str, None] = {}
    for row in list(results["full"].values()) + list(results["cells"].values()):
        for s in row.get("renders", {}):
            seen[s] = None
    return list(seen)


def curve(results: dict, scene: str, form: str, method: str, placement: str,
          noise: float = 0.0) -> dict[int, dict]:
    """Per N: ``mean`` over materials and seeds, ``lo``/``hi`` the lowest and highest
    over seeds of the mean over materials, ``materials`` and ``seeds`` counted."""
    by: dict = defaultdict(lambda: defaultdict(list))  # n -> seed -> values
    for row in results["cells"].values():
        if (row.get("status") == "finished" and row["method"] == method
                and row["placement"] == placement and math.isclose(row["noise"], noise)):
            v = _value(row, scene, form)
            if v is not None and math.isfinite(v):
                by[row["n"]][row["seed"]].append(v)
    out = {}
    for n in sorted(by):
        per_seed = [float(np.mean(v)) for v in by[n].values()]
        every = [x for v in by[n].values() for x in v]
        out[n] = {"mean": float(np.mean(every)), "lo": min(per_seed), "hi": max(per_seed),
                  "seeds": len(per_seed), "materials": max(map(len, by[n].values()))}
    return out


def full_mean(results: dict, scene: str, form: str) -> float:
    """The full-table encoding's mean over materials."""
    xs = _finite(_value(r, scene, form) for r in results["full"].values())
    return float(np.mean(xs)) if xs else math.nan


def chart(results: dict, scene: str, path: Path) -> Path:
    """SNR against N in both forms (two panels), one line per method and placement
    (mean over materials and seeds, a band from the lowest to the highest seed's mean
    over materials), the bin-placed samples as points and the full-table encoding as a
    dashed line."""
    plt = pyplot()
    cfg = results["config"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharex=True)
    colours = {"sparse": "tab:blue", "pca": "tab:orange"}
    styles = {"stratified": "-", "uniform": ":"}
    for ax, (form, label) in zip(axes, FORMS, strict=True):
        for method in cfg["methods"]:
            for placement in cfg["placements"]:
                c = curve(results, scene, form, method, placement)
                if not c:
                    continue
                ns = list(c)
                ax.plot(ns, [c[n]["mean"] for n in ns], styles.get(placement, "--"),
                        color=colours.get(method), marker=".", label=f"{method}, {placement}")
                ax.fill_between(ns, [c[n]["lo"] for n in ns], [c[n]["hi"] for n in ns],
                                color=colours.get(method), alpha=0.15, linewidth=0)
            b = curve(results, scene, form, method, "bins")
            if b:
                ax.plot(list(b), [v["mean"] for v in b.values()], "s",
                        color=colours.get(method), label=f"{method}, at the bins' positions")
        full = full_mean(results, scene, form)
        if math.isfinite(full):
            ax.axhline(full, color="k", linestyle="--", linewidth=1,
                       label=f"full-table encoding ({cfg['n_coeffs']} per channel)")
        ax.set_xscale("log")
        ax.set_xlabel("samples N")
        ax.set_ylabel(f"rendering SNR, {label} (dB)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    n_mats = len(results["full"])
    fig.suptitle(f"Encoding from samples: {scene}, {n_mats} {cfg['corpus']} {cfg['split']} "
                 f"materials, seeds {', '.join(map(str, cfg['seeds']))}", fontsize=10)
    fig.tight_layout()
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
    return path


def _f(x: float) -> str:
    return f"{x:.1f}" if x is not None and math.isfinite(x) else "-"


def _curve_table(results: dict, scene: str, form: str) -> list[str]:
    cfg = results["config"]
    series = [(m, p) for p in cfg["placements"] for m in cfg["methods"]]
    ns = sorted({r["n"] for r in results["cells"].values() if r["placement"] != "bins"
                 and r["noise"] == 0})
    curves = {s: curve(results, scene, form, *s) for s in series}
    lines = ["| N | " + " | ".join(f"{m}, {p}" for m, p in series) + " |",
             "|---" * (len(series) + 1) + "|"]
    for n in ns:
        cells = [f"{_f(curves[s][n]['mean'])} ({_f(curves[s][n]['lo'])} to "
                 f"{_f(curves[s][n]['hi'])})" if n in curves[s] else "-" for s in series]
        lines.append(f"| {n:,} | " + " | ".join(cells) + " |")
    return lines


def _fit_time_table(results: dict) -> list[str]:
    by: dict = defaultdict(list)
    for r in results["cells"].values():
        if r.get("status") == "finished":
            by[(r["method"], r["n"])].append(r["fit_s"])
    methods = results["config"]["methods"]
    ns = sorted({n for _, n in by})
    lines = ["| N | " + " | ".join(f"{m}: mean (max) s" for m in methods) + " |",
             "|---" * (len(methods) + 1) + "|"]
    for n in ns:
        lines.append(f"| {n:,} | " + " | ".join(
            f"{np.mean(by[(m, n)]):.2f} ({np.max(by[(m, n)]):.2f})" if by[(m, n)] else "-"
            for m in methods) + " |")
    return lines


def _special_table(results: dict, scene: str, form: str) -> list[str]:
    """Bin-placed samples and noisy samples beside the clean curves."""
    cfg = results["config"]
    rows = ["| samples | " + " | ".join(cfg["methods"]) + " |",
            "|---" * (len(cfg["methods"]) + 1) + "|"]
    for n in cfg["bins_n"]:
        vals = [curve(results, scene, form, m, "bins").get(n, {}).get("mean") for m in
                cfg["methods"]]
        rows.append(f"| {n:,} at the bins' positions | " + " | ".join(map(_f, vals)) + " |")
    for p in cfg["placements"]:
        for n in cfg["noise_n"] if cfg["noise"] > 0 else []:
            for noise in (0.0, cfg["noise"]):
                vals = [curve(results, scene, form, m, p, noise).get(n, {}).get("mean")
                        for m in cfg["methods"]]
                what = f"{noise:.0%} noise" if noise else "no noise"
                rows.append(f"| {n:,} {p}, {what} | " + " | ".join(map(_f, vals)) + " |")
    rows.append(f"| full table ({cfg['n_coeffs']} per channel) | "
                + " | ".join([_f(full_mean(results, scene, form))]
                             + ["-"] * (len(cfg["methods"]) - 1)) + " |")
    return rows


def goals(results: dict) -> list[dict]:
    """The goals checked on the paper's scene (else the first scene), object-only, means
    over materials and seeds: each ``{"goal", "met", "detail"}`` (``met`` None when the
    results lack what it needs)."""
    scenes = scenes_of(results)
    if not scenes:
        return []
    scene = GOAL_SCENE if GOAL_SCENE in scenes else scenes[0]
    form, cfg, out = "snr_object", results["config"], []
    for p in cfg["placements"]:
        sp, pc = (curve(results, scene, form, m, p) for m in ("sparse", "pca"))
        ns = [n for n in sp if n in pc]
        if not ns:
            continue
        gaps = {n: sp[n]["mean"] - pc[n]["mean"] for n in ns}
        worst = min(gaps, key=gaps.get)
        out.append({"goal": f"{p}: sparse at or above PCA at every N", "met": gaps[worst] >= 0,
                    "detail": f"smallest margin {gaps[worst]:+.1f} dB at N = {worst:,}"})
        late = {n: g for n, g in gaps.items() if n >= GOAL_FROM_N}
        if late:
            w = min(late, key=late.get)
            out.append({"goal": f"{p}: sparse {GOAL_MARGIN:g} dB above PCA from "
                                f"{GOAL_FROM_N:,} samples",
                        "met": late[w] >= GOAL_MARGIN,
                        "detail": f"smallest margin {late[w]:+.1f} dB at N = {w:,}"})
    full = full_mean(results, scene, form)
    for p in ["bins", *cfg["placements"]]:
        v = curve(results, scene, form, "sparse", p).get(GOAL_BINS_N)
        if v and math.isfinite(full):
            gap = v["mean"] - full
            out.append({"goal": f"{p}: {GOAL_BINS_N:,} samples within {GOAL_FULL_GAP:g} dB of "
                                "the full-table encoding" + ("" if p == "bins" else
                                                             " (reported, no target)"),
                        "met": gap >= -GOAL_FULL_GAP if p == "bins" else None,
                        "detail": f"{v['mean']:.1f} dB against {full:.1f} ({gap:+.1f})"})
    t = _finite(r["fit_s"] for r in results["cells"].values() if r.get("status") ==
                "finished" and r["method"] == "sparse" and r["n"] == GOAL_BINS_N)
    if t:
        out.append({"goal": f"a sparse fit from {GOAL_BINS_N:,} samples in at most "
                            f"{GOAL_FIT_S:g} s", "met": float(np.mean(t)) <= GOAL_FIT_S,
                    "detail": f"mean {np.mean(t):.1f} s, max {np.max(t):.1f} s over {len(t)} fits"})
    for g in out:
        g["scene"] = scene
    return out


def write_csv(results: dict, path: Path) -> Path:
    """One row per finished or failed cell and rendered scene."""
    cols = ["material", "method", "placement", "n", "seed", "noise", "status", "fit_s",
            "cos_snr", "scene", "snr_object", "snr_whole"]
    with atomic_write(path, "w") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in results["cells"].values():
            for scene, v in (r.get("renders") or {"": {}}).items():
                w.writerow([r.get(c) for c in cols[:9]] + [scene, v.get("snr_object"),
                                                          v.get("snr_whole")])
    return path


def write_acquisition_report(results: dict, out: Path) -> Path:
    """``report.md``, one chart per scene and ``results.csv`` in ``out``."""
    out = Path(out)
    cfg = results["config"]
    failed = [k for k, r in results["cells"].items() if r.get("status") != "finished"]
    lines = [f"# Encoding from samples: {len(results['full'])} {cfg['corpus']} {cfg['split']} "
             "materials", "",
             f"Samples simulated from the {'networks' if cfg['measure'] == 'nbrdf' else 'tables'}"
             f"; seeds {', '.join(map(str, cfg['seeds']))}; renders {cfg['res']} px, "
             f"{cfg['spp']} spp, seed {cfg['seed']}; {len(results['cells'])} fits, "
             f"{len(failed)} failed. Cells: mean over materials and seeds (lowest to highest "
             "seed's mean over materials), in dB.", ""]
    for k, why in results.get("skipped_scenes", {}).items():
        lines += [f"Skipped scene {k}: {why}", ""]
    lines += ["## Goals", "", "| goal | met | detail |", "|---|---|---|"]
    for g in goals(results):
        met = {True: "yes", False: "**no**", None: "-"}[g["met"]]
        lines.append(f"| {g['goal']} ({g['scene']}, object-only) | {met} | {g['detail']} |")
    for scene in scenes_of(results):
        chart(results, scene, out / f"acquisition-{scene}.png")
        lines += ["", f"## {scene}", "", f"![{scene}](acquisition-{scene}.png)", ""]
        for form, label in FORMS:
            lines += [f"{label}:", ""] + _curve_table(results, scene, form) + [""]
            lines += _special_table(results, scene, form) + [""]
    lines += ["## Fit time", ""] + _fit_time_table(results)
    if failed:
        lines += ["", "## Failed fits", ""] + [
            f"- {k}: {results['cells'][k].get('error')}" for k in failed]
    write_csv(results, out / "results.csv")
    path = out / "report.md"
    with atomic_write(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path
