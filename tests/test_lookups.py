"""The numpy lookups of the uploaded decoder data (sparse_brdf.decoders.lookups): one point
at a time as vectorised, interpolated as the trilinear blend of the bins' values, and the
scalar variants' sparse_brdf (which evaluates with them) equal to the LLVM one."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.decoders.buffers import colour_mix
from sparse_brdf.decoders.layouts import (
    channel_terms,
    grouped_channels,
    grouped_layout,
    strict_channel,
)
from sparse_brdf.decoders.lookups import GroupedLookup, StrictLookup

mi = pytest.importorskip("mitsuba")
pytest.importorskip("drjit")

from test_plugin import (  # noqa: E402
    DECODER_OPTIONS,
    as_opponent,
    eval_brdf,
    make_exact_material,
    random_pairs,
    use_variant,
)

from mitsuba_plugin.kernels import (  # noqa: E402
    Ops,
    VariantNamespace,
    bin_weight_from_cos,
    point_rho_from_cos,
    rho_from_x,
)

pytestmark = pytest.mark.numerics


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    """An rgb material on the small grid with its ensemble, and its coefficients read as
    an opponent-basis material of unequal counts (one channel empty)."""
    folder = tmp_path_factory.mktemp("lookups")
    mat = make_exact_material(folder, n_coeffs=150)
    ens = Ensemble.load(mat["ensemble"])
    opp = as_opponent(load_sbrdf(mat["sbrdf"], ens), (90, 31, 0))
    return {"ensemble": mat["ensemble"], "ens": ens, "rgb": mat["sbrdf"],
            "opponent": str(save_sbrdf(folder / "opponent.sbrdf", opp))}


def _lookups(model, ens, mix):
    """The grouped lookups of both layouts and the strict one of ``model``."""
    chans = grouped_channels(model, ens)
    out = {kind: GroupedLookup(grouped_layout(chans, tuple(model.shape), kind), chans[0], mix)
           for kind in ("union", "slots")}
    out["strict"] = StrictLookup(
        [strict_channel(*channel_terms(model, ens, c)) for c in range(3)], mix)
    return out


@pytest.mark.parametrize("basis", ["rgb", "opponent"])
def test_point_and_linear_agree_with_eval(materials, basis):
    ens = materials["ens"]
    model = load_sbrdf(materials[basis], ens)
    rng = np.random.default_rng(3)
    n = 40
    bins = tuple(rng.integers(0, s, n) for s in SMALL)
    for mix in (None, colour_mix(model.basis)):
        for name, lk in _lookups(model, ens, mix).items():
            ref = lk.eval(bins)
            got = np.array([lk.point(*(int(b[m]) for b in bins)) for m in range(n)])
            np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5, err_msg=name)
            # interpolated: the trilinear blend of the eight corners' values
            for _ in range(5):
                i0 = [int(rng.integers(0, s - 1)) for s in SMALL]
                t = rng.uniform(0, 1, 3)
                lin = tuple((a, a + 1, float(w)) for a, w in zip(i0, t, strict=True))
                corners = np.array([[i0[0] + da, i0[1] + db, i0[2] + dc] for da in (0, 1)
                                    for db in (0, 1) for dc in (0, 1)])
                wts = np.array([(t[0] if da else 1 - t[0]) * (t[1] if db else 1 - t[1])
                                * (t[2] if dc else 1 - t[2]) for da in (0, 1)
                                for db in (0, 1) for dc in (0, 1)])
                want = wts @ lk.eval(tuple(corners.T))
                np.testing.assert_allclose(lk.point_linear(lin), want, rtol=1e-5,
                                           atol=1e-5, err_msg=name)
    # the mix folded in gives the basis's transformed R, G, B from the coded channels
    if basis == "opponent":
        lk = _lookups(model, ens, None)["union"]
        mixed = _lookups(model, ens, colour_mix("opponent"))["union"]
        coded = lk.eval(bins)[:, :3]
        want = coded @ np.array(colour_mix("opponent")).T
        np.testing.assert_allclose(mixed.eval(bins)[:, :3], want, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("basis", ["rgb", "opponent"])
@pytest.mark.parametrize("interpolate", [False, True])
def test_scalar_plugin_equals_llvm(materials, basis, interpolate):
    """The scalar variants' numpy lookups against the LLVM kernels, every decoder and
    layout, at random pairs inside bins (away from their edges, where float32 and double
    angles could pick different bins)."""
    wi, wo, _ = random_pairs(SMALL, 120, np.random.default_rng(8), min_h=1)
    out = {}
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        use_variant(variant)
        for opts in DECODER_OPTIONS:
            b = mi.load_dict({"type": "sparse_brdf", "filename": materials[basis],
                              "ensemble": materials["ensemble"], "interpolate": interpolate,
                              **opts})
            out[variant, opts.get("layout", "strict")] = eval_brdf(b, wi, wo)
    # interpolation weights see the angles in float32 (LLVM) or double (scalar)
    rtol = 1e-4 if interpolate else 1e-5
    for key in ("union", "slots", "strict"):
        ref = out["llvm_ad_rgb", key]
        assert ref.max() > 0
        np.testing.assert_allclose(out["scalar_rgb", key], ref, rtol=rtol,
                                   atol=1e-6 * ref.max(), err_msg=key)



def test_scalar_inverse_transform_survives_overflow():
    """Past what a double's exp holds, the scalar inverse transform caps X (the value is
    inf once stored as float32, as in the kernel) instead of raising."""
    use_variant("scalar_rgb")
    ops = Ops(VariantNamespace(mi.scalar_rgb))
    out = rho_from_x(ops, [800.0, 1.0, -5.0], 1.0, 0.5)
    assert np.all(np.isfinite(out[1:])) and out[2] == 0.0
    np.testing.assert_allclose(out[1], 2 * np.expm1(1.0))
    assert np.isinf(np.array(mi.Color3f(*out))[0])
    assert list(rho_from_x(ops, [800.0, 1.0, 2.0], 0.0, 1.0)) == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("c", [-0.3, 0.0, 0.004, 0.2, 1.0, 1.3])
@pytest.mark.parametrize("use_cos", [True, False])
def test_scalar_one_bin_path_matches_weight_then_inverse(c, use_cos):
    """The scalar variants' one-call path of a bin (weight from cos_i cos_o, then the
    inverse transform with the transform's scale) gives what the two general steps give,
    including 0 at invalid bins and the weight's clip at 0.01 and 1."""
    use_variant("scalar_rgb")
    ops = Ops(VariantNamespace(mi.scalar_rgb))
    xs = [2.5, 0.01, -0.2]
    w, ok = bin_weight_from_cos(c, 1.0 if use_cos else 0.0)
    expect = rho_from_x(ops, xs, 1.0 if ok else 0.0, w * 300.0)
    got = point_rho_from_cos(*xs, c, use_cos, 300.0)
    np.testing.assert_allclose(got, expect, rtol=1e-12)
    if c <= 0.0:
        assert list(got) == [0.0, 0.0, 0.0]
    else:
        wt = min(max(c, 0.01), 1.0) if use_cos else 1.0
        np.testing.assert_allclose(got[0], np.expm1(2.5) / (300.0 * wt), rtol=1e-12)
        assert got[2] == 0.0
