"""Symmetric references: a source averaged over the mirror phi_d -> -phi_d and
reciprocity phi_d -> phi_d + pi, as an isotropic BRDF is."""

from __future__ import annotations

import numpy as np
import pytest

import sparse_brdf as sb
from conftest import SMALL
from sparse_brdf.brdf import BRDF
from sparse_brdf.coords import geometric_valid, grid_angles
from sparse_brdf.mlp import LAYER_SIZES, evaluate, network_inputs, save_keras, tabulate
from sparse_brdf.sources.load import symmetrize_table

pytestmark = pytest.mark.numerics


def _mirror(n3: int) -> np.ndarray:
    return (-np.arange(n3)) % n3


def _lopsided_network(seed: int = 3):
    """A random network whose difference-vector weights break both symmetries."""
    rng = np.random.default_rng(seed)
    layers = []
    for a, b in zip(LAYER_SIZES[:-1], LAYER_SIZES[1:], strict=True):
        layers.append((rng.normal(0, 0.6, (a, b)).astype(np.float32),
                       rng.normal(0, 0.1, b).astype(np.float32)))
    layers[0][0][3:5] *= 4.0  # dx, dy matter a lot
    layers[-1][1][:] -= 2.0  # values near 0.1-1 per sr
    return layers


def close(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal up to float32 rounding of the table's scale: 1e-5 relative, or 1e-6 of the
    largest value. The network is evaluated at a bin's inputs and at its mirror bin's,
    which differ in their last bits (sin and cos of phi_d and of pi - phi_d, rounded by
    numpy's SIMD kernels, differently per CPU); where this lopsided network's output is
    a small difference of large terms, that moves a value of 2e-6 by 6 % on an AMD EPYC
    with AVX-512, 1e-10 of the largest value."""
    return np.allclose(a, b, rtol=1e-5, atol=1e-6 * float(np.abs(b).max()))


def test_symmetric_tabulation_is_mirror_invariant_and_the_mean_of_four():
    layers = _lopsided_network()
    raw, valid = tabulate(layers, SMALL)
    sym, valid2 = tabulate(layers, SMALL, symmetric=True)
    assert np.array_equal(valid, valid2)
    m = _mirror(SMALL[2])
    assert close(sym, sym[:, :, m])  # mirror o reciprocity
    assert not np.allclose(raw, raw[:, :, m], rtol=1e-2)  # the raw network is lopsided
    # the mean of the network at the four sign combinations of (dx, dy), bin by bin
    th, td, pd = grid_angles(SMALL)
    x = network_inputs(th[valid], td[valid], pd[valid])
    four = [evaluate(layers, x * np.array([1, 1, 1, sx, sy, 1], np.float32))
            for sx in (1, -1) for sy in (1, -1)]
    assert close(sym[valid], np.mean(four, axis=0))
    assert np.all(sym[~valid] == 0)


def test_load_brdf_symmetrizes_networks_by_default_and_tables_on_request(tmp_path):
    path = save_keras(tmp_path / "lopsided.h5", _lopsided_network())
    m = _mirror(180)
    sym = sb.load_brdf(path)
    raw = sb.load_brdf(path, symmetrize=False)
    assert sym.meta["symmetric"] and not raw.meta["symmetric"]
    v = sym.valid
    assert close(sym.values, sym.values[:, :, m])
    assert np.abs(raw.values - raw.values[:, :, m])[v].max() > 0.05 * raw.values[v].max()
    # a table is kept as it is unless asked
    table = sb.write_merl(tmp_path / "raw.binary", raw)
    assert np.array_equal(sb.load_brdf(table).values, sb.read_merl(table).values)
    mirrored = sb.load_brdf(table, symmetrize=True)
    assert np.allclose(mirrored.values, 0.5 * (raw.values + raw.values[:, :, m]), atol=1e-6)
    assert np.allclose(mirrored.values, mirrored.values[:, :, m], atol=1e-7)


def test_symmetrize_table_keeps_a_symmetric_table():
    rng = np.random.default_rng(0)
    valid = geometric_valid(SMALL)
    v = rng.uniform(0.01, 1, (*SMALL, 3)).astype(np.float32)
    v = 0.5 * (v + v[:, :, _mirror(SMALL[2])])
    v[~valid] = 0
    once = symmetrize_table(BRDF(values=v, valid=valid, name="s"))
    assert np.allclose(once.values, v, atol=1e-7)
    assert np.array_equal(once.valid, valid)


@pytest.mark.render
def test_a_symmetrised_source_renders_mirror_symmetric(tmp_path):
    """The one-light sphere is mirror-symmetric about the plane through the camera, the
    light and the sphere's centre (the image's horizontal midline): a symmetrised table
    renders symmetric there, a lopsided one does not."""
    from sparse_brdf.evaluation.render import render_scene

    raw = sb.load_brdf(save_keras(tmp_path / "lopsided.h5", _lopsided_network()),
                       symmetrize=False)
    files = {"raw": sb.write_merl(tmp_path / "raw.binary", raw),
             "sym": sb.write_merl(tmp_path / "sym.binary", symmetrize_table(raw))}

    def asymmetry(path) -> float:
        img = render_scene("sphere_light.xml", {"material": str(path)}, spp=64, res=48,
                           params={"lightangle": 50},
                           tabulated_options={"sampling": "cosine"})
        return float(np.abs(img - img[::-1]).sum() / img.sum())

    sym, lop = asymmetry(files["sym"]), asymmetry(files["raw"])
    # what is left: pixel jitter, and the nearest-bin lookup (bins at their lower edges,
    # so phi_d and pi - phi_d can fall one bin apart); measured 0.019 against 1.15
    assert sym < 0.04
    assert lop > 10 * sym


def test_the_command_line_symmetrizes_unless_told_not_to(tmp_path):
    from sparse_brdf.cli import main

    net = save_keras(tmp_path / "lopsided.h5", _lopsided_network())
    a, b = tmp_path / "sym.binary", tmp_path / "raw.binary"
    assert main(["convert", str(net), str(a)]) == 0
    assert main(["convert", str(net), str(b), "--no-symmetrize"]) == 0
    sym, raw = sb.read_merl(a).values, sb.read_merl(b).values
    assert close(sym, sym[:, :, _mirror(180)])
    assert np.array_equal(raw, sb.load_brdf(net, symmetrize=False).values)
    assert not np.allclose(raw, sym, rtol=1e-2)
