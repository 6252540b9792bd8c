"""Memory-read costs behind the plugin decoders' speed, on Dr.Jit's LLVM backend.

    .venv/bin/python benchmarks/archive/bench_gathers.py

Times 2^22 random lookups (2^20 for the term loops) on all cores and prints lookups/s:
one float from a 16 KB / 0.5 MB / 15 MB table, a 16-float packet from the same tables
(what the grouped decoder reads per row), and a 262-term loop as the strict decoder runs
it: per-term reads of the coefficient, its atom index and the atom value, against the
same loop reading the atom values from Dr.Jit local memory filled once per lookup.
Then two variants tried for the decoders: the grouped decoder's loop (5 packets of 8 floats
from a table row and from a row of atom values) with float32 against float16 table rows,
and the strict decoder's sorted terms run as one flat loop (group ends flagged) against
nested loops over c groups, (c, b) groups and terms.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import drjit as dr
import numpy as np
from drjit.llvm import ArrayXf, ArrayXf16, Float, Float16, UInt32

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # harness.py is one up
from harness import parser  # noqa: E402


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
    parser(__doc__, json_option=False).parse_args()  # --help
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
    grouped_precision(rng, n)
    strict_nesting(rng, m)


def _aligned(a: np.ndarray, kind):
    """A Dr.Jit array mapped from a 64-byte aligned copy of ``a`` (packet loads)."""
    raw = np.empty(a.size + 64, a.dtype)
    off = (-raw.ctypes.data % 64) // a.itemsize
    out = raw[off:off + a.size]
    out[:] = a
    return kind(out)


def grouped_precision(rng, n: int, width: int = 40, packet: int = 8) -> None:
    """The grouped decoder's loop over 5 packets, float32 against float16 table rows."""
    tab = rng.random(8100 * width).astype(np.float32)
    t32, t16 = _aligned(tab, Float), _aligned(tab.astype(np.float16), Float16)
    vals = _aligned(rng.random(180 * width).astype(np.float32), Float)
    chunks = dr.opaque(UInt32, width // packet)

    def make(half: bool):
        def f(idx):
            pair, g = idx % 8100, idx % 180

            def body(h, acc):
                if half:
                    pk = dr.gather(ArrayXf16, t16, pair * chunks + h, shape=(packet, dr.width(h)))
                    t = [Float(pk[w]) for w in range(packet)]
                else:
                    t = dr.gather(ArrayXf, t32, pair * chunks + h, shape=(packet, dr.width(h)))
                v = dr.gather(ArrayXf, vals, g * chunks + h, shape=(packet, dr.width(h)))
                return h + 1, tuple(dr.fma(t[w], v[w], acc[w]) for w in range(packet))

            init = (dr.zeros(UInt32, dr.width(idx)),
                    (Float(0),) * packet)
            acc = dr.while_loop(init, lambda h, acc: h < chunks, body)[1]
            return sum(acc[1:], acc[0])

        return f

    def index(size, r):
        return UInt32(np.random.default_rng(r).integers(0, 8100 * 180, size).astype(np.uint32))

    print("\n| grouped loop, 5 packets of 8 | lookups/s |\n|---|---|")
    for name, half in (("float32 table rows", False), ("float16 table rows", True)):
        print(f"| {name} | {rate(make(half), n, index) / 1e6:.0f} M |")


def strict_nesting(rng, n: int, t_terms: int = 262, ks=(20, 15, 8)) -> None:
    """The strict decoder's terms sorted by (c, b, a): one flat loop with group-end flags
    against nested loops over c groups, (c, b) groups and terms."""
    sizes = (90, 90, 180)
    a, b, c = (rng.integers(0, k, t_terms) for k in ks)
    order = np.lexsort((a, b, c))
    a, b, c = a[order], b[order], c[order]
    s = Float(rng.standard_normal(t_terms).astype(np.float32))
    rows = [Float(rng.standard_normal(k * m).astype(np.float32))
            for k, m in zip(ks, sizes, strict=True)]
    end_c = np.append(c[1:] != c[:-1], True)
    end_b = end_c | np.append(b[1:] != b[:-1], True)
    packed = UInt32((a | (b << 10) | (c << 20) | (end_b.astype(np.int64) << 30)
                     | (end_c.astype(np.int64) << 31)).astype(np.uint32))
    n_terms = dr.opaque(UInt32, t_terms)

    def flat(idx):
        i, j, k = idx % 90, (idx // 90) % 90, idx % 180

        def body(t, st):
            acc, acc_c, acc_b = st
            p = dr.gather(UInt32, packed, t)
            eb, ec = (p & (1 << 30)) != 0, (p & (1 << 31)) != 0
            acc_b = acc_b + dr.gather(Float, s, t) * dr.gather(Float, rows[0], (p & 1023) * 90 + i)
            u2 = dr.gather(Float, rows[1], ((p >> 10) & 1023) * 90 + j, eb)
            acc_c = dr.select(eb, acc_c + acc_b * u2, acc_c)
            acc_b = dr.select(eb, 0, acc_b)
            u3 = dr.gather(Float, rows[2], ((p >> 20) & 1023) * 180 + k, ec)
            acc = dr.select(ec, acc + acc_c * u3, acc)
            return t + 1, (acc, dr.select(ec, 0, acc_c), acc_b)

        init = (dr.zeros(UInt32, dr.width(idx)), (Float(0), Float(0), Float(0)))
        return dr.while_loop(init, lambda t, st: t < n_terms, body)[1][0]

    bg = np.flatnonzero(np.append(True, (b[1:] != b[:-1]) | (c[1:] != c[:-1])))
    cg = np.flatnonzero(np.append(True, c[bg][1:] != c[bg][:-1]))
    bg_start = UInt32(np.append(bg, t_terms).astype(np.uint32))
    bg_atom = UInt32(b[bg].astype(np.uint32))
    cg_start = UInt32(np.append(cg, bg.size).astype(np.uint32))
    cg_atom = UInt32(c[bg][cg].astype(np.uint32))
    atoms_a = UInt32(a.astype(np.uint32))
    n_cg = dr.opaque(UInt32, cg.size)

    def nested(idx):
        i, j, k = idx % 90, (idx // 90) % 90, idx % 180

        def c_body(g3, acc):
            def b_body(g2, acc_c):
                def t_body(t, acc_b):
                    u1 = dr.gather(Float, rows[0], dr.gather(UInt32, atoms_a, t) * 90 + i)
                    return t + 1, acc_b + dr.gather(Float, s, t) * u1

                t1 = dr.gather(UInt32, bg_start, g2 + 1)
                acc_b = dr.while_loop((dr.gather(UInt32, bg_start, g2), Float(0)),
                                      lambda t, acc_b: t < t1, t_body)[1]
                u2 = dr.gather(Float, rows[1], dr.gather(UInt32, bg_atom, g2) * 90 + j)
                return g2 + 1, acc_c + acc_b * u2

            g1 = dr.gather(UInt32, cg_start, g3 + 1)
            acc_c = dr.while_loop((dr.gather(UInt32, cg_start, g3), Float(0)),
                                  lambda g2, acc_c: g2 < g1, b_body)[1]
            u3 = dr.gather(Float, rows[2], dr.gather(UInt32, cg_atom, g3) * 180 + k)
            return g3 + 1, acc + acc_c * u3

        init = (dr.zeros(UInt32, dr.width(idx)), Float(0))
        return dr.while_loop(init, lambda g3, acc: g3 < n_cg, c_body)[1]

    def index(size, r):
        return UInt32(np.random.default_rng(r).integers(0, 90 * 90 * 180, size).astype(np.uint32))

    print(f"\n| strict term loop, {t_terms} terms in {bg.size} (c, b) groups | lookups/s |\n"
          "|---|---|")
    for name, f in (("flat, group ends flagged", flat), ("nested: c groups, (c, b) groups, "
                                                            "terms", nested)):
        print(f"| {name} | {rate(f, n, index) / 1e6:.2f} M |")


if __name__ == "__main__":
    main()
