import numpy as np
import pytest

import sparse_brdf as sb
from sparse_brdf.coords import cosine_product, geometric_valid
from sparse_brdf.errors import ImageFileError
from sparse_brdf.metrics import cosine_weighted_snr, gamma_mse, rae, render_snr
from sparse_brdf.transforms import (
    LEVEL_KNEE,
    RELATIVE_SCALE,
    TRANSFORMS,
    cosine_weight,
    forward,
    inverse,
    material_gain,
    material_level,
    weight,
)

pytestmark = pytest.mark.numerics

SHAPE = (18, 18, 36)


@pytest.mark.parametrize("name", TRANSFORMS)
def test_inverse_of_forward_is_identity_on_valid_bins(name):
    rng = np.random.default_rng(0)
    valid = geometric_valid(SHAPE)
    rho = (rng.random((3, *SHAPE)) ** 4 * 50).astype(np.float32)
    back = inverse(forward(rho, name, valid), name, material_gain(name, rho, valid))
    np.testing.assert_allclose(back[:, valid], rho[:, valid], rtol=2e-6, atol=1e-7)
    assert np.all(back[:, ~valid] == 0)  # invalid bins are set to 0 first


def test_transform_formulas():
    rho = np.full((1, *SHAPE), 2.0, np.float32)
    np.testing.assert_allclose(forward(rho, "log-plus"), np.log(3.0), rtol=1e-6)
    c = np.clip(cosine_product(SHAPE), 0.01, 1)
    np.testing.assert_allclose(forward(rho, "log-plus-cosine")[0], np.log(2 * c + 1), rtol=1e-5)
    assert cosine_weight(SHAPE).min() == np.float32(0.01)
    s = RELATIVE_SCALE
    np.testing.assert_allclose(forward(rho, "log-relative"), np.log(2 * s + 1), rtol=1e-6)
    np.testing.assert_allclose(forward(rho, "log-relative-cosine")[0], np.log(2 * c * s + 1),
                               rtol=1e-5)


def test_level_transforms_formula_and_scale_invariance():
    """ln(1 + k rho / L), L the median luminance of the valid bins: a material and the same
    material 1,000 times brighter transform alike, and its gain is 1/L."""
    valid = geometric_valid(SHAPE)
    rho = np.full((3, *SHAPE), 2.0, np.float32)
    assert material_level(rho, valid) == 2.0  # the luminance weights sum to 1
    np.testing.assert_allclose(forward(rho, "log-level", valid)[:, valid],
                               np.log(1 + LEVEL_KNEE), rtol=1e-6)
    rng = np.random.default_rng(3)
    rho = (rng.random((3, *SHAPE)) ** 4 * 5).astype(np.float32)
    for name in ("log-level", "log-level-cosine"):
        t = forward(rho, name, valid)
        np.testing.assert_allclose(forward(rho * np.float32(1000), name, valid), t,
                                   rtol=1e-5, atol=1e-6)
        assert material_gain(name, rho * np.float32(1000), valid) == pytest.approx(
            material_gain(name, rho, valid) / 1000, rel=1e-6)
    assert material_gain("log-relative", rho, valid) == 1.0
    with pytest.raises(ValueError, match="gain"):
        inverse(t, "log-relative", 2.0)
    with pytest.raises(ValueError, match="gain"):
        inverse(t, "log-level", float("nan"))


def test_relative_transforms_code_dim_values_relatively():
    """An error of 0.01 in the transformed domain is a relative error of at most 1.5 % from
    rho = 0.01 / sr to 1 / sr in log-relative; in log-plus it is 100 % at 0.01."""
    rho = np.array([0.01, 1.0], np.float32).reshape(2, 1, 1, 1) * np.ones((1, *SHAPE),
                                                                          np.float32)
    def relative_error(name: str) -> np.ndarray:
        return np.abs(inverse(forward(rho, name) + np.float32(0.01), name) - rho) / rho

    assert relative_error("log-relative").max() < 0.015
    assert relative_error("log-plus").max() > 0.9


def test_inverse_clamps_negative():
    t = np.full((1, *SHAPE), -0.5, np.float32)
    assert inverse(t, "log-plus").min() == 0


def test_unknown_transform():
    with pytest.raises(ValueError, match="unknown transform 'log'"):
        forward(np.zeros((1, *SHAPE)), "log")


def test_snr_identical_images_is_infinite():
    img = np.random.default_rng(0).random((4, 4, 3))
    assert render_snr(img, img) == float("inf")
    assert render_snr(np.zeros((2, 2)), np.zeros((2, 2))) == float("inf")
    assert render_snr(np.zeros((2, 2)), np.ones((2, 2))) == float("-inf")


def test_snr_value():
    ref = np.ones((10, 10))
    img = ref + 0.1  # noise energy 1e-2 per pixel -> 20 dB
    assert render_snr(ref, img) == pytest.approx(20.0)
    with pytest.raises(ValueError, match="shapes differ"):
        render_snr(ref, ref[:5])
    with pytest.raises(ValueError, match="NaN"):
        render_snr(ref, np.full((10, 10), np.nan))


