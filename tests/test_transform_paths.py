"""Each transform's weight and inverse on its three paths, against each other: numpy
(:mod:`sparse_brdf.transforms`, :func:`sparse_brdf.decoders.buffers.bin_weight`), the
Dr.Jit kernels (:mod:`mitsuba_plugin.kernels`, LLVM) and the scalar variants' one-point
twins (``point_weight``, ``point_rho_from_cos``). Parametrized over
:data:`sparse_brdf.transforms.TRANSFORMS`, so a transform added later is covered."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import LOBE, SMALL
from sparse_brdf import transforms as tf
from sparse_brdf.coords import bin_angles, cos_io
from sparse_brdf.decoders.buffers import bin_weight as np_bin_weight
from sparse_brdf.transforms import (
    TRANSFORMS,
    forward,
    has_lobe,
    inverse_at_bins,
    material_scale,
    per_material,
    uses_cosine,
    weight,
)
from sparse_brdf.transforms import scale as transform_scale

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from mitsuba_plugin.kernels import (  # noqa: E402
    Ops,
    VariantNamespace,
    bin_weight,
    lobe_d_at,
    lobe_x,
    point_rho_from_cos,
    point_rho_lobe,
    point_weight,
    rho_from_x,
    shared_shape,
)

pytestmark = pytest.mark.numerics


def _gain(transform: str) -> float:
    """A material's gain for the level transforms (float32-exact, not 1), else 1."""
    return 7.25 if per_material(transform) else 1.0


@pytest.fixture(scope="module")
def bins_and_x():
    """Valid bins of the small grid (both directions above the horizon), their
    ``cos_i cos_o`` and transformed values X, small (|X| < 0.1) and large."""
    rng = np.random.default_rng(5)
    i, j, k = (rng.integers(0, n, 4000) for n in SMALL)
    th, td, pd = bin_angles(SMALL)
    ci, co = cos_io(th[i], td[j], pd[k])
    c = (ci * co).astype(np.float64)
    ok = c > 0
    x = np.concatenate([rng.uniform(-0.1, 0.1, 2000), rng.uniform(-0.5, 4.0, 2000)])
    return (i[ok], j[ok], k[ok]), c[ok], x[ok].astype(np.float32)


@pytest.mark.parametrize("transform", TRANSFORMS)
def test01_weight_on_three_paths(transform, bins_and_x):
    _weight_on_three_paths(transform, bins_and_x)


def _weight_on_three_paths(transform, bins_and_x):
    bins, c, _ = bins_and_x
    gain = _gain(transform)
    s = material_scale(transform, gain)
    grid = weight(transform, SMALL, gain)
    w_np = np_bin_weight(*bins, SMALL, transform, gain)
    np.testing.assert_array_equal(w_np, grid[bins] if isinstance(grid, np.ndarray)
                                  else np.full(w_np.shape, grid, np.float32))
    ops = Ops(VariantNamespace(mi.llvm_ad_rgb))
    u = mi.llvm_ad_rgb.UInt32
    w_dr, valid = bin_weight(ops, shared_shape(ops, SMALL), *(u(b) for b in bins),
                             ops.f(1.0 if uses_cosine(transform) else 0.0))
    assert np.all(np.array(valid))
    # the kernels take cos_i cos_o from float32 angle tables, numpy in float64: they
    # agree to float32 rounding, the formula is the same
    np.testing.assert_allclose(np.array(w_dr) * s, w_np, rtol=1e-5)
    w_pt = [(point_weight(float(v)) if uses_cosine(transform) else 1.0) * s for v in c]
    np.testing.assert_allclose(w_pt, w_np, rtol=1e-6)


@pytest.mark.parametrize("transform", TRANSFORMS)
def test02_inverse_on_three_paths(transform, bins_and_x):
    _inverse_on_three_paths(transform, bins_and_x)


def _inverse_on_three_paths(transform, bins_and_x):
    bins, c, x = bins_and_x
    gain = _gain(transform)
    lobe = LOBE if has_lobe(transform) else None
    x3 = np.stack([x, 0.5 * x, -x])  # R, G, B: the lobe's channels differ
    rho_np = inverse_at_bins(x3, transform, bins, SMALL, gain, lobe)
    s = material_scale(transform, gain)
    cos_on = uses_cosine(transform)
    ops = Ops(VariantNamespace(mi.llvm_ad_rgb))
    u, f = mi.llvm_ad_rgb.UInt32, mi.llvm_ad_rgb.Float
    shape = shared_shape(ops, SMALL)
    ub = tuple(u(b) for b in bins)
    w, ok = bin_weight(ops, shape, *ub, ops.f(1.0 if cos_on else 0.0))
    xs = [f(v) for v in x3]
    if lobe is not None:  # the kernels' lobe, from opaque scalars
        lf = [ops.f(v) for v in lobe]
        xs = lobe_x(ops, xs, w * s, lobe_d_at(ops, shape, ub, None, lf[0]), lf)
    rho_dr = np.array(rho_from_x(ops, xs, dr.select(ok, 1.0, 0.0), w * s))
    pt_ops = Ops(VariantNamespace(mi.scalar_rgb))
    pt_shape = shared_shape(pt_ops, SMALL)
    rho_pt = []
    for n, cv in enumerate(c):
        v = [float(a) for a in x3[:, n]]
        if lobe is None:
            rho_pt.append(point_rho_from_cos(*v, float(cv), cos_on, s))
            continue
        rho_pt.append(point_rho_lobe(pt_ops, pt_shape, v, float(cv), cos_on, s, lobe,
                                     int(bins[0][n])))
    # a lobe material's dim values are a float32 ratio to its bright lobe: their absolute
    # error scales with the lobe (here 1e-10 of the largest value)
    atol = 1e-7 if lobe is None else 1e-10 * float(np.abs(rho_np).max())
    for other in (rho_dr, np.array(rho_pt).T):
        np.testing.assert_allclose(other, rho_np, rtol=1e-5, atol=atol)
    # and the inverse undoes the forward transform on the grid
    rho = np.abs(x)[:1].repeat(3 * int(np.prod(SMALL))).reshape(3, *SMALL)
    t = forward(rho, transform, gain=gain, lobe=lobe)
    # (a lobe transform's float32 ratio resolves a value 40x below its lobe's peak to
    # a few 1e-5)
    np.testing.assert_allclose(
        inverse_at_bins(t[(slice(None), *bins)], transform, bins, SMALL, gain, lobe),
        rho[(slice(None), *bins)], rtol=1e-5 if lobe is None else 5e-5)


def test03_a_transform_added_to_the_table_reaches_every_path(bins_and_x, monkeypatch):
    """The transforms are data (:data:`~sparse_brdf.transforms.TRANSFORM_SPECS`): one
    more row, with a scale no transform has, is served by every path without code."""
    extra = tf.TransformSpec("log-test-cosine", 7.0, True)
    specs = (*tf.TRANSFORM_SPECS, extra)
    monkeypatch.setattr(tf, "TRANSFORM_SPECS", specs)
    monkeypatch.setattr(tf, "_SPECS", {t.name: t for t in specs})
    monkeypatch.setattr(tf, "TRANSFORMS", tuple(t.name for t in specs))
    assert transform_scale(extra.name) == 7.0 and uses_cosine(extra.name)
    _weight_on_three_paths(extra.name, bins_and_x)
    _inverse_on_three_paths(extra.name, bins_and_x)
