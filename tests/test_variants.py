"""The Mitsuba plugins in every CPU variant of the installed Mitsuba: rgb, mono and
spectral, polarized or not, scalar and LLVM; inside Mitsuba's wrappers; spectral
renders against rgb ones."""

from __future__ import annotations

import numpy as np
import pytest

from sparse_brdf.errors import PluginError
from sparse_brdf.metrics import render_snr
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.paths import SCENES_DIR

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from test_plugin import make_exact_material  # noqa: E402

import mitsuba_plugin  # noqa: E402
from mitsuba_plugin.registration import variant_kind  # noqa: E402

pytestmark = pytest.mark.numerics

#: Every variant of Mitsuba 3.9 that runs on the CPU.
CPU_VARIANTS = ("scalar_rgb", "scalar_spectral", "scalar_spectral_polarized", "llvm_ad_rgb",
                "llvm_ad_mono", "llvm_ad_mono_polarized", "llvm_ad_spectral",
                "llvm_ad_spectral_polarized")
STUDIO = str(SCENES_DIR / "envmaps" / "studio.exr")


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    """A coloured and a grey material on the small grid: each a sparse model with its own
    ensemble and that model's dense decode (its exact tabulated twin)."""
    out = {}
    for name in ("plastic-red-ggx-0.3", "plastic-grey-beckmann-0.12"):
        out[name] = make_exact_material(tmp_path_factory.mktemp(name), name, n_coeffs=200)
    # the coloured one in a level transform (its own gain, read by every variant's kernels)
    out["level"] = make_exact_material(tmp_path_factory.mktemp("level"), "plastic-red-ggx-0.3",
                                       n_coeffs=200, transform="log-level-cosine")
    # and in a lobe transform (its own lobe, mapped by every variant's kernels)
    out["lobe"] = make_exact_material(tmp_path_factory.mktemp("lobe"), "plastic-red-ggx-0.3",
                                      n_coeffs=200, transform="log-lobe-cosine")
    # and in a floor transform, its floor at half its level: G and B are 0 on ~40 % of
    # the bins (the encoder's floors are lower; this one makes every render cross it)
    out["floor"] = make_exact_material(tmp_path_factory.mktemp("floor"), "plastic-red-ggx-0.3",
                                       n_coeffs=200, transform="log-lobe-floor-cosine",
                                       floor=0.5)
    return out


def _sparse(mat, **opts):
    return {"type": "sparse_brdf", "filename": mat["sbrdf"], "ensemble": mat["ensemble"],
            **opts}


def _tabulated(mat, **opts):
    return {"type": "tabulated_brdf", "filename": mat["binary"], **opts}


def wrapped_scene(make, res: int, spp: int) -> dict:
    """Three spheres under the studio map (direct lighting, MIS), their BSDFs
    ``make(**opts)`` inside each of Mitsuba's wrappers: twosided (grouped decoder, cosine
    sampling), blendbsdf with a diffuse (strict decoder), mask (grouped, lobe sampling)."""
    def sphere(x, bsdf):
        return {"type": "sphere", "center": [x, 0.0, 0.0], "radius": 0.6, "bsdf": bsdf}

    return {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
        "sensor": {"type": "perspective", "fov": 50,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0.6, 4],
                                                              target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": spp},
                   "film": {"type": "hdrfilm", "width": 2 * res, "height": res,
                            "rfilter": {"type": "box"}}},
        "emitter": {"type": "envmap", "filename": STUDIO},
        "a": sphere(-1.3, {"type": "twosided", "bsdf": make(decoder="grouped")}),
        "b": sphere(0.0, {"type": "blendbsdf", "weight": 0.6,
                          "bsdf_0": make(decoder="strict"),
                          "bsdf_1": {"type": "diffuse", "reflectance": {
                              "type": "rgb", "value": [0.2, 0.4, 0.6]}}}),
        "c": sphere(1.3, {"type": "mask", "opacity": 0.7,
                          "bsdf": make(decoder="grouped", sampling="lobe")}),
    }


def render(scene: dict, spp: int, seed: int = 0) -> np.ndarray:
    return np.array(mi.render(mi.load_dict(scene), spp=spp, seed=seed), dtype=np.float64)


