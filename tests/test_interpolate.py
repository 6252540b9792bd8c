"""Blending encoded materials; the inputs come from the paper's encoder (RGB channels,
per-channel budgets), opponent inputs are built from them."""

import dataclasses
import functools

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.cli import main
from sparse_brdf.coding.encode import encode as _encode
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.coding.interpolate import interpolate
from sparse_brdf.coding.spec import PAPER_OPTIONS
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.transforms import FLOORS

encode = functools.partial(_encode, **PAPER_OPTIONS)


@pytest.fixture(scope="module")
def pair(small_ensemble):
    a = encode(load_brdf("mitsuba:au-ggx-0.25", shape=SMALL), small_ensemble, 64,
               transform="log-plus")
    b = encode(load_brdf("mitsuba:plastic-blue-ggx-0.2", shape=SMALL), small_ensemble, 64,
               transform="log-plus")
    return a, b


def test_endpoints(pair, small_ensemble):
    a, b = pair
    ta = a.transformed(small_ensemble)
    np.testing.assert_allclose(interpolate(a, b, 0.0, small_ensemble).transformed(
        small_ensemble), ta, atol=1e-5)
    # alpha = 1 is B expressed in A's dictionary: exact with a full budget
    full = interpolate(a, b, 1.0, small_ensemble, n_coeffs=int(np.prod(SMALL)))
    np.testing.assert_allclose(full.transformed(small_ensemble),
                               b.transformed(small_ensemble), atol=1e-4)


def test_midpoint_is_linear_in_the_transformed_domain(pair, small_ensemble):
    a, b = pair
    mid = interpolate(a, b, 0.5, small_ensemble, n_coeffs=int(np.prod(SMALL)))
    want = 0.5 * a.transformed(small_ensemble) + 0.5 * b.transformed(small_ensemble)
    np.testing.assert_allclose(mid.transformed(small_ensemble), want, atol=1e-4)
    small = interpolate(a, b, 0.5, small_ensemble)
    assert small.n_coeffs.tolist() == [64, 64, 64]


def test_errors(pair, small_ensemble):
    a, b = pair
    with pytest.raises(ValueError, match="alpha"):
        interpolate(a, b, 1.5, small_ensemble)
    c = encode(load_brdf("mitsuba:diffuse-red", shape=SMALL), small_ensemble, 16,
               transform="log-plus-cosine")
    with pytest.raises(ValueError, match="same --transform"):
        interpolate(a, c, 0.5, small_ensemble)


def _opponent(model, counts):
    """``model``'s coefficients read as opponent channels, cut to ``counts``."""
    return dataclasses.replace(
        model, basis="opponent", name=f"{model.name}-opp",
        locations=[a[:n] for a, n in zip(model.locations, counts, strict=True)],
        values=[v[:n] for v, n in zip(model.values, counts, strict=True)])


@pytest.mark.parametrize("order", ["rgb+opponent", "opponent+rgb", "opponent+opponent"])
def test_blend_across_colour_bases_is_linear_in_the_transformed_domain(pair, small_ensemble,
                                                                       order):
    """B is brought into A's basis exactly: with a full budget the blend is the linear
    mix of the two materials' transformed R, G, B; the result is in A's basis."""
    a, b = pair
    b_opp = _opponent(b, (64, 30, 0))
    x, y = {"rgb+opponent": (a, b_opp), "opponent+rgb": (b_opp, a),
            "opponent+opponent": (_opponent(a, (64, 0, 20)), b_opp)}[order]
    full = int(np.prod(SMALL))
    for alpha in (0.0, 0.3, 1.0):
        mid = interpolate(x, y, alpha, small_ensemble, n_coeffs=full)
        assert mid.basis == x.basis
        want = ((1 - alpha) * x.transformed(small_ensemble)
                + alpha * y.transformed(small_ensemble))
        np.testing.assert_allclose(mid.transformed(small_ensemble), want, atol=1e-4)


def test_opponent_blend_budget_is_joint(pair, small_ensemble):
    """An opponent result keeps the largest |s| over the three channels: 3 n_coeffs in
    all (default: the sum of the per-channel maxima), in any split, each channel sorted
    by decreasing |s|; an rgb result keeps n_coeffs per channel, as always."""
    a, b = pair
    x, y = _opponent(a, (64, 0, 20)), _opponent(b, (40, 30, 0))
    mid = interpolate(x, y, 0.5, small_ensemble)
    assert mid.n_coeffs.sum() == 64 + 30 + 20
    small = interpolate(x, y, 0.5, small_ensemble, n_coeffs=10)
    assert small.n_coeffs.sum() == 30
    kept = np.concatenate(small.values)
    full = interpolate(x, y, 0.5, small_ensemble, n_coeffs=int(np.prod(SMALL)))
    alls = np.sort(np.abs(np.concatenate(full.values)))[::-1]
    np.testing.assert_allclose(np.sort(np.abs(kept))[::-1], alls[:30], rtol=1e-6)
    for v in small.values:
        assert np.all(np.diff(np.abs(v)) <= 0)
    # rgb A, opponent B: per channel, B's mean count standing for its count
    rgb = interpolate(a, y, 0.5, small_ensemble)
    assert rgb.basis == "rgb" and rgb.n_coeffs.tolist() == [64, 64, 64]
    assert interpolate(a, y, 0.5, small_ensemble, n_coeffs=7).n_coeffs.tolist() == [7] * 3


