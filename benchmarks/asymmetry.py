"""How far the Neural-BRDF networks are from an isotropic, reciprocal BRDF.

For every network of the given corpora, on a half-resolution grid (45 x 45 x 90) at the
valid bins: the median over bins and channels of |f(x) - f(x')| relative to their mean, with x'
the direction pair under reciprocity (phi_d -> phi_d + pi: the difference vector's x and
y negated) and under the mirror (phi_d -> -phi_d: its y negated). An isotropic,
reciprocal BRDF scores 0 on both; ``load_brdf`` averages a network over both symmetries
(``docs/method.md``, "Symmetric references").

    PYTHONPATH=. .venv/bin/python benchmarks/asymmetry.py --corpus merl rgl -o asym.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from sparse_brdf.coords import geometric_valid, grid_angles
from sparse_brdf.mlp import evaluate, network_inputs
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.nbrdf import read_nbrdf_weights

SHAPE = (45, 45, 90)


def asymmetry(path) -> dict[str, float]:
    layers = read_nbrdf_weights(path)
    valid = geometric_valid(SHAPE)
    th, td, pd = grid_angles(SHAPE)
    x = network_inputs(th[valid], td[valid], pd[valid])
    f = evaluate(layers, x).astype(np.float64)
    out = {}
    for name, sign in (("reciprocity", (-1, -1)), ("mirror", (1, -1))):
        g = evaluate(layers, x * np.array([1, 1, 1, *sign, 1], np.float32)).astype(np.float64)
        rel = 2.0 * np.abs(f - g) / np.maximum(f + g, 1e-12)  # relative to their mean
        out[name] = float(np.median(rel))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--corpus", nargs="+", default=["merl", "rgl"])
    ap.add_argument("-o", "--out", type=Path)
    args = ap.parse_args(argv)
    rows = []
    for corpus in args.corpus:
        for m in get_corpus(corpus).materials:
            rows.append({"corpus": corpus, "material": m.name, **asymmetry(m.source)})
    for corpus in args.corpus:
        sel = [r for r in rows if r["corpus"] == corpus]
        for key in ("reciprocity", "mirror"):
            v = np.array([r[key] for r in sel])
            worst = sorted(sel, key=lambda r: -r[key])[:4]
            print(f"{corpus:5} {key:11} median {np.median(v):.3f}, max {v.max():.3f}; worst: "
                  + ", ".join(f"{r['material']} {r[key]:.3f}" for r in worst))
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
