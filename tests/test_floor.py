"""The floor transforms: their inverse gives 0 below a material's floor f L, and the
encoder chooses f per material (``sparse_brdf.coding.floor``)."""

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.brdf import BRDF
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.floor import TAIL_REACH, choose_floor, tail_errors
from sparse_brdf.coords import geometric_valid
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.transforms import (
    FLOORS,
    LOBE_TRANSFORMS,
    TRANSFORMS,
    check_floor,
    fit_base_lobe,
    floor_value,
    forward,
    has_floor,
    inverse,
    inverse_at_bins,
    material_gain,
)


def test_floor_transforms_are_the_lobe_pair_with_a_floor():
    """The floor pair codes as the lobe pair (forward is the same), and is the pair
    encode(transform="lobe") and "auto" over the default ensemble choose between."""
    assert LOBE_TRANSFORMS == ("log-lobe-floor", "log-lobe-floor-cosine")
    assert [t for t in TRANSFORMS if has_floor(t)] == list(LOBE_TRANSFORMS)
    brdf = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    rho, valid = brdf.channel_first(), brdf.valid
    for plain, floored in (("log-lobe", "log-lobe-floor"),
                           ("log-lobe-cosine", "log-lobe-floor-cosine")):
        np.testing.assert_array_equal(forward(rho, plain, valid), forward(rho, floored, valid))


def test_inverse_gives_zero_below_the_floor_only():
    """Values below f L (L = 1 / gain) decode as 0, the others as without a floor, in
    the table's inverse and in the inverse at bins; floor 0 changes nothing."""
    brdf = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    rho, valid = brdf.channel_first(), brdf.valid
    gain, lobe = material_gain("log-lobe-floor", rho, valid), fit_base_lobe(rho, valid)
    t = forward(rho, "log-lobe-floor", valid, gain, lobe)
    plain = inverse(t, "log-lobe", gain, lobe)
    f = 0.5  # float16-exact, high enough to cut G and B
    cut = np.float32(floor_value(f, gain))
    got = inverse(t, "log-lobe-floor", gain, lobe, f)
    low = plain < cut
    assert 0.05 < low[:, valid].mean() < 0.9
    np.testing.assert_array_equal(got, np.where(low, 0.0, plain))
    np.testing.assert_array_equal(inverse(t, "log-lobe-floor", gain, lobe, 0.0), plain)
    bins = np.nonzero(valid)
    at = inverse_at_bins(t[:, bins[0], bins[1], bins[2]], "log-lobe-floor", bins, SMALL,
                         gain, lobe, f)
    np.testing.assert_array_equal(at, got[:, bins[0], bins[1], bins[2]])


def test_check_floor_refuses_what_a_file_cannot_hold():
    assert check_floor("log-lobe-floor", FLOORS[3]) == FLOORS[3]
    assert check_floor("log-lobe", 0.0) == 0.0
    with pytest.raises(ValueError, match="has no floor"):
        check_floor("log-lobe", 0.1)
    for bad in (-0.001, 1.0, np.nan, np.inf, 0.1):  # 0.1 is not a float16 value
        with pytest.raises(ValueError, match="a floor is a float16 value"):
            check_floor("log-lobe-floor", bad)


def test_tail_errors_equal_their_definition():
    """The sorted, cumulative computation equals the sum of |ln((d + e) / (r + e))| over
    every value, each floor's decode made in full, up to the values no floor changes."""
    rng = np.random.default_rng(2)
    gain = 4.0
    ref = np.exp(rng.uniform(-14, 2, 5000)).astype(np.float32) / gain
    ref[:300] = 0.0
    dec = (ref * np.exp(rng.normal(0, 0.2, ref.size)) + rng.uniform(0, 3e-3, ref.size)
           / gain).astype(np.float32)
    e = TAIL_REACH / gain
    full = []
    for f in FLOORS:
        d = np.where(dec < np.float32(floor_value(f, gain)), 0.0, dec).astype(np.float64)
        full.append(np.abs(np.log((d + e) / (ref.astype(np.float64) + e))).sum())
    full = np.array(full)
    got = tail_errors(ref, dec, gain)
    # the values above the largest floor add the same to every floor's full sum
    np.testing.assert_allclose(got - got[0], full - full[0], rtol=1e-9, atol=1e-6)
    assert choose_floor(ref, dec, gain) == FLOORS[int(np.argmin(full))]


def test_floor_is_zero_for_a_close_decode_and_cuts_noise_over_exact_zeros():
    """A decode equal to the material keeps floor 0; a material that is exactly 0 on
    part of its values, decoded with small positive errors there, gets the floor that
    removes them and keeps the values above."""
    rng = np.random.default_rng(5)
    gain = 1.0
    ref = np.exp(rng.uniform(-4, 3, 20000)).astype(np.float32)
    assert choose_floor(ref, ref.copy(), gain) == 0.0
    ref[:4000] = 0.0
    dec = ref.copy()
    dec[:4000] = rng.uniform(0, 2e-3, 4000)
    f = choose_floor(ref, dec, gain)
    assert f == FLOORS[4]  # 3e-3: above the noise, below every nonzero value
    assert (np.where(dec < floor_value(f, gain), 0, dec) == ref).all()


def test_encoder_chooses_a_floor_where_the_material_has_exact_zeros(small_ensemble):
    """A material that is 0 on a fifth of its bins (a mirror-like table's dark tail)
    gets a floor above 0 from the encoder in the lobe pair, and its decode is 0 on more of those
    bins than without it; the same material without zeros keeps floor 0."""
    brdf = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    m = encode(brdf, small_ensemble, n_bytes=900, transform="lobe")
    assert m.transform in LOBE_TRANSFORMS and m.floor == m.stats["floor"] == 0.0
    values = brdf.values.copy()
    rng = np.random.default_rng(0)
    zero = geometric_valid(SMALL) & (rng.random(SMALL) < 0.2)
    values[zero] = 0.0
    holed = BRDF(values, brdf.valid, name="holed")
    m = encode(holed, small_ensemble, n_bytes=900, transform="lobe")
    assert m.floor > 0.0 and m.stats["floor"] == m.floor
    without = type(m)(**{**m.__dict__, "floor": 0.0}).decode(small_ensemble).values
    got = m.decode(small_ensemble).values
    assert (got[zero] == 0).mean() > (without[zero] == 0).mean() + 0.1
