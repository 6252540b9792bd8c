"""Encoding from samples: the sampling operator, exact recovery of a sparse material,
degradation with fewer samples, sample files and their errors, the commands."""

from __future__ import annotations

import numpy as np
import pytest
from test_reliability import fails, run

from conftest import SMALL, random_orthonormal
from sparse_brdf.acquisition import recovery as acquire
from sparse_brdf.acquisition.files import read_samples, write_samples
from sparse_brdf.acquisition.measurements import Samples
from sparse_brdf.acquisition.planning import measure_table, plan
from sparse_brdf.acquisition.recovery import Operator, encode_samples
from sparse_brdf.brdf import BRDF
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf
from sparse_brdf.coords import bin_angles, geometric_valid, linear_bins


@pytest.fixture(scope="module")
def ens():
    rng = np.random.default_rng(3)
    us = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    return Ensemble(*us, taus=np.array([8, 8]))


def _sparse_material(ens: Ensemble, k: int = 6, seed: int = 0) -> tuple[SparseBRDF, BRDF]:
    """A material exactly sparse in dictionary 0 (log-plus, opponent basis): a large
    constant term in the luminance channel and ``k`` small terms per channel."""
    rng = np.random.default_rng(seed)
    size = int(np.prod(SMALL))
    locs, vals = [], []
    for c in range(3):
        loc = rng.choice(np.arange(1, 400), k, replace=False)
        val = rng.uniform(0.02, 0.05, k) * np.sqrt(size) * rng.choice([-1, 1], k)
        if c == 0:
            loc, val = np.r_[0, loc], np.r_[1.0 * np.sqrt(size), val]
        locs.append(loc)
        vals.append(val.astype(np.float32))
    model = SparseBRDF("log-plus", SMALL, ens.id, [0, 0, 0], locs, vals, basis="opponent")
    return model, model.decode(ens)


def _on_bins(brdf: BRDF, n: int, seed: int) -> Samples:
    wi, wo = plan(n, "bins", seed, shape=SMALL)
    return measure_table(brdf, wi, wo)


def _coded_error(model: SparseBRDF, truth: SparseBRDF, ens: Ensemble) -> float:
    a, b = model.coded(ens), truth.coded(ens)
    return float(np.sum((a - b) ** 2) / np.sum(b ** 2))


def test_interpolated_atoms_at_the_bins_are_the_atoms(ens):
    wi, wo = plan(500, "bins", 1, shape=SMALL)
    op = Operator.of(wi, wo, SMALL)
    bins = [np.rint((1 - t) * i0 + t * i1).astype(int) % n
            for (i0, i1, t), n in zip(op.lin, SMALL, strict=True)]
    keep = bins[1] > 0  # at theta_d = 0 (wi = wo) phi_d is undefined
    for m in range(3):
        u = ens.dictionary(0)[m]
        assert np.allclose(op.rows(u, m)[keep], u[bins[m][keep]], atol=1e-4)
    # the adjoint: <A s, r> = <s, A^T r> for a random s, r
    rng = np.random.default_rng(0)
    atoms = acquire.Atoms(op, ens.dictionary(1))
    loc = rng.choice(int(np.prod(SMALL)), 50, replace=False)
    s, r = rng.standard_normal(50), rng.standard_normal(500)
    lhs = float(r @ (atoms.columns(loc, slice(None)).astype(np.float64) @ s))
    rhs = float(s @ atoms.correlate(r, slice(None))[loc])
    assert lhs == pytest.approx(rhs, rel=1e-4)


def test_phi_d_wraps_and_theta_clamps():
    th, td, pd = (a[[2, 3, -1]] for a in bin_angles(SMALL))
    from sparse_brdf.coords import angles_to_dirs
    wi, wo = angles_to_dirs(np.r_[th[0], th[0]], np.r_[td[0], td[0]],
                            np.r_[pd[2] + 0.5 * np.pi / SMALL[2], np.pi - 1e-9])
    (h0, h1, _), _, (p0, p1, pt) = linear_bins(wi, wo, SMALL)
    assert p0[0] == SMALL[2] - 1 and p1[0] == 0 and pt[0] == pytest.approx(0.5, abs=1e-6)
    assert p1[1] == 0 and pt[1] == pytest.approx(1.0, abs=1e-6)
    assert np.all(h1 <= SMALL[0] - 1)


