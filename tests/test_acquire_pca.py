"""The PCA baseline from samples: a training material is recovered from its samples,
more samples do not hurt an unseen one, options are checked."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.acquisition.pca import pca_from_samples
from sparse_brdf.acquisition.planning import measure_table, plan
from sparse_brdf.errors import UsageError
from sparse_brdf.metrics import cosine_weighted_snr
from sparse_brdf.sources.corpora import get_corpus


@pytest.fixture(scope="module")
def materials():
    corpus = get_corpus("mitsuba")
    return corpus.split("train")[::3], corpus.split("test")[:2]


def _snr(brdf, n, training, placement="bins", seed=0):
    samples = measure_table(brdf, *plan(n, placement, seed, shape=SMALL))
    fit = pca_from_samples(samples, [m.load(SMALL) for m in training], seed=seed)
    return cosine_weighted_snr(brdf.values, fit.reconstruct(), brdf.valid), fit


def test_a_training_material_is_recovered(materials):
    train, _ = materials
    brdf = train[1].load(SMALL)
    snr, fit = _snr(brdf, 2000, train)
    assert snr > 30.0, snr
    assert fit.reconstruct().shape == (*SMALL, 3)
    assert fit.info["n_coeffs"] >= 1 and fit.params["coef"].dtype == np.float32


def test_an_unseen_material_improves_with_samples(materials):
    train, test = materials
    brdf = test[0].load(SMALL)
    few, _ = _snr(brdf, 30, train)
    many, _ = _snr(brdf, 3000, train)
    assert many > 5.0 and many >= few - 0.5, (few, many)


def test_options_are_checked(materials):
    train, _ = materials
    brdf = train[0].load(SMALL)
    s = measure_table(brdf, *plan(3, "bins", 0, shape=SMALL))
    with pytest.raises(UsageError, match="folds"):
        pca_from_samples(s, [m.load(SMALL) for m in train])
    with pytest.raises(UsageError, match="folds"):
        pca_from_samples(s, [m.load(SMALL) for m in train], folds=1)
