"""Recovering a material from images with ``fit_images`` (docs/fit-images.md).

    .venv/bin/python benchmarks/fit_images_study.py [--materials silver-paint ...]
        [--fit-views envrot=0 envmap=forest.exr,envrot=90 envrot=60,envtilt=30 ...]
        [--held-out envrot=45 envrot=225] [--iterations 150] [--res 64] [--spp 16]
        [--json out.json]

For each material (the shipped demo materials: MERL test-split networks the ensemble
never saw): references are rendered from the full tabulated BRDF in ``sphere.xml`` under
several views, each a set of the scene's defaults: the map (``envmap``, the CC0 studio
map by default; the shared maps by name, e.g. ``forest.exr``), its rotation about the
vertical (``envrot``) and its tilt (``envtilt``); a bare number is an ``envrot`` of the
studio map. Some views are used for fitting and some held out. The
material's encoding (262 per channel) has every value multiplied by 1 + 0.3 z (z
standard normal, seeded), and ``fit_images`` fits the noisy values back from the
fitting views. Reported on the held-out views, object-only and whole-image SNR against
the references (same seed and spp, so the sample paths are shared): the unperturbed
encoding, the perturbed start and the fit; and, without a target, a fit that starts from
the encoding of the next material in the list. Also the time per iteration and per fit.

``--track-every N`` records the held-out SNR along the fit (every N evaluations: never
used by the fit, only reported); ``--validation`` views are rendered like the fitting
views but only pick the returned iterate (early stopping); ``--prior-weight`` is
``fit_images``'s penalty keeping the values near the (perturbed) start.
``--held-out-spp 8 256`` rates the held-out views at 8 spp (the table's) and also at 256:
at a few spp a held-out SNR is set by a handful of samples per pixel
(docs/records/fit-images-runs.md, "Runs 8 and 9").
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, parser, write_json

from sparse_brdf import encode, load_brdf
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.evaluation.render import SHARED_PATHS, object_mask, render_scene
from sparse_brdf.evaluation.scenes import find_scene, parse_defaults
from sparse_brdf.fitting.fit_images import (
    DEFAULT_LR,
    DEFAULT_LR_END,
    LOSSES,
    OPTIMIZERS,
    fit_images,
    views_for,
)
from sparse_brdf.metrics import snr_forms
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.merl import write_merl


def view_spec(text: str) -> str:
    """A view as given on the command line, normalised: ``45`` -> ``envrot=45``."""
    text = str(text).strip()
    return f"envrot={text}" if "=" not in text else text


def _params(spec: str) -> dict:
    return parse_defaults(spec.split(","), f"view {spec!r}:")


def _worst_share(ref: np.ndarray, img: np.ndarray, n: int = 5) -> float:
    """The share of an image's squared error (over all pixels) in its ``n`` worst pixels:
    near n / pixels when the error is spread, near 1 when a few samples carry it."""
    e = np.sum(np.square(img.astype(np.float64) - ref), axis=-1).ravel()
    total = float(e.sum())
    return float(np.sort(e)[-n:].sum() / total) if total > 0 else 0.0


def _held_out(scene, refs, mask, specs, src, spp, res, seeds=None,
              per_view: dict | None = None) -> tuple[float, float]:
    """Mean (object-only, whole-image) SNR of ``src`` over the views ``specs`` (rendered
    with ``seeds``, those of their references; 0 by default); each view's
    [object-only, whole-image, share of the squared error in its 5 worst pixels] goes
    into ``per_view`` when given."""
    seeds = seeds or {}
    imgs = [render_scene(scene, {"material": str(src)}, sampling=SHARED_PATHS,
                         spp=spp, seed=seeds.get(v, 0),
                         res=res, params=_params(v)) for v in specs]
    forms = [snr_forms(refs[v], img, mask) for v, img in zip(specs, imgs, strict=True)]
    if per_view is not None:
        per_view.update({v: [f.object, f.whole, _worst_share(refs[v], img)]
                         for v, f, img in zip(specs, forms, imgs, strict=True)})
    return (float(np.mean([f.object for f in forms])),
            float(np.mean([f.whole for f in forms])))


def _tracker(track: list, scene, refs, mask, args, path: Path):
    """A ``fit_images`` callback appending (evaluations, object-only, whole-image) held-out
    SNR of each iterate it sees to ``track`` (a record only: the fit never sees it)."""
    def tracked(n: int, model) -> None:
        f = save_sbrdf(path, model)
        track.append((n, *_held_out(scene, refs, mask, args.held_out, f,
                                    args.held_out_spp[0], args.res)))
    return tracked


def _run_fit(scene, views, validation, start_file, args, fit_spp, tracked):
    """``fit_images`` with the study's settings: (its result, seconds)."""
    t0 = time.perf_counter()
    fit = fit_images(scene, views, start_file, iterations=args.iterations, lr=args.lr,
                     lr_end=args.lr_end, spp=fit_spp, seed=0, optimizer=args.optimizer,
                     loss=args.loss, prior_weight=args.prior_weight, validation=validation,
                     validate_every=args.track_every or 10,
                     callback=tracked if args.track_every else None, progress=True)
    return fit, time.perf_counter() - t0