def test_cli_blend(pair, small_ensemble, tmp_path):
    a, b = pair
    ens = small_ensemble.save(tmp_path / "e.npz")
    pa, pb = save_sbrdf(tmp_path / "a.sbrdf", a), save_sbrdf(tmp_path / "b.sbrdf", b)
    out = tmp_path / "ab.sbrdf"
    assert main(["blend", str(pa), str(pb), "--alpha", "0.3", "-o", str(out),
                 "--ensemble", str(ens)]) == 0
    assert load_sbrdf(out, small_ensemble).name.endswith("@0.3")


def test_level_blends_take_the_geometric_blend_of_the_gains(small_ensemble):
    """Blending two materials coded in a level transform: the coefficients blend as in
    the other transforms, and the gain 1/L blends geometrically (ln(rho / L) blends
    linearly where the logarithm dominates): the endpoints are the materials themselves."""
    a, b = (encode(load_brdf(f"mitsuba:{n}", shape=SMALL), small_ensemble, 64,
                   transform="log-level") for n in ("au-ggx-0.25", "plastic-blue-ggx-0.2"))
    assert a.gain != b.gain
    for alpha in (0.0, 0.3, 1.0):
        mid = interpolate(a, b, alpha, small_ensemble, n_coeffs=int(np.prod(SMALL)))
        assert mid.transform == "log-level"
        assert mid.gain == pytest.approx(a.gain ** (1 - alpha) * b.gain ** alpha, rel=1e-6)
    end = interpolate(a, b, 1.0, small_ensemble, n_coeffs=int(np.prod(SMALL)))
    want = b.decode(small_ensemble)
    np.testing.assert_allclose(end.decode(small_ensemble).values[want.valid],
                               want.values[want.valid], rtol=1e-3,
                               atol=1e-4 * float(want.values.max()))


def test_lobe_transforms_blend_their_lobes(small_ensemble):
    """In a lobe transform the blend's lobe is the lobes' blend (roughness geometric, kd
    and ks linear, float16), and the ends are the two materials: ``a`` itself, ``b`` in
    ``a``'s dictionaries (exact with a full budget); between them each channel's energy
    lies between the ends'."""
    a, b = (_encode(load_brdf(f"mitsuba:{n}", shape=SMALL), small_ensemble, 64,
                    transform="log-lobe-cosine") for n in ("au-ggx-0.25", "plastic-blue-ggx-0.2"))
    full = int(np.prod(SMALL))
    valid = a.decode(small_ensemble).valid
    ends = [m.decode(small_ensemble).values[valid] for m in (a, b)]
    assert interpolate(a, b, 0.0, small_ensemble).lobe == a.lobe
    np.testing.assert_allclose(interpolate(a, b, 0.0, small_ensemble).decode(
        small_ensemble).values[valid], ends[0], rtol=1e-4, atol=1e-6)
    one = interpolate(a, b, 1.0, small_ensemble, n_coeffs=full)
    assert one.lobe == b.lobe and one.gain == b.gain
    np.testing.assert_allclose(one.decode(small_ensemble).values[valid], ends[1], rtol=1e-3,
                               atol=1e-5)
    mid = interpolate(a, b, 0.5, small_ensemble, n_coeffs=full)
    assert mid.lobe[0] == pytest.approx(np.sqrt(a.lobe[0] * b.lobe[0]), rel=1e-3)
    assert mid.lobe[1:] == pytest.approx(0.5 * (np.array(a.lobe[1:]) + b.lobe[1:]),
                                         rel=1e-3, abs=1e-6)
    energy = [np.sum(v, axis=0) for v in (*ends, mid.decode(small_ensemble).values[valid])]
    assert np.all(energy[2] > 0.5 * np.minimum(energy[0], energy[1]))
    assert np.all(energy[2] < 2.0 * np.maximum(energy[0], energy[1]))


def test_floor_transforms_blend_their_floors(small_ensemble):
    """In a floor transform each end keeps its own floor and the blend between them has
    the floors' linear blend (float16), with which it decodes."""
    a, b = (dataclasses.replace(
        _encode(load_brdf(f"mitsuba:{n}", shape=SMALL), small_ensemble, 64,
                transform="log-lobe-floor"), floor=f)
        for n, f in (("au-ggx-0.25", FLOORS[2]), ("plastic-blue-ggx-0.2", 0.75)))
    assert interpolate(a, b, 0.0, small_ensemble).floor == FLOORS[2]
    assert interpolate(a, b, 1.0, small_ensemble).floor == 0.75
    mid = interpolate(a, b, 0.5, small_ensemble)
    assert mid.floor == float(np.float16(0.5 * (FLOORS[2] + 0.75)))
    dec = mid.decode(small_ensemble).values
    plain = dataclasses.replace(mid, floor=0.0).decode(small_ensemble).values
    cut = np.float32(mid.floor / mid.gain)
    assert ((plain > 0) & (plain < cut)).any()
    np.testing.assert_array_equal(dec, np.where(plain < cut, 0.0, plain))
