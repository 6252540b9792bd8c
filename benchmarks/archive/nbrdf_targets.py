"""Experiment: should the Neural-BRDF trainer's target at a continuous angle be the
table's trilinear interpolation (the default) or the nearest bin's value?

    .venv/bin/python benchmarks/archive/nbrdf_targets.py \\
        --json docs/figures/nbrdf_targets_2026-12-02.json

For each material (default: the two glossiest demo networks, red-specular-plastic and
blue-metallic-paint2) and seed, a network is trained with the full recipe
(``train_nbrdf``, 100 epochs) once with nearest-bin targets (``coords.angles_to_bins``,
substituted for ``neural.table_values``) and, for ``--trilinear-seeds``, with the default
trilinear ones; its table is rendered against the original network's as
``benchmarks/nbrdf_refit.py`` does (``tabulated_brdf``, same seed, 128 x 128, 16 spp,
both scenes, both SNR forms). Prints one line per run.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from sparse_brdf.brdf import BRDF
from sparse_brdf.compared import neural
from sparse_brdf.coords import angles_to_bins
from sparse_brdf.evaluation.render import SHARED_PATHS, object_mask, render_scene
from sparse_brdf.evaluation.scenes import find_scene
from sparse_brdf.metrics import snr_forms
from sparse_brdf.mlp import tabulate
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # harness.py is one up
from harness import header, machine, parser, write_json  # noqa: E402

TRILINEAR = neural.table_values


def nearest(brdf: BRDF, theta_h, theta_d, phi_d):
    """The nearest-bin rule in ``neural.table_values``' form: (rho, covered)."""
    i, j, k = angles_to_bins(theta_h, theta_d, phi_d, brdf.shape)
    return brdf.values[i, j, k].astype(np.float64), brdf.valid[i, j, k]


def one_run(name: str, targets: str, seed: int, epochs: int, scenes: dict, masks: dict,
            tmp: Path) -> dict:
    """Train with ``targets`` ("nearest" or "trilinear") and render against the original."""
    brdf = load_brdf(DEMO_MATERIALS_DIR / f"{name}.h5")
    neural.table_values = nearest if targets == "nearest" else TRILINEAR
    try:
        fit = neural.train_nbrdf(brdf, epochs=epochs, seed=seed)
    finally:
        neural.table_values = TRILINEAR
    table, _ = tabulate(fit.layers, brdf.shape)
    original = str(write_merl(tmp / "original.binary", brdf))
    refit = str(write_merl(tmp / "refit.binary", BRDF(table, brdf.valid, name)))
    row = {"material": name, "targets": targets, "seed": seed, "loss": fit.loss[-1],
           "train_s": fit.seconds}
    for scene, path in scenes.items():
        ref = render_scene(path, {"material": original}, sampling=SHARED_PATHS,
                           spp=16, seed=0, res=128)
        img = render_scene(path, {"material": refit}, sampling=SHARED_PATHS,
                           spp=16, seed=0, res=128)
        snr = snr_forms(ref, img, masks[scene])
        row[scene] = {"snr_whole": snr.whole, "snr_object": snr.object}
    return row


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--materials", nargs="+",
                   default=["red-specular-plastic", "blue-metallic-paint2"])
    p.add_argument("--nearest-seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--trilinear-seeds", type=int, nargs="*", default=[1])
    p.add_argument("--scenes", nargs="+", default=["sphere", "paper_sphere"])
    p.add_argument("--epochs", type=int, default=100)
    args = p.parse_args()
    info = machine()
    scenes = {s: find_scene(s) for s in args.scenes}
    masks = {s: object_mask(path, res=128) for s, path in scenes.items()}
    runs = [("nearest", s) for s in args.nearest_seeds]
    runs += [("trilinear", s) for s in args.trilinear_seeds]
    rows = []
    with tempfile.TemporaryDirectory(prefix="nbrdf_targets_") as tmp:
        for name in args.materials:
            for targets, seed in runs:
                rows.append(one_run(name, targets, seed, args.epochs, scenes, masks,
                                    Path(tmp)))
                print(rows[-1], flush=True)
    print(header(info))
    if args.json:
        write_json(args.json, rows, args, info)


if __name__ == "__main__":
    main()