def _by_spp(scene, held: dict, mask, files: dict, args) -> tuple[dict, dict]:
    """Every model (``files``: name -> .sbrdf) on the held-out views at each
    --held-out-spp (``held``: spp -> view -> reference): per spp, name -> the views' mean
    (object-only, whole-image) SNR, and name -> view -> that view's record."""
    means: dict = {str(n): {} for n in args.held_out_spp}
    views: dict = {str(n): {} for n in args.held_out_spp}
    for n in args.held_out_spp:
        for k, f in files.items():
            if k == "other" and "fit_other" not in files:
                continue  # the other material's start, when no fit started from it
            means[str(n)][k] = _held_out(scene, held[n], mask, args.held_out, f, n,
                                         args.res, per_view=views[str(n)].setdefault(k, {}))
    return means, views


def _references(scene, brdf_path: Path, args, spps: dict, seeds: dict) -> tuple[dict, dict]:
    """The references: view -> image of the fitting, validation and (at the first
    --held-out-spp) held-out views, and spp -> view -> image of the held-out views at
    each --held-out-spp."""
    refs = {v: render_scene(scene, {"material": str(brdf_path)}, sampling=SHARED_PATHS,
                            spp=spps.get(v, args.spp),
                            seed=seeds.get(v, 0), res=args.res, params=_params(v))
            for v in [*args.fit_views, *args.validation]}
    held = {n: {v: render_scene(scene, {"material": str(brdf_path)}, sampling=SHARED_PATHS,
                                spp=n, res=args.res,
                                params=_params(v)) for v in args.held_out}
            for n in args.held_out_spp}
    refs.update(held[args.held_out_spp[0]])
    return refs, held


def _check_roles(args) -> None:
    """Refuse a view that is both fitted and held out (or validated)."""
    for a, b in ((args.fit_views, args.held_out), (args.validation, args.held_out),
                 (args.fit_views, args.validation)):
        both = {v for v in a if any(_params(v) == _params(h) for h in b)}
        if both:
            raise SystemExit(f"views in two roles: {sorted(both)}")


