"""Calibrate fit-scene's proxy: rendering SNR = cosine-weighted BRDF SNR + offset.

    .venv/bin/python benchmarks/calibrate.py BENCH_OUT/results.json [--scene sphere] \
        [--models sparse-262 ...]

Takes the median of (object-only rendering SNR in SCENE - cosine-weighted SNR) over the
finished sparse-model cells of a bench (or of the models named) and writes it, with its
provenance, to sparse_brdf/data/snr_calibration.json (read by
sparse_brdf.fitting.fit_scene, which targets the object-only SNR).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
from harness import parser

from sparse_brdf.paths import CALIBRATION_PATH


def main() -> None:
    p = parser(__doc__, json_option=False)
    p.add_argument("results", help="results.json of a bench run with renders")
    p.add_argument("--scene", default="sphere", help="the bench scene to calibrate on")
    p.add_argument("--out", type=Path, default=CALIBRATION_PATH,
                   help="where to write the calibration (default: the package's, which "
                        "fit-scene reads)")
    p.add_argument("--models", nargs="+", help="only these models' cells (names as in the "
                   "bench report; default: every sparse model)")
    args = p.parse_args()
    res = json.loads(Path(args.results).read_text())
    snr = {k: (c.get("renders") or {}).get(args.scene, {}).get("snr_object", math.nan)
           for k, c in res["cells"].items()}
    d = [snr[k] - c["cos_snr"] for k, c in res["cells"].items()
         if (c["model"] in args.models if args.models else c["model"].startswith("sparse"))
         and c.get("status") == "finished"
         and math.isfinite(snr[k]) and math.isfinite(c["cos_snr"])]
    if not d:
        raise SystemExit(f"{args.results}: no finished sparse cells with renders")
    cal = {"offset_db": float(np.median(d)), "spread_db": [float(np.percentile(d, 10)),
                                                          float(np.percentile(d, 90))],
           "cells": len(d), "models": sorted({c["model"] for c in res["cells"].values()
                                              if c["model"] in (args.models or [])}),
           "scene": args.scene, "form": "object-only",
           "bench": res["config"], "date": time.strftime("%Y-%m-%d")}
    args.out.write_text(json.dumps(cal, indent=1))
    print(f"offset {cal['offset_db']:+.1f} dB (10-90 %: {cal['spread_db'][0]:+.1f} to "
          f"{cal['spread_db'][1]:+.1f}) from {len(d)} cells; wrote {args.out}")


if __name__ == "__main__":
    main()
