"""Checks written against mutation testing (docs/testing.md, "Mutation testing"): the
results of the transforms, the metrics, the sparse model and the .sbrdf file, each
against a formula worked out here or a case given by hand."""

from __future__ import annotations

import dataclasses
import math
import struct
import warnings
import zlib

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf.coding import fileformat as ff
from sparse_brdf.coding.coefficients import T_MAX, SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coords import cosine_product, dirs_to_bins, geometric_valid
from sparse_brdf.errors import (
    BRDFFileError,
    EnsembleMismatchError,
    ImageFileError,
    InvalidBRDFError,
    UsageError,
)
from sparse_brdf.metrics import (
    SNRForms,
    cosine_weighted_snr,
    flip_exposures,
    gamma_mse,
    hdr_flip,
    make_render_proxy,
    mse,
    rae,
    render_proxy_error,
    render_snr,
    snr_forms,
)
from sparse_brdf.transforms import (
    LEVEL_KNEE,
    LOBE_KNEE,
    RELATIVE_SCALE,
    RHO_MAX,
    TRANSFORMS,
    colour_matrix,
    cosine_weight,
    forward,
    from_basis,
    has_floor,
    has_lobe,
    inverse,
    inverse_at_bins,
    per_material,
    scale,
    to_basis,
    uses_cosine,
    weight,
)

TINY = (6, 5, 10)


@pytest.fixture(scope="module")
def ens():
    rng = np.random.default_rng(3)
    us = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    return Ensemble(*us, taus=np.zeros(2))


def _model(ens_id: str, basis: str = "rgb", transform: str = "log-plus-cosine",
           counts=(40, 13, 0), seed: int = 5) -> SparseBRDF:
    rng = np.random.default_rng(seed)
    size = math.prod(SMALL)
    locs = [rng.choice(size, n, replace=False) for n in counts]
    vals = [rng.normal(0, 0.3, n).astype(np.float32) for n in counts]
    vals[0][0] = 4.0  # a bright channel
    return SparseBRDF(transform, SMALL, ens_id, [1, 0, 1], locs, vals, name="m",
                      basis=basis)


# ---------------------------------------------------------------------- transforms
def test_transform_names_weights_and_scales():
    assert [uses_cosine(n) for n in TRANSFORMS] == [False, True] * 5
    assert [scale(n) for n in TRANSFORMS] == [1.0, 1.0, RELATIVE_SCALE, RELATIVE_SCALE,
                                              LEVEL_KNEE, LEVEL_KNEE] + [LOBE_KNEE] * 4
    assert [per_material(n) for n in TRANSFORMS] == [False] * 4 + [True] * 6
    assert [has_lobe(n) for n in TRANSFORMS] == [False] * 6 + [True] * 4
    assert [has_floor(n) for n in TRANSFORMS] == [False] * 8 + [True] * 2
    assert weight("log-level", TINY, 0.5) == LEVEL_KNEE * 0.5
    assert weight("log-plus", TINY) == 1.0
    assert weight("log-relative", TINY) == RELATIVE_SCALE
    c = weight("log-plus-cosine", TINY)
    assert c is cosine_weight(TINY) and not c.flags.writeable
    np.testing.assert_allclose(c, np.clip(cosine_product(TINY), 0.01, 1.0), rtol=1e-6)
    cs = weight("log-relative-cosine", TINY)
    assert cs.dtype == np.float32 and cs.shape == TINY and not cs.flags.writeable
    np.testing.assert_allclose(cs, c * RELATIVE_SCALE, rtol=1e-6)
    for f in (uses_cosine, scale):
        with pytest.raises(UsageError, match="unknown transform 'log'"):
            f("log")


def test_inverse_clamps_overflow_to_the_float32_maximum_without_a_warning():
    t = np.array([[[[100.0, -3.0, 0.0]]]], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rho = inverse(t, "log-plus")
    assert rho.dtype == np.float32
    assert rho.ravel().tolist() == [RHO_MAX, 0.0, 0.0]
    assert RHO_MAX == float(np.finfo(np.float32).max)


@pytest.mark.parametrize("name", TRANSFORMS)
def test_inverse_at_bins_is_the_grid_inverse_at_those_bins(name):
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 3, (3, *TINY)).astype(np.float32)
    lobe = (0.125, 0.5, 0.25, 0.0, 2.0, 0.0, 1.0) if has_lobe(name) else None
    full = inverse(t, name, lobe=lobe)
    bins = tuple(rng.integers(0, n, 7) for n in TINY)
    got = inverse_at_bins(t[(slice(None), *bins)], name, bins, TINY, lobe=lobe)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, full[(slice(None), *bins)], rtol=1e-6)
    if has_lobe(name):  # the lobe's x, then the same inverse (test_transforms_metrics)
        return
    np.testing.assert_allclose(got, np.expm1(t[(slice(None), *bins)])
                               / (np.asarray(weight(name, TINY))[bins]
                                  if uses_cosine(name) else weight(name, TINY)), rtol=1e-5)


def test_colour_matrices():
    assert np.array_equal(colour_matrix("rgb"), np.eye(3))
    m = colour_matrix("opponent")
    want = np.array([[1, 1, 1], [1, -1, 0], [1, 1, -2]]) / np.sqrt([[3.0], [2.0], [6.0]])
    np.testing.assert_allclose(m, want, rtol=1e-15)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-15)
    m[:] = 0  # a copy: the module's matrix is untouched
    np.testing.assert_allclose(colour_matrix("opponent"), want, rtol=1e-15)
    with pytest.raises(UsageError, match="unknown colour basis 'xyz'"):
        colour_matrix("xyz")


def test_to_and_from_basis():
    rng = np.random.default_rng(2)
    t = rng.uniform(0, 2, (3, 4, 5)).astype(np.float64)
    for basis in ("rgb", "opponent"):
        c = to_basis(t, basis)
        assert c.dtype == np.float32 and c.shape == t.shape
        np.testing.assert_allclose(c, np.tensordot(colour_matrix(basis), t, axes=1),
                                   rtol=1e-5, atol=1e-6)
        back = from_basis(c, basis)
        assert back.dtype == np.float32
        np.testing.assert_allclose(back, t, rtol=1e-5, atol=1e-6)
    # the opponent basis puts a grey's energy into the first channel only
    grey = np.ones((3, 2))
    np.testing.assert_allclose(to_basis(grey, "opponent"), [[np.sqrt(3)] * 2, [0, 0], [0, 0]],
                               atol=1e-6)
    np.testing.assert_allclose(from_basis(np.array([[np.sqrt(3)], [0], [0]]), "opponent"),
                               np.ones((3, 1)), rtol=1e-6)


# ---------------------------------------------------------------------- metrics
def test_render_snr_with_a_mask():
    ref = np.ones((4, 5, 3))
    img = ref.copy()
    img[0] += 0.1  # the first row: 20 dB there, inf elsewhere
    mask = np.zeros((4, 5), bool)
    mask[0] = True
    assert render_snr(ref, img, mask) == pytest.approx(20.0)
    assert render_snr(ref, img, ~mask) == float("inf")
    assert render_snr(ref, img) == pytest.approx(20.0 + 10 * np.log10(4))
    with pytest.raises(ImageFileError, match="mask shape"):
        render_snr(ref, img, mask[:3])
    with pytest.raises(ImageFileError, match="selects no pixel"):
        render_snr(ref, img, np.zeros((4, 5), bool))
    with pytest.raises(ImageFileError, match="image image holds 1 NaN/inf"):
        render_snr(ref, _one_inf(ref))


