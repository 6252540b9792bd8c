"""Recovering a material from images with ``fit_images`` (docs/fit-images.md).

    .venv/bin/python benchmarks/fit_images_study.py [--materials silver-paint ...]
        [--iterations 150] [--res 64] [--spp 16] [--json out.json]

For each material (the shipped demo materials: MERL test-split networks the ensemble
never saw): references are rendered from the full tabulated BRDF in ``sphere.xml`` (the
CC0 studio map) at several map rotations, some used for fitting and some held out. The
material's encoding (262 per channel) has every value multiplied by 1 + 0.3 z (z
standard normal, seeded), and ``fit_images`` fits the noisy values back from the
fitting views. Reported on the held-out views, object-only and whole-image SNR against
the references (same seed and spp, so the sample paths are shared): the unperturbed
encoding, the perturbed start and the fit; and, without a target, a fit that starts from
the encoding of the next material in the list. Also the time per iteration and per fit.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, parser, write_json

from sparse_brdf import encode, load_brdf
from sparse_brdf.evaluation.fit_images import DEFAULT_LR, DEFAULT_LR_END, fit_images, views_for
from sparse_brdf.evaluation.render import find_scene, object_mask, render_scene
from sparse_brdf.metrics import snr_forms
from sparse_brdf.model.sbrdf import save_sbrdf
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.merl import write_merl


def _held_out(scene, refs, mask, rots, src, spp, res) -> tuple[float, float]:
    """Mean (object-only, whole-image) SNR of ``src`` over the views ``rots``."""
    forms = [snr_forms(refs[r], render_scene(scene, {"material": str(src)}, spp=spp, seed=0,
                                             res=res, params={"envrot": r}), mask)
             for r in rots]
    return (float(np.mean([f.object for f in forms])),
            float(np.mean([f.whole for f in forms])))


def study(args) -> list[dict]:
    scene = find_scene("sphere.xml")
    mask = object_mask(scene, res=args.res)
    tmp = Path(tempfile.mkdtemp(prefix="fit-images-study-"))
    rots = [*args.fit_views, *args.held_out]
    models = {m: encode(load_brdf(DEMO_MATERIALS_DIR / f"{m}.h5")) for m in args.materials}
    rows = []
    for i, name in enumerate(args.materials):
        brdf_path = write_merl(tmp / f"{name}.binary", load_brdf(DEMO_MATERIALS_DIR /
                                                                 f"{name}.h5"))
        refs = {r: render_scene(scene, {"material": str(brdf_path)}, spp=args.spp, seed=0,
                                res=args.res, params={"envrot": r}) for r in rots}
        model = models[name]
        rng = np.random.default_rng(args.seed)
        noisy = dataclasses.replace(model, values=[
            (v * (1 + 0.3 * rng.standard_normal(v.shape))).astype(np.float32)
            for v in model.values])
        other = models[args.materials[(i + 1) % len(args.materials)]]
        files = {k: save_sbrdf(tmp / f"{name}-{k}.sbrdf", m) for k, m in
                 (("clean", model), ("noisy", noisy), ("other", other))}
        views = views_for([{"envrot": r} for r in args.fit_views],
                          [refs[r] for r in args.fit_views])
        row = {"material": name, "clean": _held_out(scene, refs, mask, args.held_out,
                                                    files["clean"], args.spp, args.res),
               "noisy": _held_out(scene, refs, mask, args.held_out, files["noisy"],
                                  args.spp, args.res)}
        for start in ("noisy", "other"):
            t0 = time.perf_counter()
            fit = fit_images(scene, views, files[start], iterations=args.iterations,
                             lr=args.lr, lr_end=args.lr_end, spp=args.spp, seed=0,
                             progress=True)
            fitted = save_sbrdf(tmp / f"{name}-fit-{start}.sbrdf", fit.model)
            row[f"fit_{start}"] = _held_out(scene, refs, mask, args.held_out, fitted,
                                            args.spp, args.res)
            row[f"seconds_{start}"] = time.perf_counter() - t0
            row[f"seconds_per_iteration_{start}"] = fit.seconds_per_iteration
            row[f"fit_views_snr_{start}"] = fit.snr_db
        rows.append(row)
        print(_line(row), flush=True)
    return rows


def _pair(p: tuple[float, float]) -> str:
    return f"{p[0]:.1f} / {p[1]:.1f}"


def _line(r: dict) -> str:
    gap = (r["fit_noisy"][0] - r["clean"][0], r["fit_noisy"][1] - r["clean"][1])
    return (f"| {r['material']} | {_pair(r['clean'])} | {_pair(r['noisy'])} | "
            f"{_pair(r['fit_noisy'])} | {gap[0]:+.1f} / {gap[1]:+.1f} | "
            f"{_pair(r['fit_other'])} | {r['seconds_per_iteration_noisy']:.2f} | "
            f"{r['seconds_noisy']:.0f} |")


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--materials", nargs="+", default=["silver-paint", "blue-metallic-paint2",
                                                      "red-specular-plastic"],
                   help="shipped demo materials (names in sparse_brdf/data/materials)")
    p.add_argument("--fit-views", nargs="+", type=int, default=[0, 90, 180, 270],
                   metavar="DEG", help="map rotations (envrot) of the fitting views")
    p.add_argument("--held-out", nargs="+", type=int, default=[45, 225], metavar="DEG",
                   help="map rotations of the held-out views")
    p.add_argument("--iterations", type=int, default=150)
    p.add_argument("--lr", type=float, default=DEFAULT_LR)
    p.add_argument("--lr-end", type=float, default=DEFAULT_LR_END)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--seed", type=int, default=1, help="seed of the 30 %% noise")
    args = p.parse_args()
    print(header())
    print(f"sphere.xml, {args.res}x{args.res}, {args.spp} spp, fitting views envrot "
          f"{args.fit_views}, held out {args.held_out}, {args.iterations} iterations, lr "
          f"{args.lr} -> {args.lr * args.lr_end:g}; SNR in dB, object-only / whole-image, "
          "mean over the held-out views")
    print("| material | unperturbed | perturbed (start) | fitted | fitted - unperturbed | "
          "fitted from another material | s / iteration | s / fit |\n"
          "|---|---|---|---|---|---|---|---|")
    rows = study(args)
    if args.json:
        write_json(args.json, rows, args)


if __name__ == "__main__":
    main()
