"""Many measured materials in one scene: load time, render times, peak memory and SNR.

A grid of N spheres, each with its own material (N distinct ``.sbrdf`` files), under the
studio map, rendered with the ``direct`` integrator in ``llvm_ad_rgb`` with cosine
sampling (the same sample paths for every decoder), for each decoder of ``sparse_brdf``
(``auto`` under the default memory budget, ``grouped``, ``strict``), for one
``sparse_library`` holding the N files (``library``: each sphere names its material by
its ``sbrdf_index`` attribute; ``library_grouped``: the same with a memory budget,
``--library-budget``, for the grouped decoder's tables, up to ``--table-max`` materials)
and for the dense table (``tabulated_brdf`` of each file's decode) where it fits. Each
case runs in a process of its own, which reports its load time, first and second render times and
peak resident memory; ``empty`` is the same spheres with Mitsuba's ``diffuse`` (the
memory a scene holds without any measured material), and ``shared`` the N spheres all
holding the first material. The SNR (whole image, dB) of each decoder's image against
the table's is computed where the table was rendered.

The materials are made once into ``--library`` (kept between runs): the first
``--bases`` materials of the merl training split (Neural-BRDF fits, ``../shared/data``)
encoded with the default encoder, then blends of random pairs of them at random weights
(``sparse_brdf.interpolate``), each a file of its own.

Run: ``.venv/bin/python benchmarks/many_materials.py --json many.json --chart
docs/figures/many_materials.png`` (the results in docs/benchmarks.md, "Many materials").
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from harness import header, parser, write_json

CASES = ("empty", "shared", "library", "library_grouped", "auto", "grouped", "strict",
         "table")


def make_library(folder: Path, n: int, n_bases: int, seed: int = 0) -> list[Path]:
    """``n`` distinct ``.sbrdf`` files in ``folder`` (made where missing): the encoded
    bases, then blends of random pairs of them."""
    import sparse_brdf as sb
    from sparse_brdf.sources.corpora import get_corpus

    folder.mkdir(parents=True, exist_ok=True)
    mats = get_corpus("merl").split("train")[:n_bases]
    bases = []
    for m in mats:
        path = folder / f"base-{m.name}.sbrdf"
        if not path.exists():
            sb.save_sbrdf(path, sb.encode(sb.load_brdf(m.source)))
        bases.append(path)
    rng = np.random.default_rng(seed)
    out = list(bases[:n])
    models = [sb.load_sbrdf(b) for b in bases]
    # blends need one transform: pairs of bases encoded with the same
    pairs = [(i, j) for i in range(len(bases)) for j in range(len(bases))
             if i != j and models[i].transform == models[j].transform]
    while len(out) < n:
        i, j = pairs[int(rng.integers(len(pairs)))]
        alpha = float(np.round(rng.uniform(0.1, 0.9), 3))
        path = folder / f"blend-{len(out):04d}-{i}-{j}-{alpha}.sbrdf"
        if not path.exists():
            sb.save_sbrdf(path, sb.interpolate(models[i], models[j], alpha))
        out.append(path)
    return out


def scene_dict(mi, bsdfs, n_spheres: int, width: int, height: int, spp: int,
               library: bool = False) -> dict:
    """A grid of ``n_spheres`` spheres filling a ``width`` x ``height`` frame, sphere s
    holding ``bsdfs[s % len(bsdfs)]``; ``library``: sphere s also holds the attribute
    ``sbrdf_index`` = s (its material in a ``sparse_library``)."""
    from sparse_brdf.paths import SCENES_DIR

    cols = int(np.ceil(np.sqrt(n_spheres * width / height)))
    rows = -(-n_spheres // cols)
    dist = 1.2 * max(cols * height / width, rows) / np.tan(np.radians(20.0))
    d = {"type": "scene", "integrator": {"type": "direct"},
         "sensor": {"type": "perspective", "fov": 40, "fov_axis": "y",
                    "to_world": mi.ScalarTransform4f().look_at(
                        origin=[0, 0, float(dist) / 2], target=[0, 0, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": width, "height": height},
                    "sampler": {"type": "independent", "sample_count": spp}},
         "env": {"type": "envmap",
                 "filename": str(SCENES_DIR / "envmaps" / "studio.exr")}}
    for s in range(n_spheres):
        r, c = divmod(s, cols)
        d[f"s{s}"] = {"type": "sphere", "radius": 0.45, "bsdf": bsdfs[s % len(bsdfs)],
                      "center": [c - cols / 2 + 0.5, r - rows / 2 + 0.5, 0.0]}
        if library:
            d[f"s{s}"]["sbrdf_index"] = {"type": "uniform", "value": float(s)}
    return d


def run_case(case: str, files: list[str], width: int, height: int, spp: int,
             image: str, library_budget: float = 256.0) -> dict:
    """Load and render one case in this process; its timings and peak memory."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import mitsuba_plugin  # lazy: Mitsuba first

    mitsuba_plugin.register()
    n = len(files)
    t0, c0 = time.perf_counter(), time.process_time()
    if case == "empty":
        bsdfs = [{"type": "diffuse"}]
    elif case == "table":
        bsdfs = [mi.load_dict({"type": "tabulated_brdf", "filename": f, "sampling": "cosine"})
                 for f in files]
    elif case in ("library", "library_grouped"):
        budget = {"memory_budget": library_budget} if case == "library_grouped" else {}
        bsdfs = [mi.load_dict({"type": "sparse_library", "filenames": ",".join(files),
                               "sampling": "cosine", **budget})]
    else:
        dec = {"shared": "auto"}.get(case, case)
        use = files[:1] if case == "shared" else files
        bsdfs = [mi.load_dict({"type": "sparse_brdf", "filename": f, "decoder": dec,
                               "sampling": "cosine"}) for f in use]
        mitsuba_plugin.resolve()
    lib = case.startswith("library")
    scene = mi.load_dict(scene_dict(mi, bsdfs, n, width, height, spp, lib))
    if lib:  # as render_scene does: the indices checked, read by shape id
        mitsuba_plugin.check_scene(scene)
    load_s, load_cpu = time.perf_counter() - t0, time.process_time() - c0
    times, cpu = [], []
    for seed in range(2):
        t, c = time.perf_counter(), time.process_time()
        img = mi.render(scene, spp=spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    np.save(image, np.array(img, np.float32))
    held = [b.memory_bytes for b in bsdfs if hasattr(b, "memory_bytes")]
    decs = [getattr(b, "decoder", None) for b in bsdfs]
    decs += ["grouped"] * sum(getattr(b, "n_grouped", 0) for b in bsdfs)
    # process CPU seconds (all threads) beside wall seconds: on a shared machine the
    # CPU time is the steadier measure of the work done
    return {"case": case, "n": n, "load_s": load_s, "load_cpu_s": load_cpu,
            "render1_s": times[0], "render2_s": times[1], "render2_cpu_s": cpu[1],
            "peak_mb": resource.getrusage(
                resource.RUSAGE_SELF).ru_maxrss / 1024,
            "material_bytes": int(sum(held)), "n_grouped": decs.count("grouped")}


def measure(case: str, files, args, image: Path) -> dict:
    """:func:`run_case` in a child process (its own peak memory)."""
    cmd = [sys.executable, __file__, "--child", case, "--width", str(args.width),
           "--height", str(args.height), "--spp", str(args.spp), "--image", str(image),
           "--library-budget", str(args.library_budget),
           *map(str, files)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def snr(ref: np.ndarray, img: np.ndarray) -> float:
    """Whole-image rendering SNR in dB (docs/method.md)."""
    err = float(np.sum((ref - img) ** 2))
    return float("inf") if err == 0 else 10 * np.log10(float(np.sum(ref ** 2)) / err)


def chart(rows, path: Path) -> None:
    """Peak memory above the empty scene, and the second render's time, against N."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for case in ("library", "library_grouped", "auto", "grouped", "strict", "table", "shared"):
        pts = sorted((r["n"], r) for r in rows if r["case"] == case)
        if not pts:
            continue
        ns = [p[0] for p in pts]
        axes[0].plot(ns, [max(p[1]["above_empty_mb"], 1e-1) for p in pts], "o-", label=case)
        axes[1].plot(ns, [p[1]["render2_s"] for p in pts], "o-", label=case)
    for ax, what in zip(axes, ("peak memory above the empty scene (MB)",
                               "second render (s)"), strict=True):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("materials (N spheres, each its own)")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--library", default="many_materials_lib", help="folder of the files")
    p.add_argument("--ns", default="1,10,100,1000", help="numbers of materials")
    p.add_argument("--bases", type=int, default=24, help="encoded training materials")
    p.add_argument("--table-max", type=int, default=100,
                   help="largest N rendered with the dense tables (17.5 MB each)")
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--library-budget", type=float, default=256.0,
                   help="MiB of decoder data of the library_grouped case")
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--chart", help="PNG of memory and time against N")
    p.add_argument("--child", help=argparse_hidden())
    p.add_argument("--image")
    p.add_argument("files", nargs="*")
    args = p.parse_args()
    if args.child:
        print(json.dumps(run_case(args.child, args.files, args.width, args.height,
                                  args.spp, args.image, args.library_budget)))
        return
    ns = [int(v) for v in args.ns.split(",")]
    files = make_library(Path(args.library), max(ns), args.bases)
    images = Path(args.library) / "images"
    images.mkdir(exist_ok=True)
    rows = []
    for n in ns:
        empty = None
        for case in args.cases.split(","):
            if case in ("table", "library_grouped") and n > args.table_max:
                continue
            r = measure(case, files[:n], args, images / f"{case}-{n}.npy")
            empty = r["peak_mb"] if case == "empty" else empty
            r["above_empty_mb"] = r["peak_mb"] - (empty or 0.0)
            r["per_material_kb"] = 1e3 * r["above_empty_mb"] / n
            rows.append(r)
            print(json.dumps(r), flush=True)
        ref = images / f"table-{n}.npy"
        for r in rows:
            if r["n"] == n and ref.exists() and r["case"] in (
                    "auto", "grouped", "strict", "library", "library_grouped"):
                r["snr_vs_table_db"] = snr(np.load(ref), np.load(images / f"{r['case']}-{n}.npy"))
    print(header())
    keys = ("case", "n", "load_s", "load_cpu_s", "render1_s", "render2_s", "render2_cpu_s",
            "peak_mb", "above_empty_mb",
            "per_material_kb", "material_bytes", "n_grouped", "snr_vs_table_db")
    print(" | ".join(keys))
    for r in rows:
        print(" | ".join(f"{r.get(k):.3g}" if isinstance(r.get(k), float) else str(r.get(k))
                         for k in keys))
    if args.chart:
        chart(rows, Path(args.chart))
    if args.json:
        write_json(args.json, rows, args)


def argparse_hidden():
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