@pytest.mark.render
@pytest.mark.parametrize("material", ["plastic-red-ggx-0.3", "level", "lobe", "floor"])
@pytest.mark.parametrize("variant", CPU_VARIANTS)
def test_sparse_equals_its_table_in_every_variant(materials, variant, material):
    """In each variant, ``sparse_brdf`` renders what ``tabulated_brdf`` of the model's own
    decode renders, to >= 100 dB (the same sample paths, float32 rounding only), in
    twosided, blendbsdf and mask, both decoders and both sampling modes; in the paper's
    transform, a level transform, a lobe transform and a floor transform."""
    set_variant(variant)
    mitsuba_plugin.register()
    mat = materials[material]
    res, spp = (6, 2) if variant.startswith("scalar") else (16, 4)
    tab = {}  # the tabulated twin takes the decoder option of the sparse one: drop it

    def make_tab(decoder, **opts):
        tab[decoder] = 1
        return _tabulated(mat, **opts)

    img = render(wrapped_scene(lambda **o: _sparse(mat, **o), res, spp), spp)
    ref = render(wrapped_scene(make_tab, res, spp), spp)
    kind, _ = variant_kind(variant)
    assert img.shape[-1] == (1 if kind == "mono" else 3)
    assert np.isfinite(img).all() and ref.mean() > 1e-3
    assert render_snr(ref, img) >= 100.0, variant


def test_unsupported_variant_fails_in_one_line():
    with pytest.raises(PluginError, match="variant 'llvm_ad_rgb_double' is not"):
        mitsuba_plugin.classes("llvm_ad_rgb_double")
    with pytest.raises(PluginError, match="'scalar_xyz' is not supported"):
        mitsuba_plugin.classes("scalar_xyz")


def sphere_scene(bsdf: dict, res: int, spp: int) -> dict:
    """One sphere under Mitsuba's constant white emitter (direct lighting)."""
    return {
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0.9, 4],
                                                              target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": spp},
                   "film": {"type": "hdrfilm", "width": res, "height": res,
                            "rfilter": {"type": "box"}}},
        "emitter": {"type": "constant"},
        "s": {"type": "sphere", "bsdf": bsdf},
    }


def _render_in(variant: str, bsdf: dict, res: int, spp: int) -> np.ndarray:
    set_variant(variant)
    mitsuba_plugin.register()
    return render(sphere_scene(bsdf, res, spp), spp)


@pytest.mark.render
@pytest.mark.parametrize("name", ["plastic-grey-beckmann-0.12", "plastic-red-ggx-0.3"])
def test_spectral_render_agrees_with_rgb(materials, name):
    """A spectral render's mean colour is the rgb render's within 2 % per channel (16 x
    16 pixels, 256 spp, constant white light). Why 2 %: the two variants draw different
    random numbers (the spectral one also samples wavelengths), and the mean of such a
    render moves by up to 1.1 % from seed to seed (measured for the grey material, 0.4 %
    for the red); the upsampling round trip itself (a smooth spectrum whose colour under
    the white light is the BRDF's RGB) moved Mitsuba's own rough plastic of the same
    colours by at most 0.5 % in the same scene. Mono is the luminance, as Mitsuba
    computes it; polarized variants render their unpolarized twin's image."""
    bsdf = _sparse(materials[name])
    rgb = _render_in("llvm_ad_rgb", bsdf, 16, 256).mean((0, 1))
    spec = _render_in("llvm_ad_spectral", bsdf, 16, 256).mean((0, 1))
    assert rgb.min() > 0.01
    assert np.all(np.abs(spec / rgb - 1.0) < 0.02), (name, rgb, spec)
    mono = _render_in("llvm_ad_mono", bsdf, 16, 32)
    mono_pol = _render_in("llvm_ad_mono_polarized", bsdf, 16, 32)
    lum = _render_in("llvm_ad_rgb", bsdf, 16, 32) @ np.array([0.212671, 0.715160, 0.072169])
    np.testing.assert_allclose(mono[..., 0], lum, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(mono_pol, mono, rtol=1e-5, atol=1e-7)
