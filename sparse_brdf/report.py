"""The bench report: tables (paper's Tables 2-4), figures (Figs. 2-4) and the
speed-vs-accuracy chart, written as markdown + PNG from a bench's ``results``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .fileio import atomic_write


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _finite(xs):
    return [x for x in xs if x is not None and math.isfinite(x)]


def _mean_snr(xs: list[float]) -> float:
    """Mean of finite SNRs; inf when every one is +inf (an exact model), else nan."""
    if xs and all(math.isinf(x) and x > 0 for x in xs):
        return math.inf
    f = _finite(xs)
    return float(np.mean(f)) if f else math.nan


def summary_table(results: dict) -> list[dict]:
    """Per model: mean/std/min/max rendering SNR, RAE, bytes, render time (Table 3)."""
    by_model: dict[str, list[dict]] = {}
    for r in results["cells"].values():
        by_model.setdefault(r["model"], []).append(r)
    rows = []
    for model, cells in by_model.items():
        ok = [c for c in cells if c.get("status") == "finished"]
        snr = [c["render_snr"] for c in ok if c.get("render_snr") is not None]
        row = {"model": model, "n": len(ok), "failed": len(cells) - len(ok),
               "bytes": float(np.mean([c["bytes"] for c in ok])) if ok else float("nan"),
               "rae": float(np.mean([c["rae"] for c in ok])) if ok else float("nan"),
               "cos_snr": _mean_snr([c["cos_snr"] for c in ok])}
        if snr and all(math.isinf(x) and x > 0 for x in snr):  # identical to the reference
            row.update(snr_mean=math.inf, snr_std=0.0, snr_min=math.inf, snr_max=math.inf,
                       render_s=float(np.mean([c["render_s"] for c in ok if "render_s" in c])))
        elif _finite(snr):
            snr = _finite(snr)
            row.update(snr_mean=float(np.mean(snr)), snr_std=float(np.std(snr)),
                       snr_min=float(np.min(snr)), snr_max=float(np.max(snr)),
                       render_s=float(np.mean([c["render_s"] for c in ok if "render_s" in c])))
        rows.append(row)
    rows.sort(key=lambda r: -r.get("snr_mean", r["cos_snr"]))
    return rows


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of points not dominated (lower x and higher y are better)."""
    keep = []
    for i, (x, y) in enumerate(points):
        if not any((x2 <= x and y2 >= y) and (x2 < x or y2 > y)
                   for j, (x2, y2) in enumerate(points) if j != i):
            keep.append(i)
    return keep


