"""Encode time per material with the shipped ensemble (run on an otherwise idle machine).

    .venv/bin/python benchmarks/bench_encode.py [--n 8]
    .venv/bin/python benchmarks/bench_encode.py \
        --options selector=render,fill=invalid,basis=opponent

Times `encode` at 262 coefficients per channel: both transforms (the default) and one
forced transform; tabulation is excluded (materials are loaded first). Each material is
timed ``--repeats`` times (interleaved: every material once per round) and its median
taken, since the virtual machine's speed drifts by 10-20 % from minute to minute; the
table gives the mean and the max over materials of those medians.
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
    p.add_argument("--n", type=int, default=8, help="materials per corpus")
    p.add_argument("--corpus", nargs="+", default=None,
                   help="test splits to time (default: merl, or mitsuba without ../shared)")
    p.add_argument("--options", default="", help="encoder options KEY=VALUE,... (as in the "
                   "bench's sparse model specs), applied to every timed encode")
    p.add_argument("--repeats", type=int, default=3, help="timings per material (median)")
    args = p.parse_args()
    opts = dict(kv.split("=", 1) for kv in args.options.split(",") if kv)
    names = args.corpus or ["merl" if shared_data_dir() else "mitsuba"]
    corpus = "+".join(names)
    mats = [m for c in names for m in get_corpus(c).split("test")[: args.n]]
    ens = Ensemble.default()
    brdfs = [m.load() for m in mats]
    encode(brdfs[0], ens, **opts)  # warm-up (thread pool, caches)
    auto = np.zeros((args.repeats, len(brdfs)))
    forced = np.zeros_like(auto)
    completed = []
    for r in range(args.repeats):
        for i, b in enumerate(brdfs):
            t0 = time.perf_counter()
            m = encode(b, ens, **opts)
            auto[r, i] = time.perf_counter() - t0
            if r == 0:
                completed += [s["projections_completed"] for s in m.stats["transforms"].values()]
            t0 = time.perf_counter()
            encode(b, ens, transform="log-plus-cosine", **opts)
            forced[r, i] = time.perf_counter() - t0
    auto, forced = np.median(auto, axis=0), np.median(forced, axis=0)
    print(f"{len(brdfs)} {corpus} test materials, {ens.n_dicts} dictionaries, "
          f"{len(os.sched_getaffinity(0))} cores, {platform.node()}, {time.strftime('%Y-%m-%d')}, "
          f"options: {args.options or 'defaults'}, median of {args.repeats} per material, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"| mode | mean (s) | max (s) |\n|---|---|---|\n"
          f"| both transforms (auto) | {np.mean(auto):.2f} | {np.max(auto):.2f} |\n"
          f"| one transform (forced) | {np.mean(forced):.2f} | {np.max(forced):.2f} |")
    print(f"\nProjections completed per transform (of {3 * ens.n_dicts}; the rest pruned): "
          f"median {np.median(completed):.0f}, range {min(completed)}-{max(completed)}")


if __name__ == "__main__":
    main()
