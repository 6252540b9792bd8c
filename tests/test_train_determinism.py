"""The trainer is deterministic: the same tensors, options and seed give the same
ensemble, bit for bit, on one machine, in one process or in two. Across machines, the
objectives stay within a stated tolerance of the values pinned here.

Why a tolerance across machines: BLAS kernels round differently (OpenBLAS picks SkylakeX
kernels on a recent Xeon, Haswell's on AMD Zen), and the trainer's discrete steps (each
tensor's dictionary, each code's largest coefficients) turn a last-bit difference into a
different choice now and then. Measured on the pinned cases with OpenBLAS's Haswell,
SkylakeX and Sandybridge kernels and numpy's AVX2 and AVX-512 dispatch (2026-12-07), the
objectives after three iterations differ by up to 0.37 %; :data:`CROSS_MACHINE_RTOL`
allows 1 %. That catches a change of the algorithm that moves training by more than that
(another seed moves "masked-seeded" by 2.5 %), not a subtle one: the exact promise is
bit identity on one machine, which the other tests here check.

Any change that alters training output must change the expected values here, and say so
in its commit message; a refactoring that keeps training output must leave them as they
are (on the machine that pinned them they still match to the last bit).
"""

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.coords import geometric_valid
from sparse_brdf.training.train import train_ensemble

pytestmark = pytest.mark.numerics

#: Per case of :func:`_train`: each sparsity's objective after each iteration (pinned
#: 2026-12-07 when the dictionary update began contracting only the atoms each code
#: uses: the same products summed in another order, within 0.02 % of the values before).
EXPECTED = {
    "masked-seeded": {"16": [6067.098249363824, 5430.264279874686, 5073.231444689436],
                      "48": [3384.7034327986516, 2964.0772460545313, 2744.796654789872]},
    "unmasked-random": {"16": [6423.205564022064, 6224.589867115021, 6093.628161907196],
                        "48": [3134.307100057602, 3032.135672867298, 2977.5780671834946]},
}


#: How far the objectives may be from :data:`EXPECTED` on another machine (see the
#: module doc: up to 0.37 % measured between BLAS kernels).
CROSS_MACHINE_RTOL = 1e-2


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


def _objectives_in_subprocess(case: str) -> tuple[dict[str, list[float]], str]:
    """:func:`_objectives` and :func:`_objectives_digest` of ``case``, trained in a fresh
    Python process on this machine."""
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); "
            "import test_train_determinism as t; "
            "meta = t._train(t.make_tensors(), sys.argv[2]).meta; "
            "print(json.dumps([t._objectives(meta), t._objectives_digest(meta)]))")
    out = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), case],
                         capture_output=True, text=True, check=True)
    objectives, digest = json.loads(out.stdout.strip().splitlines()[-1])
    return objectives, digest


@pytest.mark.train
@pytest.mark.parametrize("case", sorted(EXPECTED))
def test_training_output_is_pinned(tensors, case):
    """Near the pinned values on any machine; in a second process, bit-identical to this
    one's."""
    meta = _train(tensors, case).meta
    got = _objectives(meta)
    assert got.keys() == EXPECTED[case].keys()
    for tau, want in EXPECTED[case].items():
        np.testing.assert_allclose(got[tau], want, rtol=CROSS_MACHINE_RTOL,
                                   err_msg=f"{case}, tau {tau}")
    assert _objectives_in_subprocess(case) == (got, _objectives_digest(meta))


@pytest.mark.train
def test_same_inputs_same_ensemble(tensors):
    a, b = (_train(tensors, "masked-seeded") for _ in range(2))
    assert a.id == b.id
    assert _objectives_digest(a.meta) == _objectives_digest(b.meta)
