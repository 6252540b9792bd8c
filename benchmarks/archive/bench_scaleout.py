"""Scale-out on Dask: in-process against ``--workers N`` for batch encoding, a
bench and one training iteration; encode cost against the number of materials; bytes
moved per training iteration. Results go to docs/benchmarks.md ("Scale-out on Dask").

    .venv/bin/python benchmarks/archive/bench_scaleout.py encode --n 10            # both ways
    .venv/bin/python benchmarks/archive/bench_scaleout.py encode --n 50 --only workers
    .venv/bin/python benchmarks/archive/bench_scaleout.py encode --n 136 --only workers
    .venv/bin/python benchmarks/archive/bench_scaleout.py bench
    .venv/bin/python benchmarks/archive/bench_scaleout.py train --materials 8

Materials for ``encode``: the shared Neural-BRDF networks, MERL's then RGL's, sorted by
name (136 in all); their tabulations are cached after the first run, so run once before
timing. Each mode runs in a fresh temporary folder; the cluster's start-up is timed
apart. Output is quiet (no progress bars): one line per run, then a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.cli.files import encode_batch
from sparse_brdf.coding.ensemble import resolve_ensemble
from sparse_brdf.parallel import executor
from sparse_brdf.paths import shared_data_dir
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.dataset import training_data
from sparse_brdf.training.train import train_dictionaries


def _modes(only: str | None, workers: int) -> list[int | None]:
    modes = {"inprocess": [None], "workers": [workers], None: [None, workers]}
    return modes[only]


def _timed(fn, workers: int | None) -> tuple[float, float, object]:
    """(cluster start-up seconds, run seconds, result) of ``fn(ex)``."""
    t0 = time.perf_counter()
    with executor(workers) as ex:
        t1 = time.perf_counter()
        out = fn(ex)
        t2 = time.perf_counter()
    return t1 - t0, t2 - t1, out


def _header(what: str) -> None:
    load = os.getloadavg()
    print(f"{what}: {platform.node()}, {len(os.sched_getaffinity(0))} cores, "
          f"{time.strftime('%Y-%m-%d %H:%M')}, load average {load[0]:.2f} at start")


def cmd_encode(args) -> None:
    data = shared_data_dir()
    if data is None:
        raise SystemExit("needs ../shared/data (the Neural-BRDF networks)")
    files = (sorted((data / "nbrdf" / "merl").glob("*.h5"))
             + sorted((data / "nbrdf" / "rgl").glob("*.h5")))[: args.n]
    ens = resolve_ensemble(None)
    _header(f"encode {len(files)} materials")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "src"
        src.mkdir()
        for f in files:
            (src / f.name).symlink_to(f)
        for workers in _modes(args.only, args.workers):
            out = Path(tmp) / f"out-{workers}"
            start, secs, summary = _timed(
                lambda ex, out=out: encode_batch(src, out, ens, {}, ex, progress=False),
                workers)
            enc = [r["seconds"] for r in summary["rows"] if r["status"] == "encoded"]
            rows.append((workers, start, secs, summary["failed"], float(np.mean(enc))))
            print(f"  {summary['where']}: {secs:.1f} s (+{start:.1f} s start-up), "
                  f"{summary['failed']} failed, encode {np.mean(enc):.2f} s/material "
                  f"in its process")
    _table(rows, len(files), "materials")


def _table(rows, n, unit) -> None:
    base = next((r[2] for r in rows if r[0] is None), None)
    print(f"\n| where | wall (s) | start-up (s) | s per {unit[:-1]} | speed-up |")
    print("|---|---|---|---|---|")
    for workers, start, secs, *_ in rows:
        ratio = f"{base / secs:.2f}x" if base else "-"
        name = "in-process" if workers is None else f"--workers {workers}"
        print(f"| {name} | {secs:.1f} | {start:.1f} | {secs / n:.2f} | {ratio} |")


def cmd_bench(args) -> None:
    _header("bench")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for workers in _modes(args.only, args.workers):
            cfg = BenchConfig(corpora=["mitsuba"], split="test", max_materials=args.n,
                              models=["sparse:64", "sparse:262", "naive", "tabulated"],
                              curve_coeffs=[16, 64, 262], scenes=["sphere.xml"], spp=8,
                              res=48, speed_evals=1 << 16, stability=False,
                              out=str(Path(tmp) / f"bench-{workers}"))
            start, secs, res = _timed(lambda ex, cfg=cfg: Bench(cfg, progress=False).run(ex),
                                      workers)
            cells = len(res["cells"])
            rows.append((workers, start, secs))
            print(f"  workers={workers}: {secs:.1f} s (+{start:.1f} s start-up), {cells} cells")
    _table(rows, cells, "cells")


def cmd_train(args) -> None:
    mats = get_corpus("merl" if shared_data_dir() else "mitsuba").split("train")
    data = training_data(mats[: args.materials], ("log-plus", "log-plus-cosine"),
                         (90, 90, 180))
    x = data.x
    _header(f"train: {len(x)} tensors of {x.shape[1:]} ({x.nbytes / 1e6:.0f} MB), "
            f"tau {args.tau}, K {args.dicts}, {args.iterations} iteration(s)")
    rows = []
    for workers in _modes(args.only, args.workers):
        def run(ex):
            return train_dictionaries(x, args.tau, args.dicts, n_iter=args.iterations, tol=0,
                                      seed=0, progress=False, missing=data.missing,
                                      executor=ex)

        start, secs, st = _timed(run, workers)
        h = st.history
        it = float(np.mean([r["seconds"] for r in h]))
        rows.append((workers, start, it))
        moved = {k: h[0].get(k) for k in ("bytes_to_workers", "bytes_from_workers", "tasks")}
        print(f"  workers={workers}: init {st.init_seconds:.1f} s, iteration {it:.1f} s "
              f"(cluster {h[0]['seconds_cluster']:.1f}, update {h[0]['seconds_update']:.1f}, "
              f"code {h[0]['seconds_code']:.1f}), total {secs:.1f} s; "
              f"moved per iteration {json.dumps(moved)}")
    _table(rows, 1, "iterations")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    for name, n in (("encode", 10), ("bench", 2), ("train", None)):
        s = sub.add_parser(name)
        if n is not None:
            s.add_argument("--n", type=int, default=n, help="materials")
        s.add_argument("--workers", type=int, default=2)
        s.add_argument("--only", choices=["inprocess", "workers"])
    t = sub.choices["train"]
    t.add_argument("--materials", type=int, default=8, help="MERL training materials")
    t.add_argument("--tau", type=int, default=64)
    t.add_argument("--dicts", type=int, default=4)
    t.add_argument("--iterations", type=int, default=1)
    args = p.parse_args()
    {"encode": cmd_encode, "bench": cmd_bench, "train": cmd_train}[args.what](args)


if __name__ == "__main__":
    main()
