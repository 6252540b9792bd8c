"""Memory-read costs behind the plugin decoders' speed (issue 4), on Dr.Jit's LLVM backend.

    .venv/bin/python benchmarks/bench_gathers.py

Times 2^22 random lookups (2^20 for the term loops) on all cores and prints lookups/s:
one float from a 16 KB / 0.5 MB / 15 MB table, a 16-float packet from the same tables
(what the grouped decoder reads per row), and a 262-term loop as the strict decoder runs
it: per-term reads of the coefficient, its atom index and the atom value, against the
same loop reading the atom values from Dr.Jit local memory filled once per lookup.
"""

from __future__ import annotations

import time

import drjit as dr
import numpy as np
from drjit.llvm import ArrayXf, Float, UInt32


def rate(f, n: int, make_index, repeats: int = 5) -> float:
    """Lookups per second of f(index), median of ``repeats`` runs after a warm-up."""
    times = []
    for r in range(repeats + 1):
        idx = make_index(n, r)
        dr.eval(idx)
        dr.sync_thread()
        t0 = time.perf_counter()
        dr.eval(f(idx))
        dr.sync_thread()
        if r:
            times.append(time.perf_counter() - t0)
    return n / float(np.median(times))


def main() -> None:
    rng = np.random.default_rng(0)
    n = 1 << 22
    print("| read | table | lookups/s |\n|---|---|---|")
    for rows in (256, 8100, 8100 * 15):
        tab = Float(rng.random(rows * 16).astype(np.float32))

        def index(size, r, rows=rows):
            return UInt32(np.random.default_rng(r).integers(0, rows, size).astype(np.uint32))

        def one(i, tab=tab):
            return dr.gather(Float, tab, i * 16)

        def packet(i, tab=tab):
            pk = dr.gather(ArrayXf, tab, i, shape=(16, dr.width(i)))
            acc = pk[0]
            for w in range(1, 16):
                acc = acc + pk[w]
            return acc

        size = rows * 16 * 4
        print(f"| 1 float | {size / 2**20:.2f} MB | {rate(one, n, index) / 1e6:.0f} M |")
        print(f"| 16-float packet | {size / 2**20:.2f} MB | {rate(packet, n, index) / 1e6:.0f} M |")

    # the strict decoder's term loop: 262 terms, 20 distinct atoms of one mode
    t_terms, k_atoms = 262, 20
    s_buf = Float(rng.random(t_terms).astype(np.float32))
    a_buf = UInt32(rng.integers(0, k_atoms, t_terms).astype(np.uint32))
    rows_ = Float(rng.random(k_atoms * 90).astype(np.float32))  # (K, 90) atom rows
    rows_t = Float(rng.random(90 * 24).astype(np.float32))  # (90, 24) transposed, padded
    n_terms = dr.opaque(UInt32, t_terms)

    def bins(size, r):
        return UInt32(np.random.default_rng(r).integers(0, 90, size).astype(np.uint32))

    def gathered(i):
        def body(t, acc):
            s = dr.gather(Float, s_buf, t)
            a = dr.gather(UInt32, a_buf, t)
            return t + 1, acc + s * dr.gather(Float, rows_, a * 90 + i)

        return dr.while_loop((UInt32(0), Float(0)), lambda t, acc: t < n_terms, body)[1]

    def local(i):
        loc = dr.alloc_local(Float, 24)
        for h in range(3):
            pk = dr.gather(ArrayXf, rows_t, i * 3 + h, shape=(8, dr.width(i)))
            for w in range(8):
                loc[8 * h + w] = pk[w]

        def body(t, acc):
            s = dr.gather(Float, s_buf, t)
            a = dr.gather(UInt32, a_buf, t)
            return t + 1, acc + s * loc[a]

        return dr.while_loop((UInt32(0), Float(0)), lambda t, acc: t < n_terms, body)[1]

    m = 1 << 20
    print(f"\n262-term loop, atom values gathered per term: {rate(gathered, m, bins) / 1e6:.2f} "
          f"M lookups/s\n262-term loop, atom values in local memory: "
          f"{rate(local, m, bins) / 1e6:.2f} M lookups/s")


if __name__ == "__main__":
    main()
