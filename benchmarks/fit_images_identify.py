"""What images of a sphere pin down: a fit's recovery of each coefficient value.

    .venv/bin/python benchmarks/fit_images_identify.py [--material blue-metallic-paint2]
        [--references table encoding] [--fit-scene sphere.xml] [--fit-views envrot=0 ...]
        [--closeups ANGLE:ROLL:FOV ...] [--rate envrot=45 envrot=225] [--iterations 200]
        [--json out.json]

The protocol of ``benchmarks/fit_images_study.py`` for one material (its encoding at 262
per channel, every value multiplied by 1 + 0.3 z, z standard normal, seed 1; an L-BFGS
fit from those values on the fitting views at --spp, shared sample paths), with the
fitting references rendered from the full table (``table``: the material itself) or from
the unperturbed encoding (``encoding``: the fit's exact answer is then on its support, so
what it misses is what the views do not determine). Reported:

- the rated views (``sphere.xml``, at --rate-spp: converged) and the fitting views at
  --rate-spp, object-only / whole-image SNR against the table's renders, for the
  unperturbed encoding, the perturbed start and the fit;
- each value's relative error against the unperturbed encoding, before and after the
  fit: the quartiles and 90th percentile, and the median over each channel's 20 largest
  values and over the rest;
- the cost of the small values' noise alone: the unperturbed encoding with every value
  but each channel's 20 largest taken from the perturbed start, on the rated views;
- where in the BRDF each rated view's loss sits: the unperturbed encoding's decoded table
  with one (theta_h, theta_d) region of MERL bins taken from the fit's decoded table, each
  rendered as a table and rated (``attribution``; a region that drops a view's SNR is
  one the fit got wrong and that view sees).

docs/records/fit-images-runs.md, "What the views determine".
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, parser, write_json

from sparse_brdf import decode_file, encode, load_brdf, load_sbrdf
from sparse_brdf.coding.fileformat import save_sbrdf
from sparse_brdf.evaluation.render import SHARED_PATHS, object_mask, render_scene
from sparse_brdf.evaluation.scenes import find_scene, parse_defaults
from sparse_brdf.fitting.fit_images import fit_images, views_for
from sparse_brdf.metrics import snr_forms
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.merl import write_merl

#: Per channel, how many of the largest values count as "large".
TOP = 20
#: MERL bin ranges of the attribution's regions: theta_h (0.28, 1.1, 4.4 and 90 degrees
#: at the bounds) and theta_d (degrees).
H_BANDS = ((0, 5), (5, 10), (10, 20), (20, 90))
D_BANDS = ((0, 30), (30, 60), (60, 70), (70, 80), (80, 90))


#: sphere_light.xml's camera position and the axes of its light's two rotations.
CAMERA = np.array([0.0, 0.9, 4.0])
ANGLE_AXIS = np.array([0.0, 0.975609756, -0.219512195])
ROLL_AXIS = CAMERA / np.linalg.norm(CAMERA)


def _rotate(v: np.ndarray, axis: np.ndarray, degrees: float) -> np.ndarray:
    """``v`` turned right-handedly about the unit ``axis`` (Rodrigues' formula)."""
    t = np.radians(degrees)
    return (v * np.cos(t) + np.cross(axis, v) * np.sin(t)
            + axis * np.dot(axis, v) * (1 - np.cos(t)))


def highlight(angle: float, roll: float) -> tuple[np.ndarray, float]:
    """The point of sphere_light.xml's unit sphere whose normal is the half-vector of its
    light (at ``angle`` and ``roll``, degrees) and the camera, and theta_d there (degrees).
    """
    light = _rotate(_rotate(ROLL_AXIS, ANGLE_AXIS, angle), ROLL_AXIS, roll)
    n = ROLL_AXIS.copy()
    for _ in range(100):  # fixed point: the normal is the half-vector of light and view
        view = (CAMERA - n) / np.linalg.norm(CAMERA - n)
        n = (light + view) / np.linalg.norm(light + view)
    return n, float(np.degrees(np.arccos(np.clip(np.dot(n, light), -1, 1))))


def closeup_views(specs: list[str]) -> list[str]:
    """``ANGLE:ROLL:FOV`` specs as sphere_light.xml views aimed at the light's highlight.

    Raises ValueError (one line naming the spec) for a malformed spec, a fov outside
    (0, 180) degrees or a highlight the camera does not see."""
    out = []
    for spec in specs:
        try:
            a, r, f = (float(x) for x in spec.split(":"))
        except ValueError:
            raise ValueError(f"--closeups {spec!r}: not ANGLE:ROLL:FOV (degrees)") from None
        p, _ = highlight(a, r)
        if not 0 < f < 180 or np.dot(p, CAMERA - p) <= 0 or not np.all(np.isfinite(p)):
            raise ValueError(f"--closeups {spec!r}: the fov is not in (0, 180) degrees or "
                             "the camera does not see the highlight (angle above about 155)")
        out.append(f"lightangle={a:g},lightroll={r:g},fov={f:g},"
                   + ",".join(f"target{k}={x:.5f}" for k, x in zip("xyz", p, strict=True)))
    return out


def _params(spec: str) -> dict:
    return parse_defaults(spec.split(","), f"view {spec!r}:")


def _rated(scene, mask, table, files: dict, specs, spp: int, res: int) -> dict:
    """view -> model -> [object-only, whole-image] SNR at ``spp`` (seed 0, shared paths)."""
    out: dict = {}
    for v in specs:
        ref = render_scene(scene, {"material": str(table)}, sampling=SHARED_PATHS,
                           spp=spp, res=res, params=_params(v))
        for k, f in files.items():
            img = render_scene(scene, {"material": str(f)}, sampling=SHARED_PATHS,
                               spp=spp, res=res,
                               params=_params(v))
            s = snr_forms(ref, img, mask)
            out.setdefault(v, {})[k] = [round(s.object, 2), round(s.whole, 2)]
    return out


def _by_location(model, c: int) -> dict:
    """Channel ``c``'s values keyed by their coefficient locations (a file may reorder)."""
    vals = np.asarray(model.values[c], np.float64)
    locs = np.asarray(model.locations[c]).reshape(len(vals), -1)
    return {tuple(int(x) for x in loc): float(v) for loc, v in zip(locs, vals, strict=True)}


def _value_errors(clean, other) -> dict:
    """Relative errors of ``other``'s values against ``clean``'s, per channel: quartiles
    and 90th percentile, and medians over the TOP largest and over the rest (of the
    nonzero values: ``values`` counts them)."""
    out = {}
    for c in range(len(clean.values)):
        ref, got = _by_location(clean, c), _by_location(other, c)
        # values stored as zero (below the file's precision) have no relative error
        keys = sorted((k for k in ref if ref[k] != 0), key=lambda k: -abs(ref[k]))
        err = np.array([abs(got[k] - ref[k]) / abs(ref[k]) for k in keys])
        out[str(c)] = {"values": len(keys),
                       "percentiles_25_50_75_90": np.percentile(err, [25, 50, 75, 90]
                                                                ).round(3).tolist(),
                       "median_top": round(float(np.median(err[:TOP])), 3),
                       "median_rest": round(float(np.median(err[TOP:])), 3)}
    return out


def _small_from(clean, noisy):
    """``clean`` with every value but each channel's TOP largest taken from ``noisy``."""
    vals = []
    for c in range(len(clean.values)):
        ref, noi = _by_location(clean, c), _by_location(noisy, c)
        top = set(sorted(ref, key=lambda k: -abs(ref[k]))[:TOP])
        vals.append(np.array([ref[k] if k in top else noi[k] for k in ref], np.float32))
    return dataclasses.replace(clean, values=vals)


def _attribution(scene, mask, table, clean_file, fit_file, tmp: Path, specs, spp: int,
                 res: int) -> dict:
    """view -> region -> object-only SNR of the clean table with that region from the fit."""
    clean, fit = decode_file(clean_file), decode_file(fit_file)
    out: dict = {}
    for v in specs:
        ref = render_scene(scene, {"material": str(table)}, sampling=SHARED_PATHS,
                           spp=spp, res=res, params=_params(v))
        for h0, h1 in H_BANDS:
            for d0, d1 in D_BANDS:
                vals = clean.values.copy()
                vals[h0:h1, d0:d1] = fit.values[h0:h1, d0:d1]
                f = write_merl(tmp / "hybrid.binary", dataclasses.replace(clean, values=vals))
                img = render_scene(scene, {"material": str(f)}, sampling=SHARED_PATHS,
                                   spp=spp, res=res,
                                   params=_params(v))
                out.setdefault(v, {})[f"h{h0}-{h1},d{d0}-{d1}"] = round(
                    snr_forms(ref, img, mask).object, 2)
    return out


def _fit(args, fit_scene, source: Path, start: Path):
    """The fit from ``start`` to references of ``source`` on the fitting views."""
    refs = [render_scene(fit_scene, {"material": str(source)}, sampling=SHARED_PATHS,
                         spp=args.spp, res=args.res,
                         params=_params(v)) for v in args.fit_views]
    t0 = time.perf_counter()
    fit = fit_images(fit_scene, views_for([_params(v) for v in args.fit_views], refs), start,
                     iterations=args.iterations, spp=args.spp, seed=0, optimizer="lbfgs",
                     progress=True)
    return fit, time.perf_counter() - t0


def study(args) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="fit-images-identify-"))
    scene, fit_scene = find_scene("sphere.xml"), find_scene(args.fit_scene)
    mask = object_mask(scene, res=args.res)
    fit_mask = object_mask(fit_scene, res=args.res)
    brdf = load_brdf(DEMO_MATERIALS_DIR / f"{args.material}.h5")
    table = write_merl(tmp / "table.binary", brdf)
    clean = encode(brdf)
    rng = np.random.default_rng(1)
    noisy = dataclasses.replace(clean, values=[
        (v * (1 + 0.3 * rng.standard_normal(v.shape))).astype(np.float32)
        for v in clean.values])
    files = {"clean": save_sbrdf(tmp / "clean.sbrdf", clean),
             "noisy": save_sbrdf(tmp / "noisy.sbrdf", noisy)}
    # as the renderer sees them: the files' values (stored at reduced precision)
    clean, noisy = load_sbrdf(files["clean"]), load_sbrdf(files["noisy"])
    small = save_sbrdf(tmp / "small-noisy.sbrdf", _small_from(clean, noisy))
    out = {"material": args.material, "fit_scene": args.fit_scene,
           "fit_views": args.fit_views, "rated_views": args.rate,
           "small_values_noisy": _rated(scene, mask, table, {"small_noisy": small},
                                        args.rate, args.rate_spp, args.res),
           "start_value_errors": _value_errors(clean, noisy), "fits": {}}
    for ref_kind in args.references:
        fit, seconds = _fit(args, fit_scene, table if ref_kind == "table"
                            else files["clean"], files["noisy"])
        f = save_sbrdf(tmp / f"fit-{ref_kind}.sbrdf", fit.model)
        models = {**files, "fit": f}
        out["fits"][ref_kind] = {
            "seconds": round(seconds, 1), "fit_views_snr_db": round(fit.snr_db[-1], 2),
            "rated": _rated(scene, mask, table, models, args.rate, args.rate_spp, args.res),
            "fit_views_rated": _rated(fit_scene, fit_mask, table, models, args.fit_views,
                                      args.rate_spp, args.res),
            "value_errors": _value_errors(clean, load_sbrdf(f)),
            "attribution": _attribution(scene, mask, table, files["clean"], f, tmp, args.rate,
                                        args.rate_spp, args.res)}
        print(ref_kind, out["fits"][ref_kind], flush=True)
    return out


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--material", default="blue-metallic-paint2")
    p.add_argument("--references", nargs="+", choices=("table", "encoding"),
                   default=["table", "encoding"])
    p.add_argument("--fit-scene", default="sphere.xml")
    p.add_argument("--fit-views", nargs="+", default=[
        "envrot=0", "envrot=90", "envrot=180", "envrot=270", "envrot=60,envtilt=30",
        "envrot=240,envtilt=-30", "envmap=city.exr", "envmap=courtyard.exr",
        "envmap=forest.exr", "envmap=interior.exr", "envmap=sunrise.exr",
        "envmap=sunset.exr"])
    p.add_argument("--closeups", nargs="*", default=[], metavar="ANGLE:ROLL:FOV",
                   help="more fitting views in sphere_light.xml (--fit-scene): the light at "
                        "ANGLE and ROLL degrees, the camera's fov FOV degrees, aimed at the "
                        "light's highlight")
    p.add_argument("--rate", nargs="+", default=["envrot=45", "envrot=225"])
    p.add_argument("--spp", type=int, default=8)
    p.add_argument("--rate-spp", type=int, default=256)
    p.add_argument("--res", type=int, default=32)
    p.add_argument("--iterations", type=int, default=200)
    args = p.parse_args()
    try:
        args.fit_views = args.fit_views + closeup_views(args.closeups)
    except ValueError as e:
        p.error(str(e))  # one line, exit status 2
    print(header())
    out = study(args)
    if args.json:
        write_json(args.json, out, args)


if __name__ == "__main__":
    main()
