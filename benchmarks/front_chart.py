"""Bytes against rendering SNR (docs/results.md, "Accuracy at equal bytes").

    .venv/bin/python benchmarks/front_chart.py bench_front [--out docs/figures/front.png]

Reads a bench run of ``sparse_brdf/data/configs/front.toml``: the sparse model at byte
budgets (``sparse-bN``, file version 2, and ``sparse-bN-version=1``) and the baselines.
Prints, per model, the mean file size and the mean (min) rendering SNR in both scenes and
both forms over the materials every model finished, and draws the four panels (scene x
SNR form) of mean SNR against mean bytes per material, log scale.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
from harness import parser

FORMS = (("snr_object", "object-only"), ("snr_whole", "whole-image"))


def series(name: str) -> str:
    """The curve a model belongs to: v2, v1, or the baseline's own name."""
    if name.startswith("sparse-b"):
        return "sparse, file version 1" if name.endswith("version=1") else \
            "sparse, file version 2"
    return name


def table(folder: Path) -> tuple[dict, list[str], list[str]]:
    """model -> {"bytes", (scene, form) -> (mean, min)}, the scenes, the materials."""
    cells = json.loads((folder / "results.json").read_text())["cells"]
    by: dict[str, dict[str, dict]] = defaultdict(dict)
    for c in cells.values():
        if c.get("status") == "finished" and c.get("renders"):
            by[c["model"]][c["material"]] = c
    mats = sorted(set.intersection(*(set(m) for m in by.values())))
    scenes = sorted({s for m in by.values() for c in m.values() for s in c["renders"]})
    rows = {}
    for model, cs in by.items():
        row = {"bytes": float(np.mean([cs[m]["bytes"] for m in mats]))}
        for s in scenes:
            for key, _ in FORMS:
                v = np.array([cs[m]["renders"][s][key] for m in mats])
                row[(s, key)] = (float(v.mean()), float(v.min()))
        rows[model] = row
    return rows, scenes, mats


def chart(rows: dict, scenes: list[str], out: Path) -> None:
    import matplotlib  # lazy: only the chart needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(scenes), 2, figsize=(10, 4 * len(scenes)), squeeze=False)
    groups: dict[str, list] = defaultdict(list)
    for model, row in rows.items():
        groups[series(model)].append(row)
    for i, s in enumerate(scenes):
        for j, (key, label) in enumerate(FORMS):
            ax = axes[i][j]
            for name, rs in sorted(groups.items()):
                rs = sorted(rs, key=lambda r: r["bytes"])
                x = [r["bytes"] / 1000 for r in rs]
                y = [r[(s, key)][0] for r in rs]
                style = "-o" if name.startswith("sparse") else "s"
                ax.plot(x, y, style, label=name, markersize=5)
            ax.set_xscale("log")
            ax.set_xlabel("bytes per material (kB, log)")
            ax.set_ylabel(f"mean rendering SNR, {label} (dB)")
            ax.set_title(f"{s}, {label}")
            ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main() -> None:
    ap = parser(__doc__, json_option=False)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--out", type=Path, default=Path("front.png"))
    args = ap.parse_args()
    rows, scenes, mats = table(args.folder)
    print(f"{len(mats)} materials, mean (min) dB\n")
    head = " | ".join(f"{s} {lab}" for s in scenes for _, lab in FORMS)
    print(f"| model | bytes | {head} |\n|---|---|" + "---|" * (2 * len(scenes)))
    for model, row in sorted(rows.items(), key=lambda kv: (series(kv[0]), kv[1]["bytes"])):
        vals = " | ".join(f"{row[(s, k)][0]:.1f} ({row[(s, k)][1]:.1f})"
                          for s in scenes for k, _ in FORMS)
        print(f"| {model} | {row['bytes']:.0f} | {vals} |")
    chart(rows, scenes, args.out)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
