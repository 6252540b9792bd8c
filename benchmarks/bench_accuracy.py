"""BRDF-space accuracy against the number of coefficients (the paper's Fig. 2), on unseen
materials, for both transforms; how often the gamma-mapped MSE picks the transform with
the lower BRDF-space error; and the ensemble against one HOSVD dictionary of the same
training data at equal coefficients; plus encode time.

    .venv/bin/python benchmarks/bench_accuracy.py --out docs/figures

Writes ``accuracy.json``, ``accuracy.png`` and ``accuracy.md`` into ``--out``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from harness import header, machine, parser

from sparse_brdf.coding.encode import encode, error_curve
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.dataset import training_tensors
from sparse_brdf.training.train import hosvd_ensemble
from sparse_brdf.transforms import TRANSFORMS


def measure(brdf, ens, counts):
    """RAE / cos-SNR per transform and count, plus the gamma-MSE choice at each count."""
    c = error_curve(brdf, ens, counts)
    out = {t: {"rae": c[t]["rae"], "snr": c[t]["cos_snr"]} for t in TRANSFORMS}
    out["auto"] = {"chosen": c["chosen"],
                   "rae": [c[t]["rae"][i] for i, t in enumerate(c["chosen"])],
                   "snr": [c[t]["cos_snr"][i] for i, t in enumerate(c["chosen"])],
                   "better_by_rae": [min(TRANSFORMS, key=lambda u, i=i: c[u]["rae"][i]) == t
                                     for i, t in enumerate(c["chosen"])]}
    return out


def main() -> None:
    p = parser(__doc__, json_option=False)
    p.add_argument("--corpus", nargs="+", default=["merl", "rgl"])
    p.add_argument("--counts", nargs="+", type=int, default=[16, 32, 64, 128, 262, 512, 1024])
    p.add_argument("--ensemble", help="default: the shipped one")
    p.add_argument("--no-hosvd", action="store_true", help="skip the HOSVD baseline")
    p.add_argument("--out", default="docs/figures")
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ens = Ensemble.load(args.ensemble) if args.ensemble else Ensemble.default()
    test = [m for c in args.corpus for m in get_corpus(c).split("test")]
    hosvd = None
    if not args.no_hosvd:
        train = [m for c in args.corpus for m in get_corpus(c).split("train")]
        x, _ = training_tensors(train)
        hosvd = hosvd_ensemble(x)
        del x
    info = machine()  # the load average as the timing starts
    results = {"materials": [], "counts": args.counts, "ensemble": ens.id,
               "machine": info, "date": time.strftime("%Y-%m-%d")}
    enc_times = []
    from tqdm import tqdm

    for m in tqdm(test, desc="materials"):
        brdf = m.load()
        t0 = time.perf_counter()
        encode(brdf, ens, 262)
        enc_times.append(time.perf_counter() - t0)
        row = {"name": f"{m.corpus}/{m.name}", "ensemble": measure(brdf, ens, args.counts)}
        if hosvd is not None:
            row["hosvd"] = measure(brdf, hosvd, args.counts)
        results["materials"].append(row)
    results["encode_seconds"] = enc_times
    print(header(info))
    (out / "accuracy.json").write_text(json.dumps(results, indent=1))
    report(results, out)


def report(results: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = results["counts"]
    mats = results["materials"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    series = [("ensemble", t) for t in TRANSFORMS] + [("ensemble", "auto")]
    if "hosvd" in mats[0]:
        series += [("hosvd", "auto")]
    for model, t in series:
        for ax, key, ylabel in ((axes[0], "rae", "RAE (lower is better)"),
                                (axes[1], "snr", "cosine-weighted SNR, dB")):
            v = np.array([r[model][t][key] for r in mats])
            ax.plot(counts, v.mean(0), marker="o", label=f"{model}, {t}")
            ax.set_xscale("log", base=2)
            ax.set_xlabel("coefficients per channel")
            ax.set_ylabel(ylabel)
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{len(mats)} unseen materials (mean); ensemble {results['ensemble'][:8]}")
    fig.savefig(out / "accuracy.png", dpi=100)
    plt.close(fig)

    i262 = counts.index(262) if 262 in counts else len(counts) // 2
    lines = ["| coefficients | " + " | ".join(f"{m}/{t}" for m, t in series) + " |",
             "|---" * (len(series) + 1) + "|"]
    for i, n in enumerate(counts):
        cells = []
        for model, t in series:
            rae_ = np.mean([r[model][t]["rae"][i] for r in mats])
            snr = np.mean([r[model][t]["snr"][i] for r in mats])
            cells.append(f"RAE {rae_:.4f}, {snr:.1f} dB")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    agree = sum(r["ensemble"]["auto"]["better_by_rae"][i262] for r in mats)
    chose = [r["ensemble"]["auto"]["chosen"][i262] for r in mats]
    enc = np.array(results["encode_seconds"])
    lines += ["", f"At {counts[i262]} coefficients the gamma-mapped MSE picked the transform "
              f"with the lower BRDF-space RAE for {agree} of {len(mats)} materials "
              f"(log-plus {chose.count('log-plus')}, log-plus-cosine "
              f"{chose.count('log-plus-cosine')}).",
              f"Encode time (262 coefficients, both transforms, {len(mats)} materials): "
              f"mean {enc.mean():.2f} s, max {enc.max():.2f} s."]
    (out / "accuracy.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
