"""How few pixels decide a bench's per-material numbers.

For every rendered cell of a bench folder (its ``results.json`` and the renders under
``work/``): the share of the whole image's squared error (summed over R, G, B) that its
``--top`` worst pixels hold, and, where the scene has an object mask, the range of
exposures HDR-FLIP judges the render over (stops from the one that maps the reference's
brightest pixel to 0.85 to the one that maps the object's median there,
``sparse_brdf.metrics.flip_exposures``). A cell whose error sits in a handful of pixels
(the reflections of a scene's brightest lights) moves by decibels when those pixels do; a
cell judged over 18 stops or more has its HDR-FLIP decided by the far tail of the BRDF.
Prints, per scene, how many cells are so concentrated, HDR-FLIP by exposure range, and
the cells past either line::

    .venv/bin/python benchmarks/error_concentration.py bench_standard --model sparse-b1700
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from harness import parser

from sparse_brdf.evaluation.images import read_exr
from sparse_brdf.metrics import flip_exposures

#: The exposure ranges (stops) HDR-FLIP's errors are grouped by.
SPAN_EDGES = (0.0, 10.0, 14.0, 18.0, 22.0, np.inf)


def top_share(ref: np.ndarray, img: np.ndarray, top: int) -> float:
    """The share of the squared error sum_c (img - ref)^2 over all pixels that the
    ``top`` largest pixels hold, in [0, 1]; NaN where the images are equal.

    Parameters
    ----------
    ref, img : numpy.ndarray
        Linear images of equal shape (H, W, C).
    top : int
        How many pixels, >= 1.
    """
    err = ((np.asarray(img, np.float64) - np.asarray(ref, np.float64)) ** 2).sum(-1).ravel()
    total = err.sum()
    if not total > 0:
        return float("nan")
    k = min(top, err.size)
    return float(np.partition(err, err.size - k)[err.size - k:].sum() / total)


def cell_rows(bench: Path, model: str | None, top: int) -> list[dict]:
    """One row per rendered (cell, scene) of the bench folder ``bench`` whose render and
    reference are on disk: material, model, scene, ``share`` (:func:`top_share`),
    ``stops`` (HDR-FLIP's exposure range, None without an object mask), ``flip`` and
    ``snr_whole`` as the bench scored them."""
    results = json.loads((bench / "results.json").read_text())
    rows = []
    for cell in results["cells"].values():
        if cell.get("status") != "finished" or (model and cell["model"] != model):
            continue
        stem = cell["material"].replace("/", "__")
        for scene, r in (cell.get("renders") or {}).items():
            work = bench / "work" / scene
            ref_p, img_p = work / f"{stem}__reference.exr", work / f"{stem}__{cell['model']}.exr"
            if not (ref_p.is_file() and img_p.is_file()):
                continue
            ref = read_exr(ref_p)
            mask_p = work / "object_mask.npy"
            stops = None
            if mask_p.is_file() and ref.max() > 0:
                e = flip_exposures(ref, np.load(mask_p))
                stops = e["stopExposure"] - e["startExposure"]
            rows.append({"material": cell["material"], "model": cell["model"], "scene": scene,
                         "share": top_share(ref, read_exr(img_p), top), "stops": stops,
                         "flip": r.get("flip"), "snr_whole": r.get("snr_whole")})
    return rows


def summary(rows: list[dict], top: int, share: float, stops: float) -> list[str]:
    """The printed report: per scene, the cells past ``share`` and HDR-FLIP by exposure
    range; then every cell past ``share`` or ``stops``."""
    out = []
    for scene in sorted({r["scene"] for r in rows}):
        rs = [r for r in rows if r["scene"] == scene]
        shares = np.array([r["share"] for r in rs], float)
        out.append(f"\n### {scene}\n\n{len(rs)} cells; the {top} worst pixels hold more than "
                   f"{share:.0%} of the squared error in {int(np.sum(shares > share))}, "
                   f"median share {np.nanmedian(shares):.2f}\n")
        flips = [(r["stops"], r["flip"]) for r in rs
                 if r["stops"] is not None and r["flip"] is not None]
        if flips:
            st, fl = np.array(flips, float).T
            out += ["| HDR-FLIP's exposure range (stops) | cells | HDR-FLIP mean | max |",
                    "|---|---|---|---|"]
            for lo, hi in zip(SPAN_EDGES[:-1], SPAN_EDGES[1:], strict=True):
                sel = (st >= lo) & (st < hi)
                if sel.any():
                    span = f"{lo:g} and more" if np.isinf(hi) else f"{lo:g}-{hi:g}"
                    out.append(f"| {span} | {int(sel.sum())} | {fl[sel].mean():.3f} | "
                               f"{fl[sel].max():.3f} |")
    past = [r for r in rows if r["share"] > share or (r["stops"] or 0.0) >= stops]
    if past:
        out += [f"\n### Cells past either line (share > {share:g}, range >= {stops:g} stops)\n",
                "| material | model | scene | share | stops | HDR-FLIP | whole-image dB |",
                "|---|---|---|---|---|---|---|"]
        for r in sorted(past, key=lambda r: (r["scene"], -r["share"])):
            st = "-" if r["stops"] is None else f"{r['stops']:.1f}"
            fl = "-" if r["flip"] is None else f"{r['flip']:.3f}"
            snr = "-" if r["snr_whole"] is None else f"{r['snr_whole']:.1f}"
            out.append(f"| {r['material']} | {r['model']} | {r['scene']} | "
                       f"{r['share']:.2f} | {st} | {fl} | {snr} |")
    return out


def main(argv=None) -> int:
    p = parser(__doc__, json_option=False)
    p.add_argument("bench", type=Path, help="a bench folder (its results.json and work/)")
    p.add_argument("--model", help="only this model's cells (default: every model's)")
    p.add_argument("--top", type=int, default=10, help="pixels counted (default: 10)")
    p.add_argument("--share", type=float, default=0.5,
                   help="a cell is concentrated past this share (default: 0.5)")
    p.add_argument("--stops", type=float, default=18.0,
                   help="and HDR-FLIP's range is long from this many stops (default: 18)")
    args = p.parse_args(argv)
    if not (args.bench / "results.json").is_file():
        print(f"error_concentration: {args.bench}: no results.json (not a bench folder)",
              file=sys.stderr)
        return 2
    if args.top < 1:
        print(f"error_concentration: --top: must be at least 1, got {args.top}",
              file=sys.stderr)
        return 2
    rows = cell_rows(args.bench, args.model, args.top)
    if not rows:
        print(f"error_concentration: {args.bench}: no cell with its render and reference "
              "under work/", file=sys.stderr)
        return 2
    print("\n".join(summary(rows, args.top, args.share, args.stops)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
