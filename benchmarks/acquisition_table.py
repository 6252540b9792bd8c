"""Encoding from samples: the sparse model with its atom prior against the PCA baseline
(Nielsen et al. 2015), both from the same samples, on merl test-split materials.

    .venv/bin/python benchmarks/acquisition_table.py [--materials A,B] [--n 100,1000]
        [--placements bins,uniform,stratified] [--seed 0] [--json OUT]

Samples are simulated at ``plan(n, placement, seed)`` from the tabulated material
(``--measure table``: each pair gets its bin's value) or from the Neural-BRDF network the
merl table was tabulated from, at the pairs themselves (``--measure nbrdf``: a
continuous BRDF, as a real measurement). Prints the cosine-weighted SNR of each
reconstruction against the full table, the seconds per fit, and the full-table encoding
at 262 coefficients per channel (the sparse fit's budget) for reference. The published
table: ``--materials blue-metallic-paint2,blue-fabric,silver-paint --n 100,1000,10000``
(docs/method.md, "Encoding from samples").
"""

from __future__ import annotations

import time

from harness import header, machine, parser, write_json

from sparse_brdf import Ensemble, encode, encode_samples, get_corpus, pca_from_samples
from sparse_brdf.acquisition.defaults import default_prior, trained_pca
from sparse_brdf.acquisition.planning import measure_nbrdf, measure_table, plan
from sparse_brdf.metrics import cosine_weighted_snr


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--materials", default="blue-metallic-paint2,blue-fabric,silver-paint")
    p.add_argument("--n", default="100,1000,10000")
    p.add_argument("--placements", default="bins,uniform,stratified")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--measure", choices=("table", "nbrdf"), default="table")
    args = p.parse_args()
    ens = Ensemble.default()
    test = {m.name: m for m in get_corpus("merl").split("test")}
    prior, _ = default_prior(ens), trained_pca()  # trained once, outside the timings
    info = machine()
    print(header(info))
    print("| material | placement | N | sparse (dB) | sparse fit (s) | PCA (dB) | PCA fit (s) |"
          " full-table 262 (dB) |\n|---|---|---|---|---|---|---|---|")
    rows = []
    for name in args.materials.split(","):
        brdf = test[name].load()
        full = cosine_weighted_snr(brdf.values, encode(brdf, ens, 262).decode(ens).values,
                                   brdf.valid)
        for placement in args.placements.split(","):
            for n in map(int, args.n.split(",")):
                wi, wo = plan(n, placement, args.seed)
                s = (measure_table(brdf, wi, wo) if args.measure == "table"
                     else measure_nbrdf(test[name].source, wi, wo))
                t0 = time.perf_counter()
                model = encode_samples(s, ens, prior=prior, seed=args.seed)
                ts = time.perf_counter() - t0
                sp = cosine_weighted_snr(brdf.values, model.decode(ens).values, brdf.valid)
                t0 = time.perf_counter()
                pca = pca_from_samples(s, seed=args.seed)
                tp = time.perf_counter() - t0
                pc = cosine_weighted_snr(brdf.values, pca.reconstruct(), brdf.valid)
                rows.append({"material": name, "placement": placement, "n": n,
                             "sparse_db": sp, "sparse_s": ts, "pca_db": pc, "pca_s": tp,
                             "full_table_db": full, "sparse_coeffs": int(model.n_coeffs.sum()),
                             "pca_components": pca.info["n_coeffs"]})
                print(f"| {name} | {placement} | {n} | {sp:.1f} | {ts:.1f} | {pc:.1f} | "
                      f"{tp:.1f} | {full:.1f} |", flush=True)
    if args.json:
        write_json(args.json, {"rows": rows}, args, info)


if __name__ == "__main__":
    main()
