"""Encoding a material with unmeasured bins: fitting holes as zeros (the paper) against
filling them from the model (``encode(..., fill_iters=N)``, the default N = 3).

    .venv/bin/python benchmarks/bench_missing.py [SOURCE] [--fraction 0.2]

Removes a random fraction of the measured bins, encodes at 262 coefficients, and prints
the cosine-weighted SNR against the complete material and the encode time.
"""

from __future__ import annotations

import time

import numpy as np
from harness import header, machine, parser, write_json

from sparse_brdf import BRDF, Ensemble, encode, load_brdf
from sparse_brdf.metrics import cosine_weighted_snr
from sparse_brdf.paths import shared_data_dir
from sparse_brdf.sources.corpora import get_corpus


def main() -> None:
    p = parser(__doc__)
    p.add_argument("source", nargs="?", help="default: the first test material")
    p.add_argument("--fraction", type=float, default=0.2)
    args = p.parse_args()
    src = args.source or get_corpus("merl" if shared_data_dir() else "mitsuba").split(
        "test")[0].source
    ens = Ensemble.default()
    clean = load_brdf(src)
    keep = np.random.default_rng(0).random(clean.valid.shape) >= args.fraction
    holes = BRDF(clean.values, clean.valid & keep, clean.name)
    info = machine()  # the load average as the timing starts
    print(f"{src}: {args.fraction:.0%} of the measured bins removed; {header(info)}")
    rows = []
    print("| fill_iters | cos-weighted SNR vs complete (dB) | encode (s) |\n|---|---|---|")
    for n in (0, 1, 3):
        t0 = time.perf_counter()
        rec = encode(holes, ens, 262, fill_iters=n).decode(ens, valid=clean.valid).values
        dt = time.perf_counter() - t0
        snr = cosine_weighted_snr(clean.values, rec, clean.valid)
        rows.append({"fill_iters": n, "cos_snr_db": float(snr), "encode_s": dt})
        print(f"| {n} | {snr:.1f} | {dt:.1f} |")
    full = encode(clean, ens, 262).decode(ens, valid=clean.valid).values
    snr_full = cosine_weighted_snr(clean.values, full, clean.valid)
    print(f"complete material: {snr_full:.1f} dB")
    if args.json:
        write_json(args.json, {"source": src, "fraction": args.fraction, "rows": rows,
                               "complete_cos_snr_db": float(snr_full)}, args, info)


if __name__ == "__main__":
    main()
