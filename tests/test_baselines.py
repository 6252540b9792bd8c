"""Baselines: one interface, exact storage, sensible fits on small grids."""

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.brdf import BRDF
from sparse_brdf.coding.fileformat import file_size, to_bytes
from sparse_brdf.compared.baselines import (
    CPDModel,
    NaiveModel,
    PCAModel,
    TabulatedModel,
    TuckerModel,
    bin_solid_angle,
)
from sparse_brdf.compared.sparse_model import SparseModel
from sparse_brdf.coords import bin_angles, geometric_valid
from sparse_brdf.errors import UsageError
from sparse_brdf.metrics import rae
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.load import load_brdf


@pytest.fixture(scope="module")
def brdf():
    return load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)


def test_tabulated_is_exact(brdf):
    c = TabulatedModel().compress(brdf)
    assert rae(brdf.values, c.reconstruct(), brdf.valid) == 0
    assert c.nbytes == np.prod(SMALL) * 3 * 4


def test_naive_model_storage_and_fit(brdf):
    c = NaiveModel().compress(brdf)
    assert c.nbytes == 3 * (2 + sum(SMALL)) * 4  # kd, ks folded, a, b, c per channel
    assert rae(brdf.values, c.reconstruct(), brdf.valid) < 0.05
    exact = load_brdf("mitsuba:diffuse-green", shape=SMALL)  # a constant fits exactly
    assert rae(exact.values, NaiveModel().compress(exact).reconstruct(), exact.valid) < 1e-3


KD = np.array([0.02, 0.05, 0.1])


def _separable(shape=SMALL):
    """kd + ks a(theta_h) b(theta_d) c(phi_d) per channel, non-negative factors: the naive
    model's own form, with a specular-like peak in a and a grazing rise in b."""
    th, td, pd = bin_angles(shape)
    factors = (0.05 + 4.0 * np.exp(-(th / 0.2) ** 2), 1.0 + 3.0 * (td / (np.pi / 2)) ** 4,
               1.0 + 0.3 * np.cos(pd))
    values = KD + np.array([1.0, 0.5, 0.25]) * np.einsum("i,j,k->ijk", *factors)[..., None]
    return BRDF(values.astype(np.float32), geometric_valid(shape), "separable"), factors


def _per_channel(c):
    """(kd, a, b, c) per channel from a naive Compact's params (ks folded into a)."""
    p = {k: v.astype(np.float64) for k, v in c.params.items()}
    return [(p["kd"][ch], p["ks"][ch] * p["a"][ch], p["b"][ch], p["c"][ch]) for ch in range(3)]


def test_naive_recovers_a_separable_material():
    brdf, factors = _separable()
    c = NaiveModel().compress(brdf)
    assert rae(brdf.values, c.reconstruct(), brdf.valid) < 1e-6
    np.testing.assert_allclose(c.params["kd"], KD, atol=1e-5)
    for key, f in zip("abc", factors, strict=True):
        g = c.params[key].astype(np.float64)  # unit-norm rows, one per channel
        np.testing.assert_allclose(g @ f / np.linalg.norm(f), 1.0, atol=1e-6, err_msg=key)


def test_naive_ignores_invalid_bins():
    """Unmeasured bins (a third of the grid, holding garbage) do not move the fit: the
    rest determines the separable material everywhere."""
    brdf, _ = _separable()
    valid = brdf.valid & (np.random.default_rng(0).random(SMALL) > 0.3)
    values = np.where(valid[..., None], brdf.values, np.float32(1e3))
    c = NaiveModel().compress(BRDF(values, valid, "holes"))
    assert rae(brdf.values, c.reconstruct(), brdf.valid) < 1e-5
    assert np.all(NaiveModel().weights(BRDF(values, valid, "holes"))[~valid] == 0)


