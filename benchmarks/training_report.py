"""Training time and objective per iteration of an ensemble, from its stored history.

    .venv/bin/python benchmarks/training_report.py [ENSEMBLE.npz] --out docs/figures

Writes ``training.png`` and ``training.md`` (one table row per sparsity and iteration).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sparse_brdf.model.ensemble import resolve_ensemble


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("ensemble", nargs="?", help="default: the shipped ensemble")
    p.add_argument("--out", default="docs/figures")
    args = p.parse_args()
    ens = resolve_ensemble(args.ensemble)
    hist = ens.meta["history"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # lazy: matplotlib is slow to import, and the backend must be chosen before pyplot
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    lines = ["| tau | iteration | clustered | moved | relative error | seconds |",
             "|---|---|---|---|---|---|"]
    total = 0.0
    for tau, h in hist.items():
        ax.plot([r["iteration"] for r in h], [r["relative_objective"] for r in h], marker="o",
                label=f"tau = {tau}")
        for r in h:
            total += r["seconds"]
            lines.append(f"| {tau} | {r['iteration']} | {'yes' if r['assigned'] else 'no'} | "
                         f"{r['moved']} | {r['relative_objective']:.4e} | {r['seconds']:.0f} |")
    ax.set_xlabel("iteration")
    ax.set_ylabel("training error / data energy (transformed)")
    ax.set_yscale("log")
    ax.legend()
    fig.savefig(out / "training.png", dpi=100)
    lines += ["", f"{ens.meta['n_tensors']} tensors, {ens.n_dicts} dictionaries; iterations "
              f"{total:.0f} s, whole training {ens.meta['seconds']:.0f} s, loading "
              f"{ens.meta.get('load_seconds', 0):.0f} s."]
    (out / "training.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