def _one_inf(a: np.ndarray) -> np.ndarray:
    b = a.copy()
    b[1, 1, 1] = np.inf
    return b


def test_snr_forms():
    ref = np.ones((4, 5, 3))
    img = ref + 0.1
    img[1:] = ref[1:] + 0.01
    mask = np.zeros((4, 5), bool)
    mask[1:] = True
    f = snr_forms(ref, img, mask)
    assert isinstance(f, SNRForms)
    assert f.whole == render_snr(ref, img) and f.object == render_snr(ref, img, mask)
    assert f.object == pytest.approx(40.0)
    assert f.as_dict() == {"snr_whole": f.whole, "snr_object": f.object}
    assert str(SNRForms(12.345, 6.789)) == "whole-image 12.35 dB, object-only 6.79 dB"


def _tone(x):
    """FLIP's ACES fit with its 0.6 pre-exposure (Narkowicz 2016)."""
    x = 0.6 * x
    return (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)


def test_flip_exposures_map_the_brightest_and_the_median_to_0_85():
    y, x = np.mgrid[0:8, 0:10]
    ref = np.repeat(((x + 1.0) * (y + 1.0))[..., None], 3, axis=2)
    mask = np.zeros((8, 10), bool)
    mask[2:5, 3:6] = True
    e = flip_exposures(ref, mask)
    lum = ref[..., 0]  # grey: luminance = each channel (weights sum to 1)
    assert _tone(2.0 ** e["startExposure"] * lum.max()) == pytest.approx(0.85, abs=1e-9)
    assert _tone(2.0 ** e["stopExposure"] * np.median(lum[mask])) == pytest.approx(0.85,
                                                                                abs=1e-9)
    assert e["numExposures"] == math.ceil(e["stopExposure"] - e["startExposure"]) > 2
    # a black majority in the mask: the median of the lit pixels
    dark = ref.copy()
    dark[2:4, 3:6] = 0.0
    lit = lum[4, 3:6]
    e2 = flip_exposures(dark, mask)
    assert _tone(2.0 ** e2["stopExposure"] * np.median(lit)) == pytest.approx(0.85, abs=1e-9)
    # an all-black object: the exposure range collapses to the brightest pixel's, 2 steps
    black = ref.copy()
    black[mask] = 0.0
    e3 = flip_exposures(black, mask)
    assert e3["stopExposure"] == e3["startExposure"] and e3["numExposures"] == 2
    # luminance weights Rec. 709
    rgb = np.zeros((1, 3, 3))
    rgb[0, 0, 0], rgb[0, 1, 1], rgb[0, 2, 2] = 1.0, 1.0, 1.0
    e4 = flip_exposures(rgb, np.ones((1, 3), bool))
    assert _tone(2.0 ** e4["startExposure"] * 0.7152) == pytest.approx(0.85, abs=1e-9)
    assert _tone(2.0 ** e4["stopExposure"] * 0.2126) == pytest.approx(0.85, abs=1e-9)


def _flip_image() -> np.ndarray:
    y, x = np.mgrid[0:24, 0:32].astype(np.float32)
    spot = 10.0 * np.exp(-((x - 20) ** 2 + (y - 10) ** 2) / 20.0)
    return (spot + 0.05 + 0.3 * x / 32)[..., None] * np.array([0.9, 0.7, 0.8], np.float32)


def test_hdr_flip_checks_and_options():
    ref = _flip_image()
    img = ref * 1.2
    mask = np.zeros(ref.shape[:2], bool)
    mask[5:15, 10:30] = True
    res = hdr_flip(ref, img, mask)
    assert res.mean == pytest.approx(float(np.mean(res.map[mask], dtype=np.float64)))
    assert res.mean != pytest.approx(float(res.map.mean()))
    assert hdr_flip(ref, img, ppd=20.0).mean != pytest.approx(hdr_flip(ref, img).mean)
    grey = ref[..., 1]  # (H, W): a mono image
    np.testing.assert_array_equal(hdr_flip(grey, grey * 1.2).map,
                                  hdr_flip(np.repeat(grey[..., None], 3, 2),
                                           np.repeat(grey[..., None] * 1.2, 3, 2)).map)
    for bad, match in [(ref[..., :2], r"\(H, W, 3\)"), (ref[None], r"\(H, W, 3\)")]:
        with pytest.raises(ImageFileError, match=match):
            hdr_flip(bad, bad)
    with pytest.raises(ImageFileError, match="image image holds"):
        hdr_flip(ref, np.where(mask[..., None], np.nan, img))
    with pytest.raises(ImageFileError, match="image image holds negative"):
        hdr_flip(ref, -img)
    with pytest.raises(ImageFileError, match="mask shape"):
        hdr_flip(ref, img, mask[:5])
    with pytest.raises(ImageFileError, match="selects no pixel"):
        hdr_flip(ref, img, np.zeros_like(mask))


def test_rae_mse_and_gamma_mse_values():
    ref = np.array([[1.0, 2.0], [3.0, 4.0]])
    rec = np.array([[1.5, 2.0], [2.0, 4.0]])
    assert rae(ref, rec) == pytest.approx(1.5 / 10)
    assert mse(ref, rec) == pytest.approx((0.25 + 1.0) / 4)
    assert rae(np.zeros(3), np.zeros(3)) == 0.0
    assert rae(np.zeros(3), np.array([0, -1.0, 0])) == 1.0
    assert rae(-ref, -rec) == pytest.approx(0.15)  # absolute values in the denominator
    valid = np.array([True, False])  # rows: broadcast over the last axis
    assert rae(ref, rec, valid) == pytest.approx(0.5 / 3)
    assert mse(ref, rec, valid) == pytest.approx(0.25 / 2)
    assert math.isnan(mse(ref, rec, np.zeros(2, bool)))
    assert math.isnan(gamma_mse(ref, rec, np.zeros(2, bool)))
    sq = np.array([1.0, 4.0, -9.0])
    assert gamma_mse(sq, np.array([4.0, 4.0, 9.0])) == pytest.approx((1 + 0 + 9) / 3)
    cube = np.array([1.0, 8.0, 27.0])
    assert gamma_mse(cube, np.array([8.0, 8.0, -1.0]), gamma=3.0) == pytest.approx(
        (1 + 0 + 9) / 3)
    assert gamma_mse(cube, cube * 4, gamma=1.0) == pytest.approx(
        float(np.mean((3 * cube) ** 2)))
    with pytest.raises(ValueError, match="shapes differ"):
        rae(ref, rec[:1])
    # float32 inputs are summed in float64
    big = np.random.default_rng(11).uniform(0, 1, 10**6).astype(np.float32)
    d = big - np.float32(0.1)  # float32 differences and squares, a float64 sum
    want = np.sum((d * d).astype(np.float64)) / d.size
    assert mse(big, np.full_like(big, 0.1)) == pytest.approx(want, rel=1e-10)


