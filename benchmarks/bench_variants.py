"""Render speed of ``sparse_brdf`` and ``neural_brdf`` against ``tabulated_brdf`` in the
same Mitsuba variant, interleaved in one run (docs/benchmarks.md).

Per variant: the sphere scene with the material as ``tabulated_brdf`` (its full table)
and as ``sparse_brdf`` (its encoding); when the material is a Neural-BRDF ``.h5`` network
(the default material and the demo materials are), also as ``neural_brdf`` (the network
itself, evaluated at each direction pair); and, in the ``*_ad_*`` variants, a case: the
sparse scene after ``mi.traverse`` set its ``values_0..2`` and ``params.update()`` rebuilt
the decoders (the path an inverse-rendering loop takes), rendered without gradients. Each
round renders every case once (so that the machine's slow and fast phases hit them
alike); the ratios are medians of the per-round ratios. What the differentiable values
cost an undifferentiated render: extract the commit before them
(``mkdir /tmp/before && git archive dad82e7~1 | tar -x -C /tmp/before``), run this script
with ``--plugin-root /tmp/before`` (that tree's ``mitsuba_plugin`` and ``sparse_brdf``
come first on the import path) and compare its sparse / table ratios with a run without.
The scalar variants (every BSDF call a Python call) render ``--scalar-res`` at
``--scalar-spp``; their renders are short, so on a loaded machine use more rounds.

    .venv/bin/python benchmarks/bench_variants.py [--material SOURCE] [--json PATH]
        [--variants llvm_ad_rgb,...] [--no-neural] [--also-transform lobe]

``--also-transform T`` adds a case: the material encoded with ``--transform T`` (e.g. the
lobe pair), rendered in the same rounds, its ratio to the table printed below the table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, machine, write_json

if "--plugin-root" in sys.argv:  # another checkout's plugin and library, before any import
    sys.path.insert(0, sys.argv[sys.argv.index("--plugin-root") + 1])

from render_timing import default_material, scene_args, swap_material  # noqa: E402

from sparse_brdf.coding.encode import encode  # noqa: E402
from sparse_brdf.coding.fileformat import save_sbrdf  # noqa: E402
from sparse_brdf.mitsuba_env import set_variant  # noqa: E402
from sparse_brdf.paths import SCENES_DIR  # noqa: E402
from sparse_brdf.sources.load import load_brdf  # noqa: E402

VARIANTS = ("llvm_ad_rgb", "llvm_ad_spectral", "scalar_rgb", "scalar_spectral",
            "scalar_spectral_polarized")


def _time(scene, spp: int, seed: int) -> float:
    import drjit as dr  # lazy: Dr.Jit/Mitsuba load only once a benchmark runs
    import mitsuba as mi

    t0 = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t0


def _updated(scene):
    """The scene after its values went through mi.traverse and params.update()."""
    import mitsuba as mi  # lazy: as above

    params = mi.traverse(scene)
    for key in [k for k in params.keys() if k.rsplit(".", 1)[-1].startswith("values_")]:
        params[key] = type(params[key])(np.array(params[key]))
    params.update()
    return scene


def bench_variant(variant: str, src: str, sbrdf: Path, args, more=()) -> dict:
    import mitsuba as mi  # lazy: as above

    set_variant(variant)
    small = variant.startswith("scalar")
    run = argparse.Namespace(res=args.scalar_res if small else args.res,
                             spp=args.scalar_spp if small else args.spp)
    scene_path = SCENES_DIR / "sphere.xml"
    cases = {"tabulated_brdf": {"type": "tabulated_brdf", "filename": src},
             "sparse_brdf": {"type": "sparse_brdf", "filename": str(sbrdf)}}
    if args.neural and src.lower().endswith(".h5"):
        cases["neural_brdf"] = {"type": "neural_brdf", "filename": src}
    for t, path in more:  # the same material in other transforms
        cases[f"sparse_brdf, --transform {t}"] = {"type": "sparse_brdf", "filename": str(path)}
    scenes = {k: mi.load_dict(swap_material(scene_path, d, run)) for k, d in cases.items()}
    if "_ad_" in variant:
        scenes["sparse_brdf after update()"] = _updated(
            mi.load_dict(swap_material(scene_path, cases["sparse_brdf"], run)))
    for s in scenes.values():  # warm-up: compile
        _time(s, run.spp, 0)
    times = {k: [] for k in scenes}
    for r in range(args.repeats):
        for k, s in scenes.items():
            times[k].append(_time(s, run.spp, r + 1))
    tab = np.array(times["tabulated_brdf"])
    out = {"variant": variant, "res": run.res, "spp": run.spp}
    for k, t in times.items():
        out[k] = {"median_s": float(np.median(t)),
                  "vs_tabulated": float(np.median(np.array(t) / tab))}
    return out


def main() -> None:
    p = scene_args(__doc__)
    p.set_defaults(res=128, spp=16)
    p.add_argument("--scalar-res", type=int, default=32)
    p.add_argument("--scalar-spp", type=int, default=4)
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--plugin-root", type=Path, default=None,
                   help="a checkout whose mitsuba_plugin and sparse_brdf are used instead")
    p.add_argument("--also-transform", action="append", default=[], metavar="T",
                   help="also render the material encoded with --transform T; repeatable")
    p.add_argument("--no-neural", dest="neural", action="store_false",
                   help="no neural_brdf case (e.g. for a --plugin-root without it)")
    args = p.parse_args()
    info = machine()
    src = default_material(args.material)
    with tempfile.TemporaryDirectory() as tmp:
        brdf = load_brdf(src)
        sbrdf = save_sbrdf(Path(tmp) / "m.sbrdf", encode(brdf))
        more = [(t, save_sbrdf(Path(tmp) / f"m-{i}.sbrdf", encode(brdf, transform=t)))
                for i, t in enumerate(args.also_transform)]
        rows = [bench_variant(v, src, sbrdf, args, more) for v in args.variants.split(",")]
    print(header(info))
    import mitsuba_plugin  # lazy: only to print where it came from

    print(f"material {src}, {args.repeats} interleaved rounds, plugin "
          f"{Path(mitsuba_plugin.__file__).parent}\n")
    print("| variant | res, spp | tabulated_brdf (s) | sparse_brdf (s) | sparse / table | "
          "neural_brdf (s) | neural / table | after update() / table |\n"
          "|---|---|---|---|---|---|---|---|")
    for r in rows:
        upd, net = r.get("sparse_brdf after update()"), r.get("neural_brdf")
        upd = f"{upd['vs_tabulated']:.2f}" if upd else "-"
        net = f"{net['median_s']:.3f} | {net['vs_tabulated']:.2f}" if net else "- | -"
        print(f"| {r['variant']} | {r['res']}, {r['spp']} | "
              f"{r['tabulated_brdf']['median_s']:.3f} | {r['sparse_brdf']['median_s']:.3f} | "
              f"{r['sparse_brdf']['vs_tabulated']:.2f} | {net} | {upd} |")
    for t in args.also_transform:
        key = f"sparse_brdf, --transform {t}"
        print("\n" + "; ".join(
            f"{r['variant']}: {key} / table {r[key]['vs_tabulated']:.2f}, / sparse_brdf "
            f"{r[key]['median_s'] / r['sparse_brdf']['median_s']:.2f}" for r in rows))
    if args.json:
        write_json(args.json, rows, args, info)


if __name__ == "__main__":
    main()
