"""Render speed of the plugins, in one run on one scene: sparse_brdf (grouped and strict
decoders, 32 / 128 / 262 coefficients; at 262 also the grouped decoder with its slot layout
forced, an A/B of the two layouts) against tabulated_brdf, native diffuse and native
roughconductor; JIT compile time (first render) and a material swap; memory per material;
BSDF evaluations per second; optionally a speed/memory chart (``--out``).

    HOME=$(mktemp -d) .venv/bin/python benchmarks/bench_render.py [--material SOURCE]
        [--out docs/figures]

(a fresh HOME empties Dr.Jit's on-disk kernel cache, so compile times are cold). Compile
times are measured with each case's scene alone in the process: Mitsuba's kernels include
the code of every live BSDF instance, so beside the other cases a case would also compile
theirs (a real scene pays only for its own materials).

Render times are medians over interleaved rounds (every case once per round, so that the
virtual machine's slow and fast phases hit all cases alike); the ratios are medians of the
per-round ratios. Prints a markdown table (copied into docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sparse_brdf.evaluation.speed import eval_rate
from sparse_brdf.fileio import atomic_write
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.model.encode import encode
from sparse_brdf.model.ensemble import Ensemble
from sparse_brdf.model.sbrdf import save_sbrdf
from sparse_brdf.paths import SCENES_DIR, shared_data_dir
from sparse_brdf.sources.load import load_brdf


def timed_render(scene, spp, repeats):
    """(compile seconds of the first render, median wall seconds of the next renders).

    Compile time is Dr.Jit's own (code generation + LLVM) from the kernel history of the
    first render, with the in-memory and on-disk kernel caches bypassed.
    """
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr
    import mitsuba as mi

    dr.kernel_history()  # clear
    img = mi.render(scene, spp=spp, seed=0)
    dr.eval(img)
    dr.sync_thread()
    hist = dr.kernel_history()
    compile_s = sum(k.get("codegen_time", 0) + k.get("backend_time", 0) for k in hist) / 1e3
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp, seed=r + 1)
        dr.eval(img)
        dr.sync_thread()
        times.append(time.perf_counter() - t0)
    return compile_s, float(np.median(times)) if times else float("nan")


def scene_args(doc: str) -> argparse.ArgumentParser:
    """The options every render benchmark takes (material, resolution, spp, rounds)."""
    p = argparse.ArgumentParser(description=doc,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--material", default=None,
                   help="BRDF source (default: MERL blue-metallic-paint2 if the shared data "
                        "is present, else mitsuba:cu-ggx-0.12)")
    p.add_argument("--res", type=int, default=256)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--repeats", type=int, default=7,
                   help="interleaved rounds (every case rendered once per round)")
    return p


def default_material(src: str | None) -> str:
    """``src``, or the benchmarks' default material."""
    if src is not None:
        return src
    data = shared_data_dir()
    return (str(data / "nbrdf" / "merl" / "blue-metallic-paint2.h5") if data
            else "mitsuba:cu-ggx-0.12")


def render_cases(cases, args) -> tuple[dict, list, dict]:
    """Render every (name, bsdf dict) case on the sphere scene.

    1. Per case, alone in the process: load, first render: cold compile time (Mitsuba's
    kernels call every live BSDF instance's code, so a case loaded beside the others
    would also compile theirs). 2. All cases loaded, then a warm-up render each (the
    kernels compiled while a case was alone no longer apply once the others are alive),
    then ``args.repeats`` interleaved rounds, so that the machine's slow and fast phases hit
    every case alike. Returns (compile seconds, [(name, scene)], render seconds per
    round) keyed by name.
    """
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr
    import mitsuba as mi

    scene_path = SCENES_DIR / "sphere.xml"
    compile_s = {}
    for name, bsdf_dict in cases:
        dr.flush_kernel_cache()
        scene = mi.load_dict(_swap(scene_path, bsdf_dict, args))
        compile_s[name], _ = timed_render(scene, args.spp, 0)
        print(f"{name}: compiled in {compile_s[name]:.2f} s", file=sys.stderr, flush=True)
        del scene
        gc.collect()
    loaded = [(name, mi.load_dict(_swap(scene_path, bsdf_dict, args)))
              for name, bsdf_dict in cases]
    for _, scene in loaded:  # warm-up, once every scene is alive (see above)
        timed_render(scene, args.spp, 0)
    times = {name: [] for name, _ in loaded}
    for r in range(args.repeats):
        print(f"round {r + 1}/{args.repeats}", file=sys.stderr, flush=True)
        for name, scene in loaded:
            t0 = time.perf_counter()
            img = mi.render(scene, spp=args.spp, seed=r + 1)
            dr.eval(img)
            dr.sync_thread()
            times[name].append(time.perf_counter() - t0)
    return compile_s, loaded, times