def test_masked_metrics_with_a_full_valid_mask():
    ref = np.arange(24, dtype=np.float64).reshape(2, 3, 4) + 1
    rec = ref * 1.1
    valid = np.ones((2, 3, 4), bool)
    valid[0, 0, 0] = False  # same ndim as the arrays: no channel axis to broadcast over
    assert rae(ref, rec, valid) == pytest.approx(0.1)
    assert mse(ref, rec, valid) == pytest.approx(float(np.mean((0.1 * ref.ravel()[1:]) ** 2)))


def test_cosine_weighted_snr_weights_by_the_cosines():
    shape = TINY
    valid = geometric_valid(shape)
    c = np.clip(cosine_product(shape), 0, None)
    rng = np.random.default_rng(4)
    ref = rng.uniform(0.5, 2, (*shape, 3))
    rec = ref + rng.normal(0, 0.1, ref.shape)
    s = np.sum((ref * c[..., None])[valid] ** 2)
    n = np.sum(((ref - rec) * c[..., None])[valid] ** 2)
    assert cosine_weighted_snr(ref, rec, valid) == pytest.approx(10 * np.log10(s / n))


def test_render_proxy_cells_and_error():
    shape = (12, 4, 8)
    k = make_render_proxy(shape)
    th = np.degrees(((np.arange(12) + 0.5) / 12) ** 2 * np.pi / 2)
    cell = np.floor(th / 2.0)
    want = [0] + [i for i in range(1, 12) if cell[i] != cell[i - 1]]
    assert k["starts"].tolist() == want
    assert all(not a.flags.writeable for a in k.values())
    assert make_render_proxy(shape) is k
    k10 = make_render_proxy(shape, 10.0)
    assert k10["starts"].tolist() == [0] + [i for i in range(1, 12)
                                            if th[i] // 10 != th[i - 1] // 10]
    rng = np.random.default_rng(6)
    ref = rng.uniform(0, 2, (*shape, 3)).astype(np.float32)
    rec = ref + rng.normal(0, 0.1, ref.shape).astype(np.float32)
    d = np.add.reduceat((ref - rec).astype(np.float64) * k["omega"][..., None], k["starts"],
                        axis=0) / k["cell_omega"][..., None]
    want_err = float(np.sum(d * d * k["cell_point"][..., None]))
    assert render_proxy_error(ref, rec) == pytest.approx(want_err, rel=1e-5)
    first = render_proxy_error(np.moveaxis(ref, -1, 0), np.moveaxis(rec, -1, 0))
    assert first == pytest.approx(want_err, rel=1e-5)
    valid = np.ones(shape, bool)
    valid[:, :, :4] = False
    zeroed = np.where(valid[..., None], rec, ref)
    got = render_proxy_error(ref, rec, valid=valid)
    assert got == pytest.approx(render_proxy_error(ref, zeroed), rel=1e-5) and got > 0
    assert render_proxy_error(np.moveaxis(ref, -1, 0), np.moveaxis(rec, -1, 0),
                              valid=valid) == pytest.approx(got, rel=1e-5)
    assert render_proxy_error(ref, rec, kernel=k) == render_proxy_error(ref, rec)
    with pytest.raises(ValueError, match="4-D"):
        render_proxy_error(ref, rec[:-1])
    with pytest.raises(ValueError, match="4-D"):
        render_proxy_error(ref[..., 0], rec[..., 0])
    with pytest.raises(ValueError, match="does not match"):
        render_proxy_error(ref, rec, kernel=make_render_proxy((12, 4, 9)))


# ---------------------------------------------------------------------- the sparse model
def test_model_is_checked_on_construction():
    size = math.prod(SMALL)
    ok = dict(transform="log-plus", shape=SMALL, ensemble_id="ab" * 16, dict_index=[0, 0, 0])
    m = SparseBRDF(**ok, locations=[[0, size - 1], [], []], values=[[1.0, 2.0], [], []])
    assert m.shape == SMALL and all(type(n) is int for n in m.shape)
    assert m.dict_index.dtype == np.int64 and m.n_coeffs.tolist() == [2, 0, 0]
    assert [a.dtype for a in m.locations] == [np.int64] * 3
    assert [v.dtype for v in m.values] == [np.float32] * 3
    cases = [
        ([[0, 1], [], []], [[1.0], [], []], "channel 0 has 2 locations and 1 values"),
        ([[], [size], []], [[], [1.0], []], "channel 1 has coefficient locations outside"),
        ([[], [], [-1]], [[], [], [1.0]], "channel 2 has coefficient locations outside"),
        ([[3], [], []], [[np.nan], [], []], "channel 0 has NaN/inf"),
        ([[], [3], []], [[], [-np.inf], []], "channel 1 has NaN/inf"),
        ([[], [], [7, 2, 7]], [[], [], [1.0, 2.0, 3.0]],
         "channel 2 repeats a coefficient location"),
    ]
    for locs, vals, match in cases:
        with pytest.raises(InvalidBRDFError, match=match):
            SparseBRDF(**ok, locations=locs, values=vals)
    # the largest sum of squares a finite BRDF's channel can have: 3 n T_MAX^2
    edge = np.float32(np.sqrt(3.0 * size) * T_MAX)
    fits = float(np.float64(edge) ** 2) <= 3.0 * size * T_MAX**2
    big = np.nextafter(edge, np.float32(np.inf)) if fits else edge
    small = edge if fits else np.nextafter(edge, np.float32(0))
    SparseBRDF(**ok, locations=[[5], [], []], values=[[small], [], []])
    with pytest.raises(InvalidBRDFError, match=r"channel 0's coefficients \(largest \|s\| "):
        SparseBRDF(**ok, locations=[[5], [], []], values=[[big], [], []])
    with pytest.raises(UsageError, match="colour basis"):
        SparseBRDF(**ok, locations=[[], [], []], values=[[], [], []], basis="xyz")
    # the limit is checked in float64: on the (13, 13, 16) grid, this value's exact square
    # is above it and its float32 square below
    grid = (13, 13, 16)
    over = np.float32(7990.9683)
    limit = 3.0 * math.prod(grid) * T_MAX**2
    assert float(over) ** 2 > limit >= float(np.square(over))
    with pytest.raises(InvalidBRDFError, match="larger than any finite BRDF's"):
        SparseBRDF(**{**ok, "shape": grid}, locations=[[5], [], []], values=[[over], [], []])
    # the limit itself is allowed: three values whose squares sum to it to the last bit
    at = np.array([16596.625, 6.372054, 0.004328941], np.float32)
    assert float(np.sum(np.square(at, dtype=np.float64))) == 3.0 * size * T_MAX**2
    SparseBRDF(**ok, locations=[[1, 2, 3], [], []], values=[at, [], []])


def test_model_repr_modes_and_ensemble_checks(ens):
    m = _model(ens.id, "opponent")
    assert repr(m) == (f"SparseBRDF('m', shape=(18, 18, 36), transform='log-plus-cosine', "
                       f"basis='opponent', coefficients=[40, 13, 0], dictionaries=[1, 0, 1], "
                       f"ensemble={ens.id[:8]})")
    a, b, c = m.modes(0)
    np.testing.assert_array_equal(a * 18 * 36 + b * 36 + c, m.locations[0])
    assert a.max() < 18 and b.max() < 18 and c.max() < 36
    m.check_ensemble(ens)
    other = Ensemble(*(u[:1] for u in (ens.u1, ens.u2, ens.u3)), taus=np.zeros(1))
    with pytest.raises(EnsembleMismatchError, match=f"m: encoded with ensemble {ens.id}, "
                                                    f"but ensemble {other.id} was given"):
        m.check_ensemble(other)
    for d in ([0, 2, 0], [0, -1, 0]):
        bad = SparseBRDF(m.transform, SMALL, ens.id, d, m.locations, m.values)
        with pytest.raises(EnsembleMismatchError, match="dictionary index out of range"):
            bad.check_ensemble(ens)
    SparseBRDF(m.transform, SMALL, ens.id, [1, 1, 1], m.locations, m.values).check_ensemble(ens)


def test_decode_and_eval_agree(ens):
    rng = np.random.default_rng(8)
    wi = rng.normal(size=(300, 3))
    wo = rng.normal(size=(300, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wo[:, 2] = np.abs(wo[:, 2])
    wi[-10:, 2] *= -1  # below the horizon
    wo[-20:-10, 2] *= -1
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    bins = dirs_to_bins(wi, wo, SMALL)
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0) & geometric_valid(SMALL)[bins]
    assert 100 < keep.sum() <= 280
    for basis in ("rgb", "opponent"):
        for transform in ("log-plus-cosine", "log-relative"):
            m = _model(ens.id, basis, transform)
            brdf = m.decode(ens)
            assert brdf.values.shape == (*SMALL, 3)
            np.testing.assert_array_equal(brdf.valid, geometric_valid(SMALL))
            want = np.where(keep[:, None], brdf.values[bins], 0.0)
            got = m.eval(ens, wi, wo, chunk=64)
            assert got.dtype == np.float32 and got.shape == (300, 3)
            np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6)
            assert np.all(got[-20:] == 0) and np.any(got[0] != 0)
    mask = np.zeros(SMALL, bool)
    mask[3] = True
    own = m.decode(ens, valid=mask)
    np.testing.assert_array_equal(own.valid, mask)
    np.testing.assert_allclose(own.values[3], brdf.values[3], rtol=1e-6)
    np.testing.assert_allclose(m.transformed(ens), np.tensordot(
        colour_matrix(m.basis).T, m.coded(ens), axes=1), rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------------- the .sbrdf file
def test_sizes_and_steps():
    assert ff.file_size(0) == 57 and ff.file_size(3, 2) == 57 + 2 + 24
    assert ff.min_file_size(4, version=1) == ff.file_size(0, 4)
    assert ff.min_file_size(4) == 68 + 4 + len(ff._compress(b"")[1]) + 4 == 76
    assert [ff.step(k) for k in (0, 1, 2, 3, 4, -4, -3, 8)] == [
        1.0, 2 ** 0.25, 2 ** 0.5, 2 ** 0.75, 2.0, 0.5, 2 ** -0.75, 4.0]
    for k in range(-40, 40):
        assert ff.step(k) == pytest.approx(2.0 ** (k / 4), rel=1e-15)
    assert ff.min_file_size() == 72 and ff.min_file_size(version=1) == 57
    assert ff.check_version(1) == 1
    with pytest.raises(UsageError, match="version"):
        ff.check_version(3)


def test_step_exponent_follows_its_rules():
    assert ff.step_exponent(np.zeros(0)) == 0 and ff.step_exponent(np.zeros(5)) == 0
    v = np.array([1.0, 1.0] + [4096.0] * 18)  # the 10th percentile / 2 rules: 2^(k/4) = 1/2
    assert ff.step_exponent(v) == -4
    v = np.full(20, 4096.0)  # top / 256 = 32 rules
    v[0] = 8192.0
    assert ff.step_exponent(v) == 20
    # a tiny 10th percentile: the step stops at 2^-22 of the largest
    v = np.array([1e-30] * 2 + [1.0] * 18)
    assert ff.step_exponent(v) == 4 * (math.frexp(1.0)[1] - 22)
    # values are read as float32: float64 values off every grid keep the grid of their
    # float32 copies, which lie on it
    qs = np.array([1, 1, 2, 5, 100, 5000, 3_600_001, 3_000_000, 77, 12345])
    on_grid = (qs * ff.step(-85)).astype(np.float32)  # one finer than the rule's grid
    off = on_grid.astype(np.float64) * (1 + 1e-12)
    assert ff.step_exponent(off) == ff.step_exponent(on_grid) == -85


def test_varints_encode_and_decode():
    x = np.array([0, 1, 127, 128, 300, 2**21, 2**35 - 1])
    raw = ff._varints(x)
    assert raw[:4] == bytes([0, 1, 127, 0x80])
    assert ff._varints(np.array([300])) == bytes([0xAC, 0x02])
    assert ff._varints(np.array([2**14])) == bytes([0x80, 0x80, 0x01])
    assert ff._varints(np.zeros(0, np.int64)) == b""
    back, used = ff._read_varints(np.frombuffer(raw + b"\x05", np.uint8), x.size)
    assert back.tolist() == x.tolist() and used == len(raw)
    assert ff._read_varints(np.frombuffer(b"\x07", np.uint8), 0)[1] == 0
    with pytest.raises(ValueError, match="ends after 1 of 2"):
        ff._read_varints(np.frombuffer(b"\x05\x80", np.uint8), 2)
    with pytest.raises(ValueError, match="number of 6 bytes"):
        ff._read_varints(np.frombuffer(b"\x80" * 5 + b"\x01", np.uint8), 1)
    five, _ = ff._read_varints(np.frombuffer(b"\xff" * 4 + b"\x07", np.uint8), 1)
    assert five.tolist() == [2**31 - 1]


def test_compress_picks_the_smallest_and_decompress_checks_lengths():
    raw = bytes(range(256)) * 20
    codec, packed = ff._compress(raw)
    assert codec in (1, 2) and len(packed) < len(raw) // 4
    assert ff._decompress(codec, packed, len(raw)) == raw
    assert ff._compress(b"\x01")[0] == 0
    noise = np.random.default_rng(0).integers(0, 256, 64, np.uint8).tobytes()
    assert ff._compress(noise) == (0, noise)
    z = zlib.compressobj(9, zlib.DEFLATED, -15, 9)
    deflated = z.compress(raw) + z.flush()
    assert ff._decompress(1, deflated, len(raw)) == raw
    with pytest.raises(ValueError, match=f"deflate payload holds {len(raw)} bytes, its "
                                         f"header announces {len(raw) + 1}"):
        ff._decompress(1, deflated, len(raw) + 1)
    with pytest.raises(ValueError, match=r"deflate payload holds 11\+ bytes"):
        ff._decompress(1, deflated, 10)
    with pytest.raises(ValueError, match="deflate payload holds"):
        ff._decompress(1, deflated + b"xx", len(raw))
    with pytest.raises(ValueError, match="corrupt lzma payload"):
        ff._decompress(2, b"\xff" * 20, 100)
    with pytest.raises(ValueError, match="stored payload holds 3 bytes"):
        ff._decompress(0, b"abc", 4)
    assert ff._decompress(0, b"abc", 3) == b"abc"


def test_version_1_layout_by_hand():
    locs = [np.array([5, 2]), np.array([7]), np.zeros(0, np.int64)]
    vals = [np.array([-1.5, 0.25], np.float32), np.array([3.0], np.float32),
            np.zeros(0, np.float32)]
    m = SparseBRDF("log-relative", (4, 5, 6), "0123456789abcdef" * 2, [2, 1, 0], locs, vals,
                   name="ab", basis="opponent")
    data = ff.to_bytes(m, version=1)
    head = struct.pack("<8sHBB3H16s3H3IB", ff.MAGIC, 1, 2, 1, 4, 5, 6,
                       bytes.fromhex("0123456789abcdef" * 2), 2, 1, 0, 2, 1, 0, 2)
    recs = struct.pack("<IfIfIf", 5, -1.5, 2, 0.25, 7, 3.0)
    body = head + b"ab" + recs
    assert data == body + struct.pack("<I", zlib.crc32(body))
    back = ff.from_bytes(data)
    assert (back.transform, back.shape, back.basis, back.name) == (
        "log-relative", (4, 5, 6), "opponent", "ab")
    assert back.dict_index.tolist() == [2, 1, 0]
    assert [a.tolist() for a in back.locations] == [[5, 2], [7], []]
    assert [v.tolist() for v in back.values] == [[-1.5, 0.25], [3.0], []]


def test_from_bytes_refusals_name_the_source():
    with pytest.raises(BRDFFileError, match=r"^src: too short for a \.sbrdf file \(9 bytes\)"):
        ff.from_bytes(ff.MAGIC + b"\x01", "src")
    with pytest.raises(BRDFFileError, match="bad magic"):
        ff.from_bytes(b"SBRDF\r\n\x1b" + b"\x02\x00" + bytes(80), "src")
    with pytest.raises(BRDFFileError, match=r"version 3; this reader knows 1, 2"):
        ff.from_bytes(ff.MAGIC + b"\x03\x00" + bytes(80), "src")
    m = SparseBRDF("log-plus", (4, 5, 6), "ab" * 16, [0, 0, 0], [[1], [], []],
                   [[1.0], [], []], name="x")
    for version in (1, 2):
        data = ff.to_bytes(m, version)
        n = len(data)
        with pytest.raises(BRDFFileError, match=f"truncated: {n - 1} bytes, its header "
                                                f"announces {n}"):
            ff.from_bytes(data[:-1], "src")
        with pytest.raises(BRDFFileError, match=f"has trailing bytes: {n + 1} bytes"):
            ff.from_bytes(data + b"\x00", "src")
        head = 53 if version == 1 else 68
        with pytest.raises(BRDFFileError, match="too short"):
            ff.from_bytes(data[:head + 3], "src")
        bad = bytearray(data[:-4])
        bad[10] = len(TRANSFORMS)
        with pytest.raises(BRDFFileError, match=f"unknown transform code {len(TRANSFORMS)}"):
            ff.from_bytes(bytes(bad) + struct.pack("<I", zlib.crc32(bytes(bad))), "src")
        bad[10] = TRANSFORMS.index("log-relative-cosine")  # the last without a gain
        last = ff.from_bytes(bytes(bad) + struct.pack("<I", zlib.crc32(bytes(bad))), "src")
        assert last.transform == "log-relative-cosine"
        for t, more in (("log-level-cosine", 4), ("log-lobe", 18)):
            # a level transform's file holds its gain, a lobe transform's its lobe too
            bad[10] = TRANSFORMS.index(t)
            with pytest.raises(BRDFFileError, match=f"truncated: {n} bytes, its header "
                                                    f"announces {n + more}"):
                ff.from_bytes(bytes(bad) + struct.pack("<I", zlib.crc32(bytes(bad))), "src")


def test_eval_is_zero_for_a_direction_at_or_below_the_horizon(ens):
    """Pairs whose bin is valid but one of whose directions is not above the horizon."""
    # the first atoms are constant and positive: rho > 0 in every bin
    m = SparseBRDF("log-plus", SMALL, ens.id, [0, 0, 0], [[0], [0], [0]], [[1.0]] * 3)
    up = np.array([[0.0, 0.0, 1.0]])
    for z in (0.0, -0.02):
        low = np.array([[np.sqrt(1 - z * z), 0.0, z]])
        assert geometric_valid(SMALL)[dirs_to_bins(low, up, SMALL)][0]
        assert geometric_valid(SMALL)[dirs_to_bins(up, low, SMALL)][0]
        assert m.eval(ens, low, up).tolist() == [[0.0, 0.0, 0.0]]
        assert m.eval(ens, up, low).tolist() == [[0.0, 0.0, 0.0]]
    assert np.all(m.eval(ens, up, up) > 0)


def test_load_and_decode_file(ens, tmp_path):
    from sparse_brdf.coding.ensemble import Ensemble as E
    from sparse_brdf.paths import PAPER_ENSEMBLE_ID

    with pytest.raises(FileNotFoundError, match="no such .sbrdf file"):
        ff.load_sbrdf(tmp_path / "absent.sbrdf")
    m = _model(ens.id, "opponent")
    path = ff.save_sbrdf(tmp_path / "m.sbrdf", m)
    brdf = ff.decode_file(path, ens)
    assert brdf.source == str(path)
    np.testing.assert_allclose(brdf.values, ff.as_stored(m).decode(ens).values, rtol=1e-6)
    other = E(*(u[:1] for u in (ens.u1, ens.u2, ens.u3)), taus=np.zeros(1))
    for e in (other, None):  # the wrong one; none: the file's id is not shipped
        with pytest.raises(EnsembleMismatchError, match=f"^{path}: "):
            ff.decode_file(path, e)
    with pytest.raises(EnsembleMismatchError, match=f"^{path}: m: encoded with"):
        ff.load_sbrdf(path, other)
    # no ensemble given: the shipped one the file names
    paper = E.shipped(PAPER_ENSEMBLE_ID)
    loc = np.array([0, 1234])
    shipped = SparseBRDF("log-plus", paper.shape, PAPER_ENSEMBLE_ID, [3, 5, 7], [loc] * 3,
                         [np.array([8.0, -1.0], np.float32)] * 3, name="p")
    p2 = ff.save_sbrdf(tmp_path / "p.sbrdf", shipped, version=1)
    got = ff.decode_file(p2)
    assert got.values.shape == (*paper.shape, 3)
    np.testing.assert_allclose(got.values[40, 40, 90], shipped.eval(
        paper, *_dirs_of_bin(paper.shape, (40, 40, 90)))[0], rtol=1e-4)


def _dirs_of_bin(shape, b):
    """A direction pair inside bin ``b`` (the middle of its edges)."""
    from sparse_brdf.coords import angles_to_dirs, bin_edges

    mid = [float(e[i] + e[i + 1]) / 2 for e, i in zip(bin_edges(shape), b, strict=True)]
    wi, wo = angles_to_dirs(*mid)
    wi, wo = wi.reshape(1, 3), wo.reshape(1, 3)
    assert [int(i[0]) for i in dirs_to_bins(wi, wo, shape)] == list(b)
    return wi, wo


def test_hdr_flip_hands_flip_what_it_documents(monkeypatch):
    """FLIP itself replaced by a recorder: the arguments hdr_flip passes, the map and mean
    it makes of FLIP's answer. (FLIP ends the process on a black reference, so the
    refusal must come before any call.)"""
    import flip_evaluator

    calls = []

    def fake(ref, img, mode, **kw):
        calls.append((ref, img, mode, kw))
        out = np.ones(ref.shape[:2], np.float64)
        out[0, :4] = [2.0**24, 1.0, 1.0, 1.0]  # float32 sums would lose the ones
        return out, -1.0, {}

    monkeypatch.setattr(flip_evaluator, "evaluate", fake)
    with pytest.raises(ImageFileError, match="^the reference image is black: HDR-FLIP has no "
                                             "exposure range$"):
        hdr_flip(np.zeros((2, 4, 3)), np.ones((2, 4, 3)))
    assert calls == []
    ref = np.full((2, 4, 3), 0.5)  # dim: no pixel above 1
    res = hdr_flip(ref, ref * 2, ppd=30)
    (r, i, mode, kw), = calls
    assert mode == "HDR" and r.dtype == i.dtype == np.float32
    assert r.flags.c_contiguous and r.shape == (2, 4, 3)
    assert kw == {"inputsRGB": True, "applyMagma": False, "computeMeanError": False,
                  "parameters": {"ppd": 30.0}}
    assert res.map.dtype == np.float32 and res.map.shape == (2, 4)
    assert res.mean == (2.0**24 + 3 + 4) / 8
    calls.clear()
    mask = np.array([[1, 1, 0, 0], [0, 0, 0, 1]])  # 0/1 integers: a mask, not indices
    res = hdr_flip(ref, ref, mask)
    assert res.mean == (2.0**24 + 1 + 1) / 3
    kw = calls[0][3]
    assert kw["parameters"] == {"ppd": 67.0, **flip_exposures(ref.astype(np.float32),
                                                              mask.astype(bool))}
    calls.clear()
    bright = ref.copy()
    bright[0, 2:] = bright[1, :3] = 3.0  # outside the mask: the exposures are the object's
    hdr_flip(bright, bright, mask)
    want = flip_exposures(bright.astype(np.float32), mask.astype(bool))
    assert calls[0][3]["parameters"] == {"ppd": 67.0, **want}
    assert want != flip_exposures(bright, np.ones((2, 4), bool))
    calls.clear()
    hdr_flip(ref[..., 0], ref[..., 0])  # mono (H, W): grey RGB
    assert calls[0][0].shape == (2, 4, 3)


def test_image_metric_messages():
    ref = np.ones((4, 5, 3), np.float32)
    bad = ref.copy()
    bad[0, 0] = [np.nan, np.inf, 1.0]
    for f in (render_snr, hdr_flip):
        with pytest.raises(ImageFileError, match="^reference image holds 2 NaN/inf values$"):
            f(bad, ref)
        with pytest.raises(ImageFileError, match="^image image holds 2 NaN/inf values$"):
            f(ref, bad)
    with pytest.raises(ImageFileError, match="^image image holds negative values: HDR-FLIP "
                                             "scores non-negative radiance$"):
        hdr_flip(ref, -ref)
    with pytest.raises(ImageFileError, match="^reference image holds negative"):
        hdr_flip(-ref, ref)
    for f in (render_snr, hdr_flip):
        with pytest.raises(ImageFileError, match="^the object mask selects no pixel$"):
            f(ref, ref, np.zeros((4, 5), bool))


def test_render_snr_of_integer_images():
    """8-bit images are scored as numbers, not as wrapping bytes."""
    ref = np.array([[10, 200]], np.uint8)
    img = np.array([[20, 190]], np.uint8)
    assert render_snr(ref, img) == pytest.approx(10 * np.log10((100 + 40000) / 200))


def test_flip_exposures_of_dim_objects():
    """Objects with luminance below 1, with and without black pixels."""
    ref = np.zeros((1, 4, 3))
    ref[0, :, :] = np.array([0.0, 0.5, 0.6, 0.9])[:, None]
    mask = np.array([[True, True, True, False]])
    e = flip_exposures(ref, mask)  # median 0.5 of (0, 0.5, 0.6): black is no majority
    assert _tone(2.0 ** e["stopExposure"] * 0.5) == pytest.approx(0.85, abs=1e-9)
    mask = np.array([[True, True, False, False]])
    ref[0, 0] = 0.0
    e = flip_exposures(ref, np.array([[True, False, False, False]]) | mask)
    assert _tone(2.0 ** e["stopExposure"] * 0.25) == pytest.approx(0.85, abs=1e-9)
    dark = np.zeros((1, 4, 3))
    dark[0, 2], dark[0, 3] = 0.3, 0.8  # a black majority in the mask; 0.8 outside it
    e = flip_exposures(dark, np.array([[True, True, True, False]]))
    assert _tone(2.0 ** e["stopExposure"] * 0.3) == pytest.approx(0.85, abs=1e-9)
    assert _tone(2.0 ** e["startExposure"] * 0.8) == pytest.approx(0.85, abs=1e-9)


def test_cosine_weighted_snr_counts_the_bins_it_is_given():
    shape = TINY
    c = np.clip(cosine_product(shape), 0, None)[..., None]
    rng = np.random.default_rng(9)
    ref = rng.uniform(0.5, 2, (*shape, 3))
    rec = ref + rng.normal(0, 0.1, ref.shape)
    for valid in (np.ones(shape, bool), rng.random(shape) < 0.5):
        s = np.sum((ref * c)[valid] ** 2)
        n = np.sum(((ref - rec) * c)[valid] ** 2)
        assert cosine_weighted_snr(ref, rec, valid) == pytest.approx(10 * np.log10(s / n))


def test_rgb_basis_passes_channels_through_untouched():
    t = np.array([[np.inf, 1.0], [2.0, -0.0], [np.nan, 3.0]])
    for f in (to_basis, from_basis):
        got = f(t, "rgb")
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, t.astype(np.float32))


def test_decode_names_and_long_names_as_stored(ens):
    m = _model(ens.id)
    brdf = m.decode(ens)
    assert (brdf.name, brdf.source) == ("m", "sparse")
    long = SparseBRDF("log-plus", SMALL, ens.id, [0, 0, 0], m.locations, m.values,
                      name="é" * 200)  # 400 bytes: a file keeps the first 255
    assert ff.from_bytes(ff.to_bytes(long)).name == "é" * 127 + "\ufffd"
    for version in (1, 2):
        assert ff.as_stored(long, version).name == long.name


def test_render_snr_edge_values():
    assert render_snr(np.ones((1, 1)), np.full((1, 1), 1.1)) == pytest.approx(20.0)
    ref = np.ones((4, 5, 3))
    img = ref.copy()
    img[0] += 0.1
    rows = np.zeros((4, 5), int)
    rows[0] = 1  # 0/1 integers: a mask, not indices
    assert render_snr(ref, img, rows) == pytest.approx(20.0)


def test_render_proxy_tells_the_layouts_apart():
    """The last axis is colour when it holds at most 4 entries, else phi_d."""
    rng = np.random.default_rng(10)
    for shape, channels in [((12, 6, 8), 3), ((12, 6, 8), 4), ((12, 6, 5), 3)]:
        ref = rng.uniform(0, 2, (*shape, channels)).astype(np.float32)
        rec = ref + rng.normal(0, 0.1, ref.shape).astype(np.float32)
        last = render_proxy_error(ref, rec)
        first = render_proxy_error(np.moveaxis(ref, -1, 0), np.moveaxis(rec, -1, 0))
        assert first == pytest.approx(last, rel=1e-5) and last > 0
    # differences are taken in float32
    one, above = np.ones((1, *shape)), np.full((1, *shape), 1.0 + 1e-9)
    assert render_proxy_error(one, above) == 0.0 == render_proxy_error(above, one)


def test_forward_and_from_basis_give_float32():
    rho = np.full((3, *TINY), 2.0)  # float64 in
    valid = np.ones(TINY, int)  # 0/1 integers
    valid[0] = 0
    for v in (None, valid):
        t = forward(rho, "log-plus", v)
        assert t.dtype == np.float32
        np.testing.assert_allclose(t[:, 1:], np.log(3.0), rtol=1e-6)
    assert np.all(forward(rho, "log-plus", valid)[:, 0] == 0)
    assert from_basis(np.ones((3, 2)), "opponent").dtype == np.float32


def test_ensemble_mismatch_messages(ens):
    m = _model(ens.id)
    other = Ensemble(*(u[:1] for u in (ens.u1, ens.u2, ens.u3)), taus=np.zeros(1))
    with pytest.raises(EnsembleMismatchError) as info:
        m.check_ensemble(other)
    assert str(info.value) == (
        f"m: encoded with ensemble {ens.id}, but ensemble {other.id} was given: give the "
        "file's own ensemble (--ensemble FILE.npz), or re-encode the material with this one "
        f"(sparse-brdf encode SOURCE -o NEW.sbrdf --ensemble {other.id})")
    rng = np.random.default_rng(0)
    tiny = Ensemble(*(np.stack([random_orthonormal(n, rng)] * 2) for n in TINY),
                    taus=np.zeros(2))
    grid = SparseBRDF("log-plus", SMALL, tiny.id, [0, 0, 0], [[], [], []], [[], [], []],
                      name="g")
    with pytest.raises(EnsembleMismatchError) as info:
        grid.check_ensemble(tiny)
    assert str(info.value) == "g: grid 18x18x36, but its ensemble's is 6x5x10"


def test_brdf_metrics_convert_to_float_and_sum_in_float64():
    u8 = np.array([10, 3], np.uint8), np.array([20, 0], np.uint8)
    assert rae(*u8) == pytest.approx(13 / 13)  # not |10 - 20| = 246 in bytes
    assert gamma_mse(*u8) == pytest.approx(((np.sqrt(10) - np.sqrt(20)) ** 2 + 3) / 2,
                                           rel=1e-6)  # float32, not float16 square roots
    assert gamma_mse(u8[1], u8[0]) == gamma_mse(*u8)
    ref = np.array([1.0 + 1e-9])
    one = np.array([1.0], np.float32)
    assert mse(ref, one) == pytest.approx(1e-18, rel=1e-3, abs=0)  # float64 over float32
    assert mse(one, ref) == pytest.approx(1e-18, rel=1e-3, abs=0)
    big = np.random.default_rng(12).uniform(0, 1, 10**6).astype(np.float32)
    low = np.full_like(big, 0.1)
    d = big - low
    assert rae(big, low) == pytest.approx(np.sum(np.abs(d), dtype=np.float64)
                                          / np.sum(big, dtype=np.float64), rel=1e-10)
    r = np.sqrt(big) - np.sqrt(low)
    assert gamma_mse(big, low) == pytest.approx(np.sum((r * r).astype(np.float64)) / r.size,
                                                rel=1e-10)


def test_brdf_metric_edge_cases():
    assert rae(np.array([0.5]), np.array([0.25])) == 0.5  # a reference summing below 1
    assert gamma_mse(np.array([1.0]), np.array([0.25])) == 0.25  # values below 1
    assert gamma_mse(np.array([0.125]), np.array([1.0]), gamma=3.0) == pytest.approx(0.25)
    ref = np.array([[1.0, 2.0], [3.0, 4.0]])
    rec = np.array([[1.5, 2.0], [2.0, 4.0]])
    rows = np.array([1, 0])  # 0/1 integers: a mask, not indices
    assert rae(ref, rec, rows) == rae(ref, rec, rows.astype(bool)) == pytest.approx(0.5 / 3)


def test_step_exponent_at_its_limits():
    # the 10th percentile of 11 values is the second smallest
    assert ff.step_exponent(np.array([1e-3] + [1.0] * 10)) == -32  # 1 / 256, not 1e-3 / 2
    # below 2^-126 steps stop at 2^-126
    assert ff.step_exponent(np.array([1e-40])) == ff._K_MIN
    # values on the grid one finer than the rule's (the rule capped by |q| <= 2^22):
    # kept, although their q exceed 2^21
    qs = np.array([1, 1, 2, 5, 100, 5000, 3_600_001, 3_000_000, 77, 12345])
    v = (qs * ff.step(-85)).astype(np.float32)
    assert ff.step_exponent(v) == -85
    m = SparseBRDF("log-plus", SMALL, "ab" * 16, [0, 0, 0], [np.arange(10), [], []],
                   [v, [], []])
    back = ff.from_bytes(ff.to_bytes(m))
    np.testing.assert_array_equal(np.sort(back.values[0]), np.sort(v))
    # the same at the finest step, 2^-126
    q = np.array([4900, 4000, 4500, 4100, 4300, 4200, 4400, 4600, 4700, 4800, 4051])
    v = (q * 2.0**-126).astype(np.float32)
    assert ff.step_exponent(v) == ff._K_MIN


def test_to_bytes_grid_limits_and_long_ids():
    def model(shape, ens_id="ab" * 16):
        return SparseBRDF("log-plus", shape, ens_id, [0, 0, 0], [[], [], []], [[], [], []],
                          name="big")

    for version in (1, 2):
        assert ff.from_bytes(ff.to_bytes(model((65535, 1, 1)), version)).shape == (65535, 1, 1)
        for shape in [(65536, 1, 1), (65535, 65535, 2), (32768, 32768, 4)]:
            with pytest.raises(UsageError) as info:
                ff.to_bytes(model(shape), version)
            assert str(info.value) == (f"big: grid {shape} is too large for the .sbrdf format "
                                       "(sides of at most 65535 bins)")
    # the file holds the first 32 hex digits of the ensemble id
    assert ff.from_bytes(ff.to_bytes(model(SMALL, "cd" * 20))).ensemble_id == "cd" * 16


_HEAD2 = struct.Struct("<8sHBB3H16s3H3IBB3hII")


def _v2(fields: dict, raw: bytes | None = None, model: SparseBRDF | None = None) -> bytes:
    """A version-2 file of ``model`` (default: one coefficient in channel 0) with header
    fields replaced by index, and optionally a stored (codec 0) payload ``raw``."""
    if model is None:
        model = SparseBRDF("log-plus", (4, 5, 6), "ab" * 16, [0, 0, 0], [[7], [], []],
                           [[0.5], [], []], name="n")
    data = ff.to_bytes(model)
    head = list(_HEAD2.unpack_from(data))
    name = data[_HEAD2.size: _HEAD2.size + head[14]]
    packed = data[_HEAD2.size + head[14]: -4]
    if raw is not None:
        head[15], head[19], packed = 0, len(raw), raw
    for i, v in fields.items():
        head[i] = v
    head[20] = len(packed)
    body = _HEAD2.pack(*head) + name + packed
    return body + struct.pack("<I", zlib.crc32(body))


def test_version_2_header_checks():
    def refused(data: bytes, message: str):
        with pytest.raises(BRDFFileError) as info:
            ff.from_bytes(data, "f")
        assert str(info.value) == "f: " + message

    refused(_v2({15: 3}), "unknown payload codec 3")
    refused(_v2({17: ff._K_MAX + 1}), f"quantisation step exponents [{ff.step_exponent([0.5])}"
                                      f", {ff._K_MAX + 1}, 0] out of range")
    assert ff.from_bytes(_v2({17: ff._K_MAX, 18: ff._K_MIN})).n_coeffs.tolist() == [1, 0, 0]
    for shape in [(65535, 65535, 2), (32768, 32768, 4)]:
        size = math.prod(shape)
        refused(_v2({4: shape[0], 5: shape[1], 6: shape[2]}),
                f"coefficient counts [1, 0, 0] exceed the {size} atoms of the grid, or the "
                "grid the format's 2^32")
    refused(_v2({11: 121}), "coefficient counts [121, 0, 0] exceed the 120 atoms of the grid, "
                            "or the grid the format's 2^32")
    full = SparseBRDF("log-plus", (1, 1, 2), "ab" * 16, [0, 0, 0], [[0, 1], [], []],
                      [[0.5, 0.25], [], []])
    assert ff.from_bytes(ff.to_bytes(full)).n_coeffs.tolist() == [2, 0, 0]  # every atom
    refused(_v2({}, raw=bytes(11)), "payload of 11 bytes for 1 coefficients")
    # gap 7 (1 byte), zigzag q 300 (2 bytes), then 2 bytes too many
    refused(_v2({}, raw=bytes([7, 0xAC, 0x02, 0, 0])), "payload has 2 bytes after its numbers")


def test_describe_a_file(tmp_path):
    from sparse_brdf.paths import PAPER_ENSEMBLE_ID

    with pytest.raises(FileNotFoundError, match="no such .sbrdf file"):
        ff.describe(tmp_path / "absent.sbrdf")
    junk = tmp_path / "junk.sbrdf"
    junk.write_bytes(b"not a file of ours")
    with pytest.raises(BRDFFileError, match=f"^{junk}: not a .sbrdf file"):
        ff.describe(junk)
    m = SparseBRDF("log-relative-cosine", (4, 5, 6), PAPER_ENSEMBLE_ID, [3, 1, 2],
                   [[1, 2, 3], [], [9]], [[0.5, 0.25, -1.0], [], [2.0]], name="d",
                   basis="opponent")
    p1 = ff.save_sbrdf(tmp_path / "v1.sbrdf", m, version=1)
    p2 = ff.save_sbrdf(tmp_path / "v2.sbrdf", dataclasses.replace(m, basis="rgb",
                                                                   ensemble_id="ab" * 16))
    assert ff.describe(p1) == {
        "version": 1, "codec": None, "bytes": 57 + 1 + 8 * 4, "ensemble": PAPER_ENSEMBLE_ID,
        "ensemble_shipped": True, "grid": [4, 5, 6], "transform": "log-relative-cosine",
        "gain": 1.0, "lobe": None, "floor": 0.0, "basis": "opponent",
        "channels": ["luminance", "red-green", "yellow-blue"],
        "coefficients": [3, 0, 1], "coefficients_total": 4, "dictionaries": [3, 1, 2]}
    d2 = ff.describe(p2)
    data = p2.read_bytes()
    assert (d2["version"], d2["bytes"], d2["ensemble_shipped"]) == (2, len(data), False)
    assert d2["codec"] == ff.CODECS[data[53]] and d2["channels"] == ["R", "G", "B"]
    assert type(d2["version"]) is int


def test_model_flattens_and_converts_its_inputs():
    m = SparseBRDF("log-plus", SMALL, "ab" * 16, np.array([[1], [0], [1]], np.int32),
                   [np.array([[3, 4]]), [], []], [np.array([[1.0], [2.0]]), [], []])
    assert m.dict_index.dtype == np.int64 and m.dict_index.shape == (3,)
    assert m.locations[0].tolist() == [3, 4] and m.values[0].tolist() == [1.0, 2.0]
    with pytest.raises(ValueError):  # as many value arrays as location arrays
        SparseBRDF("log-plus", SMALL, "ab" * 16, [0, 0, 0], [[], [], []], [[], []])


def test_from_bytes_at_its_size_limits():
    with pytest.raises(BRDFFileError, match="bad magic"):
        ff.from_bytes(b"NOTSBRDF\x01\x00", "f")  # 10 bytes: magic and version only
    empty = SparseBRDF("log-plus", SMALL, "ab" * 16, [0, 0, 0], [[], [], []], [[], [], []],
                       name="")
    data = ff.to_bytes(empty, version=1)
    assert len(data) == 57 and ff.from_bytes(data).n_coeffs.tolist() == [0, 0, 0]
    bad = bytearray(data[:-4])
    bad[11] = 0x02
    with pytest.raises(BRDFFileError) as info:
        ff.from_bytes(bytes(bad) + struct.pack("<I", zlib.crc32(bytes(bad))), "f")
    assert str(info.value) == ("f: unknown flags 0x02 in byte 11 (this reader knows 0x01, the "
                               "opponent colour basis): written by a newer version?")


def test_read_payload_value_range_and_order():
    # q = 2^24 - 1 at step 2^104: exactly float32's largest, within its range (then refused
    # as larger than any finite BRDF's coefficients)
    raw = ff._varints(np.array([0, 2 * (2**24 - 1)]))
    with pytest.raises(BRDFFileError, match="larger than any finite BRDF's"):
        ff.from_bytes(_v2({16: 416}, raw=raw), "f")
    with pytest.raises(BRDFFileError, match="beyond the float32 range"):
        ff.from_bytes(_v2({16: 417}, raw=raw), "f")
    # equal magnitudes keep their locations' order (a stable sort)
    locs = np.random.default_rng(13).choice(math.prod(SMALL), 300, replace=False)
    vals = np.random.default_rng(14).choice([1.0, 2.0, -3.0, -1.0], 300).astype(np.float32)
    back = ff.from_bytes(ff.to_bytes(SparseBRDF("log-plus", SMALL, "ab" * 16, [0, 0, 0],
                                                [locs, [], []], [vals, [], []])))
    order = np.lexsort((locs, -np.abs(vals)))  # by magnitude, then by location
    assert back.locations[0].tolist() == locs[order].tolist()
    np.testing.assert_allclose(back.values[0], vals[order], rtol=1e-3)