def speed_accuracy_chart(rows: list[dict], path: Path) -> None:
    plt = _plt()
    rows = [r for r in rows if "snr_mean" in r and math.isfinite(r["snr_mean"])]
    if not rows:
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for ax, key, label in ((axes[0], "render_s", "render time (s)"),
                           (axes[1], "bytes", "bytes per material")):
        pts = [(r[key], r["snr_mean"]) for r in rows]
        front = set(pareto(pts))
        for i, (r, (x, y)) in enumerate(zip(rows, pts, strict=True)):
            ax.scatter(x, y, s=60 if i in front else 30,
                       marker="*" if i in front else "o",
                       color="C3" if r["model"].startswith("sparse") else "C0")
            ax.annotate(r["model"], (x, y), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        fx = sorted(pts[i] for i in front)
        ax.plot([p[0] for p in fx], [p[1] for p in fx], "--", color="grey", lw=1,
                label="Pareto front")
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("mean rendering SNR (dB)")
        ax.legend(fontsize=8)
    fig.suptitle("Speed and size against accuracy (stars: Pareto-optimal)")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def curve_figure(results: dict, path: Path) -> None:
    curves = results["curves"]
    if not curves:
        return
    plt = _plt()
    first = next(iter(curves.values()))
    counts = first["counts"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for t in ("log-plus", "log-plus-cosine"):
        for ax, key, lab in ((axes[0], "rae", "RAE"), (axes[1], "cos_snr", "cos-weighted SNR")):
            v = np.array([c[t][key] for c in curves.values()])
            ax.plot(counts, v.mean(0), marker="o", label=t)
            ax.set_xscale("log", base=2)
            ax.set_xlabel("coefficients per channel")
            ax.set_ylabel(f"{lab} (mean of {len(curves)} materials)")
    axes[0].set_yscale("log")
    axes[0].legend()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def difference_figure(results: dict, out: Path, max_materials: int = 4) -> list[Path]:
    """Renders and false-colour |ref - img| x 10 (jet) per material (Figs. 3, 4)."""
    from .render import read_exr

    work = out / "work"
    mats = sorted({r["material"] for r in results["cells"].values()})[:max_materials]
    models = sorted({r["model"] for r in results["cells"].values()})
    paths = []
    plt = _plt()
    for key in mats:
        stem = key.replace("/", "__")
        ref_p = work / f"{stem}__reference.exr"
        if not ref_p.is_file():
            continue
        ref = read_exr(ref_p)
        shown = [m for m in models if (work / f"{stem}__{m}.exr").is_file()]
        fig, axes = plt.subplots(2, len(shown) + 1, figsize=(2.2 * (len(shown) + 1), 4.6),
                                 constrained_layout=True)
        axes = np.atleast_2d(axes)
        tone = lambda im: np.clip(im / (1 + im), 0, 1) ** (1 / 2.2)  # noqa: E731
        axes[0, 0].imshow(tone(ref))
        axes[0, 0].set_title("reference", fontsize=8)
        axes[1, 0].axis("off")
        for i, m in enumerate(shown, start=1):
            img = read_exr(work / f"{stem}__{m}.exr")
            cell = results["cells"].get(f"{key}|{m}", {})
            axes[0, i].imshow(tone(img))
            axes[0, i].set_title(f"{m}\n{cell.get('render_snr', float('nan')):.1f} dB",
                                 fontsize=8)
            diff = np.abs(ref - img).mean(-1) * 10  # linear radiance, as the paper's figures
            axes[1, i].imshow(np.clip(diff, 0, 1), cmap="jet", vmin=0, vmax=1)
            axes[1, i].set_title("|ref - img| x 10", fontsize=7)
        for a in axes.ravel():
            a.set_xticks([])
            a.set_yticks([])
        fig.suptitle(key, fontsize=9)
        p = out / f"renders-{stem}.png"
        fig.savefig(p, dpi=90)
        plt.close(fig)
        paths.append(p)
    return paths


def transform_table(results: dict) -> tuple[list[str], dict]:
    """Transform choice by gamma-mapped MSE and by plain MSE against the render-SNR-better
    one (Table 2); needs the forced-transform cells sparse-N-log-plus[-cosine]."""
    lines, agree = [], {"gamma": 0, "plain": 0, "n": 0}
    for key, c in sorted(results["curves"].items()):
        counts = c["counts"]
        i = counts.index(262) if 262 in counts else len(counts) // 2
        lp = results["cells"].get(f"{key}|sparse-{counts[i]}-log-plus", {})
        lpc = results["cells"].get(f"{key}|sparse-{counts[i]}-log-plus-cosine", {})
        if "render_snr" not in lp or "render_snr" not in lpc:
            continue
        best = "log-plus" if lp["render_snr"] >= lpc["render_snr"] else "log-plus-cosine"
        by_gamma = min(("log-plus", "log-plus-cosine"), key=lambda t: c[t]["gamma_mse"][i])
        by_plain = min(("log-plus", "log-plus-cosine"), key=lambda t: c[t]["mse"][i])
        agree["gamma"] += by_gamma == best
        agree["plain"] += by_plain == best
        agree["n"] += 1
        lines.append(f"| {key} | {lp['render_snr']:.1f} | {lpc['render_snr']:.1f} | {best} | "
                     f"{by_gamma} | {by_plain} |")
    return lines, agree


def write_report(results: dict, out: Path) -> Path:
    """results.csv, report.md and its PNGs in ``out``."""
    from .bench import write_csv

    out = Path(out)
    write_csv(results, out / "results.csv")
    rows = summary_table(results)
    speed_accuracy_chart(rows, out / "speed_accuracy.png")
    curve_figure(results, out / "error_vs_coeffs.png")
    figs = difference_figure(results, out)
    nf = _finite(list(results["noise_floor"].values()))
    cfg = results["config"]
    md = ["# sparse-brdf bench report", "",
          f"Corpora {cfg['corpora']} ({cfg['split']} split), scene `{cfg['scene']}`, "
          f"{cfg['res']}x{cfg['res']}, {cfg['spp']} spp, seed {cfg['seed']}.", ""]
    if nf:
        md += [f"Noise floor (two reference renders, seeds {cfg['seed']} and "
               f"{cfg['noise_seed']}): mean {np.mean(nf):.1f} dB, min {np.min(nf):.1f} dB. "
               "Model and reference share seed and sampling, so model SNRs well above the "
               "noise floor are meaningful.", ""]
    md += ["## Rendering SNR per model (Table 3)", "",
           "| model | materials | failed | bytes | RAE | cos-SNR (dB) | SNR mean | std | min | "
           "max | render (s) |", "|---" * 11 + "|"]
    for r in rows:
        md.append(f"| {r['model']} | {r['n']} | {r['failed']} | {r['bytes']:.0f} | "
                  f"{r['rae']:.4f} | {r['cos_snr']:.1f} | {r.get('snr_mean', math.nan):.1f} | "
                  f"{r.get('snr_std', math.nan):.1f} | {r.get('snr_min', math.nan):.1f} | "
                  f"{r.get('snr_max', math.nan):.1f} | {r.get('render_s', math.nan):.2f} |")
    md += ["", "![speed vs accuracy](speed_accuracy.png)", "",
           "## Per material (Table 4)", "", "| material | model | SNR (dB) | RAE | status |",
           "|---|---|---|---|---|"]
    for r in sorted(results["cells"].values(), key=lambda r: (r["material"], r["model"])):
        md.append(f"| {r['material']} | {r['model']} | {r.get('render_snr', math.nan):.1f} | "
                  f"{r.get('rae', math.nan):.4f} | {r['status']}"
                  f"{': ' + r['error'] if r.get('error') else ''} |")
    lines, agree = transform_table(results)
    if lines:
        md += ["", "## Transform choice (Table 2)", "",
               f"Gamma-mapped MSE picked the render-SNR-better transform for {agree['gamma']} "
               f"of {agree['n']} materials; plain MSE for {agree['plain']}.", "",
               "| material | SNR log-plus | SNR log-plus-cosine | better | gamma-MSE picks | "
               "MSE picks |", "|---|---|---|---|---|---|", *lines]
    if results.get("stability"):
        from .stability import stability_markdown

        md += ["", "## Stability", "",
               f"Perturbations of {results['stability']['material']}; cosine-weighted SNR "
               "against the clean BRDF, or the outcome.", "",
               *stability_markdown(results["stability"]["rows"])]
    md += ["", "## Error against coefficients (Fig. 2)", "",
           "![error vs coefficients](error_vs_coeffs.png)", "", "## Renders (Figs. 3, 4)", ""]
    md += [f"![{p.stem}]({p.name})" for p in figs]
    path = out / "report.md"
    with atomic_write(path, "w") as f:
        f.write("\n".join(md) + "\n")
    return path
