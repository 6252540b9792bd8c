"""What the eye sees under one light: HDR-FLIP and both SNR forms of encoded materials.

A sphere under one distant light (``scenes/sphere_light.xml``) at several angles from the
camera; each material's reference table and each encoding's decoded table are rendered
by ``tabulated_brdf`` with the same bin lookup, cosine sampling, seed and spp, so two
images differ only by the model's error. Scores: HDR-FLIP over the sphere's pixels
(``sparse_brdf.hdr_flip``) and the rendering SNR in both forms.

Variants are ``NAME=OPTIONS`` with OPTIONS a comma-separated list of ``KEY=VALUE`` options of
``sparse_brdf.encode`` (``transform``, ``basis``, ...), ``n_coeffs``, ``paper=1`` (the
paper's encoder) and ``ensemble=PATH``. ``scale=S`` encodes the BRDF multiplied by S and
divides the decoded table by S (a probe of the transform's precision at low values).

Example::

    PYTHONPATH=. .venv/bin/python benchmarks/one_light.py --corpus merl rgl \\
        --variant default= --variant paper=paper=1 -o one_light.json

Writes a JSON with one row per material, variant and angle; prints the means per corpus,
and, with ``--maps DIR``, PNGs of reference, model and FLIP map for each row; with
``--grid PNG``, one figure of every material and angle: the reference, then each variant's
render and FLIP map. ``--scene`` scores another scene of ``scenes/`` the same way (without
angles), e.g. the environment-lit worst maps of ``docs/results.md``::

    PYTHONPATH=. .venv/bin/python benchmarks/one_light.py --corpus rgl --scene sphere.xml \
        --materials cc_iris_purple_gem_rgb irid_flake_paint1_fine_rgb cg_sunflower_rgb \
        --variant default= --variant previous=ensemble=5fea9b89 \
        --grid docs/figures/env_lit_worst.png -o env_lit_worst.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import sparse_brdf as sb
from sparse_brdf.brdf import BRDF
from sparse_brdf.evaluation.render import object_mask, render_scene

SCENE = "sphere_light.xml"


def parse_variant(text: str) -> tuple[str, dict]:
    name, _, spec = text.partition("=")
    opts: dict = {}
    for item in filter(None, spec.split(",")):
        k, _, v = item.partition("=")
        try:
            opts[k] = json.loads(v)
        except json.JSONDecodeError:
            opts[k] = v
    return name, opts


def encode_variant(brdf: BRDF, opts: dict) -> BRDF:
    opts = dict(opts)
    scale = float(opts.pop("scale", 1.0))
    n = int(opts.pop("n_coeffs", sb.DEFAULT_N_COEFFS))
    ens_path = opts.pop("ensemble", None)
    ens = sb.Ensemble.load(ens_path) if ens_path else sb.Ensemble.default()
    if opts.pop("paper", 0):
        opts = {**sb.PAPER_OPTIONS, **opts}
    src = brdf if scale == 1.0 else BRDF(values=brdf.values * np.float32(scale),
                                         valid=brdf.valid, name=brdf.name)
    model = sb.encode(src, ens, n_coeffs=n, **opts)
    rec = model.decode(ens)
    values = rec.values / np.float32(scale) if scale != 1.0 else rec.values
    return BRDF(values=np.where(brdf.valid[..., None], values, 0).astype(np.float32),
                valid=brdf.valid, name=brdf.name)


def render(table: Path, angle: float | None, res: int, spp: int,
           scene: str = SCENE) -> np.ndarray:
    return render_scene(scene, {"material": str(table)}, spp=spp, seed=0, res=res,
                        params={} if angle is None else {"lightangle": angle},
                        tabulated_options={"sampling": "cosine"})


def tonemap(img: np.ndarray, exposure: float) -> np.ndarray:
    x = np.clip(img * 2.0**exposure, 0, None)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (np.clip(x, 0, 1) * 255 + 0.5).astype(np.uint8)


def save_maps(path: Path, ref: np.ndarray, img: np.ndarray, fmap: np.ndarray, title: str):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    exposure = -float(np.log2(max(np.percentile(ref[ref > 0], 99.5), 1e-6)))
    fig, ax = plt.subplots(1, 3, figsize=(9, 3.2))
    for a, im, t in zip(ax, (tonemap(ref, exposure), tonemap(img, exposure), fmap),
                        ("reference", "model", "HDR-FLIP"), strict=True):
        a.imshow(im, cmap="magma" if im.ndim == 2 else None, vmin=0, vmax=1)
        a.set_title(t)
        a.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def save_grid(path: Path, rows: list[tuple[str, np.ndarray, list]]) -> None:
    """One figure: per row (title, reference, [(variant and scores, image, FLIP map)]), the
    reference, then each variant's render and FLIP map (the reference's exposure)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 1 + 2 * max(len(v) for _, _, v in rows)
    fig, axes = plt.subplots(len(rows), cols, figsize=(2.2 * cols, 2.4 * len(rows)),
                             squeeze=False)
    for ax, (title, ref, variants) in zip(axes, rows, strict=True):
        exposure = -float(np.log2(max(np.percentile(ref[ref > 0], 99.5), 1e-6)))
        panels = [(tonemap(ref, exposure), f"{title}\nreference")]
        for name, img, fmap in variants:
            panels += [(tonemap(img, exposure), name), (fmap, "HDR-FLIP map")]
        for a in ax:
            a.axis("off")
        for a, (im, t) in zip(ax, panels, strict=False):
            a.imshow(im, cmap="magma" if im.ndim == 2 else None, vmin=0, vmax=1)
            a.set_title(t, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def score_material(args, corpus: str, m, todo: list, masks: dict, rows: list,
                   tmp: Path) -> list:
    """Render material ``m``'s reference and each variant of ``todo``, append a row per
    variant and angle to ``rows`` (saving the JSON as it goes); return the grid rows."""
    key = f"{corpus}/{m.name}"
    kw = {} if args.symmetrize else {"symmetrize": False}
    ref_brdf = sb.load_brdf(m.source, **kw)
    ref_path = sb.write_merl(tmp / "ref.binary", ref_brdf)
    refs = {a: render(ref_path, a, args.res, args.spp, args.scene)
            for a in args.angles}
    cells = {a: [] for a in args.angles}
    for name, opts in todo:
        t0 = time.perf_counter()
        rec = encode_variant(ref_brdf, opts)
        t_enc = time.perf_counter() - t0
        rec_path = sb.write_merl(tmp / "rec.binary", rec)
        for a in args.angles:
            img = render(rec_path, a, args.res, args.spp, args.scene)
            flip = sb.hdr_flip(refs[a], img, masks[a])
            snr = sb.snr_forms(refs[a], img, masks[a])
            cells[a].append((f"{name}: FLIP {flip.mean:.3f}\n{snr.object:.1f} / "
                             f"{snr.whole:.1f} dB", img, flip.map))
            rows.append({"corpus": corpus, "material": key, "variant": name,
                         "scene": args.scene, "angle": a, "flip": flip.mean,
                         "flip_p95": float(np.percentile(flip.map[masks[a]], 95)),
                         # FLIP's own exposure range (from the whole image,
                         # whose median is the black background)
                         "flip_image_range": float(np.mean(sb.hdr_flip(
                             refs[a], img).map[masks[a]])),
                         "snr_whole": snr.whole, "snr_object": snr.object,
                         "encode_s": t_enc})
            if args.maps:
                save_maps(args.maps / f"{m.name}_{name}_{a or 0:g}.png", refs[a],
                          img, flip.map, f"{key} {name} {a or 0:g} deg: FLIP "
                          f"{flip.mean:.3f}, {snr}")
        print(key, name, " ".join(
            f"{r['angle'] or 0:g}:{r['flip']:.3f}/{r['snr_object']:.1f}"
            for r in rows[-len(args.angles):]), f"({t_enc:.1f} s)", flush=True)
        args.out.write_text(json.dumps(rows, indent=1))
    return [(m.name if a is None else f"{m.name} {a:g} deg", refs[a], cells[a])
            for a in args.angles if cells[a]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--corpus", nargs="+", default=["merl", "rgl"])
    ap.add_argument("--split", default="test")
    ap.add_argument("--materials", nargs="*", help="only these material names")
    ap.add_argument("--variant", action="append", default=None,
                    help="NAME=KEY=VALUE,... (repeatable; default: default=)")
    ap.add_argument("--angles", type=float, nargs="+", default=[0.0, 40.0, 70.0])
    ap.add_argument("--scene", default=SCENE,
                    help=f"a scene of scenes/ (default {SCENE}; angles only for it)")
    ap.add_argument("--grid", type=Path, help="one PNG of every material and angle")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--symmetrize", type=int, default=1, help="1: symmetrised references")
    ap.add_argument("--maps", type=Path, help="folder for reference/model/FLIP PNGs")
    ap.add_argument("-o", "--out", type=Path, required=True)
    args = ap.parse_args(argv)
    variants = [parse_variant(v) for v in (args.variant or ["default="])]
    if args.scene != SCENE:
        args.angles = [None]
    grid: list = []
    rows = json.loads(args.out.read_text()) if args.out.exists() else []
    done = {(r["material"], r["variant"], r["angle"]) for r in rows
            if r.get("scene", SCENE) == args.scene}
    masks = {a: object_mask(args.scene, res=args.res,
                            params={} if a is None else {"lightangle": a})
             for a in args.angles}
    if args.maps:
        args.maps.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for corpus in args.corpus:
            for m in sb.get_corpus(corpus).split(args.split):
                if args.materials and m.name not in args.materials:
                    continue
                key = f"{corpus}/{m.name}"
                todo = [(n, o) for n, o in variants
                        if any((key, n, a) not in done for a in args.angles)]
                if not todo:
                    continue
                grid += score_material(args, corpus, m, todo, masks, rows, tmp)
    if args.grid and grid:
        save_grid(args.grid, grid)
    summarize(rows)
    return 0


def summarize(rows: list[dict]) -> None:
    keys = sorted({(r["corpus"], r["variant"]) for r in rows})
    print(f"{'corpus':6} {'variant':22} {'FLIP mean':>9} {'FLIP max':>9} "
          f"{'obj dB':>7} {'whole dB':>8} n")
    for corpus, variant in keys:
        sel = [r for r in rows if r["corpus"] == corpus and r["variant"] == variant]
        f = np.array([r["flip"] for r in sel])
        print(f"{corpus:6} {variant:22} {f.mean():9.3f} {f.max():9.3f} "
              f"{np.mean([r['snr_object'] for r in sel]):7.2f} "
              f"{np.mean([r['snr_whole'] for r in sel]):8.2f} {len(sel)}")


if __name__ == "__main__":
    sys.exit(main())
