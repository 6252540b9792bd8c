"""The bench's charts: rendering SNR (both forms) and HDR-FLIP against speed and bytes
with their Pareto fronts, error against coefficients, and the logarithmic axes they share.
matplotlib is imported only when a figure is drawn."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..fileio import atomic_path
from ..metrics import OBJECT_ONLY, WHOLE_IMAGE
from ..transforms import TRANSFORMS

FORMS = (("snr_object", OBJECT_ONLY), ("snr_whole", WHOLE_IMAGE))


def pyplot():
    """matplotlib's pyplot on the Agg backend (files, no screen)."""
    import matplotlib  # lazy: matplotlib + pyplot take ~0.4 s to import; only figures need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def pareto(points: list[tuple[float, float]], higher_x: bool = False) -> list[int]:
    """Indices of points not dominated (higher y is better; lower x, or higher x when
    ``higher_x``)."""
    pts = [(-x if higher_x else x, y) for x, y in points]
    keep = []
    for i, (x, y) in enumerate(pts):
        if not any((x2 <= x and y2 >= y) and (x2 < x or y2 > y)
                   for j, (x2, y2) in enumerate(pts) if j != i):
            keep.append(i)
    return keep


def speed_accuracy_chart(rows: list[dict], path: Path, title: str = "") -> bool:
    """Mean rendering SNR (both forms) and mean HDR-FLIP against each model's evaluations
    per second and against bytes per material, with the Pareto fronts. False when nothing
    to plot."""
    fig = speed_accuracy_figure(rows, title)
    if fig is None:
        return False
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100)
    pyplot().close(fig)
    return True


def log_axis(ax, values: list[float], which: str = "x") -> None:
    """A logarithmic axis (``which``: "x" or "y") whose ticks are labelled however narrow
    the values' range: within one power of ten, plain numbers at 1, 1.5, 2, 3, 5 and 7
    times each power."""
    from matplotlib import ticker  # lazy: matplotlib is imported only for the figures

    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    lo, hi = min(values), max(values)
    if hi < 10 * lo:  # no power of ten, or one, in range: label the in-between ticks
        axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 1.5, 2.0, 3.0, 5.0,
                                                                7.0)))
        axis.set_major_formatter(ticker.FuncFormatter(lambda x, _: f"{x:.3g}"))
        pad = (hi / lo) ** 0.15 if hi > lo else 1.3
        (ax.set_xlim if which == "x" else ax.set_ylim)(lo / pad, hi * pad)
    axis.set_minor_formatter(ticker.NullFormatter())


#: What the speed and size charts plot against: (result key, axis label, higher is better).
CHART_MEASURES = (*((key, f"mean rendering SNR, {label} (dB)", True) for key, label in FORMS),
                  ("flip", "mean HDR-FLIP (0 is identical)", False))


def speed_accuracy_figure(rows: list[dict], title: str = ""):
    """The figure of :func:`speed_accuracy_chart` (a matplotlib ``Figure``): a row of two
    charts (against speed, against bytes) for each of :data:`CHART_MEASURES` that some
    model has, or None when no row has a mean rendering SNR."""
    plt = pyplot()
    rows = [r for r in rows if math.isfinite(r.get("snr_object_mean", math.nan))]
    if not rows:
        return None
    measures = [m for m in CHART_MEASURES
                if any(math.isfinite(r.get(f"{m[0]}_mean", math.nan)) for r in rows)]
    fig, axes = plt.subplots(len(measures), 2, figsize=(11, 4 * len(measures)),
                             constrained_layout=True, squeeze=False)
    for i, (key, ylabel, higher_y) in enumerate(measures):
        for ax, xkey, xlabel, higher in (
                (axes[i, 0], "evals_per_s", "BRDF evaluations per second (own evaluator)", True),
                (axes[i, 1], "bytes", "bytes per material", False)):
            sub = [r for r in rows if math.isfinite(r.get(xkey, math.nan)) and r[xkey] > 0
                   and math.isfinite(r.get(f"{key}_mean", math.nan))]
            if not sub:
                ax.set_visible(False)
                continue
            pts = [(r[xkey], r[f"{key}_mean"]) for r in sub]
            front = set(pareto([(x, y if higher_y else -y) for x, y in pts], higher_x=higher))
            for j, (r, (x, y)) in enumerate(zip(sub, pts, strict=True)):
                if math.isfinite(r.get(f"{key}_se", math.nan)):  # several seeds
                    ax.errorbar(x, y, yerr=r[f"{key}_se"], color="grey", capsize=3, lw=1)
                ax.scatter(x, y, s=60 if j in front else 30, marker="*" if j in front else "o",
                           color="C3" if r["model"].startswith("sparse") else "C0")
                ax.annotate(r["model"], (x, y), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
            fx = sorted(pts[j] for j in front)
            ax.plot([p[0] for p in fx], [p[1] for p in fx], "--", color="grey", lw=1,
                    label="Pareto front")
            log_axis(ax, [p[0] for p in pts])
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
            ax.legend(fontsize=8)
    fig.suptitle(f"Speed and size against accuracy{title} (stars: Pareto-optimal; red: sparse)")
    return fig


def curve_figure(results: dict, path: Path) -> None:
    curves = results["curves"]
    if not curves:
        return
    plt = pyplot()
    first = next(iter(curves.values()))
    counts = first["counts"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for t in [t for t in TRANSFORMS if t in first]:
        for ax, key, lab in ((axes[0], "rae", "RAE"), (axes[1], "cos_snr", "cos-weighted SNR, dB")):
            v = np.array([c[t][key] for c in curves.values()])
            ax.plot(counts, v.mean(0), marker="o", label=t)
            ax.set_xscale("log", base=2)
            ax.set_xlabel("coefficients per channel")
            ax.set_ylabel(f"{lab} (mean of {len(curves)} materials)")
    rae = [x for c in curves.values() for t in TRANSFORMS if t in c for x in c[t]["rae"]]
    log_axis(axes[0], [x for x in rae if x > 0] or [1.0], "y")
    axes[0].legend()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
