"""Byte-budget encoding: the count revised within one encoding against a second
encoding at the count that fitted (docs/benchmarks.md, "Encode time").

    .venv/bin/python benchmarks/bytes_passes.py [--budgets 1600 6300] [--n 14]
        [--corpus merl] [--json PATH]

For each test material and budget, ``encode_to_bytes`` runs twice: as shipped (one
encoding: the fill's later rounds are coded at the count whose file fits, measured
after each fit, ``budget.RECOUNT``) and with ``RECOUNT = False`` (a first encoding at
the generous guess, trimmed, then encoded again at the count that fitted: the method
before). Both files are scored against the full table: cosine-weighted SNR and the
render-proxy error (the encoder's own selector), and timed in this process. The table
gives both and their difference per material.
"""

from __future__ import annotations

import time

import numpy as np
from harness import header, parser, write_json

from sparse_brdf import Ensemble, cosine_weighted_snr, get_corpus
from sparse_brdf.coding import budget
from sparse_brdf.metrics import make_render_proxy, render_proxy_error


def _score(brdf, model, ens, kernel) -> dict:
    rec = model.decode(ens).values
    return {"cos_snr": cosine_weighted_snr(brdf.values, rec, brdf.valid),
            "render_proxy": render_proxy_error(brdf.values, rec, kernel, brdf.valid),
            "transform": model.transform,
            "coeffs": [int(x) for x in model.n_coeffs]}


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--budgets", type=int, nargs="+", default=[1600, 6300])
    p.add_argument("--n", type=int, default=14, help="test materials per corpus")
    p.add_argument("--corpus", nargs="+", default=["merl"])
    args = p.parse_args()
    ens = Ensemble.default()
    mats = [m for c in args.corpus for m in get_corpus(c).split("test")[: args.n]]
    rows = []
    shipped = budget.RECOUNT
    for m in mats:
        brdf = m.load()
        kernel = make_render_proxy(brdf.shape)
        for n_bytes in args.budgets:
            row = {"material": m.name, "budget": n_bytes}
            for label, recount in (("one", shipped), ("two", False)):
                budget.RECOUNT = recount
                t0 = time.perf_counter()
                model = budget.encode_to_bytes(brdf, ens, n_bytes)
                seconds = time.perf_counter() - t0
                row[label] = {**_score(brdf, model, ens, kernel), "seconds": seconds,
                              "passes": model.stats["byte_budget"]["passes"]}
            budget.RECOUNT = shipped
            rows.append(row)
            one, two = row["one"], row["two"]
            print(f"{m.name:28s} {n_bytes:5d}  one: {one['cos_snr']:6.2f} dB "
                  f"{one['render_proxy']:.3g} {one['seconds']:5.2f} s ({one['passes']})  "
                  f"two: {two['cos_snr']:6.2f} dB {two['render_proxy']:.3g} "
                  f"{two['seconds']:5.2f} s ({two['passes']})  {one['transform']}/"
                  f"{two['transform']}", flush=True)
    print(header())
    print("| budget | materials | one pass: mean cos-SNR (dB) | two passes | mean difference "
          "(dB) | one pass has the lower render-proxy error | mean time one / two (s) |")
    print("|---|---|---|---|---|---|---|")
    for n_bytes in args.budgets:
        rs = [r for r in rows if r["budget"] == n_bytes]
        one = np.array([r["one"]["cos_snr"] for r in rs])
        two = np.array([r["two"]["cos_snr"] for r in rs])
        better = sum(r["one"]["render_proxy"] <= r["two"]["render_proxy"] for r in rs)
        t1 = np.mean([r["one"]["seconds"] for r in rs])
        t2 = np.mean([r["two"]["seconds"] for r in rs])
        print(f"| {n_bytes:,} | {len(rs)} | {one.mean():.2f} | {two.mean():.2f} | "
              f"{(one - two).mean():+.2f} (min {(one - two).min():+.2f}, max "
              f"{(one - two).max():+.2f}) | {better} of {len(rs)} | {t1:.2f} / {t2:.2f} |")
    if args.json:
        write_json(args.json, rows, args)


if __name__ == "__main__":
    main()
