"""Experiment: how fast can a decoder that holds only the nonzero terms and their atom
rows be on Mitsuba's LLVM backend if every material gets its own kernel?

The plugin's strict decoder loops over the terms with one kernel for every material, and
every term's atom indices are data: each read is a 16-lane gather (docs/benchmarks.md).
Here the structure goes into the kernel instead ("unrolled"): per lookup, the atom rows
of the union of the three channels' distinct atoms are read as 8-float packets, one row
per mode, and the terms are traced as straight-line multiply-adds nested as
sum_c U3[k, c] sum_b U2[j, b] sum_a s U1[i, a], with the coefficients s as kernel inputs
(``dr.opaque``). Same memory as the strict decoder, but a new kernel (and a cold LLVM
compile) for every material whose atom structure differs. Not offered by the plugin:
this benchmark answers whether dropping the one-kernel rule would reach the
strict decoder's goal (<= 1.5x ``tabulated_brdf``).

    HOME=$(mktemp -d) .venv/bin/python benchmarks/archive/bench_unrolled.py [--material SOURCE]

(a fresh HOME empties Dr.Jit's on-disk kernel cache, so compile times are cold). Prints
a markdown table: render time (median of interleaved rounds, ratio to tabulated_brdf as
the median of per-round ratios), cold compile time of each case alone, memory, BSDF
evaluations per second, and the largest relative difference between the unrolled and
the strict decoder's eval at random directions.
"""

from __future__ import annotations

import importlib
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sparse_brdf.benchmark.speed import eval_rate, random_directions
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.decoders.layouts import channel_terms
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.sources.load import load_brdf

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # render_timing.py is one up
from render_timing import default_material, render_cases, scene_args  # noqa: E402


