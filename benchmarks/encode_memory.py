"""Whole ``sparse-brdf encode`` commands under different process memory settings.

    .venv/bin/python benchmarks/encode_memory.py [--n 8] [--repeats 3] [-- --bytes 6300]

Each material is encoded as a new process under each setting, interleaved (the order
reverses every round), and each setting's median per material is taken; the line gives
the mean over materials. The settings: ``plain`` (the command's own: no madvised huge
pages, glibc's malloc thresholds raised), ``huge-pages`` (numpy's madvised huge pages
back on), ``glibc-default`` (glibc's own malloc thresholds), ``arena-1`` (the command's,
plus one malloc arena). Extra arguments after ``--`` go to ``encode``. docs/benchmarks.md,
"Whole commands after cutting fixed costs".
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time

from harness import header, parser, write_json

from sparse_brdf import get_corpus

#: Extra environment of each setting (the command reads these before its own defaults).
SETTINGS = {
    "plain": {},
    "huge-pages": {"NUMPY_MADVISE_HUGEPAGE": "1"},
    # a glibc.malloc tunable that changes nothing: the command then leaves malloc alone
    "glibc-default": {"GLIBC_TUNABLES": "glibc.malloc.check=0"},
    "arena-1": {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=33554432:"
                                  "glibc.malloc.trim_threshold=1073741824:"
                                  "glibc.malloc.arena_max=1"},
}


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--n", type=int, default=8, help="test materials")
    p.add_argument("--corpus", default="merl", help="whose test split")
    p.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS))
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("extra", nargs="*", help="arguments for encode (after --)")
    args = p.parse_args()
    print(header())
    mats = [str(m.source) for m in get_corpus(args.corpus).split("test")[: args.n]]
    settings = {k: SETTINGS[k] for k in args.settings}
    times = {m: {k: [] for k in settings} for m in mats}
    out = tempfile.mkdtemp(prefix="encode-memory-")
    for r in range(args.repeats):
        for m in mats:
            for k in (list(settings) if r % 2 == 0 else list(settings)[::-1]):
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "sparse_brdf.cli", "encode", m, "-o",
                                os.path.join(out, f"{k}.sbrdf"), *args.extra], check=True,
                               env=dict(os.environ, **settings[k]), cwd=out,
                               stdout=subprocess.DEVNULL)
                times[m][k].append(time.perf_counter() - t0)
    rows = {}
    for k in settings:
        med = [statistics.median(times[m][k]) for m in mats]
        rows[k] = {"mean": sum(med) / len(med), "per_material": med}
        print(f"{k:14s} mean {rows[k]['mean']:.3f} s  " + " ".join(f"{x:.2f}" for x in med))
    if args.json:
        write_json(args.json, rows, args)


if __name__ == "__main__":
    main()
