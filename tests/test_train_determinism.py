"""The trainer is deterministic: the same tensors, options and seed give the same
ensemble, bit for bit, on one machine. The expected objectives below pin today's training
output on the small grid, on tensors drawn from a seeded generator (numpy's PCG64 draws
the same numbers everywhere; a corpus tabulated by Mitsuba differs between machines in
its last bits, which the seeded initialisation can amplify).

Across machines, BLAS kernels round differently: OpenBLAS picks its kernels for the CPU
it finds (SkylakeX on a recent Xeon, Haswell's on AMD Zen), and after three iterations
the objectives of the two differ by up to 0.4 %. The pinned runs therefore train in a
subprocess with ``OPENBLAS_CORETYPE=Haswell`` (kernels every x86-64 CPU with AVX2 runs
alike) and two BLAS threads, and compare the objectives to a relative 1e-7, far below
what any change to the algorithm moves them by. Any change
that alters training output must change the expected values here, and say so in its
commit message; a refactoring that keeps training output must leave them as they are.
"""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.coords import geometric_valid
from sparse_brdf.training.train import train_ensemble

#: Per case of :func:`_train`: each sparsity's objective after each iteration.
EXPECTED = {
    "masked-seeded": {"16": [6071.4233666042255, 5443.544977039515, 5097.796315116813],
                      "48": [3384.702959920659, 2964.076748916321, 2744.30517882383]},
    "unmasked-random": {"16": [6423.206832408905, 6225.604632854462, 6094.25118637085],
                        "48": [3134.2653279304504, 3032.129642188549, 2977.572200655937]},
}


#: The BLAS kernels and thread count of the pinned runs (see the module doc).
PINNED_BLAS = {"OPENBLAS_CORETYPE": "Haswell", "OPENBLAS_NUM_THREADS": "2"}


@pytest.fixture(scope="module")
def tensors() -> np.ndarray:
    return make_tensors()


def make_tensors() -> np.ndarray:
    """48 smooth tensors on the small grid, (48, 18, 18, 36): a seeded draw, summed along
    each axis so that neighbouring bins correlate as measured ones do."""
    x = np.random.default_rng(20261202).standard_normal((48, *SMALL))
    for axis in (1, 2, 3):
        x = np.cumsum(x, axis=axis) / np.sqrt(x.shape[axis])
    return x.astype(np.float32)


def _objectives_digest(meta: dict) -> str:
    """A hash of the objectives of every iteration of every sparsity (exact floats)."""
    obj = {tau: [[h["objective"], h["objective_before_update"], h["moved"]] for h in hist]
           for tau, hist in sorted(meta["history"].items())}
    return hashlib.sha256(json.dumps(obj).encode()).hexdigest()[:16]


def _train(x: np.ndarray, case: str):
    if case == "masked-seeded":
        # a few unmeasured bins above the horizon, shared by one material's channels
        holes = np.zeros(SMALL, bool)
        holes[5:8, 3:6, 10:20] = True
        holes &= geometric_valid(SMALL)
        kw = dict(masked=True, init="seeded", missing={i: holes for i in range(3, 6)})
    else:
        kw = dict(masked=False, init="random")
    return train_ensemble(x, taus=(16, 48), n_dicts=3, n_iter=3, seed=5, progress=False,
                          reassign_every=1, tol=0, **kw)


def _objectives(meta: dict) -> dict[str, list[float]]:
    return {str(tau): [h["objective"] for h in hist]
            for tau, hist in sorted(meta["history"].items())}


def _pinned_objectives(case: str) -> dict[str, list[float]]:
    """:func:`_objectives` of ``case``, trained in a subprocess on the pinned BLAS."""
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); "
            "import test_train_determinism as t; from threadpoolctl import threadpool_info; "
            "res = t._objectives(t._train(t.make_tensors(), sys.argv[2]).meta); "
            "blas = [i.get('architecture') for i in threadpool_info() "
            "if i.get('internal_api') == 'openblas']; "
            "print(json.dumps({'blas': blas, 'objectives': res}))")
    out = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), case],
                         env={**os.environ, **PINNED_BLAS}, capture_output=True, text=True,
                         check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    if not got["blas"] or set(got["blas"]) != {"Haswell"}:
        pytest.skip(f"numpy's BLAS here is not an OpenBLAS that runs Haswell kernels "
                    f"({got['blas']}): the pinned objectives need them")
    return got["objectives"]


@pytest.mark.parametrize("case", sorted(EXPECTED))
def test_training_output_is_pinned(case):
    got = _pinned_objectives(case)
    assert got.keys() == EXPECTED[case].keys()
    for tau, want in EXPECTED[case].items():
        np.testing.assert_allclose(got[tau], want, rtol=1e-7, err_msg=f"{case}, tau {tau}")


def test_same_inputs_same_ensemble(tensors):
    a, b = (_train(tensors, "masked-seeded") for _ in range(2))
    assert a.id == b.id
    assert _objectives_digest(a.meta) == _objectives_digest(b.meta)