def unrolled_data(model, ensemble, packet: int = 8):
    """(rows, terms): per mode an (n_m, P_m) float32 array whose column p is the p-th
    distinct (dictionary, atom) of that mode over the three channels (P_m padded to
    whole packets), and per channel the terms (s, p1, p2, p3) sorted by (p3, p2, p1)."""
    keys: list[dict] = [{}, {}, {}]
    chans = []
    for c in range(3):
        s, modes, _ = channel_terms(model, ensemble, c)
        d = int(model.dict_index[c])
        pos = []
        for m in range(3):
            for a in np.unique(modes[m]):
                keys[m].setdefault((d, int(a)), len(keys[m]))
            pos.append(np.array([keys[m][(d, int(a))] for a in modes[m]], np.int64))
        chans.append((s, pos))
    rows = []
    for m in range(3):
        width = packet * -(-max(len(keys[m]), 1) // packet)
        r = np.zeros((model.shape[m], width), np.float32)
        for (d, a), p in keys[m].items():
            r[:, p] = ensemble.dictionary(d)[m][:, a]
        rows.append(r)
    terms = []
    for s, (p1, p2, p3) in chans:
        order = np.lexsort((p1, p2, p3))
        terms.append([(float(s[t]), int(p1[t]), int(p2[t]), int(p3[t])) for t in order])
    return rows, terms


def nested_sum(ops_fma, terms, u1, u2, u3):
    """sum_c u3[c] sum_b u2[b] sum_a s u1[a] over ``terms`` sorted by (c, b, a)."""
    acc = acc_c = acc_b = None
    prev = None

    def add(x, y, z):
        return x * y if z is None else ops_fma(x, y, z)

    for s, a, b, c in terms:
        if prev is not None and (b, c) != prev[:2]:
            acc_c = add(acc_b, u2[prev[0]], acc_c)
            acc_b = None
            if c != prev[1]:
                acc = add(acc_c, u3[prev[1]], acc)
                acc_c = None
        acc_b = add(s, u1[a], acc_b)
        prev = (b, c)
    acc_c = add(acc_b, u2[prev[0]], acc_c)
    return add(acc_c, u3[prev[1]], acc)


def make_unrolled_class():
    """A subclass of the current variant's SparseBSDF whose strict lookups are unrolled
    (nearest bins only; construct it with decoder="strict")."""
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr
    import mitsuba as mi

    import mitsuba_plugin
    from mitsuba_plugin.kernels import Ops, VariantNamespace

    _, sparse, _ = mitsuba_plugin.classes()
    ops = Ops(VariantNamespace(importlib.import_module(f"mitsuba.{mi.variant()}")))

    class UnrolledBSDF(sparse):
        def _build_strict(self, model, ens) -> None:
            rows, terms = unrolled_data(model, ens)
            self._u_width = [r.shape[1] for r in rows]
            self._u_rows = [ops.floats(r) for r in rows]
            self._u_terms = [[(ops.f(s), a, b, c) for s, a, b, c in t] for t in terms]
            self._u_cache = {}
            self.memory_bytes = sum(r.nbytes for r in rows) + 4 * sum(map(len, terms))
            self.channels = []

        def _x_strict(self, c, bins, lin, active):
            if lin is not None:
                raise NotImplementedError("the experiment covers nearest-bin lookups")
            key = tuple(b.index for b in bins)
            if key not in self._u_cache:  # the three channels share the row reads
                us = []
                for m in range(3):
                    per = self._u_width[m] // 8
                    us.append([x for h in range(per) for x in
                               ops.gather_packet(self._u_rows[m], bins[m] * per + h, 8,
                                                 active)])
                self._u_cache = {key: us}
            u1, u2, u3 = self._u_cache[key]
            return nested_sum(dr.fma, self._u_terms[c], u1, u2, u3)

    return UnrolledBSDF


def max_rel_diff(a, b) -> float:
    """Largest |a - b| / max(|b|, 1e-3 max|b|) over all channels."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    floor = 1e-3 * np.abs(b).max()
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), floor)))


def main() -> None:
    args = scene_args(__doc__, json_option=False).parse_args()
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr
    import mitsuba as mi

    import mitsuba_plugin

    set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    unrolled = make_unrolled_class()
    mi.register_bsdf("sparse_brdf_unrolled", lambda props: unrolled(props))

    src = default_material(args.material)
    ens = Ensemble.default()
    brdf = load_brdf(src)
    tmp = Path(tempfile.mkdtemp())
    files = {n: save_sbrdf(tmp / f"m{n}.sbrdf", encode(brdf, ens, n)) for n in (32, 128, 262)}
    cases = [("tabulated_brdf", {"type": "tabulated_brdf", "filename": src})]
    for dec in ("grouped", "strict"):
        cases.append((f"sparse_brdf {dec} 262", {"type": "sparse_brdf", "decoder": dec,
                                                  "filename": str(files[262])}))
    for n in (32, 128, 262):
        cases.append((f"unrolled {n}", {"type": "sparse_brdf_unrolled", "decoder": "strict",
                                        "filename": str(files[n])}))
    compile_s, loaded, times = render_cases(cases, args)
    tab_t = np.array(times["tabulated_brdf"])

    # the unrolled and the strict decoder at the same random directions
    si, wo = random_directions(1 << 16, np.random.default_rng(1))
    bsdfs = {name: scene.shapes()[0].bsdf() for name, scene in loaded}
    ctx = mi.BSDFContext()
    diff = max_rel_diff(bsdfs["unrolled 262"].eval(ctx, si, wo),
                        bsdfs["sparse_brdf strict 262"].eval(ctx, si, wo))

    print(f"\n{args.res}x{args.res}, {args.spp} spp, sphere.xml; material {src}; "
          f"{args.repeats} interleaved rounds; {platform.node()}, {time.strftime('%Y-%m-%d')}")
    print("| BSDF | render (s) | vs tabulated | compile (s) | memory (bytes) | evals/s |")
    print("|---|---|---|---|---|---|")
    for name, _ in loaded:
        t = np.array(times[name])
        mem = getattr(bsdfs[name], "memory_bytes", None)
        print(f"| {name} | {np.median(t):.3f} | {np.median(t / tab_t):.2f}x | "
              f"{compile_s[name]:.2f} | {'' if mem is None else f'{mem:,}'} | "
              f"{eval_rate(bsdfs[name]) / 1e6:.1f} M |")
    print(f"\nunrolled vs strict decoder at 262, 65,536 random direction pairs: largest "
          f"relative difference {diff:.1e}")


if __name__ == "__main__":
    main()
