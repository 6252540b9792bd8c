"""Training time and objective per iteration of an ensemble, from its stored history.

    .venv/bin/python benchmarks/training_report.py [ENSEMBLE.npz] --out docs/figures
    .venv/bin/python benchmarks/training_report.py --checkpoint-dir ckpt/ --out /tmp/r

Writes ``training.png`` (relative objective per iteration), ``training_objective.png``
(the objective curve: before and after each iteration's dictionary update, clusterings
marked, and the fraction of tensors each clustering moved), ``training_time.png`` (where
the time went: loading, and per sparsity its initialisation, clustering, dictionary
updates and re-coding) and ``training.md`` (one table row per sparsity and iteration,
with the same split of its seconds). With ``--checkpoint-dir`` the histories are read
from a running (or interrupted) training's checkpoints instead.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from harness import parser

from sparse_brdf.coding.ensemble import resolve_ensemble


def _histories(args) -> tuple[dict, dict]:
    """{tau: history} and the ensemble's meta (empty for checkpoints)."""
    if args.checkpoint_dir:
        hist = {}
        for p in sorted(Path(args.checkpoint_dir).glob("tau-*.npz"),
                        key=lambda p: int(p.stem.split("-")[1])):
            with np.load(p, allow_pickle=False) as z:
                hist[p.stem.split("-")[1]] = json.loads(str(z["history"]))
        if not hist:
            raise SystemExit(f"{args.checkpoint_dir}: no tau-*.npz checkpoints")
        return hist, {}
    ens = resolve_ensemble(args.ensemble)
    return ens.meta["history"], {**ens.meta, "n_dicts": ens.n_dicts}


def _plot_objective(hist: dict, meta: dict, path: Path) -> None:
    import matplotlib.pyplot as plt  # lazy: slow to import; backend chosen by the caller

    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, height_ratios=(3, 1),
                                 constrained_layout=True)
    for n, (tau, h) in enumerate(hist.items()):
        colour = f"C{n}"
        total = h[0]["objective"] / h[0]["relative_objective"]
        xs, ys = [], []
        for r in h:  # sawtooth: clustering / re-coding, then the dictionary update
            xs += [r["iteration"] - 0.5, r["iteration"]]
            ys += [r["objective_before_update"] / total, r["relative_objective"]]
        ax.plot(xs[1:], ys[1:], color=colour, lw=1, label=f"tau = {tau}")
        for r in h:
            ax.plot(r["iteration"], r["relative_objective"], "o", color=colour,
                    mfc=colour if r["assigned"] else "white", ms=5)
        cl = [r for r in h if r["assigned"]]
        frac = [r.get("moved_fraction", r["moved"] / meta.get("n_tensors", np.nan))
                for r in cl]
        bx.plot([r["iteration"] for r in cl], frac, "o-", color=colour, ms=4)
    what = "valid bins" if meta.get("masked", False) else "all bins"
    ax.set_ylabel(f"training error / data energy\n(transformed, {what})")
    ax.set_yscale("log")
    ax.legend(title="filled: clustering iteration", fontsize=8, loc="upper right")
    bx.set_ylabel("moved by\nclustering")
    bx.set_yscale("log")
    bx.axhline(meta.get("max_moved", 0.01), color="grey", ls=":", lw=1)
    bx.set_xlabel("iteration")
    fig.savefig(path, dpi=100)


#: The phases of a sparsity's training, as its history records their seconds.
PHASES = (("init", "initialisation"), ("seconds_cluster", "clustering"),
          ("seconds_update", "dictionary update"), ("seconds_code", "re-coding"))


def time_split(hist: dict, meta: dict) -> dict[str, dict[str, float]]:
    """Seconds per phase (:data:`PHASES`) of each sparsity, and loading's (from ``meta``;
    0 for checkpoints): {row: {phase: seconds}}."""
    inits = meta.get("init_seconds", {})
    rows = {"loading": {"loading": float(meta.get("load_seconds", 0.0))}}
    for tau, h in hist.items():
        rows[f"tau = {tau}"] = {label: (float(inits.get(tau, 0.0)) if key == "init" else
                                        sum(float(r.get(key, 0.0)) for r in h))
                                for key, label in PHASES}
    return rows


def _plot_time(rows: dict, path: Path) -> None:
    import matplotlib.pyplot as plt  # lazy: slow to import; backend chosen by the caller

    fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
    labels = list(rows)[::-1]
    phases = ["loading"] + [label for _, label in PHASES]
    left = np.zeros(len(labels))
    for n, phase in enumerate(phases):
        w = np.array([rows[r].get(phase, 0.0) for r in labels])
        ax.barh(labels, w, left=left, color=f"C{n}", label=phase)
        left += w
    for y, total in enumerate(left):
        ax.text(total, y, f" {total:.0f} s", va="center", fontsize=8)
    ax.set_xlabel(f"seconds (the phases together: {left.sum():.0f} s)")
    ax.set_xlim(0, left.max() * 1.15)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.savefig(path, dpi=100)


def main() -> None:
    p = parser(__doc__, json_option=False)
    p.add_argument("ensemble", nargs="?", help="default: the shipped ensemble")
    p.add_argument("--checkpoint-dir", help="read the histories from these checkpoints")
    p.add_argument("--out", default="docs/figures")
    args = p.parse_args()
    hist, meta = _histories(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # lazy: matplotlib is slow to import, and the backend must be chosen before pyplot
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    lines = ["| tau | iteration | clustered | moved | relative error | seconds (clustering "
             "+ update + re-coding) |", "|---|---|---|---|---|---|"]
    total = 0.0
    for tau, h in hist.items():
        ax.plot([r["iteration"] for r in h], [r["relative_objective"] for r in h], marker="o",
                label=f"tau = {tau}")
        for r in h:
            total += r["seconds"]
            lines.append(f"| {tau} | {r['iteration']} | {'yes' if r['assigned'] else 'no'} | "
                         f"{r['moved']} | {r['relative_objective']:.4e} | {r['seconds']:.0f} "
                         f"({r.get('seconds_cluster', 0):.0f} + {r.get('seconds_update', 0):.0f}"
                         f" + {r.get('seconds_code', 0):.0f}) |")
    ax.set_xlabel("iteration")
    ax.set_ylabel("training error / data energy (transformed)")
    ax.set_yscale("log")
    ax.legend()
    fig.savefig(out / "training.png", dpi=100)
    _plot_objective(hist, meta, out / "training_objective.png")
    split = time_split(hist, meta)
    _plot_time(split, out / "training_time.png")
    lines += ["", "| where the time went | " + " | ".join(label for _, label in PHASES)
              + " | total |", "|---" * (len(PHASES) + 2) + "|"]
    for row, phases in split.items():
        if row != "loading":
            lines.append(f"| {row} | " + " | ".join(f"{v:.0f} s" for v in phases.values())
                         + f" | {sum(phases.values()):.0f} s |")
    if meta:
        opts = ", ".join(f"{k} {meta[k]}" for k in ("masked", "init", "basis", "reassign_every",
                                                     "tol", "max_moved") if k in meta)
        lines += ["", f"{meta['n_tensors']} tensors, {meta['n_dicts']} dictionaries; "
                  f"iterations {total:.0f} s, whole training {meta['seconds']:.0f} s, loading "
                  f"{meta.get('load_seconds', 0):.0f} s." + (f" Options: {opts}." if opts else "")]
    else:
        lines += ["", f"from checkpoints: iterations {total:.0f} s so far."]
    (out / "training.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
