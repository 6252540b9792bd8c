"""The Mitsuba plugins sparse_brdf and tabulated_brdf (mitsuba_plugin), and the numpy
data they upload (sparse_brdf.decoders.layouts)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from conftest import LOBE, SMALL, random_orthonormal
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.coding.spec import PAPER_OPTIONS
from sparse_brdf.coding.tensor import hosvd_factors, mode_grams
from sparse_brdf.coords import (
    angles_to_dirs,
    bin_angles,
    cos_io,
    dirs_to_angles,
    dirs_to_bins,
    geometric_valid,
)
from sparse_brdf.decoders.buffers import mix_channels
from sparse_brdf.decoders.layouts import (
    UNION_ATOMS,
    channel_terms,
    choose_decoder,
    grouped_bytes,
    grouped_channel,
    grouped_eval,
    grouped_layout,
    n_slots,
    strict_channel,
)
from sparse_brdf.decoders.lobe import sparse_profile
from sparse_brdf.decoders.lookups import layout_eval, model_x, strict_eval
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl
from sparse_brdf.transforms import (
    TRANSFORMS,
    colour_matrix,
    cosine_weight,
    forward,
    has_lobe,
    inverse,
    per_material,
)

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain  # noqa: E402

import mitsuba_plugin  # noqa: E402
from mitsuba_plugin.kernels import expm1  # noqa: E402

pytestmark = pytest.mark.numerics

FULL = (90, 90, 180)
#: The decoders and grouped layouts every evaluation test runs (the two layouts share
#: one kernel; each material's data is in one of them).
DECODER_OPTIONS = ({"decoder": "grouped", "layout": "union"},
                   {"decoder": "grouped", "layout": "slots"},
                   {"decoder": "strict"})


# ----------------------------------------------------------------------------- helpers


def use_variant(name: str) -> str:
    set_variant(name)
    mitsuba_plugin.register()
    return name


@pytest.fixture(params=["scalar_rgb", "llvm_ad_rgb"])
def variant(request):
    return use_variant(request.param)


@pytest.fixture
def llvm():
    return use_variant("llvm_ad_rgb")


def make_exact_material(folder, name: str = "plastic-red-ggx-0.3", n_coeffs: int = 400,
                        transform: str = "auto", floor: float | None = None):
    """A glossy material on the small grid, its own HOSVD ensemble (K=1), its sparse code
    (the paper's encoder; ``transform``: the one to code in, "auto" the paper's choice;
    ``floor``: a floor transform's floor instead of the encoder's) and the model's full
    decode as a MERL file (the exact tabulated twin of the model).

    Returns a dict of paths: ensemble, sbrdf, binary (decoded model), original (binary).
    """
    brdf = load_brdf(f"mitsuba:{name}", shape=SMALL)
    grams = None
    # the transforms' grams (a lobe transform's only for a material coded in it)
    for t in (t for t in TRANSFORMS if not has_lobe(t) or t == transform):
        y = forward(brdf.channel_first(), t, brdf.valid)
        for c in range(3):
            g = mode_grams(y[c])
            grams = g if grams is None else tuple(a + b for a, b in zip(grams, g, strict=True))
    ens = Ensemble(*(f[None] for f in hosvd_factors(grams)), taus=np.zeros(1))
    # n_coeffs in each R, G, B channel
    model = encode(brdf, ens, n_coeffs, transform=transform, **PAPER_OPTIONS)
    if floor is not None:
        model = dataclasses.replace(model, floor=floor)
    sbrdf = save_sbrdf(folder / f"{name}.sbrdf", model)
    model = load_sbrdf(sbrdf, ens)  # the values as the file holds them (quantised)
    paths = {"ensemble": str(ens.save(folder / "ens.npz")), "sbrdf": str(sbrdf),
             "binary": str(write_merl(folder / f"{name}-decoded.binary", model.decode(ens))),
             "original": str(write_merl(folder / f"{name}.binary", brdf))}
    return paths


@pytest.fixture(scope="session")
def exact_material(tmp_path_factory):
    return make_exact_material(tmp_path_factory.mktemp("exact"))


@pytest.fixture(scope="session")
def full_random(tmp_path_factory):
    """A random orthonormal ensemble on the full MERL grid and a random sparse model per
    transform (60 terms per channel plus a large constant atom)."""
    folder = tmp_path_factory.mktemp("full")
    rng = np.random.default_rng(7)
    ens = Ensemble(*(random_orthonormal(n, rng)[None] for n in FULL), taus=np.zeros(1))
    size = int(np.prod(FULL))
    out = {"ensemble": str(ens.save(folder / "ens.npz")), "ens": ens}
    for t in TRANSFORMS:
        locs, vals = [], []
        for _ in range(3):
            locs.append(np.concatenate([[0], rng.choice(np.arange(1, size), 60, replace=False)]))
            vals.append(np.concatenate([[0.2 * np.sqrt(size)],
                                        rng.normal(0, 0.2, 60)]).astype(np.float32))
        model = SparseBRDF(t, FULL, ens.id, [0, 0, 0], locs, vals, name=f"random-{t}",
                           gain=0.4375 if per_material(t) else 1.0,  # a level's own gain
                           lobe=LOBE if has_lobe(t) else None)
        out[t] = str(save_sbrdf(folder / f"random-{t}.sbrdf", model))
    return out


def random_pairs(shape, n, rng, lo=0.2, hi=0.8, min_h=0, min_z=0.02):
    """Direction pairs inside random bins, away from their edges (fractions in [lo, hi]),
    rotated by a random phi_h, with wi and wo swapped at random; both above the horizon
    (z > ``min_z``).
    Directions are rounded to float32 (what the plugin sees). theta_h bins below
    ``min_h`` are skipped: there theta_h is so small (< 2e-4 rad) that phi_d is
    ill-conditioned in float32. Returns wi, wo (N, 3) and the bins (i, j, k)."""
    n1, n2, n3 = shape
    i = rng.integers(min_h, n1, n)
    j, k = (rng.integers(0, m, n) for m in shape[1:])
    u = rng.uniform(lo, hi, (3, n))
    th = ((i + u[0]) / n1) ** 2 * np.pi / 2
    td = (j + u[1]) / n2 * np.pi / 2
    pd = (k + u[2]) / n3 * np.pi
    wi, wo = angles_to_dirs(th, td, pd)
    phi = rng.uniform(0, 2 * np.pi, n)
    c, s = np.cos(phi), np.sin(phi)

    def rot(v):
        return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], -1)

    wi, wo = rot(wi), rot(wo)
    swap = rng.random(n) < 0.5
    wi, wo = np.where(swap[:, None], wo, wi), np.where(swap[:, None], wi, wo)
    wi = wi.astype(np.float32).astype(np.float64)
    wo = wo.astype(np.float32).astype(np.float64)
    keep = (wi[:, 2] > min_z) & (wo[:, 2] > min_z)
    return wi[keep], wo[keep], (i[keep], j[keep], k[keep])


def eval_brdf(bsdf, wi, wo):
    """BSDF values (eval / cos_o) at direction pairs, (N, 3), in the current variant."""
    ctx = mi.BSDFContext()
    if mi.variant().startswith("scalar"):
        out = []
        for a, b in zip(wi, wo, strict=True):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*map(float, a))
            out.append(np.array(bsdf.eval(ctx, si, mi.Vector3f(*map(float, b)))))
        f = np.array(out, np.float64)
    else:
        si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
        si.wi = mi.Vector3f(np.ascontiguousarray(wi.T, np.float32))
        f = np.array(bsdf.eval(ctx, si, mi.Vector3f(np.ascontiguousarray(wo.T, np.float32))),
                     np.float64).reshape(3, -1).T
    return f / wo[:, 2:3]


def as_opponent(model: SparseBRDF, counts, name: str | None = None) -> SparseBRDF:
    """``model``'s coefficients read as opponent-basis channels, channel c cut to its
    ``counts[c]`` largest (0: an empty channel): a valid material of unequal counts."""
    return dataclasses.replace(
        model, basis="opponent", name=name or f"{model.name}-opponent",
        locations=[a[:n] for a, n in zip(model.locations, counts, strict=True)],
        values=[v[:n] for v, n in zip(model.values, counts, strict=True)])


@pytest.fixture(scope="session")
def opponent_material(exact_material, tmp_path_factory):
    """The exact material's coefficients as an opponent-basis material with 400, 0 and
    90 coefficients in its channels (the middle one empty), as a .sbrdf file."""
    ens = Ensemble.load(exact_material["ensemble"])
    model = as_opponent(load_sbrdf(exact_material["sbrdf"], ens), (400, 0, 90))
    path = save_sbrdf(tmp_path_factory.mktemp("opponent") / "opponent.sbrdf", model)
    return {"ensemble": exact_material["ensemble"], "sbrdf": str(path)}


# ------------------------------------------------------------------------ registration


def test_register_is_idempotent_per_variant():
    for v in ("scalar_rgb", "llvm_ad_rgb"):
        set_variant(v)
        assert mitsuba_plugin.register() == v
        assert mitsuba_plugin.register() == v
    t1, s1, n1, _ = mitsuba_plugin.classes("llvm_ad_rgb")
    t2, s2, n2, _ = mitsuba_plugin.classes("scalar_rgb")
    assert t1 is not t2 and s1 is not s2 and n1 is not n2


# ---------------------------------------------------------------------- numpy mirrors


def test_grouped_and_strict_data_reproduce_the_model(exact_material):
    ens = Ensemble.load(exact_material["ensemble"])
    model = load_sbrdf(exact_material["sbrdf"], ens)
    x = model.transformed(ens)
    bins = tuple(a.ravel() for a in np.indices(SMALL))
    for c in range(3):
        terms = channel_terms(model, ens, c)
        for g in (None, 0, 1, 2):  # automatic choice and every forced grouped mode
            ch = grouped_channel(*terms, mode_g=g)
            np.testing.assert_allclose(grouped_eval(ch, bins), x[c].ravel(), atol=2e-5)
        st = strict_channel(*terms)
        np.testing.assert_allclose(strict_eval(st, bins), x[c].ravel(), atol=2e-5)
        assert st.nbytes < ch.nbytes


def test_grouped_layout_reproduces_channels_and_bin_weight(exact_material):
    """The uploaded layout (slots of 3 channels + the bin's cos_i cos_o) gives the
    channels' X and the weight's cosine product at every bin, for every grouped mode."""
    ens = Ensemble.load(exact_material["ensemble"])
    model = load_sbrdf(exact_material["sbrdf"], ens)
    x = model.transformed(ens)
    bins = tuple(a.ravel() for a in np.indices(SMALL))
    th, td, pd = bin_angles(SMALL)
    ci, co = cos_io(th[bins[0]], td[bins[1]], pd[bins[2]])
    for g in range(3):
        chans = [grouped_channel(*channel_terms(model, ens, c), mode_g=g,
                                   source=int(model.dict_index[c])) for c in range(3)]
        union = {(ch.source, int(a)) for ch in chans for a in ch.atoms}
        for kind in ("slots", "union"):
            lay = grouped_layout(chans, SMALL, kind)
            assert lay.kind == kind
            if kind == "slots":
                assert lay.chunks == n_slots([ch.k for ch in chans]) // 2
            else:
                assert lay.chunks == max(2, -(-len(union) // UNION_ATOMS))
            xs, cc = layout_eval(lay, chans[0], bins)
            for c in range(3):
                np.testing.assert_allclose(xs[c], x[c].ravel(), atol=2e-5)
            np.testing.assert_allclose(cc, ci * co, atol=1e-6)
        auto = grouped_layout(chans, SMALL)
        assert auto.packets == min(grouped_layout(chans, SMALL, k).packets
                                   for k in ("slots", "union"))
    # channels on different grouped modes cannot share rows
    mixed = [grouped_channel(*channel_terms(model, ens, c), mode_g=c) for c in range(3)]
    with pytest.raises(ValueError, match="one grouped mode"):
        grouped_layout(mixed, SMALL)


@pytest.mark.parametrize("counts", [(400, 0, 90), (0, 37, 400), (5, 400, 0)])
def test_numpy_decoders_mix_the_opponent_basis(exact_material, counts):
    """Both decoders' data and the layouts give the coded channels (an empty channel
    gives 0), and the mix M^T turns them into the transformed R, G, B at every bin."""
    ens = Ensemble.load(exact_material["ensemble"])
    model = as_opponent(load_sbrdf(exact_material["sbrdf"], ens), counts)
    assert model.n_coeffs.tolist() == list(counts)
    coded, x = model.coded(ens), model.transformed(ens)
    np.testing.assert_allclose(x, np.tensordot(colour_matrix("opponent").T, coded, 1),
                               atol=1e-5)
    bins = tuple(a.ravel() for a in np.indices(SMALL))
    for c in range(3):
        st = strict_channel(*channel_terms(model, ens, c))
        np.testing.assert_allclose(strict_eval(st, bins), coded[c].ravel(), atol=2e-5)
        assert st.n_terms == counts[c]
    np.testing.assert_allclose(mix_channels(coded.reshape(3, -1), "opponent"),
                               x.reshape(3, -1), atol=1e-5)
    assert mix_channels(coded, "rgb") is coded
    for decoder, kind in (("grouped", "slots"), ("grouped", "union"), ("strict", None)):
        np.testing.assert_allclose(model_x(model, ens, bins, decoder, kind),
                                   x.reshape(3, -1), atol=3e-5)
    # the lobe fit sees the R, G, B profile, not the coded channels'
    rgb = dataclasses.replace(model, basis="rgb")
    assert not np.allclose(sparse_profile(model, ens), sparse_profile(rgb, ens))


def test_auto_decoder_and_memory(exact_material, llvm):
    ens = Ensemble.load(exact_material["ensemble"])
    model = load_sbrdf(exact_material["sbrdf"], ens)
    assert choose_decoder("auto", model, ens) == "grouped"
    assert choose_decoder("auto", model, ens, max_bytes=0) == "strict"
    with pytest.raises(ValueError, match="decoder"):
        choose_decoder("dense", model, ens)
    mem = {}
    for dec in ("grouped", "strict"):
        b = mi.load_dict({"type": "sparse_brdf", "filename": exact_material["sbrdf"],
                          "ensemble": exact_material["ensemble"], "decoder": dec})
        assert b.decoder == dec and f"decoder={dec}" in b.to_string()
        mem[dec] = b.memory_bytes
    assert mem["grouped"] == grouped_bytes(model, ens)
    tab = mi.load_dict({"type": "tabulated_brdf", "filename": exact_material["binary"]})
    assert tab.memory_bytes == int(np.prod(SMALL)) * 3 * 4
    assert 0 < mem["strict"] < mem["grouped"]


# --------------------------------------------------------------------------- evaluation


@pytest.mark.parametrize("transform", TRANSFORMS)
def test_sparse_eval_matches_numpy_decoder(full_random, variant, transform):
    ens = full_random["ens"]
    model = load_sbrdf(full_random[transform], ens)
    rng = np.random.default_rng(11)
    n = 150 if variant.startswith("scalar") else 4000
    wi, wo, bins = random_pairs(FULL, n, rng, min_h=1)
    valid = geometric_valid(FULL)[bins]
    ref = model.eval(ens, wi, wo)
    for opts in DECODER_OPTIONS:
        b = mi.load_dict({"type": "sparse_brdf", "filename": full_random[transform],
                          "ensemble": full_random["ensemble"], **opts})
        assert b.layout == opts.get("layout")
        out = eval_brdf(b, wi, wo)
        # the plugin zeroes bins below the horizon at their angles (like the tabulated
        # reference and SparseBRDF.decode); the numpy evaluator does not
        assert np.all(out[~valid] == 0)
        np.testing.assert_allclose(out[valid], ref[valid], rtol=1e-5,
                                   atol=1e-6 * float(np.abs(ref).max()))


@pytest.mark.parametrize("transform", TRANSFORMS)
def test_opponent_eval_matches_numpy_decoder(full_random, variant, transform, tmp_path):
    """An opponent-basis material with unequal counts (one channel empty): both decoders
    and layouts, scalar and LLVM, against SparseBRDF.eval (which mixes in numpy)."""
    ens = full_random["ens"]
    path = str(save_sbrdf(tmp_path / "opponent.sbrdf",
                          as_opponent(load_sbrdf(full_random[transform], ens), (61, 23, 0))))
    model = load_sbrdf(path, ens)  # as the file holds it (version 2 quantises the values)
    rng = np.random.default_rng(12)
    n = 150 if variant.startswith("scalar") else 4000
    wi, wo, bins = random_pairs(FULL, n, rng, min_h=1)
    valid = geometric_valid(FULL)[bins]
    ref = model.eval(ens, wi, wo)
    # the mix matters: the same coefficients read as R, G, B give other values
    rgb = dataclasses.replace(model, basis="rgb").eval(ens, wi, wo)
    assert (np.abs(rgb - ref) / (np.abs(ref) + 1e-3))[valid].max() > 0.1
    for opts in DECODER_OPTIONS:
        b = mi.load_dict({"type": "sparse_brdf", "filename": path,
                          "ensemble": full_random["ensemble"], **opts})
        assert b.basis == "opponent" and "basis=opponent" in b.to_string()
        assert b.n_terms == (61, 23, 0)
        out = eval_brdf(b, wi, wo)
        assert np.all(out[~valid] == 0)
        np.testing.assert_allclose(out[valid], ref[valid], rtol=1e-5,
                                   atol=1e-6 * float(np.abs(ref).max()))
        err = np.sum((out[valid] - ref[valid]) ** 2)
        snr = 10 * np.log10(np.sum(ref[valid] ** 2) / max(err, 1e-300))
        assert snr > 110, f"{opts}: {snr:.1f} dB"


def test_invalid_bins_stay_zero_when_the_model_overflows(full_random, tmp_path, variant):
    """X = 100 everywhere: exp overflows float32 at every bin; bins below the horizon at
    their angles must still give exactly 0 (not inf * 0 = nan) in both decoders, scalar
    (double math.expm1, inf once stored as float32) and LLVM."""
    ens = full_random["ens"]
    size = int(np.prod(FULL))
    x_const = 100.0 * np.sqrt(size)  # the constant atom (0, 0, 0) is 1/sqrt(size)
    model = SparseBRDF("log-plus", FULL, ens.id, [0, 0, 0], [np.array([0])] * 3,
                       [np.array([x_const], np.float32)] * 3, name="overflow")
    path = str(save_sbrdf(tmp_path / "overflow.sbrdf", model))
    # pairs above the horizon in bins that are not valid at their lower-edge angles are
    # rare (near grazing): draw many, keep those and some valid ones
    wi, wo, bins = random_pairs(FULL, 400_000, np.random.default_rng(5), lo=0.02, hi=0.98,
                                min_h=1, min_z=1e-3)
    valid = geometric_valid(FULL)[bins]
    pick = np.flatnonzero(~valid)
    pick = np.concatenate([pick, np.flatnonzero(valid)[:200]])
    wi, wo, valid = wi[pick], wo[pick], valid[pick]
    assert (~valid).sum() >= 10
    for opts in DECODER_OPTIONS:
        b = mi.load_dict({"type": "sparse_brdf", "filename": path,
                          "ensemble": full_random["ensemble"], **opts})
        out = eval_brdf(b, wi, wo)
        assert not np.isnan(out).any()
        assert np.all(out[~valid] == 0) and np.all(np.isinf(out[valid]))


def test_tabulated_eval_equals_table(exact_material, variant):
    brdf = load_brdf(exact_material["binary"])
    rng = np.random.default_rng(5)
    n = 300 if variant.startswith("scalar") else 5000
    wi, wo, _ = random_pairs(SMALL, n, rng, 0.02, 0.98)
    bins = dirs_to_bins(wi, wo, SMALL)
    b = mi.load_dict({"type": "tabulated_brdf", "filename": exact_material["binary"]})
    out = eval_brdf(b, wi, wo)
    np.testing.assert_allclose(out, brdf.values[bins], rtol=2e-6, atol=1e-7)
    # below the horizon on either side: zero
    wi_low = wi.copy()
    wi_low[:, 2] *= -1
    assert np.all(eval_brdf(b, wi_low[:20], wo[:20]) == 0)


def test_reciprocity(exact_material, llvm):
    rng = np.random.default_rng(9)
    wi, wo, _ = random_pairs(SMALL, 3000, rng)
    for d in ({"type": "tabulated_brdf", "filename": exact_material["binary"]},
              {"type": "sparse_brdf", "filename": exact_material["sbrdf"],
               "ensemble": exact_material["ensemble"], "decoder": "grouped"},
              {"type": "sparse_brdf", "filename": exact_material["sbrdf"],
               "ensemble": exact_material["ensemble"], "decoder": "strict",
               "interpolate": True}):
        b = mi.load_dict(d)
        f1, f2 = eval_brdf(b, wi, wo), eval_brdf(b, wo, wi)
        # interpolation weights see float32 rounding of the angles: a looser tolerance
        rtol = 1e-4 if d.get("interpolate") else 1e-5
        np.testing.assert_allclose(f1, f2, rtol=rtol, atol=1e-6 * f1.max())
        assert f1.max() > 0


def _trilinear(grid, th, td, pd):
    """Numpy trilinear interpolation between lower-edge samples (phi_d periodic)."""
    n1, n2, n3 = grid.shape[:3]
    x = [np.sqrt(th / (np.pi / 2)) * n1, td / (np.pi / 2) * n2, pd / np.pi * n3]
    lo, w = [], []
    for m, (xm, n) in enumerate(zip(x, (n1, n2, n3), strict=True)):
        if m < 2:
            xm = np.clip(xm, 0, n - 1)
            f = np.minimum(np.floor(xm), n - 2)
        else:
            f = np.floor(xm)
        lo.append(f.astype(int))
        w.append(xm - f)
    out = 0.0
    for e in np.ndindex(2, 2, 2):
        idx = [lo[0] + e[0], lo[1] + e[1], (lo[2] + e[2]) % n3]
        wt = np.prod([w[m] if e[m] else 1 - w[m] for m in range(3)], axis=0)
        out = out + (wt[:, None] * grid[idx[0], idx[1], idx[2]].reshape(len(wt), -1)
                     if grid.ndim == 4 else wt * grid[idx[0], idx[1], idx[2]])
    return out

def _interpolated_sparse(model, ens, th, td, pd) -> np.ndarray:
    """numpy reference of an interpolated sparse lookup: the transformed R, G, B (coded
    channels already mixed back), the cosine weight and validity interpolated trilinearly,
    then the inverse transform."""
    x = _trilinear(np.moveaxis(model.transformed(ens), 0, -1), th, td, pd)
    use_cos = model.transform == "log-plus-cosine"
    w = _trilinear(cosine_weight(SMALL).astype(np.float64), th, td, pd) if use_cos else 1.0
    v = _trilinear(geometric_valid(SMALL).astype(np.float64), th, td, pd)
    return np.maximum(np.expm1(x) / np.reshape(w, (-1, 1)) * v[:, None], 0)


def _check_interpolated_decoders(material, wi, wo, ref) -> None:
    """Every decoder with ``interpolate=True`` evaluates ``ref`` at the pairs."""
    for opts in DECODER_OPTIONS:
        s = mi.load_dict({"type": "sparse_brdf", "filename": material["sbrdf"],
                          "ensemble": material["ensemble"], "interpolate": True, **opts})
        np.testing.assert_allclose(eval_brdf(s, wi, wo), ref, rtol=1e-4,
                                   atol=1e-5 * ref.max())



def test_interpolation_matches_numpy(exact_material, llvm):
    ens = Ensemble.load(exact_material["ensemble"])
    model = load_sbrdf(exact_material["sbrdf"], ens)
    rng = np.random.default_rng(3)
    wi, wo, _ = random_pairs(SMALL, 3000, rng, 0.0, 1.0)
    th, td, pd = dirs_to_angles(wi, wo)
    pd = np.where(pd < 0, pd + np.pi, pd)
    # tabulated: trilinear interpolation of the table
    tab = load_brdf(exact_material["binary"])
    b = mi.load_dict({"type": "tabulated_brdf", "filename": exact_material["binary"],
                      "interpolate": True})
    np.testing.assert_allclose(eval_brdf(b, wi, wo), _trilinear(tab.values, th, td, pd),
                               rtol=1e-4, atol=1e-5 * tab.values.max())
    # sparse: interpolated X, w and validity, then the inverse transform
    ref = _interpolated_sparse(model, ens, th, td, pd)
    _check_interpolated_decoders(exact_material, wi, wo, ref)


def test_opponent_interpolation_matches_numpy(opponent_material, llvm):
    """Interpolated lookups of an opponent material: the coded X interpolated, mixed
    back to R, G, B, then the inverse transform (interpolation and mix commute)."""
    ens = Ensemble.load(opponent_material["ensemble"])
    model = load_sbrdf(opponent_material["sbrdf"], ens)
    assert model.basis == "opponent" and model.n_coeffs.tolist() == [400, 0, 90]
    rng = np.random.default_rng(4)
    wi, wo, _ = random_pairs(SMALL, 3000, rng, 0.0, 1.0)
    th, td, pd = dirs_to_angles(wi, wo)
    pd = np.where(pd < 0, pd + np.pi, pd)
    ref = _interpolated_sparse(model, ens, th, td, pd)
    _check_interpolated_decoders(opponent_material, wi, wo, ref)


def test_rgb_kernels_are_unchanged_by_the_opponent_mix(exact_material, opponent_material,
                                                       llvm):
    """The mix is a Python branch at trace time: an rgb material traces the kernel it
    always did (a second rgb material reuses it), an opponent one its own, and a second
    opponent material reuses that (M^T is a constant, not per-material data)."""
    rng = np.random.default_rng(8)
    wi, wo, _ = random_pairs(SMALL, 512, rng)
    ens = Ensemble.load(exact_material["ensemble"])
    rgb2 = dataclasses.replace(load_sbrdf(exact_material["sbrdf"], ens), name="rgb2",
                               values=[0.5 * v for v in load_sbrdf(exact_material["sbrdf"],
                                                                   ens).values])
    opp2 = as_opponent(load_sbrdf(exact_material["sbrdf"], ens), (100, 100, 3), "opp2")
    folder = Path(opponent_material["sbrdf"]).parent
    files = {"rgb": exact_material["sbrdf"], "opp": opponent_material["sbrdf"],
             "rgb2": str(save_sbrdf(folder / "rgb2.sbrdf", rgb2)),
             "opp2": str(save_sbrdf(folder / "opp2.sbrdf", opp2))}
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for decoder in ("grouped", "strict"):
            hashes = {}
            for key, path in files.items():
                b = mi.load_dict({"type": "sparse_brdf", "filename": path,
                                  "ensemble": exact_material["ensemble"],
                                  "decoder": decoder})
                dr.kernel_history()  # clear
                eval_brdf(b, wi, wo)
                hashes[key] = {k["hash"] for k in dr.kernel_history()
                               if k["type"] == dr.KernelType.JIT
                               and k["operation_count"] > 200}
            assert hashes["rgb"] and hashes["opp"], decoder
            assert hashes["rgb2"] <= hashes["rgb"], decoder
            assert hashes["opp2"] <= hashes["opp"], decoder
            assert not hashes["opp"] & hashes["rgb"], decoder
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


# ------------------------------------------------------------------------------ errors


def test_missing_or_corrupt_file_fails_at_load(exact_material, tmp_path, llvm):
    ens = exact_material["ensemble"]
    corrupt = tmp_path / "corrupt.sbrdf"
    data = bytearray(open(exact_material["sbrdf"], "rb").read())
    data[70] ^= 0xFF
    corrupt.write_bytes(bytes(data))
    truncated = tmp_path / "truncated.binary"
    truncated.write_bytes(open(exact_material["binary"], "rb").read()[:1000])
    cases = [
        ({"type": "sparse_brdf", "filename": str(tmp_path / "nope.sbrdf"), "ensemble": ens},
         "nope.sbrdf"),
        ({"type": "sparse_brdf", "filename": str(corrupt), "ensemble": ens}, "corrupt.sbrdf"),
        ({"type": "sparse_brdf", "filename": exact_material["sbrdf"],
          "ensemble": str(tmp_path / "noens.npz")}, "noens.npz"),
        ({"type": "tabulated_brdf", "filename": str(tmp_path / "nope.binary")}, "nope.binary"),
        ({"type": "tabulated_brdf", "filename": str(truncated)}, "truncated.binary"),
        ({"type": "sparse_brdf", "filename": exact_material["sbrdf"], "ensemble": ens,
          "decoder": "bogus"}, "decoder"),
        ({"type": "tabulated_brdf", "filename": exact_material["binary"],
          "sampling": "ggx"}, "sampling"),
    ]
    for d, needle in cases:
        with pytest.raises(Exception) as info:
            mi.load_dict(d)
        assert needle in str(info.value), str(info.value)
    # an .sbrdf file encoded with another ensemble
    other = Ensemble(*(random_orthonormal(n, np.random.default_rng(1))[None] for n in SMALL),
                     taus=np.zeros(1)).save(tmp_path / "other.npz")
    with pytest.raises(Exception, match="ensemble"):
        mi.load_dict({"type": "sparse_brdf", "filename": exact_material["sbrdf"],
                      "ensemble": str(other)})
    # every property is read; an unknown one is rejected by Mitsuba
    with pytest.raises(Exception, match="unreferenced|unused|foo"):
        mi.load_dict({"type": "tabulated_brdf", "filename": exact_material["binary"],
                      "foo": 1})


# ---------------------------------------------------------------------------- sampling


def _load(exact_material, plugin, sampling):
    d = {"type": plugin, "sampling": sampling}
    if plugin == "sparse_brdf":
        d.update(filename=exact_material["sbrdf"], ensemble=exact_material["ensemble"])
    else:
        d.update(filename=exact_material["binary"])
    return d


@pytest.mark.parametrize("plugin", ["sparse_brdf", "tabulated_brdf"])
@pytest.mark.parametrize("sampling", ["cosine", "lobe"])
def test_pdf_matches_sample_chi2(exact_material, llvm, plugin, sampling):
    d = _load(exact_material, plugin, sampling)
    b = mi.load_dict(d)
    if sampling == "lobe":
        assert b.lobe_exponent > 1 and 0.05 <= b.lobe_prob <= 0.95
    for wi in ([0.0, 0.0, 1.0], [0.7, 0.2, float(np.sqrt(1 - 0.53))]):
        sample, pdf = BSDFAdapter(plugin, d, wi=wi)
        chi2 = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf,
                             sample_dim=3, sample_count=100_000, res=61, ires=8)
        assert chi2.run(0.01, quiet=True), chi2.messages


@pytest.mark.parametrize("sampling", ["cosine", "lobe"])
def test_pdf_integral_weight_and_eval_pdf(exact_material, llvm, sampling):
    b = mi.load_dict(_load(exact_material, "sparse_brdf", sampling))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(2)
    n = 200_000
    wi = np.array([0.5, 0.0, np.sqrt(0.75)], np.float32)
    # integral of the pdf over the sphere (uniform directions)
    z = rng.uniform(-1, 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    wo = np.stack([r * np.cos(phi), r * np.sin(phi), z]).astype(np.float32)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(np.repeat(wi[:, None], n, 1))
    p = np.array(b.pdf(ctx, si, mi.Vector3f(wo)))
    integral = p.mean() * 4 * np.pi
    if sampling == "cosine":
        assert integral == pytest.approx(1.0, abs=0.01)
    else:  # the lobe loses the part of its mass that falls below the horizon
        assert 0.8 < integral < 1.01
    f, p2 = b.eval_pdf(ctx, si, mi.Vector3f(wo))
    np.testing.assert_array_equal(np.array(p2), p)
    np.testing.assert_array_equal(np.array(f), np.array(b.eval(ctx, si, mi.Vector3f(wo))))
    # sampled weights are eval / pdf
    u = rng.random((3, n)).astype(np.float32)
    bs, weight = b.sample(ctx, si, mi.Float(u[0]), mi.Point2f(u[1:]))
    ev = np.array(b.eval(ctx, si, bs.wo))
    pd = np.array(bs.pdf)
    assert np.allclose(pd, np.array(b.pdf(ctx, si, bs.wo)), rtol=1e-5)
    ok = pd > 0
    np.testing.assert_allclose(np.array(weight)[:, ok], ev[:, ok] / pd[ok], rtol=1e-4,
                               atol=1e-7)
    assert np.all(np.isfinite(np.array(weight)))


def test_component_flags(exact_material, llvm):
    b = mi.load_dict(_load(exact_material, "sparse_brdf", "cosine"))
    assert b.flags() & int(+mi.BSDFFlags.GlossyReflection)
    assert b.flags() & int(+mi.BSDFFlags.FrontSide)
    assert b.component_count() == 1


def test_log_plus_inverse_is_exact_near_zero(llvm):
    """The kernel's exp(x) - 1 keeps its relative precision for tiny x."""
    x = np.array([1e-7, 1e-5, 1e-3, 0.1, 3.0, -0.5], np.float32)
    np.testing.assert_allclose(np.array(expm1(mi.Float(x))), np.expm1(x.astype(np.float64)),
                               rtol=2e-6)
    assert inverse(np.zeros((1, 1, 1)), "log-plus").item() == 0.0