def test_a_sparse_material_is_recovered_exactly(ens, monkeypatch):
    truth, brdf = _sparse_material(ens)
    samples = _on_bins(brdf, 3000, seed=1)
    monkeypatch.setattr(acquire, "RIDGE", 1e-9)
    model = encode_samples(samples, ens, n_coeffs=20, transform="log-plus", prior=None)
    assert model.ensemble_id == ens.id and list(model.dict_index) == [0, 0, 0]
    assert _coded_error(model, truth, ens) < 1e-6
    for c in range(3):  # the support itself
        assert set(truth.locations[c]) <= set(model.locations[c])


def test_a_level_transform_codes_samples_at_their_own_level(ens):
    """Under a level transform the model's gain is 1/L of the samples themselves (their
    median luminance), stored with it; the same samples 100 times brighter give the same
    coefficients and a 100 times smaller gain, so the same material, 100 times brighter."""
    import dataclasses

    _, brdf = _sparse_material(ens, seed=4)
    samples = _on_bins(brdf, 2000, seed=3)
    model = encode_samples(samples, ens, n_coeffs=20, transform="log-level-cosine",
                           prior=None)
    lum = samples.rgb @ np.array([0.2126, 0.7152, 0.0722])
    assert model.transform == "log-level-cosine"
    assert model.gain == pytest.approx(1 / np.median(lum), rel=1e-6)
    bright = encode_samples(dataclasses.replace(samples, rgb=samples.rgb * 100), ens,
                            n_coeffs=20, transform="log-level-cosine", prior=None)
    assert bright.gain == pytest.approx(model.gain / 100, rel=1e-6)
    for c in range(3):
        np.testing.assert_array_equal(np.sort(bright.locations[c]), np.sort(model.locations[c]))
        np.testing.assert_allclose(np.sort(bright.values[c]), np.sort(model.values[c]),
                                   rtol=1e-3, atol=1e-4 * float(np.abs(model.values[c]).max()))
    np.testing.assert_allclose(bright.decode(ens).values, 100 * model.decode(ens).values,
                               rtol=2e-3, atol=1e-3 * float(model.decode(ens).values.max()))


def test_default_ridge_stays_close_and_degrades_with_fewer_samples(ens):
    truth, brdf = _sparse_material(ens, seed=2)
    errs = []
    for n in (4000, 1500, 400, 60):
        model = encode_samples(_on_bins(brdf, n, seed=n), ens, n_coeffs=20,
                               transform="log-plus", prior=None)
        errs.append(_coded_error(model, truth, ens))
    assert errs[0] < 1e-2, errs
    for more, fewer in zip(errs, errs[1:], strict=False):
        assert fewer >= 0.8 * more, errs  # monotone within noise
    assert errs[-1] > 3 * errs[0]


def test_same_seed_same_model(ens):
    _, brdf = _sparse_material(ens, seed=4)
    s = _on_bins(brdf, 800, seed=5)
    a = encode_samples(s, ens, n_coeffs=10, seed=3, prior=None)
    b = encode_samples(s, ens, n_coeffs=10, seed=3, prior=None)
    assert all(np.array_equal(x, y) for x, y in zip(a.values, b.values, strict=True))
    assert a.transform in ("log-plus", "log-plus-cosine")
    assert int(a.n_coeffs.sum()) <= 30


@pytest.mark.parametrize("placement", ["uniform", "stratified", "bins"])
def test_placements_are_above_the_horizon_and_seeded(placement):
    wi, wo = plan(300, placement, seed=7, shape=SMALL)
    assert wi.shape == wo.shape == (300, 3)
    assert np.all(wi[:, 2] > 0) and np.all(wo[:, 2] > 0)
    assert np.allclose(np.linalg.norm(wi, axis=1), 1.0)
    assert np.array_equal(wi, plan(300, placement, seed=7, shape=SMALL)[0])
    assert not np.array_equal(wi, plan(300, placement, seed=8, shape=SMALL)[0])


