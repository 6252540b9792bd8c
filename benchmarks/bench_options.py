"""The encoder's options, one at a time and combined, on the test materials.

    .venv/bin/python benchmarks/bench_options.py [--json out.json] [--n N]

For every test material of MERL and RGL (14 + 7; the shared data are needed) and every
option set below, encodes at 262 coefficients per channel with the shipped ensemble and
reports, over the materials, the mean and the minimum of

- the cosine-weighted SNR (``metrics.cosine_weighted_snr``, dB), and
- the render-proxy SNR: 10 log10(P(ref, 0) / P(ref, rec)) with P the render-proxy error
  on valid bins (``metrics.render_proxy_error``; the proxy of a zero reconstruction is
  the signal), so that materials of different brightness average fairly,

the geometric mean of the render-proxy error relative to the paper's encoder, how many
materials it improves, and the encode time (wall and process CPU seconds, numpy threads
at their default). No renders: see ``docs/method.md``, "Encoding", for why the proxy
predicts them.
"""

from __future__ import annotations

import time

import numpy as np
from harness import header, machine, parser, write_json

from sparse_brdf import Ensemble, encode, get_corpus
from sparse_brdf.metrics import cosine_weighted_snr, make_render_proxy, render_proxy_error

PAPER = "paper (defaults)"
VARIANTS = {
    PAPER: {},
    "selector=render": dict(selector="render"),
    "fill=invalid": dict(fill="invalid"),
    "basis=opponent": dict(basis="opponent"),
    "rgb, budget=joint": dict(budget="joint"),
    "render + fill": dict(selector="render", fill="invalid"),
    "render + opponent": dict(selector="render", basis="opponent"),
    "fill + opponent": dict(fill="invalid", basis="opponent"),
    "all three": dict(selector="render", fill="invalid", basis="opponent"),
}


def measure(n: int | None, corpora: list[str], variants: list[str]) -> list[dict]:
    """One row per material and option set (``variants``: names of ``VARIANTS``)."""
    ens = Ensemble.default()
    kernel = make_render_proxy(ens.shape)
    mats = [m for c in corpora for m in get_corpus(c).split("test")[:n]]
    rows = []
    for mat in mats:
        b = mat.load()
        encode(b, ens)  # warm-up (thread pool, caches)
        zero = render_proxy_error(b.values, np.zeros_like(b.values), kernel, valid=b.valid)
        for name in variants:
            kw = VARIANTS[name]
            t0, c0 = time.perf_counter(), time.process_time()
            m = encode(b, ens, **kw)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            rec = m.decode(ens, valid=b.valid).values
            rows.append(dict(
                material=f"{mat.corpus}/{b.name}", variant=name, wall=wall, cpu=cpu,
                transform=m.transform, coefficients=m.n_coeffs.tolist(),
                cos_snr=cosine_weighted_snr(b.values, rec, b.valid),
                proxy=render_proxy_error(b.values, rec, kernel, valid=b.valid),
                proxy_zero=zero))
            r = rows[-1]
            print(f"{r['material']:34s} {name:18s} {wall:5.2f} s {m.transform:16s} "
                  f"cos-SNR {r['cos_snr']:6.2f} proxy-SNR "
                  f"{10 * np.log10(zero / r['proxy']):6.2f} {r['coefficients']}", flush=True)
    return rows


def table(rows: list[dict]) -> str:
    by = {(r["material"], r["variant"]): r for r in rows}
    mats = list(dict.fromkeys(r["material"] for r in rows))
    out = [f"{len(mats)} materials, 262 coefficients per channel (joint budgets: 786)", "",
           "| options | cos-SNR mean | cos-SNR min | proxy-SNR mean | proxy-SNR min | "
           "proxy error / paper's (geo. mean) | better than paper | wall (s) | CPU (s) |",
           "|---|---|---|---|---|---|---|---|---|"]
    for v in dict.fromkeys(r["variant"] for r in rows):
        xs = [by[m, v] for m in mats if (m, v) in by]
        snr = np.array([x["cos_snr"] for x in xs])
        psnr = np.array([10 * np.log10(x["proxy_zero"] / x["proxy"]) for x in xs])
        ratio = np.array([x["proxy"] / by[x["material"], PAPER]["proxy"] for x in xs])
        out.append(f"| {v} | {snr.mean():.2f} | {snr.min():.2f} | {psnr.mean():.2f} | "
                   f"{psnr.min():.2f} | {np.exp(np.mean(np.log(ratio))):.3f} | "
                   f"{int(np.sum(ratio < 1 - 1e-9))}/{len(xs)} | "
                   f"{np.mean([x['wall'] for x in xs]):.2f} | "
                   f"{np.mean([x['cpu'] for x in xs]):.2f} |")
    return "\n".join(out)


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--n", type=int, default=None, help="at most N materials per corpus")
    p.add_argument("--corpus", nargs="+", default=["merl", "rgl"], help="test splits")
    p.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS),
                   help="option sets (the paper's is always measured: the reference)")
    args = p.parse_args()
    info = machine()  # the load average as the timing starts
    rows = measure(args.n, args.corpus, [PAPER, *(v for v in args.variants if v != PAPER)])
    if args.json:
        write_json(args.json, rows, args, info)
    print()
    print(header(info))
    print(table(rows))


if __name__ == "__main__":
    main()
