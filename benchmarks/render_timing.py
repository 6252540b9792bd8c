"""Render timing shared by the render benchmarks (``bench_render.py``,
``bench_variants.py``, ``bench_lookup_call.py``): their options, default material, the
sphere scene with a material swapped in, and the interleaved-rounds timing of a list of
cases."""

from __future__ import annotations

import argparse
import gc
import sys
import time

import numpy as np
from harness import parser

from sparse_brdf.paths import SCENES_DIR, shared_data_dir

#: The package's BSDFs (they take a ``sampling`` property; Mitsuba's own do not).
PLUGIN_BSDFS = ("sparse_brdf", "tabulated_brdf", "neural_brdf")


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


def scene_args(doc: str, json_option: bool = True) -> argparse.ArgumentParser:
    """The options every render benchmark takes (material, resolution, spp, rounds)."""
    p = parser(doc, json_option=json_option)
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
        scene = mi.load_dict(swap_material(scene_path, bsdf_dict, args))
        compile_s[name], _ = timed_render(scene, args.spp, 0)
        print(f"{name}: compiled in {compile_s[name]:.2f} s", file=sys.stderr, flush=True)
        del scene
        gc.collect()
    loaded = [(name, mi.load_dict(swap_material(scene_path, bsdf_dict, args)))
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


def swap_material(scene_path, bsdf_dict, args):
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
        # the renders the timings were recorded with: the plugins' cosine sampling unless a
        # case sets it (Mitsuba's own BSDFs take no sampling property)
        "sphere": {"type": "sphere", "bsdf": ({"sampling": "cosine", **bsdf_dict}
                                              if bsdf_dict["type"] in PLUGIN_BSDFS
                                              else bsdf_dict)},
    }
