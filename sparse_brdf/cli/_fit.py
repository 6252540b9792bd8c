"""``fit-scene`` and ``fit-images``: the fewest coefficients per material that reach a
target SNR in a scene (docs/fit-scene.md), and a ``.sbrdf``'s values fitted to reference
images by inverse rendering (docs/fit-images.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..coding import budget as budget_module
from ..coding.fileformat import save_sbrdf
from ..decoders.layouts import DECODERS
from ..errors import OutputError
from ..evaluation.images import read_exr
from ..evaluation.render import SHARED_PATHS, find_scene
from ..evaluation.scenes import parse_overrides
from ..fileio import check_writable
from ..fitting import fit_images as fit_images_module
from ..fitting.fit_images import fit_images, load_views
from ..fitting.fit_scene import fit_scene
from ..params import Interval
from ._options import RENDER, SBRDF, check_outputs, default_of, typed


def cmd_fit_scene(args: argparse.Namespace) -> int:
    """``fit-scene``: each material's fewest coefficients for a target SNR."""
    if Path(args.output).exists() and not Path(args.output).is_dir():
        raise OutputError(f"-o {args.output}: fit-scene writes a folder (a .sbrdf per "
                          "material and fit-scene.md), not a file")
    check_writable(Path(args.output) / "fit-scene.md")
    rep = fit_scene(find_scene(args.scene), args.target_snr, parse_overrides(args.material),
                    args.output, ensemble_path=args.ensemble, spp=args.spp, res=args.res,
                    seed=args.seed, max_bytes=args.bytes)
    print(f"scene SNR with every material sparse: object-only "
          f"{rep['scene_snr_all_sparse']:.1f} dB, whole-image "
          f"{rep['scene_snr_all_sparse_whole']:.1f} dB; "
          f"{rep['bytes_total']} bytes of coefficients; wrote {args.output}/fit-scene.md")
    return 0


def cmd_fit_images(args: argparse.Namespace) -> int:
    """``fit-images``: a ``.sbrdf``'s values fitted to reference images."""
    scene = find_scene(args.scene)
    validation = args.validation_view or []
    paths = [*(fit_images_module.parse_view(v)[0] for v in args.view),
             *(fit_images_module.parse_view(v, "--validation-view")[0] for v in validation)]
    check_outputs([(args.output, SBRDF, "-o")], [args.start, *paths])
    views = load_views(args.view, read_exr)
    held = load_views(validation, read_exr, option="--validation-view")
    result = fit_images(scene, views, args.start, material=args.material,
                        ensemble=args.ensemble, iterations=args.iterations, lr=args.lr,
                        lr_end=args.lr_end, spp=args.spp, seed=args.seed,
                        checkpoint_dir=args.checkpoint_dir, decoder=args.decoder,
                        variant=args.variant, optimizer=args.optimizer,
                        loss=args.loss, prior_weight=args.prior_weight, validation=held,
                        validate_every=args.validate_every)
    save_sbrdf(args.output, result.model)
    snr = result.snr_db
    print(f"wrote {args.output}: {result.iterations} iterations in {result.seconds:.0f} s "
          f"({result.seconds_per_iteration:.2f} s each); the views' mean whole-image SNR "
          f"{snr[0]:.1f} dB at the start, {snr[-1]:.1f} dB at the last iteration")
    if result.best_evaluation is not None:
        best = dict(result.validation_snr_db)[result.best_evaluation]
        print(f"kept the iterate after {result.best_evaluation} evaluations: the "
              f"validation views' whole-image SNR {result.validation_snr_db[0][1]:.1f} dB "
              f"at the start, {best:.1f} dB there")
    return 0


def add_fit_scene(sub) -> None:
    """``fit-scene``."""
    fs = sub.add_parser("fit-scene", help="give each material of a scene the fewest "
                                          "coefficients that reach a target rendering SNR "
                                          "in that scene")
    fs.add_argument("scene", help="scene XML: any Mitsuba 3 scene file, or the name of a "
                                  "shipped scene")
    fs.add_argument("--target-snr", type=typed(Interval(float)), required=True, metavar="DB",
                    help="the object-only rendering SNR each material must reach (the "
                         "object: the shapes of the fitted materials)")
    fs.add_argument("--material", action="append", default=[], metavar="ID=FILE",
                    help="measured material of BSDF ID (repeatable); tabulated_brdf BSDFs "
                         "with a filename in the XML are found by themselves")
    fs.add_argument("-o", "--output", default=default_of(fit_scene, "out"),
                    help="output folder (a .sbrdf per material and fit-scene.md)")
    fs.add_argument("--spp", type=typed(RENDER["spp"]), default=default_of(fit_scene, "spp"),
                    help="spp of the verification renders")
    fs.add_argument("--res", type=typed(RENDER["res"]), default=default_of(fit_scene, "res"),
                    help="the verification renders' longer side in pixels (aspect ratio "
                         "kept; the scene's $res where it declares one)")
    fs.add_argument("--seed", type=typed(RENDER["seed"]), default=default_of(fit_scene, "seed"),
                    help="seed of the verification renders (reference and models share it, "
                         f"with {SHARED_PATHS} sampling)")
    fs.add_argument("--bytes", type=typed(budget_module.PARAMETERS["n_bytes"]),
                    default=default_of(fit_scene, "max_bytes"), metavar="N",
                    help="per material: no .sbrdf file holds more than N bytes (the ladder "
                         "of budgets ends at the largest coefficients that fit; default: no "
                         "limit)")
    fs.add_argument("--ensemble", help="ensemble .npz (default: the shipped one)")
    fs.set_defaults(func=cmd_fit_scene)


