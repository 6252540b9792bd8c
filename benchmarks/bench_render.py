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

import gc
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, machine, write_json
from render_timing import default_material, render_cases, scene_args, swap_material, timed_render

from sparse_brdf.benchmark.speed import eval_rate
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.fileio import atomic_write
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.paths import SCENES_DIR
from sparse_brdf.sources.load import load_brdf

COUNTS = (32, 128, 262)
ROW_KEYS = ("bsdf", "render_s", "vs_diffuse", "vs_tabulated", "compile_s", "memory_bytes",
            "evals_per_s")


def _cases(src: str, files: dict[int, Path]) -> list[tuple[str, dict]]:
    """(name, BSDF dict) of every timed case, the fast ones first (so that their renders
    and the table's are close in time)."""
    cases = [("native diffuse", {"type": "diffuse"}), ("native roughconductor",
             {"type": "roughconductor", "material": "Cu", "alpha": 0.12}),
             ("tabulated_brdf", {"type": "tabulated_brdf", "filename": src})]
    for n in files:
        cases.append((f"sparse_brdf grouped {n}", {"type": "sparse_brdf",
                      "filename": str(files[n]), "decoder": "grouped"}))
    if 262 in files:  # the grouped decoder with the other layout forced (an A/B in one run)
        cases.append(("sparse_brdf grouped-slots 262", {"type": "sparse_brdf",
                      "layout": "slots", "filename": str(files[262]), "decoder": "grouped"}))
    for n in files:
        cases.append((f"sparse_brdf strict {n}", {"type": "sparse_brdf",
                      "filename": str(files[n]), "decoder": "strict"}))
    return cases


def _rows(loaded, compile_s: dict, times: dict) -> list[tuple]:
    """One row per case: render seconds, ratios to the first case and to the table (medians
    of the per-round ratios), compile seconds, memory and evaluations per second."""
    base = np.array(times[loaded[0][0]])
    tab_t = np.array(times["tabulated_brdf"])
    rows = []
    for name, scene in loaded:
        bsdf = scene.shapes()[0].bsdf()
        t = np.array(times[name])
        rows.append((name, float(np.median(t)), float(np.median(t / base)),
                     float(np.median(t / tab_t)), compile_s[name],
                     getattr(bsdf, "memory_bytes", None), eval_rate(bsdf)))
    return rows


def _swap_cost(scene_path: Path, first: Path, second: Path, args) -> tuple[int, float]:
    """Kernels compiled anew when a second sparse material follows a first, and the
    second's compile seconds."""
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr
    import mitsuba as mi

    gc.collect()
    dr.flush_kernel_cache()

    def kernels():
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}

    dr.kernel_history()  # clear
    s1 = mi.load_dict(swap_material(scene_path, {"type": "sparse_brdf", "filename": str(first),
                                                 "decoder": "grouped"}, args))
    timed_render(s1, args.spp, 0)
    k1 = kernels()
    s2 = mi.load_dict(swap_material(scene_path, {"type": "sparse_brdf",
                                                 "filename": str(second),
                                                 "decoder": "grouped"}, args))
    first2, _ = timed_render(s2, args.spp, 0)
    return len(kernels() - k1), first2


def _print_table(rows, layouts: dict, swap: tuple[int, float], src: str, args, info) -> None:
    print(f"{args.res}x{args.res}, {args.spp} spp, sphere.xml; material {src}; "
          f"{args.repeats} interleaved rounds; {header(info)}")
    print("| BSDF | render (s) | vs diffuse | vs tabulated | compile (s) | memory (bytes) | "
          "evals/s |")
    print("|---|---|---|---|---|---|---|")
    for name, t, rel, rel_tab, comp, mem, rate in rows:
        print(f"| {name} | {t:.3f} | {rel:.2f}x | {rel_tab:.2f}x | {comp:.2f} | "
              f"{'' if mem is None else f'{mem:,}'} | {rate / 1e6:.1f} M |")
    print(f"\nSwapping to a second sparse material: {swap[0]} kernels compiled anew "
          f"(compile {swap[1]:.2f} s).")
    print("Grouped layouts: " + ", ".join(f"{n}: {lay} ({pk} packets per lookup)"
                                          for n, (lay, pk) in layouts.items()))


def main() -> None:
    p = scene_args(__doc__)
    p.add_argument("--out", type=Path, default=None,
                   help="also write render_speed.json and the speed/memory chart "
                        "render_speed.png into this folder")
    p.add_argument("--counts", default=",".join(map(str, COUNTS)),
                   help="coefficients per channel of the sparse cases, comma-separated")
    args = p.parse_args()
    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr

    set_variant("llvm_ad_rgb")
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    info = machine()  # the load average as the timing starts

    src = default_material(args.material)
    ens = Ensemble.default()
    brdf = load_brdf(src)
    tmp = Path(tempfile.mkdtemp())
    counts = [int(n) for n in args.counts.split(",")]
    files = {n: save_sbrdf(tmp / f"m{n}.sbrdf", encode(brdf, ens, n)) for n in counts}
    second = save_sbrdf(tmp / "other.sbrdf", encode(load_brdf("mitsuba:au-ggx-0.25"), ens, 262))
    compile_s, loaded, times = render_cases(_cases(src, files), args)
    rows = _rows(loaded, compile_s, times)
    layouts = {name.split(" ", 1)[1]: (scene.shapes()[0].bsdf().layout,
                                       scene.shapes()[0].bsdf().packets)
               for name, scene in loaded if "grouped" in name}
    del loaded  # swapping materials: a second sparse material reuses the compiled kernels
    swap = _swap_cost(SCENES_DIR / "sphere.xml", files[max(files)], second, args)
    _print_table(rows, layouts, swap, src, args, info)
    record = {"material": src, "res": args.res, "spp": args.spp,
              "rounds": args.repeats, "date": time.strftime("%Y-%m-%d"),
              "rows": [dict(zip(ROW_KEYS, r, strict=True)) for r in rows],
              "swap_new_kernels": swap[0],
              "grouped_layouts": {n: {"layout": lay, "packets": pk}
                                  for n, (lay, pk) in layouts.items()}}
    if args.json:
        write_json(args.json, record, args, info)
    if args.out is not None:
        write_json(args.out / "render_speed.json", record, args, info)
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
    # the decoders' goals at 262 coefficients: grouped <= 1.0x, strict <= 1.5x the table
    for goal, color in ((1.0, "tab:red"), (1.5, "tab:blue")):
        axes[0].axhline(goal, color=color, linestyle="--", linewidth=0.8, alpha=0.6)
    axes[0].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Plugins on the sphere scene ({record['res']}x{record['res']}, "
                 f"{record['spp']} spp; labels: coefficients per channel)")
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
