import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.cli import main
from sparse_brdf.model.encode import encode
from sparse_brdf.model.interpolate import interpolate
from sparse_brdf.model.sbrdf import load_sbrdf, save_sbrdf
from sparse_brdf.sources.load import load_brdf


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


def test_cli_blend(pair, small_ensemble, tmp_path):
    a, b = pair
    ens = small_ensemble.save(tmp_path / "e.npz")
    pa, pb = save_sbrdf(tmp_path / "a.sbrdf", a), save_sbrdf(tmp_path / "b.sbrdf", b)
    out = tmp_path / "ab.sbrdf"
    assert main(["blend", str(pa), str(pb), "--alpha", "0.3", "-o", str(out),
                 "--ensemble", str(ens)]) == 0
    assert load_sbrdf(out, small_ensemble).name.endswith("@0.3")
