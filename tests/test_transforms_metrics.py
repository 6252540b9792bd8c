import numpy as np
import pytest

import sparse_brdf as sb
from sparse_brdf.coords import bin_angles, cosine_product, geometric_valid
from sparse_brdf.errors import ImageFileError
from sparse_brdf.metrics import cosine_weighted_snr, gamma_mse, rae, render_snr
from sparse_brdf.transforms import (
    LEVEL_KNEE,
    LOBE_ALPHAS,
    LOBE_KNEE,
    LOBE_POWER,
    RELATIVE_SCALE,
    TRANSFORMS,
    check_lobe,
    cosine_weight,
    fit_base_lobe,
    forward,
    ggx,
    has_lobe,
    inverse,
    lobe_rows,
    material_gain,
    material_level,
    material_lobe,
    to_lobe,
    weight,
)

pytestmark = pytest.mark.numerics

SHAPE = (18, 18, 36)


@pytest.mark.parametrize("name", TRANSFORMS)
def test_inverse_of_forward_is_identity_on_valid_bins(name):
    rng = np.random.default_rng(0)
    valid = geometric_valid(SHAPE)
    rho = (rng.random((3, *SHAPE)) ** 4 * 50).astype(np.float32)
    back = inverse(forward(rho, name, valid), name, material_gain(name, rho, valid),
                   material_lobe(name, rho, valid))
    # the lobe transforms code a float32 ratio to the lobe: far below the lobe (rho <<
    # 1e-6 of this material's 50), its absolute error is that of the lobe's log
    atol = 1e-6 if has_lobe(name) else 1e-7
    np.testing.assert_allclose(back[:, valid], rho[:, valid], rtol=2e-6, atol=atol)
    if not has_lobe(name):
        assert np.all(back[:, ~valid] == 0)  # invalid bins are set to 0 first
    else:  # an invalid bin codes t = 0: the lobe itself
        lobe = np.broadcast_to(lobe_rows(material_lobe(name, rho, valid), SHAPE)[
            :, :, None, None], rho.shape)
        np.testing.assert_allclose(back[:, ~valid], lobe[:, ~valid], rtol=1e-5)


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


def _lobe_material(alpha: float, kd, ks, shape=SHAPE) -> np.ndarray:
    """rho = kd + ks D(theta_h; alpha) per channel on the grid, (3, *shape), float32."""
    th = np.broadcast_to(bin_angles(shape)[0][:, None, None], shape)
    return (np.asarray(kd)[:, None, None, None]
            + np.asarray(ks)[:, None, None, None] * ggx(th, alpha)[None]).astype(np.float32)


def test_base_lobe_fit_recovers_a_lobe_material():
    """A material that is a lobe of the grid's alphas is fitted back: that alpha, its kd
    and ks to float16 rounding, and the lobe transforms code it as zeros."""
    valid = geometric_valid(SHAPE)
    alpha = LOBE_ALPHAS[11]
    rho = _lobe_material(alpha, [0.05, 0.2, 0.01], [0.3, 0.1, 0.0])
    lobe = fit_base_lobe(rho, valid)
    assert lobe[0] == float(np.float16(alpha))
    np.testing.assert_allclose(lobe[1:], [0.05, 0.2, 0.01, 0.3, 0.1, 0.0], rtol=2e-3,
                               atol=1e-6)
    assert check_lobe("log-lobe", lobe) == lobe  # float16-exact, as files hold it
    for name in ("log-lobe", "log-lobe-cosine"):
        t = forward(rho, name, valid)
        assert np.abs(t).max() < 0.01 * np.log(LOBE_KNEE)  # float16 rounding of the lobe


def test_base_lobe_fit_is_the_weighted_least_squares_solution():
    """The row-reduced fit equals least squares over every valid bin with weights
    1 / (mean_c rho + L) (kd, ks > 0 here, so the constraint is inactive), at the alpha
    whose residual is smallest."""
    rng = np.random.default_rng(2)
    valid = geometric_valid(SHAPE)
    rho = _lobe_material(0.08, [0.1, 0.3, 0.05], [0.2, 0.05, 0.1])
    rho = (rho * rng.uniform(0.7, 1.3, rho.shape)).astype(np.float32)  # not a lobe
    lobe = fit_base_lobe(rho, valid)
    level = material_level(rho, valid)
    w = 1.0 / (rho[:, valid].astype(np.float64).mean(0) + level)
    th = np.broadcast_to(bin_angles(SHAPE)[0][:, None, None], SHAPE)[valid]
    best = None
    for a in LOBE_ALPHAS:
        design = np.stack([np.ones(th.size), ggx(th, a)], 1) * w[:, None]
        sol, res = [], 0.0
        for c in range(3):
            x, r, *_ = np.linalg.lstsq(design, rho[c, valid] * w, rcond=None)
            sol.append(x)
            res += float(r[0])
        if best is None or res < best[0]:
            best = (res, a, np.array(sol))
    assert lobe[0] == float(np.float16(best[1]))
    np.testing.assert_allclose(lobe[1:4], best[2][:, 0], rtol=2e-3)
    np.testing.assert_allclose(lobe[4:], best[2][:, 1], rtol=2e-3)