def test_stratified_is_denser_near_the_specular_peak():
    from sparse_brdf.coords import dirs_to_angles
    th_u = dirs_to_angles(*plan(4000, "uniform", 0))[0]
    th_s = dirs_to_angles(*plan(4000, "stratified", 0))[0]
    assert np.mean(th_s < np.radians(5)) > 3 * np.mean(th_u < np.radians(5))


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_sample_files_round_trip(tmp_path, suffix):
    wi, wo = plan(50, "uniform", 0)
    s = Samples(wi, wo, np.abs(np.random.default_rng(0).standard_normal((50, 3))),
                weight=np.linspace(0.5, 2, 50))
    back = read_samples(write_samples(tmp_path / f"s{suffix}", s))
    for key in ("wi", "wo", "rgb", "weight"):
        assert np.allclose(getattr(back, key), getattr(s, key), rtol=1e-12), key


HEAD = "wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,r,g,b\n"
GOOD = "0,0,1,0.6,0,0.8,0.1,0.2,0.3\n"


@pytest.mark.parametrize("text, names", [
    ("", ["empty"]),
    ("a,b,c\n1,2,3\n", ["header"]),
    (HEAD, ["no samples"]),
    (HEAD + GOOD + "0,0,1,0.6,0,-0.8,0.1,0.2,0.3\n", ["row 2", "horizon"]),
    (HEAD + GOOD + "0,0,1,0.6,0,0.8,nan,0.2,0.3\n", ["row 2", "NaN"]),
    (HEAD + GOOD + "0,0,1,0.6,0,0.8,0.1,-0.2,0.3\n", ["row 2", "negative"]),
    (HEAD + "0,0,1,0.6,0,0.8,0.1,0.2\n", ["row 1", "values"]),
    (HEAD + "0,0,1,0.6,0,0.8,x,0.2,0.3\n", ["row 1", "not a number"]),
    (HEAD + "0,0,2,0.6,0,0.8,0.1,0.2,0.3\n", ["row 1", "unit"]),
])
def test_bad_sample_files_give_one_line(capsys, tmp_path, text, names):
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    fails(capsys, "encode-samples", bad, "-o", tmp_path / "out.sbrdf",
          names=[bad, *names])
    assert not (tmp_path / "out.sbrdf").exists()


def test_bad_npz_and_missing_file(capsys, tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, wi=np.zeros((3, 3)))
    fails(capsys, "encode-samples", bad, "-o", tmp_path / "o.sbrdf", names=[bad, "wo"])
    fails(capsys, "encode-samples", tmp_path / "nope.csv", "-o", tmp_path / "o.sbrdf",
          names=["nope.csv"])


def test_commands_plan_and_encode(capsys, tmp_path, ens):
    code, out, err = run(capsys, "plan-samples", 20, "-o", tmp_path / "plan.csv",
                         "--placement", "uniform")
    assert code == 0, err
    assert len(read_samples(tmp_path / "plan.csv")) == 20
    ens_path = ens.save(tmp_path / "ens.npz")
    _, brdf = _sparse_material(ens)
    write_samples(tmp_path / "s.npz", _on_bins(brdf, 600, seed=0))
    code, out, err = run(capsys, "encode-samples", tmp_path / "s.npz", "-o",
                         tmp_path / "m.sbrdf", "--ensemble", ens_path, "--coeffs", 8,
                         "--prior", "none")
    assert code == 0, err
    model = load_sbrdf(tmp_path / "m.sbrdf", ens)
    assert model.ensemble_id == ens.id and int(model.n_coeffs.sum()) <= 24
    assert geometric_valid(SMALL).shape == model.decode(ens).valid.shape


# ------------------------------------------------------------------ with an atom prior


@pytest.fixture(scope="module")
def prior_and_truth(ens):
    """An atom prior of training materials that share one support in dictionary 0 with
    different values, and an unseen material on that support."""
    from sparse_brdf.acquisition.prior import compute_prior

    truth, _ = _sparse_material(ens, seed=6)
    rng = np.random.default_rng(0)
    train = []
    for _ in range(8):
        vals = [v * rng.uniform(0.5, 1.5, v.size).astype(np.float32) for v in truth.values]
        m = SparseBRDF("log-plus", SMALL, ens.id, [0, 0, 0], truth.locations, vals,
                       basis="opponent")
        train.append(m.decode(ens))
    return compute_prior(ens, train, transforms=("log-plus",)), truth


