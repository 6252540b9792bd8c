"""Render speed of one material stored as file version 1 and version 2.

    .venv/bin/python benchmarks/archive/bench_file_versions.py [--material mitsuba:cu-ggx-0.12]
        [--rounds 5] [--res 128] [--spp 16]

Encodes the material once (default encoder, 262 coefficients per channel), writes it as
version 1 and version 2, then, for both decoders: the time to load each file (read,
dequantise, build the plugin's buffers: ``mi.load_dict``), its BSDF evaluations per
second, and the median render time of ``sphere.xml`` over interleaved rounds (every case
once per round, after one warm-up render each, so that compilation is excluded and the
machine's slow and fast phases hit all cases alike). Version 2's values are dequantised
to float32 when the file is read, so the plugin's buffers have the same layout and size
and only their values differ by the quantisation.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from sparse_brdf.benchmark.speed import eval_rate
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.evaluation.render import SHARED_PATHS, render_scene
from sparse_brdf.evaluation.scenes import find_scene
from sparse_brdf.sources.load import load_brdf


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--material", default="mitsuba:cu-ggx-0.12")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--res", type=int, default=128)
    p.add_argument("--spp", type=int, default=16)
    args = p.parse_args()
    import mitsuba as mi  # lazy: only the timing needs the renderer

    import mitsuba_plugin
    from sparse_brdf.mitsuba_env import set_variant

    set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()
    ens = Ensemble.default()
    model = encode(load_brdf(args.material), ens)
    tmp = Path(tempfile.mkdtemp())
    files = {v: str(save_sbrdf(tmp / f"v{v}.sbrdf", model, version=v)) for v in (1, 2)}
    cases = [(v, d) for d in ("grouped", "strict") for v in (1, 2)]
    load_s, rate = {}, {}
    for v, d in cases:
        t0 = time.perf_counter()
        bsdf = mi.load_dict({"type": "sparse_brdf", "filename": files[v], "decoder": d})
        load_s[(v, d)] = time.perf_counter() - t0
        rate[(v, d)] = eval_rate(bsdf, n=1 << 18)
        del bsdf

    def render(v, d):
        return render_scene(find_scene("sphere.xml"), {"material": files[v]}, sampling=SHARED_PATHS,
                            spp=args.spp, seed=0,
                            res=args.res, sparse_options={"decoder": d})

    for case in cases:  # warm-up: compile every kernel once
        render(*case)
    times: dict = {c: [] for c in cases}
    for _ in range(args.rounds):
        for case in cases:
            t0 = time.perf_counter()
            render(*case)
            times[case].append(time.perf_counter() - t0)
    print(f"{args.material}, {int(model.n_coeffs.sum())} coefficients; "
          f"{os.path.getsize(files[1])} B (v1), {os.path.getsize(files[2])} B (v2); "
          f"{args.res}x{args.res}, {args.spp} spp, {args.rounds} rounds; "
          f"{platform.node()}, {len(os.sched_getaffinity(0))} cores, "
          f"load average {os.getloadavg()[0]:.1f}, {time.strftime('%Y-%m-%d')}")
    print("| decoder | version | load (s) | evals/s | render median (s) | render / v1 |")
    print("|---|---|---|---|---|---|")
    for v, d in cases:
        med = float(np.median(times[(v, d)]))
        ratio = float(np.median(np.array(times[(v, d)]) / np.array(times[(1, d)])))
        print(f"| {d} | {v} | {load_s[(v, d)]:.3f} | {rate[(v, d)]:.3g} | {med:.3f} | "
              f"{ratio:.3f} |")


if __name__ == "__main__":
    main()
