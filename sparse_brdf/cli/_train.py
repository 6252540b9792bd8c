"""``train``: a dictionary ensemble trained on corpora (docs/method.md, Training)."""

from __future__ import annotations

import argparse
import math
import sys
import time

from ..coding.ensemble import Ensemble
from ..coords import GRID_BINS, GRID_SIDE, check_grid
from ..errors import UsageError
from ..sources.corpora import SPLITS, TRAINING_CORPORA, get_corpus
from ..sources.dataset import training_data, training_fingerprint
from ..training.train import train_dictionaries, train_ensemble
from ..transforms import COLOUR_BASES, TRANSFORMS
from ._options import (
    ENSEMBLE_NPZ,
    TRAIN,
    add_symmetrize,
    add_where,
    check_outputs,
    default_of,
    typed,
)


def cmd_train(args: argparse.Namespace) -> int:
    """``train``: an ensemble trained on corpora, saved as ``.npz``."""
    check_outputs([(args.output, ENSEMBLE_NPZ, "-o")], [args.extend])
    shape = check_grid(args.grid, "--grid")
    if max(args.taus) > math.prod(shape):
        raise UsageError(f"--taus {max(args.taus)}: a tensor of that grid has only "
                         f"{math.prod(shape)} coefficients")
    materials = []
    for name in args.corpus:
        materials += get_corpus(name).split(args.split)
    t0 = time.perf_counter()
    data = training_data(materials, args.transform, shape, basis=args.basis,
                         symmetrize=args.symmetrize)
    x = data.x
    if args.dicts > len(x):
        raise UsageError(f"--dicts {args.dicts}: more dictionaries than the {len(x)} "
                         "training tensors")
    load_s = time.perf_counter() - t0
    meta = {
        "data": [f"{m.corpus}/{m.name}" for m in materials],
        "corpora": args.corpus, "split": args.split, "transforms": list(args.transform),
        "basis": args.basis, "grid": list(shape), "load_seconds": load_s,
        "data_sha256": data.digest(), "symmetrize": args.symmetrize is not False,
        "data_fingerprint": training_fingerprint(materials, args.transform, shape,
                                                 basis=args.basis, symmetrize=args.symmetrize,
                                                 data=data),
        "command": "sparse-brdf " + " ".join(sys.argv[1:]),
        "created": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }
    ens = train_ensemble(x, args.taus, args.dicts, args.iterations, seed=args.seed,
                         checkpoint_dir=args.checkpoint_dir, meta=meta,
                         reassign_every=args.reassign_every, masked=args.masked,
                         missing=data.missing, init=args.init, tol=args.tol,
                         max_moved=args.max_moved, shard_tensors=args.shard_tensors,
                         warm_start=args.warm_start,
                         workers=args.workers, scheduler=args.scheduler)
    if args.extend:
        ens = Ensemble.load(args.extend).union(ens)
    ens.save(args.output)
    print(f"wrote {args.output}: {ens.n_dicts} dictionaries, id {ens.id}, "
          f"trained in {ens.meta.get('seconds', 0):.0f} s on {len(x)} tensors, loaded in "
          f"{load_s:.0f} s (benchmarks/training_report.py shows where the time went)")
    return 0


def add_train(sub) -> None:
    """``train``."""
    t = sub.add_parser("train", help="train a dictionary ensemble (docs/method.md, Training)")
    t.add_argument("--corpus", nargs="+", default=list(TRAINING_CORPORA),
                   help="corpora to train on (names or folders)")
    t.add_argument("--split", default="train", choices=SPLITS,
                   help="which materials of the corpora to train on")
    t.add_argument("--transform", nargs="+", default=default_of(training_data, "transforms"),
                   choices=TRANSFORMS,
                   help="value transforms the dictionaries are trained in, one set each (the "
                        "paper's ensembles: log-plus log-plus-cosine)")
    add_symmetrize(t)
    t.add_argument("--basis", default=default_of(training_data, "basis"), choices=COLOUR_BASES,
                   help="colour basis of the training channels (the encoder's coded channels)")
    t.add_argument("--taus", nargs="+", type=typed(TRAIN["tau"].capped(GRID_BINS.hi)),
                   default=default_of(train_ensemble, "taus"),
                   help="training sparsities; one set of dictionaries per value")
    t.add_argument("--dicts", type=typed(TRAIN["n_dicts"]),
                   default=default_of(train_ensemble, "n_dicts"), help="dictionaries per sparsity")
    t.add_argument("--iterations", type=typed(TRAIN["n_iter"]),
                   default=default_of(train_ensemble, "n_iter"),
                   help="at most this many iterations per sparsity")
    t.add_argument("--reassign-every", type=typed(TRAIN["reassign_every"]),
                   default=default_of(train_dictionaries, "reassign_every"),
                   help="cluster against every dictionary at every N-th iteration")
    t.add_argument("--tol", type=typed(TRAIN["tol"]), default=default_of(train_dictionaries, "tol"),
                   help="stop once an iteration lowers the objective by less than this "
                        "(relative) and the latest clustering moved at most --max-moved")
    t.add_argument("--max-moved", type=typed(TRAIN["max_moved"]),
                   default=default_of(train_dictionaries, "max_moved"),
                   help="fraction of tensors a clustering may move for training to stop")
    t.add_argument("--shard-tensors", type=typed(TRAIN["shard_tensors"]),
                   default=default_of(train_dictionaries, "shard_tensors"),
                   help="tensors per shard: sums over tensors run per shard, then over "
                        "the shards, so this fixes the floating-point order (any executor "
                        "gives the same result for one value); 0: one shard of all, the "
                        "order that trained the shipped default ensemble (docs/ensemble.md)")
    t.add_argument("--masked", action=argparse.BooleanOptionalAction,
                   default=default_of(train_dictionaries, "masked"),
                   help="fit valid bins only (bins below the horizon and unmeasured bins "
                        "are free values); --no-masked fits them as zeros")
    t.add_argument("--init", default=default_of(train_dictionaries, "init"), choices=TRAIN["init"],
                   help="initial clusters: seeded (k-means++ in the training error) or "
                        "random balanced")
    t.add_argument("--warm-start", action=argparse.BooleanOptionalAction,
                   default=default_of(train_ensemble, "warm_start"),
                   help="start each sparsity after the first from the previous one's "
                        "dictionaries and clusters (no new seeding or unpruned first "
                        "clustering: docs/ensemble.md)")
    t.add_argument("--seed", type=typed(TRAIN["seed"]), default=default_of(train_ensemble, "seed"),
                   help="seed of the initial clusters: the same seed gives the same ensemble")
    t.add_argument("--grid", nargs=3, type=typed(GRID_SIDE),
                   default=default_of(training_data, "shape"), metavar=("N_H", "N_D", "N_P"),
                   help="the tensors' grid (theta_h, theta_d, phi_d bins)")
    t.add_argument("--checkpoint-dir", help="checkpoint every iteration here and resume "
                                            "(default: no checkpoints)")
    t.add_argument("--extend", help="unite the new dictionaries with this ensemble (default: "
                                    "a new ensemble of these alone)")
    t.add_argument("-o", "--output", required=True, help="output ensemble .npz")
    add_where(t, "the per-tensor work of each iteration")
    t.set_defaults(func=cmd_train)