def test_with_a_prior_a_material_on_its_atoms_is_recovered(ens, prior_and_truth):
    prior, truth = prior_and_truth
    assert prior.loc.shape[:3] == (1, 3, ens.n_dicts)
    for c in range(3):  # the pool of dictionary 0 holds the shared support
        assert set(truth.locations[c]) <= set(prior.loc[0, c, 0])
    brdf = truth.decode(ens)
    model = encode_samples(_on_bins(brdf, 1500, seed=2), ens, n_coeffs=20,
                           transform="log-plus", prior=prior, pca_fallback=False)
    assert list(model.dict_index) == [0, 0, 0]
    assert _coded_error(model, truth, ens) < 1e-3
    assert model.stats["transforms"]["log-plus"]["channels"][0]["order"] in ("prior",
                                                                             "greedy")


def test_the_prior_helps_most_with_few_samples(ens, prior_and_truth):
    prior, truth = prior_and_truth
    brdf = truth.decode(ens)
    s = _on_bins(brdf, 40, seed=3)
    with_prior = encode_samples(s, ens, n_coeffs=20, transform="log-plus", prior=prior,
                                pca_fallback=False)
    without = encode_samples(s, ens, n_coeffs=20, transform="log-plus", prior=None)
    assert _coded_error(with_prior, truth, ens) < 0.5 * _coded_error(without, truth, ens)


def test_a_prior_of_another_ensemble_is_refused(ens, prior_and_truth):
    from sparse_brdf.errors import UsageError

    prior, truth = prior_and_truth
    rng = np.random.default_rng(4)
    other = Ensemble(*[np.stack([random_orthonormal(n, rng)]) for n in SMALL],
                     taus=np.array([8]))
    s = _on_bins(truth.decode(ens), 100, seed=0)
    with pytest.raises(UsageError, match="prior"):
        encode_samples(s, other, prior=prior)


def test_the_pca_fallback_is_taken_when_pca_predicts_better(ens, prior_and_truth):
    prior, truth = prior_and_truth
    brdf = truth.decode(ens)
    # PCA trained on the material itself (and a scaled copy) predicts it best
    twin = BRDF(brdf.values * 1.5, brdf.valid, "twin")
    s = _on_bins(brdf, 40, seed=3)
    model = encode_samples(s, ens, n_coeffs=20, transform="log-plus", prior=prior,
                           training=[brdf, twin])
    assert model.stats["fallback"]["model"] == "pca"
    assert model.stats["pca_cv_cosine_error"] < model.stats["fallback"][
        "sparse_cv_cosine_error"]
    assert model.ensemble_id == ens.id and int(model.n_coeffs.sum()) <= 60  # joint budget
    plain = encode_samples(s, ens, n_coeffs=20, transform="log-plus", prior=prior,
                           pca_fallback=False)
    assert "fallback" not in plain.stats
    assert _coded_error(model, truth, ens) < _coded_error(plain, truth, ens)


class _FakeMaterial:
    """A corpus material as the defaults read one: a source path, a name and load()."""

    def __init__(self, i: int, rng: np.random.Generator):
        self.source, self.name = f"/data/m{i}.binary", f"m{i}"
        values = rng.uniform(0.01, 2.0, (*SMALL, 3)).astype(np.float32)
        self.brdf = BRDF(values, geometric_valid(SMALL), name=self.name)

    def load(self, shape=None):
        return self.brdf


def _fake_materials(n: int, seed: int) -> list[_FakeMaterial]:
    """``n`` materials of random values on the small grid."""
    rng = np.random.default_rng(seed)
    return [_FakeMaterial(i, rng) for i in range(n)]


def test_the_pca_fallback_basis_is_cached_like_the_prior(tmp_path, monkeypatch, capsys):
    """The first use fits the basis and says so; the next process reads it back from the
    cache (memory-mapped), the same arrays, without fitting again."""
    from sparse_brdf.acquisition import defaults as acquisition

    monkeypatch.setenv("SPARSE_BRDF_CACHE", str(tmp_path))
    monkeypatch.setattr(acquisition, "_PCA", {})
    mats = _fake_materials(4, seed=4)
    first = acquisition.trained_pca(mats)
    assert "fitting the PCA fallback's basis on 4 training materials" in capsys.readouterr().err
    assert len(list(tmp_path.glob("*.pca"))) == 1
    acquisition._PCA.clear()  # as a new process

    def no_fit(self, brdfs):
        raise AssertionError("fitted again")

    monkeypatch.setattr(acquisition.PCAModel, "fit", no_fit)
    again = acquisition.trained_pca(mats)
    assert capsys.readouterr().err == ""
    assert isinstance(again.basis_, np.memmap)
    for name in ("basis_", "mean_", "median_", "mask_"):
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name))
    assert again.n_coeffs == first.n_coeffs == 3


