"""Does the pruned projection select what the full search selects?

    .venv/bin/python benchmarks/archive/check_pruning.py

On the first 5 MERL and 3 RGL-EPFL test materials, both transforms, and (coefficients,
max error) in (262, -), (64, -), (1024, -), (262, 1e-4): encodes with `project_all` (every
dictionary projected in full) and with `project_pruned`, and prints per case whether the
chosen dictionaries and coefficients agree, the two times and how many of the 96
(channel, dictionary) projections the pruned search completed. Needs ../shared/data.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from sparse_brdf import Ensemble, get_corpus
from sparse_brdf.coding.encode import DEFAULT_N_COEFFS
from sparse_brdf.coding.projection import project_all, project_pruned, select
from sparse_brdf.transforms import TRANSFORMS, forward

CASES = ((DEFAULT_N_COEFFS, None), (64, None), (1024, None), (DEFAULT_N_COEFFS, 1e-4))

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # harness.py is one up
from harness import parser  # noqa: E402


def same(a, b) -> bool:
    """Same dictionaries, and the same coefficients (as location -> value sets)."""
    if a.dict_index.tolist() != b.dict_index.tolist():
        return False
    for c in range(3):
        oa, ob = np.argsort(a.locations[c]), np.argsort(b.locations[c])
        if not np.array_equal(a.locations[c][oa], b.locations[c][ob]):
            return False
        if not np.allclose(a.values[c][oa], b.values[c][ob], rtol=1e-5, atol=1e-6):
            return False
    return True


def main() -> None:
    parser(__doc__, json_option=False).parse_args()  # --help
    ens = Ensemble.default()
    mats = get_corpus("merl").split("test")[:5] + get_corpus("rgl").split("test")[:3]
    agree = 0
    total = 0
    for m in mats:
        b = m.load()
        for t in TRANSFORMS:
            y = forward(b.channel_first(), t, b.valid)
            for n, max_error in CASES:
                t0 = time.perf_counter()
                full = select(project_all(b, ens, t, n, y=y), n, max_error)
                t1 = time.perf_counter()
                p = project_pruned(b, ens, t, n, max_error, y=y)
                pruned = select(p, n, max_error)
                t2 = time.perf_counter()
                ok = same(full, pruned)
                agree += ok
                total += 1
                done = int(np.isfinite(p.residual[:, :, 0]).sum())
                print(f"{m.name[:24]:24s} {t:16s} n={n:4d} max_error={max_error} "
                      f"full {t1 - t0:.2f} s, pruned {t2 - t1:.2f} s, completed {done:2d}/96, "
                      f"{'same' if ok else 'DIFFERENT'}")
    print(f"{agree} of {total} cases select the same dictionaries and coefficients")


if __name__ == "__main__":
    main()
