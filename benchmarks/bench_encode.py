"""Encode time per material with the shipped ensemble (run on an otherwise idle machine).

    .venv/bin/python benchmarks/bench_encode.py [--n 8]
    .venv/bin/python benchmarks/bench_encode.py \
        --options selector=render,fill=invalid,basis=opponent

Times `encode` at 262 coefficients per channel: both transforms (the default, gamma-MSE
choice) and one forced transform; tabulation is excluded (materials are loaded first).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from sparse_brdf import Ensemble, encode, get_corpus
from sparse_brdf.paths import shared_data_dir


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n", type=int, default=8, help="materials")
    p.add_argument("--options", default="", help="encoder options KEY=VALUE,... (as in the "
                   "bench's sparse model specs), applied to every timed encode")
    args = p.parse_args()
    opts = dict(kv.split("=", 1) for kv in args.options.split(",") if kv)
    corpus = "merl" if shared_data_dir() else "mitsuba"
    mats = get_corpus(corpus).split("test")[: args.n]
    ens = Ensemble.default()
    brdfs = [m.load() for m in mats]
    encode(brdfs[0], ens, **opts)  # warm-up (thread pool, caches)
    auto, forced, completed = [], [], []
    for b in brdfs:
        t0 = time.perf_counter()
        m = encode(b, ens, **opts)
        auto.append(time.perf_counter() - t0)
        completed += [s["projections_completed"] for s in m.stats["transforms"].values()]
        t0 = time.perf_counter()
        encode(b, ens, transform="log-plus-cosine", **opts)
        forced.append(time.perf_counter() - t0)
    print(f"{len(brdfs)} {corpus} test materials, {ens.n_dicts} dictionaries, "
          f"{len(os.sched_getaffinity(0))} cores, {platform.node()}, {time.strftime('%Y-%m-%d')}, "
          f"options: {args.options or 'defaults'}")
    print(f"| mode | mean (s) | max (s) |\n|---|---|---|\n"
          f"| both transforms (auto) | {np.mean(auto):.2f} | {np.max(auto):.2f} |\n"
          f"| one transform (forced) | {np.mean(forced):.2f} | {np.max(forced):.2f} |")
    print(f"\nProjections completed per transform (of {3 * ens.n_dicts}; the rest pruned): "
          f"median {np.median(completed):.0f}, range {min(completed)}-{max(completed)}")


if __name__ == "__main__":
    main()