def test_missing_training_data_names_the_way_without_it(monkeypatch):
    """Without the measured training corpus the default prior cannot be built: the error
    says so and names ``--prior none``."""
    from sparse_brdf.acquisition import defaults as acquisition
    from sparse_brdf.errors import MissingDataError

    class Empty:
        def split(self, name):
            return []

    monkeypatch.setattr(acquisition, "get_corpus", lambda name: Empty())
    with pytest.raises(MissingDataError, match="--prior none"):
        acquisition.training_materials()


def test_only_the_first_encode_samples_builds_the_prior_and_the_basis(tmp_path, monkeypatch,
                                                                      capsys, ens):
    """The first ``encode-samples`` with the default prior builds the atom prior (a
    progress bar per training material, saying what it does and where it caches) and the
    PCA fallback's basis; the next run, a new process, reads both from the cache."""
    from sparse_brdf.acquisition import defaults as acquisition

    mats = _fake_materials(3, seed=5)
    monkeypatch.setenv("SPARSE_BRDF_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(acquisition, "training_materials", lambda: mats)
    monkeypatch.setattr(acquisition, "_PCA", {})
    builds = {"prior": 0, "basis": 0}

    def counted(name, fn):
        def build(*args, **kwargs):
            builds[name] += 1
            return fn(*args, **kwargs)
        return build

    monkeypatch.setattr(acquisition, "compute_prior",
                        counted("prior", acquisition.compute_prior))
    monkeypatch.setattr(acquisition.PCAModel, "fit",
                        counted("basis", acquisition.PCAModel.fit))
    ens_path = ens.save(tmp_path / "ens.npz")
    _, brdf = _sparse_material(ens)
    write_samples(tmp_path / "s.npz", _on_bins(brdf, 300, seed=0))
    args = ("encode-samples", tmp_path / "s.npz", "--ensemble", ens_path, "--coeffs", 8)

    code, _, err = run(capsys, *args, "-o", tmp_path / "a.sbrdf")
    assert code == 0, err
    assert builds == {"prior": 1, "basis": 1}
    assert "computing the atom prior" in err and str(tmp_path / "cache") in err
    assert "atom prior:   0%" in err and "0/3" in err  # a bar over the 3 materials
    assert len(list((tmp_path / "cache").glob("*.pca"))) == 1

    acquisition._PCA.clear()  # as a new process
    code, _, err = run(capsys, *args, "-o", tmp_path / "b.sbrdf")
    assert code == 0, err
    assert builds == {"prior": 1, "basis": 1}
    assert "computing" not in err and "fitting" not in err
    assert (tmp_path / "a.sbrdf").read_bytes() == (tmp_path / "b.sbrdf").read_bytes()


def test_the_prior_cache_key_names_what_the_prior_depends_on(monkeypatch, ens):
    """A change of anything the prior is computed from gives another cache entry."""
    from sparse_brdf.acquisition import defaults as acquisition

    class Material:
        def __init__(self, source):
            self.source = source

    mats = [Material("/data/a.h5"), Material("/data/b.h5")]
    path = acquisition.prior_path(ens, mats)
    assert acquisition.prior_path(ens, list(mats)) == path
    assert acquisition.prior_path(ens, mats[:1]) != path
    monkeypatch.setitem(acquisition.ENCODE_OPTIONS, "basis", "rgb")
    assert acquisition.prior_path(ens, mats) != path
    monkeypatch.undo()
    monkeypatch.setattr(acquisition, "PRIOR_VERSION", acquisition.PRIOR_VERSION + 1)
    assert acquisition.prior_path(ens, mats) != path


def test_the_lobe_transforms_are_refused_from_samples(ens, prior_and_truth):
    """A base lobe is fitted to a material's table, which samples are not: the lobe
    transforms are not among encode_samples' choices, and asking for one names them."""
    from sparse_brdf.errors import UsageError

    _, truth = prior_and_truth
    s = _on_bins(truth.decode(ens), 100, seed=0)
    for t in ("lobe", "log-lobe", "log-lobe-cosine"):
        with pytest.raises(UsageError, match=f"transform {t!r}.*log-level-cosine"):
            encode_samples(s, ens, transform=t)