def study(args) -> list[dict]:
    scene = find_scene("sphere.xml")
    mask = object_mask(scene, res=args.res)
    tmp = Path(tempfile.mkdtemp(prefix="fit-images-study-"))
    _check_roles(args)
    # the fitting views' render seeds: all 0 (the held-out views' too), or the i-th
    # fitting view's i (its reference rendered with it): more sampled directions
    seeds = ({v: i for i, v in enumerate([*args.fit_views, *args.validation])}
             if args.view_seeds == "distinct" else {})
    # the fitting (and validation) views' spp (their references', the fit's): --fit-spp,
    # or --spp
    fit_spp = args.fit_spp or args.spp
    spps = {v: fit_spp for v in [*args.fit_views, *args.validation]}
    models = {m: encode(load_brdf(DEMO_MATERIALS_DIR / f"{m}.h5")) for m in args.materials}
    rows = []
    for i, name in enumerate(args.materials):
        brdf_path = write_merl(tmp / f"{name}.binary", load_brdf(DEMO_MATERIALS_DIR /
                                                                 f"{name}.h5"))
        refs, held = _references(scene, brdf_path, args, spps, seeds)
        model = models[name]
        rng = np.random.default_rng(args.seed)
        noisy = dataclasses.replace(model, values=[
            (v * (1 + 0.3 * rng.standard_normal(v.shape))).astype(np.float32)
            for v in model.values])
        other = models[args.materials[(i + 1) % len(args.materials)]]
        files = {k: save_sbrdf(tmp / f"{name}-{k}.sbrdf", m) for k, m in
                 (("clean", model), ("noisy", noisy), ("other", other))}
        views = views_for([_params(v) for v in args.fit_views],
                          [refs[v] for v in args.fit_views],
                          [seeds.get(v, 0) for v in args.fit_views])
        validation = views_for([_params(v) for v in args.validation],
                               [refs[v] for v in args.validation],
                               [seeds.get(v, 0) for v in args.validation])
        # each view's (object-only, whole-image) SNR, per model
        per_view: dict[str, dict] = {k: {} for k in ("clean", "noisy", "clean_fit_views")}
        row = {"material": name, "clean": _held_out(scene, refs, mask, args.held_out,
                                                    files["clean"], args.held_out_spp[0],
                                                    args.res,
                                                    per_view=per_view["clean"]),
               "noisy": _held_out(scene, refs, mask, args.held_out, files["noisy"],
                                  args.held_out_spp[0], args.res, per_view=per_view["noisy"]),
               # the unperturbed encoding on the fitting views (is a fit over-fitting?)
               "clean_fit_views": _held_out(scene, refs, mask, args.fit_views,
                                            files["clean"], fit_spp, args.res, seeds,
                                            per_view["clean_fit_views"]),
               "per_view": per_view}
        for start in args.starts:
            track: list[tuple[int, float, float]] = []
            tracked = _tracker(track, scene, refs, mask, args,
                               tmp / f"{name}-track-{start}.sbrdf")
            fit, seconds = _run_fit(scene, views, validation, files[start], args, fit_spp,
                                    tracked)
            fitted = save_sbrdf(tmp / f"{name}-fit-{start}.sbrdf", fit.model)
            per_view[f"fit_{start}"], per_view[f"fit_{start}_fit_views"] = {}, {}
            row[f"fit_{start}"] = _held_out(scene, refs, mask, args.held_out, fitted,
                                            args.held_out_spp[0], args.res,
                                            per_view=per_view[f"fit_{start}"])
            row[f"fit_{start}_fit_views"] = _held_out(scene, refs, mask, args.fit_views,
                                                      fitted, fit_spp, args.res, seeds,
                                                      per_view[f"fit_{start}_fit_views"])
            files[f"fit_{start}"] = fitted
            row[f"seconds_{start}"] = seconds  # the fit, with its tracking and validation
            row[f"held_out_track_{start}"] = track  # (evaluations, object, whole)
            row[f"validation_snr_{start}"] = fit.validation_snr_db
            row[f"best_evaluation_{start}"] = fit.best_evaluation
            row[f"seconds_per_iteration_{start}"] = fit.seconds_per_iteration
            row[f"fit_views_snr_{start}"] = fit.snr_db
        row["held_out_by_spp"], row["per_view_by_spp"] = _by_spp(scene, held, mask, files,
                                                                 args)
        rows.append(row)
        print(_line(row), flush=True)
        for n, r in row["held_out_by_spp"].items():
            print(f"  held out at {n} spp: " + ", ".join(f"{k} {_pair(v)}"
                                                         for k, v in r.items()), flush=True)
    return rows


def _pair(p: tuple[float, float]) -> str:
    return f"{p[0]:.1f} / {p[1]:.1f}"