def test_naive_factors_are_non_negative():
    """A dip below the diffuse level (two theta_h rows of zeros) pulls an unconstrained
    fit's a[i] below zero; the fit keeps kd, ks, a, b, c >= 0 (the constraint is met
    with equality there), so the stored model never evaluates negative."""
    brdf, _ = _separable()
    values = brdf.values.copy()
    values[3:5] = 0.0
    c = NaiveModel().compress(BRDF(values, brdf.valid, "dip"))
    for key in ("kd", "ks", "a", "b", "c"):
        assert c.params[key].min() >= 0, key
    assert np.all(c.params["a"][:, 3:5] == 0)
    assert c.reconstruct().min() >= 0


def test_naive_fit_minimises_its_objective(brdf):
    """No small change of any stored number (kd or one entry of a, b, c, by 1 %) lowers
    the documented weighted objective: the fit is a minimum of it."""
    model = NaiveModel()
    per = _per_channel(model.compress(brdf))
    e0 = model.objective(brdf, per)
    rng = np.random.default_rng(1)
    for _ in range(40):
        ch, which, sign = rng.integers(3), rng.integers(4), rng.choice([-1.0, 1.0])
        kd, *f = (np.copy(x) for x in per[ch])
        if which == 3:
            kd = kd * (1 + 0.01 * sign) + 1e-6
        else:
            f[which][rng.integers(len(f[which]))] *= 1 + 0.01 * sign
        e = model.objective(brdf, [*per[:ch], (kd, *f), *per[ch + 1:]])
        assert e[ch] >= e0[ch] * (1 - 1e-9)


def test_naive_weights_and_solid_angle():
    om = bin_solid_angle(SMALL)
    assert om.shape == SMALL and om.min() > 0
    assert np.isclose(om.sum(), 8 * np.pi**2)  # 4 cos td sin th sin td over the grid's range
    assert om[0, 9, 0] < om[1, 9, 0] < om[9, 9, 0]  # square-root spacing: small first bins
    brdf, _ = _separable()
    w = NaiveModel(solid_angle_power=1.0, cos_power=0.0).weights(brdf)
    np.testing.assert_allclose(w[..., 1], np.where(brdf.valid, om, 0.0))
    with pytest.raises(ValueError, match="q must be in"):
        NaiveModel(q=1.5)


@pytest.mark.parametrize("model, numbers", [
    (CPDModel(1, n_iter=5), 3 * (sum(SMALL) + 1)),
    (TuckerModel((2, 2, 2)), 3 * (8 + 2 * sum(SMALL))),
])
def test_tensor_baselines(brdf, model, numbers):
    c = model.compress(brdf)
    rec = c.reconstruct()
    assert c.nbytes == numbers * 4
    assert rec.shape == brdf.values.shape and np.all(np.isfinite(rec)) and rec.min() >= 0
    assert rae(brdf.values, rec, brdf.valid) < 0.5


def test_pca_needs_training_and_caps_components(brdf):
    with pytest.raises(UsageError, match="fit"):
        PCAModel(5).compress(brdf)
    train = [m.load(SMALL) for m in get_corpus("mitsuba").split("train")[:8]]
    model = PCAModel(300).fit(train)
    c = model.compress(brdf)
    assert c.info["n_coeffs"] <= 7 and c.nbytes == 4 * c.info["n_coeffs"]
    # a training material is reproduced by its own projection
    own = train[3]
    assert rae(own.values, model.compress(own).reconstruct(), own.valid) < 1e-3


def test_sparse_model_counts_file_bytes(brdf, small_ensemble):
    c = SparseModel(small_ensemble, 16).compress(brdf)  # version 2: its file, header included
    assert c.nbytes == len(to_bytes(c.info["model"])) < file_size(48, len(brdf.name))
    assert rae(brdf.values, c.reconstruct(), brdf.valid) < 1
    v1 = SparseModel(small_ensemble, 16, version=1).compress(brdf)
    assert v1.nbytes == file_size(48, len(brdf.name)) and v1.model == "sparse-16-version=1"