def main() -> None:
    p = scene_args(__doc__)
    p.add_argument("--out", type=Path, default=None,
                   help="also write render_speed.json and the speed/memory chart "
                        "render_speed.png into this folder")
    args = p.parse_args()
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr
    import mitsuba as mi

    set_variant("llvm_ad_rgb")
    dr.set_flag(dr.JitFlag.KernelHistory, True)

    src = default_material(args.material)
    ens = Ensemble.default()
    brdf = load_brdf(src)
    tmp = Path(tempfile.mkdtemp())
    files = {}
    for n in (32, 128, 262):
        files[n] = save_sbrdf(tmp / f"m{n}.sbrdf", encode(brdf, ens, n))
    second = save_sbrdf(tmp / "other.sbrdf", encode(load_brdf("mitsuba:au-ggx-0.25"), ens, 262))
    scene_path = SCENES_DIR / "sphere.xml"
    cases = [("native diffuse", {"type": "diffuse"}), ("native roughconductor",
             {"type": "roughconductor", "material": "Cu", "alpha": 0.12}),
             ("tabulated_brdf", {"type": "tabulated_brdf", "filename": src})]
    for n in (32, 128, 262):
        cases.append((f"sparse_brdf grouped {n}", {"type": "sparse_brdf",
                      "filename": str(files[n]), "decoder": "grouped"}))
    # the grouped decoder at 262 with the other layout forced (an A/B in the same run);
    # the fast cases first, so that their renders and the table's are close in time
    cases.append(("sparse_brdf grouped-slots 262", {"type": "sparse_brdf", "layout": "slots",
                  "filename": str(files[262]), "decoder": "grouped"}))
    for n in (32, 128, 262):
        cases.append((f"sparse_brdf strict {n}", {"type": "sparse_brdf",
                      "filename": str(files[n]), "decoder": "strict"}))
    compile_s, loaded, times = render_cases(cases, args)
    loaded = [(name, scene, compile_s[name]) for name, scene in loaded]
    base = np.array(times[loaded[0][0]])
    tab_t = np.array(times["tabulated_brdf"])
    rows = []
    for name, scene, comp in loaded:
        bsdf = scene.shapes()[0].bsdf()
        t = np.array(times[name])
        rows.append((name, float(np.median(t)), float(np.median(t / base)),
                     float(np.median(t / tab_t)), comp,
                     getattr(bsdf, "memory_bytes", None), eval_rate(bsdf)))
    layouts = {name.split(" ", 1)[1]: (scene.shapes()[0].bsdf().layout,
                                       scene.shapes()[0].bsdf().packets)
               for name, scene, _ in loaded if "grouped" in name}
    # swapping materials: a second sparse material reuses the compiled kernels
    del loaded, scene, bsdf
    gc.collect()
    dr.flush_kernel_cache()
    def kernels():
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}

    dr.kernel_history()  # clear
    s1 = mi.load_dict(_swap(scene_path, {"type": "sparse_brdf", "filename": str(files[262]),
                                         "decoder": "grouped"}, args))
    timed_render(s1, args.spp, 0)
    k1 = kernels()
    s2 = mi.load_dict(_swap(scene_path, {"type": "sparse_brdf", "filename": str(second),
                                         "decoder": "grouped"}, args))
    first2, _ = timed_render(s2, args.spp, 0)
    compiled = kernels() - k1
    print(f"{args.res}x{args.res}, {args.spp} spp, sphere.xml; material {src}; "
          f"{args.repeats} interleaved rounds; {platform.node()}, {time.strftime('%Y-%m-%d')}")
    print("| BSDF | render (s) | vs diffuse | vs tabulated | compile (s) | memory (bytes) | "
          "evals/s |")
    print("|---|---|---|---|---|---|---|")
    for name, t, rel, rel_tab, comp, mem, rate in rows:
        print(f"| {name} | {t:.3f} | {rel:.2f}x | {rel_tab:.2f}x | {comp:.2f} | "
              f"{'' if mem is None else f'{mem:,}'} | {rate / 1e6:.1f} M |")
    print(f"\nSwapping to a second sparse material: {len(compiled)} kernels compiled anew "
          f"(compile {first2:.2f} s).")
    print("Grouped layouts: " + ", ".join(f"{n}: {lay} ({pk} packets per lookup)"
                                          for n, (lay, pk) in layouts.items()))
    if args.out is not None:
        keys = ("bsdf", "render_s", "vs_diffuse", "vs_tabulated", "compile_s",
                "memory_bytes", "evals_per_s")
        record = {"material": src, "res": args.res, "spp": args.spp,
                  "rounds": args.repeats, "date": time.strftime("%Y-%m-%d"),
                  "rows": [dict(zip(keys, r, strict=True)) for r in rows],
                  "swap_new_kernels": len(compiled),
                  "grouped_layouts": {n: {"layout": lay, "packets": pk}
                                      for n, (lay, pk) in layouts.items()}}
        with atomic_write(args.out / "render_speed.json", "w") as f:
            json.dump(record, f, indent=1)
        plot_speed_memory(record, args.out / "render_speed.png")
        print(f"wrote {args.out / 'render_speed.json'} and {args.out / 'render_speed.png'}")