def add_fit_images(sub) -> None:
    """``fit-images``."""
    fi = sub.add_parser(
        "fit-images",
        help="fit a .sbrdf's coefficient values to reference images (inverse rendering)",
        description="Optimise the coefficient values of START (its support is kept) so "
                    "that renders of SCENE match the reference images, with Mitsuba's "
                    "Adam through the plugin's differentiable values (docs/fit-images.md)."
                    " Each --view is an EXR image and the scene defaults it was taken "
                    "with, e.g. ref.exr:envrot=90 or ref.exr:envmap=forest.exr,envrot=90,"
                    "envtilt=30; each image's size sets the film's. The fit renders with "
                    f"{SHARED_PATHS} sampling: render the references with --sampling "
                    f"{SHARED_PATHS}, the fit's --seed and --spp.")
    fi.add_argument("scene", help="scene XML (a path, or a name in the shipped scenes/)")
    fi.add_argument("--view", action="append", required=True, metavar="IMAGE.exr[:K=V,...]",
                    help="a reference image and its scene defaults (repeatable)")
    fi.add_argument("--start", required=True, metavar="FILE.sbrdf",
                    help="the starting coefficients (their dictionaries and atoms are kept)")
    fi.add_argument("-o", "--output", required=True, metavar="OUT.sbrdf",
                    help="the fitted .sbrdf (checked writable before the fit)")
    fi.add_argument("--material", default=default_of(fit_images, "material"),
                    help="id of the scene's BSDF that the model replaces")
    fip = fit_images_module.PARAMETERS
    fi.add_argument("--iterations", type=typed(fip["iterations"]),
                    default=default_of(fit_images, "iterations"),
                    help="optimiser iterations (evaluations of the loss)")
    fi.add_argument("--optimizer", choices=fit_images_module.OPTIMIZERS,
                    default=default_of(fit_images, "optimizer"),
                    help="adam, or lbfgs (L-BFGS-B on the shared-path loss; --iterations "
                         "then counts its evaluations, --lr and --lr-end are not used)")
    fi.add_argument("--loss", choices=fit_images_module.LOSSES,
                    default=default_of(fit_images, "loss"),
                    help="relative: the views' mean relative squared error; log: its "
                         "mean logarithm (the views' mean SNR in dB)")
    fi.add_argument("--prior-weight", type=typed(fip["prior_weight"]),
                    default=default_of(fit_images, "prior_weight"),
                    help="weight (>= 0) of a penalty W * mean(((value - start) / scale)^2) "
                         "on the values' change relative to the start (scale: each "
                         "value's starting magnitude, floored at 1e-3 of its channel's "
                         "largest); the relative loss is a relative squared error (1e-4 "
                         "at 40 dB), so useful weights are small, e.g. 1e-6 to 1e-4; with "
                         "--loss log 1 dB is 0.23 of the loss, so weights are larger; 0 "
                         "(the default): the views alone")
    fi.add_argument("--validation-view", action="append", metavar="IMAGE.exr[:K=V,...]",
                    help="a reference never fitted, as --view: every --validate-every "
                         "evaluations the fit renders these, and writes the iterate they "
                         "match best (early stopping; repeatable; default: none, the last "
                         "iterate is written)")
    fi.add_argument("--validate-every", type=typed(fip["validate_every"]),
                    default=default_of(fit_images, "validate_every"),
                    help="evaluations (iterations) between two validations")
    fi.add_argument("--lr", type=typed(fip["lr"]), default=default_of(fit_images, "lr"),
                    help="Adam's first learning rate, a relative step per value")
    fi.add_argument("--lr-end", type=typed(fip["lr_end"]),
                    default=default_of(fit_images, "lr_end"),
                    help="the last iteration's rate as a fraction of --lr (geometric decay)")
    fi.add_argument("--spp", type=typed(fip["spp"]), default=default_of(fit_images, "spp"),
                    help="samples per pixel of each render (use the references' spp)")
    fi.add_argument("--seed", type=typed(RENDER["seed"]), default=default_of(fit_images, "seed"),
                    help="the references' seed: the fit's renders share their sample paths "
                         f"(render the references with --sampling {SHARED_PATHS})")
    fi.add_argument("--checkpoint-dir", default=None,
                    help="keep fit-images.npz here; a rerun resumes from it (default: no "
                         "checkpoint)")
    fi.add_argument("--decoder", choices=DECODERS, default=default_of(fit_images, "decoder"),
                    help="the sparse_brdf plugin's decoder of the fit's renders")
    fi.add_argument("--variant", default=default_of(fit_images, "variant"),
                    help="a differentiable Mitsuba variant (llvm_ad_*, cuda_ad_*)")
    fi.add_argument("--ensemble", help="ensemble .npz (default: the shipped one)")
    fi.set_defaults(func=cmd_fit_images)