def test_rae_and_gamma_mse_use_valid_bins_only():
    valid = geometric_valid(SHAPE)
    ref = np.ones((*SHAPE, 3))
    rec = ref * 1.1
    rec[~valid] = 100  # ignored
    assert rae(ref, rec, valid) == pytest.approx(0.1)
    assert gamma_mse(ref, ref * 4, valid) == pytest.approx(1.0)  # sqrt(4) - sqrt(1) = 1
    assert cosine_weighted_snr(ref, rec, valid) == pytest.approx(20.0)


@pytest.mark.parametrize("shape", [(90, 90, 180), (8, 6, 12)])
def test_render_proxy_kernel_is_the_full_grid_formula(shape):
    """The kernel is built on the (theta_h, theta_d) plane and expanded over phi_d; it
    must equal, bit for bit, the formula evaluated bin by bin on the whole grid."""
    from sparse_brdf.coords import bin_solid_angle, cos_io
    from sparse_brdf.metrics import make_render_proxy

    n1, n2, n3 = shape
    th = ((np.arange(n1) + 0.5) / n1) ** 2 * np.pi / 2
    td = (np.arange(n2) + 0.5) / n2 * np.pi / 2
    pd = (np.arange(n3) + 0.5) / n3 * np.pi
    ci, co = (np.clip(c, 0, None) for c in cos_io(th[:, None, None], td[None, :, None],
                                                   pd[None, None, :]))
    omega = bin_solid_angle(shape)
    point = ci * co * 0.5 * (ci + co) * omega
    k = make_render_proxy(shape)
    starts = k["starts"]
    np.testing.assert_array_equal(k["omega"], omega.astype(np.float32))
    np.testing.assert_array_equal(k["cell_omega"], np.add.reduceat(omega, starts, axis=0))
    np.testing.assert_array_equal(k["cell_point"], np.add.reduceat(point, starts, axis=0))


@pytest.mark.parametrize("name", TRANSFORMS)
def test_forward_masks_exactly_as_zeroing_first(name):
    """forward with a mask equals zeroing the invalid bins and then transforming, bit for
    bit, whatever the invalid bins held (NaN, inf, negative values)."""
    rng = np.random.default_rng(5)
    shape = (6, 5, 10)
    rho = (rng.random((3, *shape)) * 20).astype(np.float32)
    valid = rng.random(shape) > 0.3
    rho[:, ~valid] = np.array([np.nan, np.inf, -4.0], np.float32)[:, None]
    zeroed = np.where(valid, rho, np.float32(0))
    gain = material_gain(name, rho, valid)  # a level transform's: from the valid bins
    expect = np.log1p(zeroed * weight(name, shape, gain)).astype(np.float32)
    got = forward(rho, name, valid)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, expect)
    np.testing.assert_array_equal(forward(zeroed, name, gain=gain), expect)


def _studio_like_image(seed: int = 0) -> np.ndarray:
    """A smooth HDR image with a bright spot on a dim background, (48, 64, 3)."""
    y, x = np.mgrid[0:48, 0:64].astype(np.float32)
    spot = 20.0 * np.exp(-((x - 40) ** 2 + (y - 20) ** 2) / 30.0)
    base = 0.05 + 0.3 * (x / 64.0)
    rng = np.random.default_rng(seed)
    tint = rng.uniform(0.6, 1.0, 3).astype(np.float32)
    return (spot + base)[..., None] * tint


def test_hdr_flip_is_zero_for_identical_images_and_grows_with_brightness():
    ref = _studio_like_image()
    assert sb.hdr_flip(ref, ref).mean == 0.0
    scores = [sb.hdr_flip(ref, ref * s).mean for s in (1.01, 1.1, 1.5)]
    assert 0.0 < scores[0] < scores[1] < scores[2] < 1.0
    res = sb.hdr_flip(ref, ref * 1.1)
    assert res.map.shape == ref.shape[:2] and res.map.dtype == np.float32
    assert np.isclose(res.mean, res.map.mean(), rtol=1e-5)


def test_hdr_flip_averages_over_the_mask_only():
    ref = _studio_like_image()
    img = ref.copy()
    img[:, :32] *= 2.0  # only the left half differs
    right = np.zeros(ref.shape[:2], bool)
    right[:, 40:] = True  # far enough from the change for FLIP's filters
    assert sb.hdr_flip(ref, img, right).mean < 0.2 * sb.hdr_flip(ref, img, ~right).mean
    mono = sb.hdr_flip(ref[..., :1], img[..., :1])
    assert mono.mean > 0.0 and mono.map.shape == ref.shape[:2]


@pytest.mark.parametrize("bad, match", [
    (np.zeros((48, 64, 3), np.float32), "black"),
    (np.full((48, 64, 3), np.nan, np.float32), "NaN"),
    (-np.ones((48, 64, 3), np.float32), "negative"),
    (np.ones((48, 60, 3), np.float32), "shapes differ"),
])
def test_hdr_flip_refuses_what_it_cannot_score(bad, match, monkeypatch):
    import flip_evaluator

    def flip_not_reached(*args, **kwargs):  # FLIP ends the process on a black reference
        raise AssertionError("hdr_flip handed FLIP what it cannot score")

    monkeypatch.setattr(flip_evaluator, "evaluate", flip_not_reached)
    img = _studio_like_image()
    ref = bad if bad.shape == img.shape else np.ones((48, 60, 3), np.float32)
    with pytest.raises(ImageFileError, match=match):
        sb.hdr_flip(ref, img)