def _line(r: dict) -> str:
    if "fit_noisy" not in r:
        return (f"| {r['material']} | {_pair(r['clean'])} | {_pair(r['noisy'])} | - | - | "
                f"{_pair(r['fit_other'])} | {r['seconds_per_iteration_other']:.2f} | "
                f"{r['seconds_other']:.0f} |")
    gap = (r["fit_noisy"][0] - r["clean"][0], r["fit_noisy"][1] - r["clean"][1])
    return (f"| {r['material']} | {_pair(r['clean'])} | {_pair(r['noisy'])} | "
            f"{_pair(r['fit_noisy'])} | {gap[0]:+.1f} / {gap[1]:+.1f} | "
            f"{_pair(r['fit_other']) if 'fit_other' in r else '-'} | "
            f"{r['seconds_per_iteration_noisy']:.2f} | "
            f"{r['seconds_noisy']:.0f} |")


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--materials", nargs="+", default=["silver-paint", "blue-metallic-paint2",
                                                      "red-specular-plastic"],
                   help="shipped demo materials (names in sparse_brdf/data/materials)")
    p.add_argument("--fit-views", nargs="+", type=view_spec, default=["envrot=0", "envrot=90",
                   "envrot=180", "envrot=270"], metavar="K=V[,K=V]",
                   help="the fitting views' scene defaults (a bare number: envrot)")
    p.add_argument("--held-out", nargs="+", type=view_spec, default=["envrot=45",
                   "envrot=225"], metavar="K=V[,K=V]", help="the held-out views")
    p.add_argument("--iterations", type=int, default=150)
    p.add_argument("--optimizer", choices=OPTIMIZERS, default="adam",
                   help="adam, or lbfgs (then --iterations counts its evaluations)")
    p.add_argument("--view-seeds", choices=["same", "distinct"], default="same",
                   help="render every view with seed 0, or the i-th fitting view (and "
                        "its reference) with seed i; held-out views always use 0")
    p.add_argument("--loss", choices=LOSSES, default="relative",
                   help="relative (mean relative squared error) or log (mean SNR in dB)")
    p.add_argument("--lr", type=float, default=DEFAULT_LR)
    p.add_argument("--lr-end", type=float, default=DEFAULT_LR_END)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--starts", nargs="+", choices=["noisy", "other"],
                   default=["noisy", "other"],
                   help="the fits to run: from the perturbed encoding, from the next "
                        "material's encoding")
    p.add_argument("--fit-spp", type=int, default=None,
                   help="spp of the fitting views and their references (default --spp; "
                        "the held-out views use --held-out-spp)")
    p.add_argument("--held-out-spp", type=int, nargs="+", default=None, metavar="N",
                   help="spp of the held-out views and their references (default --spp); "
                        "with several, the first is the table's and every model is also "
                        "rated at the others (held_out_by_spp in the JSON)")
    p.add_argument("--seed", type=int, default=1, help="seed of the 30 %% noise")
    p.add_argument("--validation", nargs="*", type=view_spec, default=[],
                   metavar="K=V[,K=V]",
                   help="views rendered like the fitting views (their spp and seeds) that "
                        "only pick the returned iterate (fit_images' validation)")
    p.add_argument("--prior-weight", type=float, default=0.0,
                   help="fit_images' prior_weight (penalty on the values' relative change)")
    p.add_argument("--track-every", type=int, default=0,
                   help="record the held-out SNR every N evaluations (0: not at all); "
                        "also the validation cadence")
    args = p.parse_args()
    args.held_out_spp = args.held_out_spp or [args.spp]
    print(header())
    opt = (f"adam, lr {args.lr} -> {args.lr * args.lr_end:g}" if args.optimizer == "adam"
           else args.optimizer) + f", {args.loss} loss, {args.view_seeds} view seeds"
    print(f"sphere.xml, {args.res}x{args.res}, {args.spp} spp (fitting views "
          f"{args.fit_spp or args.spp}), fitting views "
          f"{args.fit_views}, validation {args.validation}, prior weight "
          f"{args.prior_weight:g}, held out {args.held_out} at {args.held_out_spp} spp, "
          f"{args.iterations} iterations "
          f"({opt}); SNR in dB, object-only / whole-image, mean over the held-out views")
    print("| material | unperturbed | perturbed (start) | fitted | fitted - unperturbed | "
          "fitted from another material | s / iteration | s / fit |\n"
          "|---|---|---|---|---|---|---|---|")
    rows = study(args)
    if args.json:
        write_json(args.json, rows, args)


if __name__ == "__main__":
    main()
