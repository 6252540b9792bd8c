"""The ``neural_brdf`` Mitsuba plugin (a Neural-BRDF network evaluated at the direction
pair) and saving trained networks in the published Keras layout (NeuralFit.save)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.compared.neural import NeuralFit, train_nbrdf
from sparse_brdf.coords import dirs_to_angles
from sparse_brdf.errors import PluginError
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.mlp import evaluate, network_inputs, tabulate
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.nbrdf import read_nbrdf_weights

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from test_variants import CPU_VARIANTS, render, wrapped_scene  # noqa: E402

import mitsuba_plugin  # noqa: E402
from mitsuba_plugin.registration import variant_kind  # noqa: E402

#: A glossy shipped network (a specular peak, so lobe sampling has a lobe to fit).
GLOSSY = str(DEMO_MATERIALS_DIR / "red-specular-plastic.h5")
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


def use(variant: str) -> str:
    if variant not in mi.variants():
        pytest.skip(f"Mitsuba variant {variant} is not in this installation")
    set_variant(variant)
    mitsuba_plugin.register()
    return variant


def random_pairs(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """``n`` float32 direction pairs, both in the upper hemisphere, (n, 3) each."""
    v = np.random.default_rng(seed).standard_normal((2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0].astype(np.float32), v[1].astype(np.float32)


def bsdf_eval(bsdf, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``bsdf.eval`` (BRDF times cos_o) at the pairs, (n, channels), current variant."""
    ctx = mi.BSDFContext()
    if mi.variant().startswith("scalar"):
        out = []
        for a, b in zip(wi, wo, strict=True):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*map(float, a))
            out.append(np.array(bsdf.eval(ctx, si, mi.Vector3f(*map(float, b)))).ravel())
        return np.array(out, np.float64)
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(np.ascontiguousarray(wi.T))
    if "spectral" in mi.variant():
        si.wavelengths = type(si.wavelengths)(np.tile(np.float32([420, 510, 580, 660])[:, None],
                                             (1, len(wi))))
    f = np.array(bsdf.eval(ctx, si, mi.Vector3f(np.ascontiguousarray(wo.T))), np.float64)
    return f.reshape(-1, len(wi)).T


