"""The baselines' own Dr.Jit evaluators (mitsuba_plugin.evaluators) and the speed axis
(sparse_brdf.benchmark.speed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.compared.baselines import (
    CPDModel,
    NaiveModel,
    PCAModel,
    TabulatedModel,
    TuckerModel,
)
from sparse_brdf.compared.sparse_model import SparseModel
from sparse_brdf.coords import (
    angles_to_bins,
    dirs_to_angles,
    geometric_valid,
    grid_coords,
)
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.dataset import training_tensors
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.training.train import hosvd_ensemble

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from mitsuba_plugin.evaluators import (  # noqa: E402
    KINDS,
    evaluator_for,
    make_evaluator,
)
from sparse_brdf.benchmark.speed import evals_per_second  # noqa: E402
from sparse_brdf.mitsuba_env import set_variant  # noqa: E402

pytestmark = pytest.mark.numerics

MODELS = {
    "naive": lambda: NaiveModel(),
    "cpd-1": lambda: CPDModel(1, n_iter=10),
    "cpd-3": lambda: CPDModel(3, n_iter=10),
    "tucker-1x1x1": lambda: TuckerModel((1, 1, 1)),
    "tucker-2x1x3": lambda: TuckerModel((2, 1, 3)),
}


@pytest.fixture(scope="module")
def brdf():
    return load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)


@pytest.fixture(scope="module")
def other():
    return load_brdf("mitsuba:principled-clearcoat-red-0.4", shape=SMALL)


@pytest.fixture(scope="module")
def pca_model():
    train = [m.load(SMALL) for m in get_corpus("mitsuba").split("train")[:4]]
    return PCAModel(40).fit(train)


@pytest.fixture(scope="module")
def compacts(brdf, pca_model):
    import warnings

    with warnings.catch_warnings():  # tensorly: ranks above a mode's size are clipped
        warnings.simplefilter("ignore", UserWarning)
        out = {name: make().compress(brdf) for name, make in MODELS.items()}
    out["pca-40"] = pca_model.compress(brdf)
    return out


@pytest.fixture
def llvm():
    return set_variant("llvm_ad_rgb")


def random_pairs(n: int, shape, seed: int = 0, margin: float = 1e-3):
    """Random upper-hemisphere pairs (wi, wo), each (m, 3) float32, whose continuous grid
    coordinates (float64) are at least ``margin`` of a bin from every bin boundary
    (float32 lookups may differ from float64 ones by one bin at boundaries), and their
    bins (i, j, k)."""
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    v = v.astype(np.float32)
    th, td, pd = dirs_to_angles(v[0].astype(np.float64), v[1].astype(np.float64))
    pd = np.where(pd < 0, pd + np.pi, pd)
    x = np.stack(grid_coords(np.maximum(th, 0), td, pd, shape))
    far = np.all(np.abs(x - np.round(x)) > margin, axis=0)
    wi, wo = v[0][far], v[1][far]
    return wi, wo, angles_to_bins(th[far], td[far], pd[far], shape)


def expected_at(compact, bins, shape) -> np.ndarray:
    """The model's dense reconstruction at the bins, 0 at bins below the horizon."""
    rec = compact.reconstruct()[bins]
    return rec * geometric_valid(shape)[bins][:, None]


# --------------------------------------------------------------------------- agreement


@pytest.mark.parametrize("name", [*MODELS, "pca-40"])
def test01_evaluator_matches_reconstruction(llvm, compacts, name):
    c = compacts[name]
    wi, wo, bins = random_pairs(20000, SMALL)
    assert len(wi) > 15000
    got = evaluator_for(c).eval_numpy(wi, wo)
    want = expected_at(c, bins, SMALL)
    assert got.shape == want.shape and np.all(np.isfinite(got)) and got.min() >= 0
    assert np.count_nonzero(want) > 0.5 * want.size
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=2e-5)


def test02_pca_is_zero_outside_its_mask(llvm, compacts, pca_model):
    c = compacts["pca-40"]
    wi, wo, bins = random_pairs(20000, SMALL, seed=3)
    got = evaluator_for(c).eval_numpy(wi, wo)
    outside = ~pca_model.mask_[bins]
    assert outside.any()
    assert np.all(got[outside] == 0)


@pytest.mark.parametrize("name", ["naive", "cpd-1", "tucker-2x1x3", "pca-40"])
def test03_below_horizon_is_zero(llvm, compacts, name):
    ev = evaluator_for(compacts[name])
    rng = np.random.default_rng(5)
    v = rng.standard_normal((2, 4000, 3)).astype(np.float32)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    got = ev.eval_numpy(v[0], v[1])
    below = (v[0][:, 2] <= 0) | (v[1][:, 2] <= 0)
    assert np.all(got[below] == 0) and np.any(got[~below] > 0)
    # pairs above the horizon whose bin is below it (grazing): 0 as in the plugins
    wi, wo, bins = random_pairs(20000, SMALL, seed=6)
    invalid = ~geometric_valid(SMALL)[bins]
    assert invalid.any()
    assert np.all(ev.eval_numpy(wi, wo)[invalid] == 0)


