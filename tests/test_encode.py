"""Encoding, model selection, coefficient files and decoding: the paper's encoder
(``PAPER_OPTIONS``); tests/test_encode_options.py covers the options beyond it."""

import functools

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf.brdf import BRDF
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.encode import encode as _encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import file_size, load_sbrdf, save_sbrdf
from sparse_brdf.coding.projection import project_all, project_pruned, select
from sparse_brdf.coding.spec import DEFAULT_N_COEFFS, PAPER_OPTIONS
from sparse_brdf.coding.tensor import reconstruct, sparse_to_dense
from sparse_brdf.coords import angles_to_dirs, geometric_valid, grid_angles
from sparse_brdf.errors import BRDFFileError, EnsembleMismatchError
from sparse_brdf.metrics import cosine_weighted_snr
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.transforms import forward, inverse

pytestmark = pytest.mark.numerics

encode = functools.partial(_encode, **PAPER_OPTIONS)


def _random_ensemble(k, seed=0):
    rng = np.random.default_rng(seed)
    us = [np.stack([random_orthonormal(n, rng) for _ in range(k)]) for n in SMALL]
    return Ensemble(*us, taus=np.zeros(k))


def test_exactly_sparse_tensor_is_recovered_and_its_dictionary_selected():
    ens = _random_ensemble(4)
    rng = np.random.default_rng(1)
    k_true = 2
    size = int(np.prod(SMALL))
    # atom (0, 0, 0) is constant and positive (see random_orthonormal): a large weight on
    # it keeps the tensor positive, so that it is a valid log-plus BRDF
    locs = [np.concatenate([[0], np.sort(rng.choice(np.arange(1, size), 9, replace=False))])
            for _ in range(3)]
    vals = [np.concatenate([[np.sqrt(size)], rng.uniform(0.5, 3, 9)]).astype(np.float32)
            for _ in range(3)]
    y = np.stack([reconstruct(sparse_to_dense(a, v, SMALL), *ens.dictionary(k_true))
                  for a, v in zip(locs, vals, strict=True)])
    rho = inverse(y, "log-plus")
    brdf = BRDF(np.moveaxis(rho, 0, -1), np.ones(SMALL, bool), "sparse-by-construction")
    m = encode(brdf, ens, n_coeffs=50, max_error=1e-6, transform="log-plus")
    assert m.dict_index.tolist() == [k_true] * 3
    assert m.n_coeffs.tolist() == [10, 10, 10]
    for c in range(3):
        order = np.argsort(m.locations[c])
        np.testing.assert_array_equal(m.locations[c][order], locs[c])
        np.testing.assert_allclose(m.values[c][order], vals[c], rtol=1e-4)
    g = geometric_valid(SMALL)  # decoding marks below-horizon bins invalid
    np.testing.assert_allclose(m.decode(ens).values[g], brdf.values[g], rtol=1e-4, atol=1e-5)


def test_more_coefficients_lower_error(small_ensemble):
    b = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    errs = [encode(b, small_ensemble, n).stats["transforms"]["log-plus"]["relative_residual"][0]
            for n in (8, 64, 512)]
    assert errs[0] > errs[1] > errs[2]


def test_transform_chosen_by_gamma_mse(small_ensemble):
    b = load_brdf("mitsuba:cu-ggx-0.12", shape=SMALL)
    m = encode(b, small_ensemble, 32)
    st = m.stats["transforms"]
    assert m.transform == min(st, key=lambda t: st[t]["gamma_mse"])
    forced = encode(b, small_ensemble, 32, transform="log-plus")
    assert forced.transform == "log-plus" and set(forced.stats["transforms"]) == {"log-plus"}


def test_max_error_stops_early(small_ensemble):
    b = load_brdf("mitsuba:diffuse-white", shape=SMALL)
    m = encode(b, small_ensemble, 500, max_error=1e-2)
    assert np.all(m.n_coeffs < 500)
    assert max(m.stats["transforms"][m.transform]["relative_residual"]) <= 1e-2


def test_pointwise_eval_matches_full_decode(small_ensemble):
    b = load_brdf("mitsuba:principled-clearcoat-red-0.4", shape=SMALL)
    m = encode(b, small_ensemble, 64)
    full = m.decode(small_ensemble)
    th, td, pd = grid_angles(SMALL)
    # directions inside each bin, away from its edges
    wi, wo = angles_to_dirs(th + 1e-4, td + 1e-4, pd + 1e-4)
    keep = geometric_valid(SMALL) & (wi[..., 2] > 1e-3) & (wo[..., 2] > 1e-3)
    v = m.eval(small_ensemble, wi[keep], wo[keep])
    np.testing.assert_allclose(v, full.values[keep], rtol=1e-4, atol=1e-5)
    below = m.eval(small_ensemble, np.array([[0, 0, -1.0]]), np.array([[0, 0, 1.0]]))
    assert np.all(below == 0)