def numpy_brdf(layers, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The network's BRDF values at the pairs from mlp.py's numpy forward pass, (n, 3)."""
    th, td, pd = dirs_to_angles(wi.astype(np.float64), wo.astype(np.float64))
    return evaluate(layers, network_inputs(th, td, np.where(pd < 0, pd + np.pi, pd)))


def grey_layers():
    """The glossy network with its last layer's green column in all three outputs (a
    grey material)."""
    (k1, b1), (k2, b2), (k3, b3) = read_nbrdf_weights(GLOSSY)
    return [(k1, b1), (k2, b2), (np.repeat(k3[:, 1:2], 3, axis=1), np.repeat(b3[1:2], 3))]


# --------------------------------------------------------------------- saving networks


def test_saved_network_reads_back_bit_for_bit(tmp_path):
    """A trained network saved with NeuralFit.save reads back with the same bits, tabulates
    through load_brdf as the network itself, and overwrites atomically."""
    brdf = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    fit = train_nbrdf(brdf, epochs=1, n_samples=4096, batch_size=256, progress=False)
    path = fit.save(tmp_path / "red.h5")
    got = read_nbrdf_weights(path)
    assert len(got) == 3
    for (k, b), (k0, b0) in zip(got, fit.layers, strict=True):
        assert k.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(k, k0)
        np.testing.assert_array_equal(b, b0)
    table = load_brdf(str(path), symmetrize=False)
    values, valid = tabulate(fit.layers)
    np.testing.assert_array_equal(table.values, values)
    np.testing.assert_array_equal(table.valid, valid)
    # by default a network is tabulated symmetrised (mirror and reciprocity)
    np.testing.assert_array_equal(load_brdf(str(path)).values,
                                  tabulate(fit.layers, symmetric=True)[0])
    # the same layout as the shipped (Keras-written) files: names and attributes
    import h5py  # lazy: as in the library

    with h5py.File(path, "r") as f, h5py.File(GLOSSY, "r") as ref:
        assert list(f.attrs["layer_names"]) == list(ref.attrs["layer_names"])
        for name in ("dense_1", "dense_2", "dense_3"):
            assert list(f[name].attrs["weight_names"]) == list(ref[name].attrs["weight_names"])
            assert set(f[name][name]) == set(ref[name][name])
    other = NeuralFit(grey_layers()).save(path)  # replaces the file
    np.testing.assert_array_equal(read_nbrdf_weights(other)[2][0], grey_layers()[2][0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["red.h5"]


def test_save_refuses_a_wrong_number_of_layers(tmp_path):
    with pytest.raises(ValueError, match="3 layers"):
        NeuralFit(grey_layers()[:2]).save(tmp_path / "two.h5")
    assert not (tmp_path / "two.h5").exists()


# ------------------------------------------------------------------------------ the BSDF


@pytest.mark.numerics
@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_eval_is_the_numpy_network_times_cos_o(variant):
    """eval at 300 direction pairs is mlp.py's forward pass times cos_o (float32
    arithmetic, fused multiply-adds in another order); 0 below the horizon."""
    use(variant)
    layers = read_nbrdf_weights(GLOSSY)
    bsdf = mi.load_dict({"type": "neural_brdf", "filename": GLOSSY})
    assert bsdf.memory_bytes == 2700 and bsdf.widths == (21, 21, 3)
    wi, wo = random_pairs(300)
    want = numpy_brdf(layers, wi, wo) * wo[:, 2:3]
    assert np.count_nonzero(want) > 0.9 * want.size
    np.testing.assert_allclose(bsdf_eval(bsdf, wi, wo), want, rtol=2e-4, atol=1e-5)
    below = wo * np.float32([1, 1, -1])
    assert np.all(bsdf_eval(bsdf, wi[:20], below[:20]) == 0.0)


def test_grey_network_in_spectral_and_mono(tmp_path):
    """A grey network's spectrum is flat at its RGB value (the grey's closed-form
    upsampling), polarized or not; a coloured one's mono value is its luminance."""
    path = str(NeuralFit(grey_layers()).save(tmp_path / "grey.h5"))
    wi, wo = random_pairs(200, seed=4)
    want = numpy_brdf(grey_layers(), wi, wo)[:, :1] * wo[:, 2:3]
    assert np.count_nonzero(want) > 0.9 * want.size
    for variant in ("llvm_ad_spectral", "llvm_ad_spectral_polarized"):
        use(variant)
        f = bsdf_eval(mi.load_dict({"type": "neural_brdf", "filename": path}), wi, wo)
        if variant.endswith("polarized"):  # a depolarizer: the [0, 0] entries
            f = f[:, : f.shape[1] // 16]
        np.testing.assert_allclose(f, np.repeat(want, 4, axis=1), rtol=1e-4, atol=1e-6)
    use("llvm_ad_mono")
    layers = read_nbrdf_weights(GLOSSY)
    mono = bsdf_eval(mi.load_dict({"type": "neural_brdf", "filename": GLOSSY}), wi, wo)
    lum = (numpy_brdf(layers, wi, wo) * wo[:, 2:3]) @ LUMINANCE
    np.testing.assert_allclose(mono[:, 0], lum, rtol=2e-4, atol=1e-5)


@pytest.mark.render
@pytest.mark.parametrize("variant", CPU_VARIANTS)
def test_renders_in_every_cpu_variant(variant):
    """Three spheres (twosided, blendbsdf, mask; cosine and lobe sampling) under the
    studio map render finite, lit images in each CPU variant."""
    use(variant)
    res, spp = (6, 2) if variant.startswith("scalar") else (16, 4)

    def make(decoder=None, **opts):  # the scene's decoder option is sparse_brdf's
        return {"type": "neural_brdf", "filename": GLOSSY, **opts}

    img = render(wrapped_scene(make, res, spp), spp)
    kind, _ = variant_kind(variant)
    assert img.shape[:2] == (res, 2 * res)
    assert img.shape[-1] == (1 if kind == "mono" else 3)
    assert np.isfinite(img).all() and img.mean() > 1e-3


@pytest.mark.numerics
def test_lobe_is_the_tabulated_networks_lobe():
    """Lobe sampling fits the same lobe as tabulated_brdf reading the same file."""
    use("llvm_ad_rgb")
    n = mi.load_dict({"type": "neural_brdf", "filename": GLOSSY, "sampling": "lobe"})
    t = mi.load_dict({"type": "tabulated_brdf", "filename": GLOSSY, "sampling": "lobe"})
    assert n.lobe_exponent > 1.0
    assert (n.lobe_exponent, n.lobe_prob) == (t.lobe_exponent, t.lobe_prob)


def test_bad_files_fail_at_load_in_one_line(tmp_path):
    """A missing, a non-HDF5 and a wrongly shaped file: a PluginError naming the plugin
    and the file, in one line."""
    use("llvm_ad_rgb")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not an HDF5 file\n" * 4)
    wide = tmp_path / "wide.h5"
    rng = np.random.default_rng(0)
    NeuralFit([(rng.random((6, 4), np.float32), np.zeros(4, np.float32)),
               (rng.random((4, 4), np.float32), np.zeros(4, np.float32)),
               (rng.random((4, 5), np.float32), np.zeros(5, np.float32))]).save(wide)
    for name in ("nope.h5", "junk.h5", "wide.h5"):
        with pytest.raises(Exception) as info:
            mi.load_dict({"type": "neural_brdf", "filename": str(tmp_path / name)})
        last = str(info.value).strip().splitlines()[-1]
        assert last.startswith(f"{PluginError.__name__}: neural_brdf: cannot load "), last
        assert name in last, last
    with pytest.raises(Exception, match="sampling"):
        mi.load_dict({"type": "neural_brdf", "filename": GLOSSY, "sampling": "ggx"})
