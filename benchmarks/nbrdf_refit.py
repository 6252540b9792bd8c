"""Faithfulness of the Neural-BRDF trainer: refit the six shipped demo networks from
their own tables and render the refit against the original.

    .venv/bin/python benchmarks/nbrdf_refit.py --time-budget 150 \\
        --json docs/figures/nbrdf_refit.json

Each demo material (``sparse_brdf/data/materials/*.h5``, a Neural-BRDF network of
Sztrajman et al. 2021 fitted to a measured MERL material) is tabulated on the 90 x 90 x
180 grid; :func:`sparse_brdf.compared.neural.train_nbrdf` trains a new network on that table
(the published recipe: 800,000 samples, batch 512, Adam 5e-4, 100 epochs, seed 0; stopped
early if ``--time-budget`` seconds are exceeded, and the row says so). Both tables are
rendered as the bench renders a model, through ``tabulated_brdf`` with the same sampler
and seed (``--spp`` 16, ``--res`` 128, ``--seed`` 0, the bench's defaults), in the studio
sphere (``sphere``) and the paper's scene (``paper_sphere``, skipped with a line when the
Grace Cathedral map is absent); the rendering SNR of the refit against the original's
render is given in both forms (whole-image, object-only), beside the noise floor (the
original rendered with seed 1 against seed 0). Also per material: training time (wall
and CPU), epochs run, the loss after each epoch, and the cosine-weighted SNR of the
tables.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, machine, parser, write_json

from sparse_brdf.brdf import BRDF
from sparse_brdf.compared.neural import train_nbrdf
from sparse_brdf.errors import MissingDataError
from sparse_brdf.evaluation.render import SHARED_PATHS, noise_floor_snr, object_mask, render_scene
from sparse_brdf.evaluation.scenes import check_scene_data, find_scene
from sparse_brdf.metrics import cosine_weighted_snr, snr_forms
from sparse_brdf.mlp import tabulate
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl

SCENES = ("sphere", "paper_sphere")


def usable_scenes(names) -> dict[str, Path]:
    """The scenes whose data is here (a line for each one skipped)."""
    out = {}
    for name in names:
        path = find_scene(name)
        try:
            check_scene_data(path)
        except MissingDataError as exc:
            print(f"skipping {name}: {exc}")
            continue
        out[name] = path
    return out


def refit(path: Path, budget: float | None, epochs: int, seed: int) -> tuple[BRDF, dict]:
    """The original table and the refit's training record (its table under ``table``)."""
    brdf = load_brdf(path)
    t0, c0 = time.perf_counter(), time.process_time()
    fit = train_nbrdf(brdf, epochs=epochs, seed=seed, time_budget=budget, progress=True)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    table, _ = tabulate(fit.layers, brdf.shape)
    return brdf, {"material": path.stem, "train_s": wall, "train_cpu_s": cpu,
                  "epochs": fit.epochs, "steps": fit.steps, "stopped_early": fit.stopped_early,
                  "loss": fit.loss[-1] if fit.loss else None, "loss_curve": fit.loss,
                  "cos_snr": cosine_weighted_snr(brdf.values, table, brdf.valid),
                  "table": table}


def render_pair(scene: Path, original: str, refitted: str, mask: np.ndarray, spp: int,
                res: int, seed: int) -> dict:
    """Both SNR forms of the refit against the original, and the original's noise floor."""
    ref = render_scene(scene, {"material": original}, sampling=SHARED_PATHS,
                       spp=spp, seed=seed, res=res)
    alt = render_scene(scene, {"material": original}, sampling=SHARED_PATHS,
                       spp=spp, seed=seed + 1, res=res)
    img = render_scene(scene, {"material": refitted}, sampling=SHARED_PATHS,
                       spp=spp, seed=seed, res=res)
    snr, floor = snr_forms(ref, img, mask), noise_floor_snr(ref, alt, mask)
    return {"snr_whole": snr.whole, "snr_object": snr.object,
            "floor_whole": floor.whole, "floor_object": floor.object}


def run(args) -> list[dict]:
    """One row per material: training record and, per scene, the rendering SNRs."""
    scenes = usable_scenes(args.scenes)
    masks = {name: object_mask(path, res=args.res) for name, path in scenes.items()}
    files = sorted(DEMO_MATERIALS_DIR.glob("*.h5"))
    if args.materials:
        files = [f for f in files if f.stem in set(args.materials)]
    rows = []
    with tempfile.TemporaryDirectory(prefix="nbrdf_refit_") as tmpdir:
        tmp = Path(tmpdir)
        for path in files:
            brdf, row = refit(path, args.time_budget, args.epochs, args.seed)
            table = row.pop("table")
            original = str(write_merl(tmp / f"{path.stem}-original.binary", brdf))
            refitted = str(write_merl(tmp / f"{path.stem}-refit.binary",
                                      BRDF(table, brdf.valid, brdf.name)))
            row["renders"] = {name: render_pair(scene, original, refitted, masks[name],
                                                args.spp, args.res, args.seed)
                              for name, scene in scenes.items()}
            rows.append(row)
            print(line(row), flush=True)
    return rows


def line(row: dict) -> str:
    """One printed line per material."""
    renders = "; ".join(f"{s}: {r['snr_whole']:.1f} / {r['snr_object']:.1f} dB (floor "
                        f"{r['floor_whole']:.1f} / {r['floor_object']:.1f})"
                        for s, r in row["renders"].items())
    early = ", stopped by the time budget" if row["stopped_early"] else ""
    return (f"{row['material']:26s} {row['epochs']} epochs in {row['train_s']:.0f} s "
            f"(CPU {row['train_cpu_s']:.0f} s{early}), loss {row['loss']:.4f}, cos-SNR "
            f"{row['cos_snr']:.1f} dB; whole / object: {renders}")


def summary(rows: list[dict]) -> dict:
    """Means over the materials: training time and, per scene, both SNR forms."""
    out = {"train_s_mean": float(np.mean([r["train_s"] for r in rows])),
           "train_cpu_s_mean": float(np.mean([r["train_cpu_s"] for r in rows])),
           "stopped_early": sum(r["stopped_early"] for r in rows)}
    for scene in rows[0]["renders"] if rows else ():
        for key in ("snr_whole", "snr_object", "floor_whole", "floor_object"):
            out[f"{scene}_{key}_mean"] = float(np.mean([r["renders"][scene][key]
                                                        for r in rows]))
    return out


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--time-budget", type=float, default=None,
                   help="seconds of training per material (default: none)")
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scenes", nargs="+", default=list(SCENES))
    p.add_argument("--res", type=int, default=128)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--materials", nargs="*", help="demo material names (default: all six)")
    args = p.parse_args()
    info = machine()  # the load average as the timing starts
    rows = run(args)
    summ = summary(rows)
    print(header(info))
    print(", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
                    for k, v in summ.items()))
    if args.json:
        write_json(args.json, {"rows": rows, "summary": summ}, args, info)


if __name__ == "__main__":
    main()
