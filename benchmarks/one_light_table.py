"""The "Under one light" tables of ``docs/results.md`` from a bench folder.

For each model and corpus: HDR-FLIP (mean and max over materials and the one-light
scenes, ``sphere_light-lightangle=*``) and both SNR forms (mean over the same cells), and
the same for each other scene; the worst cells of one model. Reads ``results.json`` of a
bench run, e.g. ``sparse-brdf bench standard --out bench_standard``::

    .venv/bin/python benchmarks/one_light_table.py bench_standard --worst sparse-262
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
from harness import parser

ONE_LIGHT = "sphere_light-lightangle="


def rows_by(results: dict) -> dict:
    """{(model, corpus, scene group): [(material, scene, flip, snr_object, snr_whole)]}."""
    out = defaultdict(list)
    for cell in results["cells"].values():
        if cell.get("status") != "finished":
            continue
        corpus = cell["material"].split("/")[0]
        for scene, r in (cell.get("renders") or {}).items():
            group = "one light" if scene.startswith(ONE_LIGHT) else scene
            out[(cell["model"], corpus, group)].append(
                (cell["material"], scene, r.get("flip"), r["snr_object"], r["snr_whole"]))
    return out


def table(groups: dict, group: str) -> list[str]:
    lines = ["| model | corpus | HDR-FLIP mean | HDR-FLIP max | object-only (dB) | "
             "whole-image (dB) | cells |", "|---|---|---|---|---|---|---|"]
    for (model, corpus, g), rows in sorted(groups.items()):
        if g != group or model == "tabulated":
            continue
        f = np.array([r[2] for r in rows if r[2] is not None], float)
        mean, top = (f"{f.mean():.3f}", f"{f.max():.3f}") if f.size else ("-", "-")
        lines.append(f"| {model} | {corpus} | {mean} | {top} | "
                     f"{np.mean([r[3] for r in rows]):.1f} | "
                     f"{np.mean([r[4] for r in rows]):.1f} | {len(rows)} |")
    return lines


def main(argv=None) -> int:
    p = parser(__doc__, json_option=False)
    p.add_argument("bench", type=Path, help="a bench folder (its results.json)")
    p.add_argument("--worst", help="list this model's five worst cells by HDR-FLIP")
    args = p.parse_args(argv)
    groups = rows_by(json.loads((args.bench / "results.json").read_text()))
    for group in sorted({g for _, _, g in groups}, key=lambda g: g != "one light"):
        print(f"\n### {group}\n")
        print("\n".join(table(groups, group)))
    if args.worst:
        cells = [r for (m, _, g), rows in groups.items() if m == args.worst and
                 g == "one light" for r in rows]
        print(f"\nworst cells of {args.worst}:")
        for r in sorted(cells, key=lambda r: -(r[2] or 0))[:5]:
            print(f"  {r[0]} {r[1]}: FLIP {r[2]:.3f}, {r[3]:.1f} / {r[4]:.1f} dB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
