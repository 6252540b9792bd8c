"""Per-corpus tables and the speed/size charts of a bench's ``results.csv`` (e.g. ``bench
peers``), with each model's evaluations per second measured in one process.

    .venv/bin/python benchmarks/peers_summary.py bench_peers/results.csv \\
        --material abc:blue-acrylic --out docs/figures --json docs/figures/peers.json

Means (and minima) of the rendering SNR per corpus, scene and form, over the cells whose
metrics and renders are complete (the cell's ``renders`` columns), whatever the cell's
status says (a cell whose speed step failed after its renders still counts). The speed
axis: ``benchmark.speed.evals_per_second`` of every model on one material, all in this
process one after another (Neural-BRDF trained for one epoch: its cost per lookup does not
depend on its weights; PCA on 5 training materials: its evaluator's cost does not depend
on them either).
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path

import numpy as np
from harness import header, parser, write_json

from sparse_brdf import get_corpus, load_brdf
from sparse_brdf.benchmark.charts import speed_accuracy_chart
from sparse_brdf.benchmark.speed import evals_per_second
from sparse_brdf.compared.specs import make_model

SCENES = ("paper_sphere", "sphere")
FORMS = ("snr_object", "snr_whole")
#: The spec measured for each model name of the bench (its own evaluator).
SPEED_SPECS = {"sparse-262": "sparse:262", "sparse-b2700": "sparse:b2700",
               "nbrdf": "nbrdf:epochs=1,n_samples=20000", "naive": "naive",
               "pca-40": "pca:4"}


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [r for r in csv.DictReader(f) if r.get("snr_object@sphere")]


def summarise(rows: list[dict]) -> dict:
    """{model: {corpus: {scene@form: (mean, min)}, "bytes": mean}} over complete cells."""
    acc: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    size: dict = defaultdict(list)
    for r in rows:
        corpus = r["material"].split("/", 1)[0]
        size[r["model"]].append(float(r["bytes"]))
        for s in SCENES:
            for f in FORMS:
                v = float(r[f"{f}@{s}"])
                if math.isfinite(v):
                    for c in (corpus, "all"):
                        acc[r["model"]][c][f"{s}@{f}"].append(v)
    return {m: {"bytes": float(np.mean(size[m])), "n": len(acc[m]["all"][f"sphere@{FORMS[0]}"]),
                **{c: {k: (float(np.mean(v)), float(np.min(v))) for k, v in d.items()}
                   for c, d in acc[m].items()}} for m in acc}


def speeds(material: str, models: list[str], pairs: int = 1 << 20) -> dict[str, float]:
    """Evaluations per second of each model name of ``models`` (``SPEED_SPECS``), on
    ``pairs`` random direction pairs per call."""
    brdf = load_brdf(material)
    train = [m.load() for m in get_corpus("mitsuba").split("train")[:5]]
    out = {}
    for name in models:
        spec = SPEED_SPECS[name]
        model = make_model(spec)
        model.progress = False
        if model.learns:
            model.fit(train)
        out[name] = evals_per_second(model.compress(brdf), pairs,
                                     ensemble=getattr(model, "ensemble", None))
        print(f"{name}: {out[name] / 1e6:.1f} M evaluations/s", flush=True)
    return out


def table(summary: dict, corpora: list[str], scene: str) -> str:
    head = " | ".join(f"{c}: object / whole" for c in corpora)
    lines = [f"| model | bytes | {head} |", "|---" * (2 + len(corpora)) + "|"]
    for m, d in summary.items():
        cells = " | ".join(
            "{:.1f} ({:.1f}) / {:.1f} ({:.1f})".format(*d[c][f"{scene}@snr_object"],
                                                       *d[c][f"{scene}@snr_whole"])
            for c in corpora)
        lines.append(f"| {m} | {d['bytes']:.0f} | {cells} |")
    return "\n".join(lines)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("csv", type=Path)
    ap.add_argument("--material", default="abc:blue-acrylic",
                    help="the material of the speed axis")
    ap.add_argument("--out", type=Path, default=Path("."), help="folder of the charts")
    ap.add_argument("--speed-models", nargs="*", choices=list(SPEED_SPECS),
                    default=list(SPEED_SPECS), help="the models whose speed is measured")
    ap.add_argument("--pairs", type=int, default=1 << 20,
                    help="direction pairs per timed call")
    args = ap.parse_args()
    summary = summarise(read_rows(args.csv))
    corpora = sorted({c for d in summary.values() for c in d if isinstance(d[c], dict)
                      and c != "all"}) + ["all"]
    print(header())
    evals = speeds(args.material, args.speed_models, args.pairs)
    for scene in SCENES:
        print(f"\n{scene}, mean (min) rendering SNR in dB\n")
        print(table(summary, corpora, scene))
        rows = [{"model": m, "bytes": d["bytes"], "evals_per_s": evals.get(m, math.nan),
                 "snr_object_mean": d["all"][f"{scene}@snr_object"][0],
                 "snr_whole_mean": d["all"][f"{scene}@snr_whole"][0]}
                for m, d in summary.items()]
        speed_accuracy_chart(rows, args.out / f"peers_speed_accuracy-{scene}.png",
                             f", {scene}, {summary[next(iter(summary))]['n']} materials")
    if args.json:
        write_json(args.json, {"summary": summary, "evals_per_s": evals}, args)


if __name__ == "__main__":
    main()