def test_lobe_transforms_formula_and_scale_invariance():
    """t = ((b w + 1) / K)^G (ln(rho w + 1) - ln(b w + 1)), w = K [c] / L: zero where rho
    is the lobe, invariant to the material's brightness (up to the lobe's float16
    rounding), and the inverse gives rho back."""
    valid = geometric_valid(SHAPE)
    rng = np.random.default_rng(4)
    rho = _lobe_material(0.05, [0.02, 0.05, 0.01], [0.1, 0.02, 0.3])
    rho = (rho * rng.uniform(0.5, 2.0, rho.shape)).astype(np.float32)
    for name in ("log-lobe", "log-lobe-cosine"):
        gain, lobe = material_gain(name, rho, valid), material_lobe(name, rho, valid)
        w = np.asarray(weight(name, SHAPE, gain), np.float64)
        b = lobe_rows(lobe, SHAPE)[:, :, None, None]
        o = np.log1p(b * w)
        want = ((b * w + 1) / LOBE_KNEE) ** LOBE_POWER * (np.log1p(rho * w) - o)
        t = forward(rho, name, valid)
        np.testing.assert_allclose(t[:, valid], want[:, valid], rtol=1e-4, atol=1e-5)
        # float32, as the coded values: absolute error ~ 1e-7 of ln(b W + 1)
        np.testing.assert_allclose(to_lobe(np.log1p(rho * w), w, b)[:, valid],
                                   want[:, valid], rtol=1e-5, atol=2e-5)
        bright = forward(rho * np.float32(1000), name, valid)
        np.testing.assert_allclose(bright, t, rtol=0, atol=5e-3 * np.abs(t).max())
        back = inverse(t, name, gain, lobe)
        np.testing.assert_allclose(back[:, valid], rho[:, valid], rtol=2e-5)
    with pytest.raises(ValueError, match="needs the material's base lobe"):
        inverse(t, "log-lobe", gain)
    with pytest.raises(ValueError, match="has no base lobe"):
        inverse(t, "log-level", gain, lobe)
    for bad in [(0.0, *lobe[1:]), (*lobe[:6], -1.0), (*lobe[:6], np.nan), lobe[:6],
                (0.1001, *lobe[1:])]:
        with pytest.raises(ValueError, match="base lobe"):
            check_lobe("log-lobe", bad)


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
    lobe = material_lobe(name, rho, valid)  # a lobe transform's: the same
    expect = np.log1p(zeroed * weight(name, shape, gain)).astype(np.float32)
    if lobe is not None:  # the ratio to the lobe; an invalid bin codes the lobe itself
        b = lobe_rows(lobe, shape)[:, :, None, None]
        expect = np.where(valid, to_lobe(expect, weight(name, shape, gain), b),
                          0).astype(np.float32)
    got = forward(rho, name, valid)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, expect)
    np.testing.assert_array_equal(forward(zeroed, name, valid, gain, lobe), expect)


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


def test_base_lobe_keeps_a_mirror_like_peak(shared_data):
    """MERL chrome-steel (a training material): its peak is 600 times the shoulder of its
    relative least-squares fit. The base lobe takes the peak's roughness, and its value
    at theta_h = 0 is within a factor of 8 of the material's mean over the first theta_d
    bins there (the relative fit alone missed it by 600 times)."""
    from sparse_brdf.sources.load import load_brdf

    brdf = load_brdf(shared_data / "nbrdf" / "merl" / "chrome-steel.h5")
    rho, valid = brdf.channel_first(), brdf.valid
    lobe = fit_base_lobe(rho, valid)
    assert lobe[0] < 0.02
    peak = lobe_rows(lobe, brdf.shape)[:, 0]
    want = np.array([rho[c, 0, :10][valid[0, :10]].mean() for c in range(3)])
    assert np.all(peak > want / 8) and np.all(peak < want * 8), (peak, want)
