"""Baselines: one interface, exact storage, sensible fits on small grids."""

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.baselines import (
    CPDModel,
    NaiveModel,
    PCAModel,
    SparseModel,
    TabulatedModel,
    TuckerModel,
)
from sparse_brdf.corpora import get_corpus
from sparse_brdf.io import load_brdf
from sparse_brdf.metrics import rae


@pytest.fixture(scope="module")
def brdf():
    return load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)


def test_tabulated_is_exact(brdf):
    c = TabulatedModel().fit(brdf)
    assert rae(brdf.values, c.reconstruct(), brdf.valid) == 0
    assert c.nbytes == np.prod(SMALL) * 3 * 4


def test_naive_model_storage_and_fit(brdf):
    c = NaiveModel().fit(brdf)
    assert c.nbytes == 3 * (2 + sum(SMALL)) * 4  # kd, ks folded, a, b, c per channel
    assert rae(brdf.values, c.reconstruct(), brdf.valid) < 0.05
    exact = load_brdf("mitsuba:diffuse-green", shape=SMALL)  # a constant fits exactly
    assert rae(exact.values, NaiveModel().fit(exact).reconstruct(), exact.valid) < 1e-3


@pytest.mark.parametrize("model, numbers", [
    (CPDModel(1, n_iter=5), 3 * (sum(SMALL) + 1)),
    (TuckerModel((2, 2, 2)), 3 * (8 + 2 * sum(SMALL))),
])
def test_tensor_baselines(brdf, model, numbers):
    c = model.fit(brdf)
    rec = c.reconstruct()
    assert c.nbytes == numbers * 4
    assert rec.shape == brdf.values.shape and np.all(np.isfinite(rec)) and rec.min() >= 0
    assert rae(brdf.values, rec, brdf.valid) < 0.5


def test_pca_needs_training_and_caps_components(brdf):
    with pytest.raises(RuntimeError, match="train"):
        PCAModel(5).fit(brdf)
    train = [m.load(SMALL) for m in get_corpus("mitsuba").split("train")[:8]]
    model = PCAModel(300).train(train)
    c = model.fit(brdf)
    assert c.info["n_coeffs"] <= 7 and c.nbytes == 4 * c.info["n_coeffs"]
    # a training material is reproduced by its own projection
    own = train[3]
    assert rae(own.values, model.fit(own).reconstruct(), own.valid) < 1e-3


def test_sparse_model_counts_file_bytes(brdf, small_ensemble):
    c = SparseModel(small_ensemble, 16).fit(brdf)
    assert c.nbytes == 8 * 48
    assert rae(brdf.values, c.reconstruct(), brdf.valid) < 1