def test_file_round_trip_and_size(small_ensemble, tmp_path):
    b = load_brdf("mitsuba:au-ggx-0.25", shape=SMALL)
    m = encode(b, small_ensemble, 40)
    p = save_sbrdf(tmp_path / "au.sbrdf", m, version=1)  # exact values (v2: test_sbrdf_v2)
    assert p.stat().st_size == file_size(120, len(m.name)) == 57 + len(m.name) + 8 * 120
    r = load_sbrdf(p, small_ensemble)
    assert (r.transform, r.shape, r.ensemble_id, r.name) == (m.transform, m.shape,
                                                            m.ensemble_id, m.name)
    for c in range(3):
        np.testing.assert_array_equal(r.locations[c], m.locations[c])
        np.testing.assert_array_equal(r.values[c], m.values[c])
    np.testing.assert_array_equal(r.decode(small_ensemble).values,
                                  m.decode(small_ensemble).values)


@pytest.mark.parametrize("mangle, match", [
    (lambda d: d[:-10], "truncated"),
    (lambda d: d + b"xx", "trailing"),
    (lambda d: d[:20], "too short"),
    (lambda d: b"NOTSBRDF" + d[8:], "magic"),
    (lambda d: d[:70] + bytes([d[70] ^ 0xFF]) + d[71:], "checksum"),
    (lambda d: d[:8] + b"\x09\x00" + d[10:], "version 9"),
])
def test_corrupt_files_give_clear_errors(small_ensemble, tmp_path, mangle, match):
    m = encode(load_brdf("mitsuba:diffuse-red", shape=SMALL), small_ensemble, 16)
    good = save_sbrdf(tmp_path / "good.sbrdf", m).read_bytes()
    bad = tmp_path / "bad.sbrdf"
    bad.write_bytes(mangle(good))
    with pytest.raises(BRDFFileError, match=match) as e:
        load_sbrdf(bad)
    assert "bad.sbrdf" in str(e.value)


def test_wrong_ensemble_is_refused(small_ensemble, tmp_path):
    m = encode(load_brdf("mitsuba:diffuse-red", shape=SMALL), small_ensemble, 16)
    p = save_sbrdf(tmp_path / "m.sbrdf", m)
    other = _random_ensemble(2)
    with pytest.raises(EnsembleMismatchError, match="m.sbrdf.*encoded with ensemble"):
        load_sbrdf(p, other)
    with pytest.raises(EnsembleMismatchError):
        m.decode(other)


def test_grid_mismatch_is_refused(small_ensemble):
    b = load_brdf("mitsuba:diffuse-red", shape=(9, 9, 18))
    with pytest.raises(ValueError, match="does not match"):
        encode(b, small_ensemble)


def test_sparse_model_validates():
    with pytest.raises(ValueError, match="outside"):
        SparseBRDF("log-plus", SMALL, "0" * 32, [0, 0, 0], [[10**9], [], []], [[1.0], [], []])


def test_unmeasured_bins_are_filled_not_fitted_as_zeros(small_ensemble):
    clean = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    keep = np.random.default_rng(0).random(SMALL) >= 0.2
    holes = BRDF(clean.values, clean.valid & keep, "holes")
    snr = {}
    for n in (0, 3):
        rec = encode(holes, small_ensemble, 64, fill_iters=n).decode(
            small_ensemble, valid=clean.valid).values
        snr[n] = cosine_weighted_snr(clean.values, rec, clean.valid)
    assert snr[3] > snr[0] + 3


def _same_selection(a, b):
    assert a.dict_index.tolist() == b.dict_index.tolist()
    for c in range(3):  # the same coefficients (order among near-equal ones may differ)
        oa, ob = np.argsort(a.locations[c]), np.argsort(b.locations[c])
        np.testing.assert_array_equal(a.locations[c][oa], b.locations[c][ob])
        np.testing.assert_allclose(a.values[c][oa], b.values[c][ob], rtol=1e-5, atol=1e-6)


def test_pruned_projection_selects_what_the_full_search_selects(small_ensemble):
    pruned = 0
    for name in ("plastic-red-ggx-0.3", "cu-ggx-0.12", "diffuse-white"):
        b = load_brdf(f"mitsuba:{name}", shape=SMALL)
        for t in ("log-plus", "log-plus-cosine"):
            y = forward(b.channel_first(), t, b.valid)
            for n, max_error in ((8, None), (64, None), (300, None), (64, 1e-3)):
                p = project_pruned(b, small_ensemble, t, n, max_error, y=y)
                full = select(project_all(b, small_ensemble, t, n, y=y), n, max_error)
                _same_selection(select(p, n, max_error), full)
                pruned += int(np.isinf(p.residual[:, :, 0]).sum())
                with pytest.raises(ValueError, match="pruned"):
                    select(p, n + 1, max_error)
    assert pruned > 0  # the bounds did drop dictionaries


def test_pruned_projection_on_measured_data(shared_data):
    data = shared_data
    b = load_brdf(str(data / "nbrdf" / "merl" / "green-plastic.h5"))
    ens = Ensemble.default()
    for t, n in (("log-plus", 1024), ("log-plus-cosine", DEFAULT_N_COEFFS)):
        p = project_pruned(b, ens, t, n)
        _same_selection(select(p, n), select(project_all(b, ens, t, n), n))
