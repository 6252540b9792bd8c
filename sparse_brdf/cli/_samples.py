"""``encode-samples`` and ``plan-samples``: a material encoded from measured samples, and
the direction pairs to measure (docs/method.md, Encoding from samples)."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..acquisition import PRIORS
from ..acquisition import recovery as acquire_module
from ..acquisition.files import read_samples
from ..acquisition.planning import PLACEMENTS, plan
from ..coding import budget as budget_module
from ..coding.fileformat import save_sbrdf
from ..coords import GRID_BINS
from ._options import SAMPLES_FILE, SBRDF, check_outputs, default_of, typed
from .files import PLAN_PAIRS, check_measured, plan_samples_file, samples_constant


def cmd_encode_samples(args: argparse.Namespace) -> int:
    """``encode-samples``: measured samples to a ``.sbrdf`` file."""
    t0 = time.perf_counter()
    check_outputs([(args.output, SBRDF, "-o")], [args.samples, args.ensemble])
    samples = read_samples(args.samples)
    if samples_constant(samples) and np.any(samples.rgb):  # all zeros: refused below
        print(f"sparse-brdf: warning: {args.samples}: every sample has the same value "
              f"{samples.rgb[0].tolist()}: a Lambertian material, or values not measured "
              "(a plan's zeros or one value copied into every row)", file=sys.stderr)
    check_measured(samples)
    # encode_samples resolves the ensemble, checks the counts and resolves the prior, once
    model = acquire_module.encode_samples(samples, args.ensemble, args.coeffs, args.bytes,
                                          seed=args.seed, prior=args.prior)
    path = save_sbrdf(args.output, model)
    st = model.stats
    print(f"wrote {path} ({path.stat().st_size} bytes) from {st['samples']} samples: "
          f"{model.transform}, coefficients {model.n_coeffs.tolist()}, dictionaries "
          f"{model.dict_index.tolist()}; {time.perf_counter() - t0:.1f} s in all (the "
          f"sparse fit {st['seconds']:.1f} s)")
    return 0


def cmd_plan_samples(args: argparse.Namespace) -> int:
    """``plan-samples``: direction pairs to measure, as a samples file."""
    check_outputs([(args.output, SAMPLES_FILE, "-o")], [])
    path = plan_samples_file(args.output, args.n, args.placement, args.seed)
    print(f"wrote {path}: {args.n} direction pairs ({args.placement}); measure them and "
          "fill in r,g,b")
    return 0


def add_samples_commands(sub) -> None:
    """``encode-samples`` and ``plan-samples``."""
    acq = acquire_module.PARAMETERS
    es = sub.add_parser(
        "encode-samples", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="encode measured samples (direction pairs and RGB values) as a .sbrdf",
        description="Compressed sensing with the ensemble's dictionaries (docs/method.md, "
                    "Encoding from samples): per coded channel a sparse fit through the "
                    "sampling operator (atoms interpolated between the bins) over the "
                    "atoms training materials use, toward their training values; the "
                    "support size, dictionary and transform chosen by cross-validation on "
                    "held-out samples. SAMPLES is a CSV with the header "
                    "wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,r,g,b[,weight] or an .npz with arrays "
                    "wi, wo, rgb[, weight]: unit directions in the local frame (z the "
                    "normal), linear RGB in 1/sr. Repeated pairs count as repeated "
                    "measurements.",
        epilog="example:\n  sparse-brdf plan-samples 2000 -o plan.csv\n  (measure, fill in "
               "r,g,b)\n  sparse-brdf encode-samples plan.csv -o material.sbrdf")
    es.add_argument("samples", help="samples file (.csv or .npz)")
    es.add_argument("-o", "--output", required=True, help="output .sbrdf (written atomically)")
    budget = es.add_mutually_exclusive_group()
    budget.add_argument("--coeffs", type=typed(acq["n_coeffs"].capped(GRID_BINS.hi)),
                        default=default_of(acquire_module.encode_samples, "n_coeffs"),
                        help="the coefficient budget N: a joint budget of 3 x N shared over "
                             "the three coded channels (one channel may hold more than N), "
                             "fewer when held-out samples say more would overfit (default "
                             "%(default)s)")
    budget.add_argument("--bytes", type=typed(budget_module.PARAMETERS["n_bytes"]),
                        default=default_of(acquire_module.encode_samples, "n_bytes"),
                        metavar="N", help="the file holds at most N bytes (default: --coeffs)")
    es.add_argument("--ensemble", help="ensemble .npz or id (default: the shipped default)")
    es.add_argument("--seed", type=typed(acq["seed"]),
                    default=default_of(acquire_module.encode_samples, "seed"),
                    help="seed of the cross-validation folds (default %(default)s)")
    es.add_argument("--prior", choices=PRIORS,
                    default=default_of(acquire_module.encode_samples, "prior"),
                    help="default: each dictionary restricted to the atoms the training "
                         "split's materials use, fitted toward their values (computed once "
                         "and cached; needs the merl data); none: every atom, no prior "
                         "(default %(default)s)")
    es.set_defaults(func=cmd_encode_samples)

    ps = sub.add_parser(
        "plan-samples", help="write direction pairs to measure, as a samples CSV with zero values",
        description="uniform: each direction uniform over the hemisphere; stratified: "
                    "strata of the grid's coordinates (dense near the specular peak); "
                    "bins: random valid bins at their lower-edge angles.")
    ps.add_argument("n", type=typed(PLAN_PAIRS), help="direction pairs")
    ps.add_argument("-o", "--output", required=True,
                    help="output samples file: .csv (or .npz)")
    ps.add_argument("--placement", default=default_of(plan, "placement"), choices=PLACEMENTS,
                    help="where the pairs lie (see above)")
    ps.add_argument("--seed", type=typed(acq["seed"]), default=default_of(plan, "seed"),
                    help="the same seed gives the same pairs")
    ps.set_defaults(func=cmd_plan_samples)