def test04_scalar_variant_agrees(compacts):
    wi, wo, _ = random_pairs(200, SMALL, seed=7)
    wi, wo = wi[:40], wo[:40]
    for name in ("naive", "cpd-3", "tucker-2x1x3", "pca-40"):
        set_variant("llvm_ad_rgb")
        ref = evaluator_for(compacts[name]).eval_numpy(wi, wo)
        set_variant("scalar_rgb")
        ev = evaluator_for(compacts[name])
        got = np.array([list(ev.eval(mi.Vector3f(*a), mi.Vector3f(*b)))
                        for a, b in zip(wi.tolist(), wo.tolist(), strict=True)])
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-6, err_msg=name)
    set_variant("llvm_ad_rgb")


def test05_second_material_reuses_the_kernel(llvm, brdf, other, pca_model):
    """Per-material numbers are kernel inputs: a second material (and another rank or
    coefficient count) compiles nothing new."""
    wi, wo, _ = random_pairs(4096, SMALL, seed=8)
    pairs = {"naive": (NaiveModel(n_iter=3), NaiveModel(n_iter=3)),
             "cpd": (CPDModel(1, n_iter=3), CPDModel(2, n_iter=3)),
             "tucker": (TuckerModel((1, 1, 1)), TuckerModel((2, 2, 2))),
             "pca": (pca_model, PCAModel(2).fit([brdf, other, brdf]))}
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for kind, (first, second) in pairs.items():
            hashes = []
            for model, mat in ((first, brdf), (second, other)):
                ev = evaluator_for(model.compress(mat))
                dr.kernel_history()  # clear
                ev.eval_numpy(wi, wo)
                hashes.append({k["hash"] for k in dr.kernel_history()
                               if k["type"] == dr.KernelType.JIT
                               and k["operation_count"] > 100})
            assert hashes[0] and hashes[1] <= hashes[0], f"{kind}: new kernel compiled"
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


# ------------------------------------------------------------------------- params, errors


def test06_params_hold_what_nbytes_counts(compacts, brdf):
    for name, c in {**compacts, "tabulated": TabulatedModel().compress(brdf)}.items():
        assert c.params is not None, name
        assert c.param_nbytes() == c.nbytes, name
        assert all(v.dtype == np.float32 for k, v in c.params.items()
                   if not k.startswith("shared_")), name


def test07_evaluator_errors(llvm, compacts):
    with pytest.raises(ValueError, match="no evaluator for model kind 'bogus'"):
        make_evaluator("bogus", {})
    params = dict(compacts["naive"].params)
    del params["ks"]
    with pytest.raises(ValueError, match="lacks 'ks'"):
        make_evaluator("naive", params)
    bad = {**compacts["cpd-3"].params, "b": np.zeros((3, 18, 2), np.float32)}
    with pytest.raises(ValueError, match=r"params\['b'\] must have shape \(3, n, 3\)"):
        make_evaluator("cpd", bad)
    assert set(KINDS) == {"naive", "cpd", "tucker", "pca", "nbrdf"}


# --------------------------------------------------------------------------------- speed


@pytest.fixture(scope="module")
def small_hosvd(brdf, other):
    mats = get_corpus("mitsuba").split("train")[:3]
    return hosvd_ensemble(training_tensors(mats, shape=SMALL, progress=False)[0],
                          progress=False)


@pytest.mark.parametrize("name", ["naive", "cpd-3", "tucker-2x1x3", "pca-40"])
def test08_evals_per_second_of_baselines(compacts, name):
    rate = evals_per_second(compacts[name], n=4096, repeats=2)
    assert math.isfinite(rate) and rate > 0


@pytest.mark.parametrize("decoder", ["grouped", "strict"])
def test09_evals_per_second_of_sparse_and_tabulated(brdf, small_hosvd, decoder):
    c = SparseModel(small_hosvd, 16).compress(brdf)
    assert math.isfinite(r := evals_per_second(c, n=4096, repeats=2, ensemble=small_hosvd,
                                               decoder=decoder)) and r > 0
    for model in (TabulatedModel().compress(brdf), brdf):
        rate = evals_per_second(model, n=4096, repeats=1)
        assert math.isfinite(rate) and rate > 0


def test10_evals_per_second_checks_its_arguments(compacts):
    with pytest.raises(ValueError, match="n must be a positive integer"):
        evals_per_second(compacts["naive"], n=0)
    with pytest.raises(ValueError, match="repeats must be a positive integer"):
        evals_per_second(compacts["naive"], n=16, repeats=0)
    with pytest.raises(ValueError, match="unknown decoder 'fast'"):
        evals_per_second(compacts["naive"], n=16, decoder="fast")
    with pytest.raises(TypeError, match="must be a Compact, SparseBRDF or BRDF"):
        evals_per_second("naive", n=16)
