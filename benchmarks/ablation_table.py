"""Ablation table from one or more bench results (docs/results.md, "Accuracy at equal
coefficients").

    .venv/bin/python benchmarks/ablation_table.py bench_ablation [bench_ablation_v2 ...]

Prints, per model, the mean and minimum rendering SNR in both scenes and both forms
(object-only and whole-image, dB) over the materials every listed model finished, split by
corpus, plus encode time and bytes. Rows are named ``<bench folder>: <model>``.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np
from harness import parser

FORMS = (("snr_object", "object"), ("snr_whole", "whole"))


def load(folder: Path) -> dict[str, dict[str, dict]]:
    """model -> material -> cell, finished cells only."""
    cells = json.loads((folder / "results.json").read_text())["cells"]
    out: dict[str, dict[str, dict]] = defaultdict(dict)
    for c in cells.values():
        if c.get("status") == "finished" and c.get("renders"):
            out[f"{folder.name}: {c['model']}"][c["material"]] = c
    return out


def main() -> None:
    ap = parser(__doc__, json_option=False)
    ap.add_argument("folders", nargs="+", type=Path)
    args = ap.parse_args()
    models: dict[str, dict[str, dict]] = {}
    for f in args.folders:
        models.update(load(f))
    common = set.intersection(*(set(m) for m in models.values()))
    scenes = sorted({s for m in models.values() for c in m.values() for s in c["renders"]})
    for corpus in ("all", "merl", "rgl"):
        mats = sorted(m for m in common if corpus == "all" or m.startswith(corpus + "/"))
        if not mats:
            continue
        head = " | ".join(f"{s} {lab}" for s in scenes for _, lab in FORMS)
        print(f"\n{corpus}: {len(mats)} materials, mean (min) dB\n")
        print(f"| model | {head} | encode s | bytes |")
        print("|---|" + "---|" * (len(scenes) * len(FORMS) + 2))
        for name, cells in models.items():
            row = []
            for s in scenes:
                for key, _ in FORMS:
                    v = np.array([cells[m]["renders"][s][key] for m in mats])
                    row.append(f"{v.mean():.1f} ({v.min():.1f})")
            t = np.mean([cells[m]["fit_s"] for m in mats])
            b = np.mean([cells[m]["bytes"] for m in mats])
            print(f"| {name} | " + " | ".join(row) + f" | {t:.2f} | {b:.0f} |")


if __name__ == "__main__":
    main()
