"""Bytes per coefficient of .sbrdf version 2 against version 1, and what quantising the
values costs (docs/file-format.md, "Measured").

    python benchmarks/sbrdf_sizes.py [--counts 64 262 1024] [--materials DIR_OR_FILES...]
    python benchmarks/sbrdf_sizes.py --bytes 6365 [--materials ...]

For every material (default: the six demo materials, ``sparse_brdf/data/materials``),
every count and both encoders (today's default, the paper's), it encodes with the shipped
ensemble and prints one markdown row: file bytes of version 1 and version 2, version 2's
bytes per coefficient (header included), the largest quantisation error relative to the
channel's largest |value|, and the cosine-weighted BRDF SNR of the in-memory model and of
the version-2 file's (their difference is what quantisation costs).

With ``--bytes N``: each material encoded to at most N bytes per file
(:func:`~sparse_brdf.coding.budget.encode_to_bytes`, today's encoder) as version 1 and as
version 2, and the cosine-weighted BRDF SNR of each (accuracy at equal bytes, BRDF space).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from harness import header, parser, write_json

from sparse_brdf.coding.budget import encode_to_bytes
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import resolve_ensemble
from sparse_brdf.coding.fileformat import as_stored, to_bytes
from sparse_brdf.coding.spec import PAPER_OPTIONS
from sparse_brdf.metrics import cosine_weighted_snr
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.load import load_brdf


def quantisation_error(model, stored) -> float:
    """Largest |decoded - encoded| over the coefficients, relative to the channel's max."""
    worst = 0.0
    for c in range(3):
        if model.values[c].size == 0:
            continue
        a, b = np.argsort(model.locations[c]), np.argsort(stored.locations[c])
        err = np.abs(model.values[c][a].astype(np.float64) - stored.values[c][b]).max()
        worst = max(worst, float(err / np.abs(model.values[c]).max()))
    return worst


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--counts", nargs="+", type=int, default=[64, 262, 1024])
    ap.add_argument("--materials", nargs="+", default=[str(DEMO_MATERIALS_DIR)])
    ap.add_argument("--bytes", type=int, help="accuracy of v1 and v2 at this byte budget")
    args = ap.parse_args()
    files = []
    for m in args.materials:
        files += sorted(Path(m).glob("*.h5")) if Path(m).is_dir() else [Path(m)]
    ens = resolve_ensemble(None)
    if args.bytes:
        equal_bytes(files, ens, args.bytes)
        return
    rows = []
    print(header())
    print("| material | coefficients/channel | encoder | coefficients | v1 bytes | v2 bytes | "
          "v2 bytes/coefficient | max error / max abs | cos-SNR in memory | cos-SNR v2 file |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for f in files:
        brdf = load_brdf(str(f))
        for n in args.counts:
            for enc, opts in (("default", {}), ("paper", PAPER_OPTIONS)):
                m = encode(brdf, ens, n, **opts)
                s = as_stored(m)
                t = int(m.n_coeffs.sum())
                snr = [cosine_weighted_snr(brdf.values, x.decode(ens, valid=brdf.valid).values,
                                           brdf.valid) for x in (m, s)]
                row = {"material": brdf.name, "n": n, "encoder": enc, "coefficients": t,
                       "v1": len(to_bytes(m, 1)), "v2": len(to_bytes(m)),
                       "error": quantisation_error(m, s), "snr": snr[0], "snr_v2": snr[1]}
                rows.append(row)
                print(f"| {row['material']} | {n} | {enc} | {t} | {row['v1']} | {row['v2']} | "
                      f"{row['v2'] / t:.2f} | {row['error']:.1e} | {snr[0]:.3f} | "
                      f"{snr[1]:.3f} |", flush=True)
    for n in args.counts:
        sel = [r for r in rows if r["n"] == n]
        coeffs = sum(r["coefficients"] for r in sel)
        loss = [r["snr"] - r["snr_v2"] for r in sel]
        print(f"\n{n}/channel: v2 {sum(r['v2'] for r in sel) / coeffs:.2f} bytes/coefficient "
              f"(v1 {sum(r['v1'] for r in sel) / coeffs:.2f}), SNR change max "
              f"{max(loss):+.4f} dB, mean {np.mean(loss):+.4f} dB")
    if args.json:
        write_json(args.json, rows, args)


def equal_bytes(files, ens, n_bytes: int) -> None:
    """Cosine-weighted BRDF SNR of version 1 and version 2 files of at most ``n_bytes``."""
    print("| material | v1: coefficients | v1: bytes | v1: cos-SNR | v2: coefficients | "
          "v2: bytes | v2: cos-SNR | gain |\n|---|---|---|---|---|---|---|---|")
    gains = []
    for f in files:
        brdf = load_brdf(str(f))
        row = []
        for version in (1, 2):
            m = encode_to_bytes(brdf, ens, n_bytes, version)
            snr = cosine_weighted_snr(brdf.values, m.decode(ens, valid=brdf.valid).values,
                                      brdf.valid)
            row += [int(m.n_coeffs.sum()), len(to_bytes(m, version)), snr]
        gains.append(row[5] - row[2])
        print(f"| {brdf.name} | {row[0]} | {row[1]} | {row[2]:.2f} | {row[3]} | {row[4]} | "
              f"{row[5]:.2f} | {gains[-1]:+.2f} dB |", flush=True)
    print(f"\nmean gain {np.mean(gains):+.2f} dB, min {min(gains):+.2f} dB at {n_bytes} bytes")


if __name__ == "__main__":
    main()