def plot_speed_memory(record: dict, path: Path) -> None:
    """Two panels over memory per material (log scale): render time relative to
    tabulated_brdf, and BSDF evaluations per second; native BSDFs (no per-material
    memory) as horizontal lines."""
    # lazy: matplotlib is needed only with --out, and its backend is chosen first
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    styles = {"grouped": ("tab:red", "o"), "strict": ("tab:blue", "s"),
              "tabulated_brdf": ("black", "D")}
    for ax, key, label in ((axes[0], "vs_tabulated", "render time / tabulated_brdf"),
                           (axes[1], "evals_per_s", "BSDF evaluations per second")):
        for name, (color, marker) in styles.items():
            pts = [r for r in record["rows"] if r["memory_bytes"]
                   and name in (r["bsdf"], *r["bsdf"].split()[1:2])]
            if not pts:
                continue
            ax.plot([r["memory_bytes"] for r in pts], [r[key] for r in pts], marker=marker,
                    color=color, label=name, linestyle="-" if len(pts) > 1 else "none")
            for r in pts:
                ax.annotate(r["bsdf"].rsplit(" ", 1)[-1] if name != "tabulated_brdf"
                            else "table", (r["memory_bytes"], r[key]),
                            textcoords="offset points", xytext=(4, 4), fontsize=8)
        for r in record["rows"]:
            if not r["memory_bytes"]:
                ax.axhline(r[key], color="gray", linestyle=":", linewidth=1)
                ax.annotate(r["bsdf"], (0.01, r[key]), xycoords=("axes fraction", "data"),
                            ha="left", va="bottom", fontsize=7, color="gray")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("memory per material (bytes)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    # the issue's goals at 262 coefficients: grouped <= 1.0x, strict <= 1.5x the table
    for goal, color in ((1.0, "tab:red"), (1.5, "tab:blue")):
        axes[0].axhline(goal, color=color, linestyle="--", linewidth=0.8, alpha=0.6)
    axes[0].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Plugins on the sphere scene ({record['res']}x{record['res']}, "
                 f"{record['spp']} spp; labels: coefficients per channel)")
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=100)
    plt.close(fig)


def _swap(scene_path, bsdf_dict, args):
    """The sphere scene as a dict with the material replaced (Mitsuba's dict API)."""
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import mitsuba as mi

    import mitsuba_plugin

    mitsuba_plugin.register()
    env = str(scene_path.parent / "envmaps" / "studio.exr")
    return {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": 32,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0.9, 4], [0, 0, 0],
                                                              [0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": args.spp},
                   "film": {"type": "hdrfilm", "width": args.res, "height": args.res,
                            "rfilter": {"type": "box"}}},
        "emitter": {"type": "envmap", "filename": env},
        "sphere": {"type": "sphere", "bsdf": bsdf_dict},
    }


if __name__ == "__main__":
    main()
