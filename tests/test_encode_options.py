"""The encoder's options: the render- and albedo-proxy transform selectors, filling every
invalid bin,
the opponent colour basis with a joint budget; their spec grammar and CLI flags. Each
option is tested against the paper's encoder (``encode`` below defaults to
``PAPER_OPTIONS``; explicit keywords override it)."""

import functools
import json

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.cli import main
from sparse_brdf.coding.encode import encode as _encode
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.coding.spec import ENCODE_OPTIONS, PAPER_OPTIONS, check_options
from sparse_brdf.compared import baselines
from sparse_brdf.compared.specs import make_model
from sparse_brdf.coords import bin_solid_angle, geometric_valid
from sparse_brdf.metrics import (
    albedo_proxy_error,
    cosine_weighted_snr,
    make_albedo_proxy,
    make_render_proxy,
    render_proxy_error,
)
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl
from sparse_brdf.transforms import forward, inverse, to_basis

encode = functools.partial(_encode, **PAPER_OPTIONS)


def _valid_error(brdf, model, ens):
    """Relative squared error of the transformed R, G, B on valid bins."""
    y = forward(brdf.channel_first(), model.transform, brdf.valid)[:, brdf.valid]
    d = y - model.transformed(ens)[:, brdf.valid]
    return float(np.sum(np.square(d, dtype=np.float64)) / np.sum(np.square(y, dtype=np.float64)))


# ----------------------------------------------------------------------- render proxy
def test_bin_solid_angle_lives_in_coords():
    assert baselines.bin_solid_angle is bin_solid_angle


def test_render_proxy_layouts_mask_and_cache():
    rng = np.random.default_rng(0)
    valid = geometric_valid(SMALL)
    ref = (rng.random((*SMALL, 3)) * valid[..., None]).astype(np.float32)
    rec = (ref * (1 + 0.1 * rng.standard_normal(ref.shape))).astype(np.float32)
    k = make_render_proxy(SMALL)
    assert make_render_proxy(SMALL) is k  # cached per shape
    e = render_proxy_error(ref, np.where(valid[..., None], rec, 0), k)
    assert e > 0 and render_proxy_error(ref, ref, k) == 0
    first = render_proxy_error(np.moveaxis(ref, -1, 0), np.moveaxis(rec, -1, 0), valid=valid)
    assert first == pytest.approx(e, rel=1e-5)  # channel-first, masked here
    assert render_proxy_error(ref, rec, valid=valid) == pytest.approx(e, rel=1e-6)


def test_render_proxy_averages_sign_alternating_errors_within_a_cell():
    # the first three theta_h bins of the small grid fall in one 2-degree cell
    k = make_render_proxy(SMALL)
    assert k["starts"][:2].tolist() == [0, 3]
    om = bin_solid_angle(SMALL)
    ref = np.zeros((*SMALL, 1), np.float32)
    same, alternating = ref.copy(), ref.copy()
    same[0, 5, 3], same[1, 5, 3] = 1 / om[0, 5, 3], 1 / om[1, 5, 3]
    alternating[0, 5, 3], alternating[1, 5, 3] = 1 / om[0, 5, 3], -1 / om[1, 5, 3]
    assert render_proxy_error(ref, alternating, k) < 1e-6 * render_proxy_error(ref, same, k)


def test_render_selector_picks_the_smaller_proxy_error(small_ensemble):
    b = load_brdf("mitsuba:cu-ggx-0.12", shape=SMALL)
    m = encode(b, small_ensemble, 32, selector="render")
    st = m.stats["transforms"]
    assert m.transform == min(st, key=lambda t: st[t]["render_proxy"])
    assert m.stats["selector"] == "render" and m.stats["options"]["selector"] == "render"
    rec = m.decode(small_ensemble, valid=b.valid).values
    assert st[m.transform]["render_proxy"] == pytest.approx(
        render_proxy_error(b.values, rec, valid=b.valid), rel=1e-4)
    with pytest.raises(ValueError, match="unknown selector"):
        encode(b, small_ensemble, 32, selector="psnr")


def test_albedo_proxy_integrates_a_lambertian_table_to_its_albedo():
    """A constant table rho = a / pi reflects a at every theta_o; the proxy of a zero
    reconstruction is then sum_c a_c^2 times the integral of cos_o over the hemisphere
    (pi), and an error of 10 % everywhere gives 1 % of it."""
    a = np.array([0.8, 0.5, 0.1])
    ref = np.broadcast_to(a / np.pi, (*SMALL, 3)).astype(np.float32)
    k = make_albedo_proxy(SMALL)
    assert make_albedo_proxy(SMALL) is k and not k["weight"].flags.writeable
    albedo = np.moveaxis(ref, -1, 0).reshape(3, -1)[:, k["index"]] @ k["weight"]
    assert albedo == pytest.approx(np.broadcast_to(a[:, None], albedo.shape), rel=2e-3)
    zero = albedo_proxy_error(ref, np.zeros_like(ref), k)
    assert zero == pytest.approx(np.pi * np.sum(a * a), rel=5e-3)
    assert albedo_proxy_error(ref, 0.9 * ref, k) == pytest.approx(0.01 * zero, rel=1e-5)
    assert albedo_proxy_error(ref, ref, k) == 0


def test_albedo_proxy_adds_errors_of_one_sign_and_masks_invalid_bins():
    rng = np.random.default_rng(1)
    valid = geometric_valid(SMALL)
    ref = (rng.random((*SMALL, 3)) * valid[..., None]).astype(np.float32)
    noise = 0.05 * rng.standard_normal(ref.shape).astype(np.float32)
    biased = albedo_proxy_error(ref, ref * 1.05, valid=valid)
    random = albedo_proxy_error(ref, ref * (1 + noise), valid=valid)
    # equal squared errors per bin; the render proxy sees them alike, this one does not
    assert biased > 20 * random
    garbage = np.where(valid[..., None], ref * 1.05, 1e6).astype(np.float32)
    assert albedo_proxy_error(ref, garbage, valid=valid) == pytest.approx(biased, rel=1e-6)
    first = albedo_proxy_error(np.moveaxis(ref, -1, 0), np.moveaxis(garbage, -1, 0),
                               valid=valid)
    assert first == pytest.approx(biased, rel=1e-6)
    with pytest.raises(ValueError, match="equal 4-D"):
        albedo_proxy_error(ref, ref[:-1])
    with pytest.raises(ValueError, match="does not match"):
        albedo_proxy_error(ref[:, :8], ref[:, :8], make_albedo_proxy(SMALL))
    coarser = (SMALL[0], SMALL[1], SMALL[2] // 2)  # its bins are all inside SMALL's
    with pytest.raises(ValueError, match="does not match"):
        albedo_proxy_error(ref, ref, make_albedo_proxy(coarser))


def test_render_albedo_selector_picks_the_smaller_product(small_ensemble):
    b = load_brdf("mitsuba:cu-ggx-0.12", shape=SMALL)
    m = encode(b, small_ensemble, 32, selector="render-albedo")
    st = m.stats["transforms"]
    product = {t: st[t]["render_proxy"] * st[t]["albedo_proxy"] for t in st}
    assert m.transform == min(product, key=product.get)
    assert all(st[t]["render_albedo"] == product[t] for t in st)
    assert m.stats["selector"] == "render-albedo"
    rec = m.decode(small_ensemble, valid=b.valid).values
    assert st[m.transform]["albedo_proxy"] == pytest.approx(
        albedo_proxy_error(b.values, rec, valid=b.valid), rel=1e-4)


# ------------------------------------------------------------------- invalid-bin fill
def test_filling_invalid_bins_needs_fewer_coefficients(small_ensemble):
    """Below-horizon bins fitted as zeros put a sharp edge into a smooth material; as
    free values they cost nothing: a quarter of the coefficients fit the valid bins
    better, and at equal counts the error falls several-fold."""
    for name in ("diffuse-white", "plastic-red-ggx-0.3"):
        b = load_brdf(f"mitsuba:{name}", shape=SMALL)
        err = {(fill, n): _valid_error(b, encode(b, small_ensemble, n, transform="log-plus",
                                                  fill=fill), small_ensemble)
               for fill in ("missing", "invalid") for n in (8, 32)}
        assert err["invalid", 8] < err["missing", 32]
        assert err["invalid", 32] < 0.2 * err["missing", 32]


def test_fill_residual_never_increases_and_stats(small_ensemble):
    b = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    m = encode(b, small_ensemble, 16, transform="log-plus", fill="invalid", fill_iters=6)
    f = m.stats["transforms"]["log-plus"]["fill"]
    h = [f["valid_residual_unfilled"], *f["valid_residual"]]
    assert 1 <= f["fits"] == len(f["valid_residual"]) <= 6
    assert all(b_ <= a * (1 + 1e-4) for a, b_ in zip(h, h[1:], strict=False))
    assert h[-1] < 0.5 * h[0]
    assert m.n_coeffs.tolist() == [16, 16, 16]
    # fill_iters=0: the zero-filled encoding itself
    m0 = encode(b, small_ensemble, 16, transform="log-plus", fill="invalid", fill_iters=0)
    plain = encode(b, small_ensemble, 16, transform="log-plus", fill_iters=0)
    assert [a.tolist() for a in m0.locations] == [a.tolist() for a in plain.locations]


def test_fill_invalid_fills_unmeasured_bins_too(small_ensemble):
    clean = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    keep = np.random.default_rng(0).random(SMALL) >= 0.2
    holes = type(clean)(clean.values * keep[..., None], clean.valid & keep, "holes")
    snr = {fill: cosine_weighted_snr(clean.values, encode(
        holes, small_ensemble, 64, fill=fill, fill_iters=i).decode(
        small_ensemble, valid=clean.valid).values, clean.valid)
        for fill, i in (("missing", 0), ("invalid", 3))}
    assert snr["invalid"] > snr["missing"] + 3


# ------------------------------------------------------------ opponent basis, joint budget
def test_opponent_basis_spends_a_joint_budget(small_ensemble):
    b = load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)
    m = encode(b, small_ensemble, 32, transform="log-plus", basis="opponent")
    assert m.basis == "opponent" and m.n_coeffs.sum() == 3 * 32
    st = m.stats["transforms"]["log-plus"]
    assert st["budget"]["coefficients"] == m.n_coeffs.tolist()
    assert st["budget"]["energy_share"][0] == max(st["budget"]["energy_share"])
    assert m.n_coeffs[0] > 32  # the luminance channel gets the largest share
    # the kept coefficients are the 96 largest of the three channels' projections
    y = to_basis(forward(b.channel_first(), "log-plus", b.valid), "opponent")
    kept = sum(float(np.sum(v.astype(np.float64) ** 2)) for v in m.values)
    res = float(np.sum(np.square(y - m.coded(small_ensemble), dtype=np.float64)))
    assert res == pytest.approx(float(np.sum(np.square(y, dtype=np.float64))) - kept, rel=1e-3)
    # decoding mixes the channels back: the same values as the transformed R, G, B
    np.testing.assert_allclose(m.decode(small_ensemble).values[b.valid],
                               np.moveaxis(inverse(m.transformed(small_ensemble), "log-plus"),
                                           0, -1)[b.valid], rtol=1e-5, atol=1e-6)
    chan = encode(b, small_ensemble, 32, transform="log-plus", basis="opponent",
                  budget="channel")
    assert chan.n_coeffs.tolist() == [32, 32, 32]


def test_joint_max_error_is_relative_to_the_total_energy(small_ensemble):
    b = load_brdf("mitsuba:diffuse-white", shape=SMALL)
    m = encode(b, small_ensemble, 200, max_error=1e-2, transform="log-plus", basis="opponent")
    assert m.n_coeffs.sum() < 600
    y = to_basis(forward(b.channel_first(), "log-plus", b.valid), "opponent")
    res = float(np.sum(np.square(y - m.coded(small_ensemble), dtype=np.float64)))
    assert res <= 1e-2 * float(np.sum(np.square(y, dtype=np.float64))) * (1 + 1e-3)


def test_all_levers_combined(small_ensemble, tmp_path):
    b = load_brdf("mitsuba:cu-ggx-0.35", shape=SMALL)
    plain = encode(b, small_ensemble, 16)
    m = encode(b, small_ensemble, 16, selector="render", fill="invalid", basis="opponent")
    assert m.n_coeffs.sum() == 48 and m.basis == "opponent"
    assert m.stats["options"] == {"selector": "render", "fill": "invalid", "fill_iters": 3,
                                  "basis": "opponent", "budget": "joint"}
    snr = [cosine_weighted_snr(b.values, x.decode(small_ensemble, valid=b.valid).values,
                               b.valid) for x in (plain, m)]
    assert snr[1] > snr[0] + 3
    back = load_sbrdf(save_sbrdf(tmp_path / "m.sbrdf", m, version=1), small_ensemble)  # exact
    assert back.basis == "opponent"
    np.testing.assert_array_equal(back.decode(small_ensemble).values,
                                  m.decode(small_ensemble).values)


def test_options_are_checked():
    assert check_options()["budget"] == "joint"
    assert check_options(basis="rgb")["budget"] == "channel"
    assert check_options(basis="opponent")["budget"] == "joint"
    assert check_options(fill="invalid")["fill_iters"] == 3
    for bad, match in ((dict(fill="all"), "unknown fill"), (dict(basis="xyz"), "colour basis"),
                       (dict(budget="x"), "unknown budget"),
                       (dict(fill_iters=-1), "fill_iters must be an integer in"),
                       (dict(colour="rgb"), "unknown encoding option")):
        with pytest.raises(ValueError, match=match):
            check_options(**bad)


# --------------------------------------------------------------- spec grammar and CLI
def test_sparse_spec_grammar_gives_unique_names(small_ensemble):
    names = {spec: make_model(spec, small_ensemble).name for spec in (
        "sparse:262", "sparse:262:log-plus", "sparse:262:selector=gamma-mse",
        "sparse:262:auto:fill=missing", "sparse:262:basis=rgb", "sparse:262:paper",
        "sparse:262:log-plus:selector=gamma-mse,fill=missing,basis=rgb",
        "sparse:262:fill=invalid,fill_iters=5", "sparse:262:basis=rgb,budget=joint",
        "sparse:262:budget=channel", "sparse:262:selector=render")}
    assert len(set(names.values())) == len(names)
    assert names["sparse:262"] == "sparse-262"
    assert names["sparse:262:log-plus:selector=gamma-mse,fill=missing,basis=rgb"] == \
        "sparse-262-log-plus-paper"
    assert names["sparse:262:basis=rgb,budget=joint"] == "sparse-262-basis=rgb-budget=joint"
    assert names["sparse:262:selector=render"] == "sparse-262-selector=render"
    # an option at its default, or in another order, is the same model
    assert make_model("sparse:262:fill=invalid,selector=render-albedo",
                      small_ensemble).name == "sparse-262"
    assert make_model("sparse:262:basis=rgb,fill=missing", small_ensemble).name == \
        make_model("sparse:262:fill=missing,basis=rgb,budget=channel", small_ensemble).name
    for bad in ("sparse:262:fill", "sparse:262:colour=rgb", "sparse:262:fill=all",
                "sparse:262:fill=invalid,fill=missing", "sparse:262:fill_iters=x"):
        with pytest.raises(ValueError):
            make_model(bad, small_ensemble)


def test_cli_encode_flags(small_ensemble, tmp_path, capsys):
    ens = small_ensemble.save(tmp_path / "e.npz")
    sb = tmp_path / "m.sbrdf"
    src = tmp_path / "src.binary"  # a small-grid material the CLI can load
    write_merl(src, load_brdf("mitsuba:cu-ggx-0.35", shape=SMALL))
    capsys.readouterr()
    assert main(["encode", str(src), "-o", str(sb), "--coeffs", "20", "--ensemble", str(ens),
                 "--selector", "render", "--fill", "invalid", "--basis", "opponent",
                 "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert sum(info["coefficients"]) == 60
    assert info["options"]["basis"] == "opponent" and info["options"]["fill"] == "invalid"
    assert load_sbrdf(sb).basis == "opponent"



def test_the_defaults_are_the_three_options(small_ensemble):
    """Without options, ``encode`` is the render-albedo selector, invalid fill and opponent
    basis with a joint budget; ``PAPER_OPTIONS`` gives the paper's encoder."""
    b = load_brdf("mitsuba:cu-ggx-0.35", shape=SMALL)
    m = _encode(b, small_ensemble, 16)
    assert m.stats["options"] == {"selector": "render-albedo", "fill": "invalid", "fill_iters": 3,
                                  "basis": "opponent", "budget": "joint"}
    assert {k: ENCODE_OPTIONS[k] for k in PAPER_OPTIONS} != PAPER_OPTIONS
    p = _encode(b, small_ensemble, 16, **PAPER_OPTIONS)
    assert p.basis == "rgb" and p.stats["options"]["fill"] == "missing"
    assert make_model("sparse:16:paper", small_ensemble).name == "sparse-16-paper"
    assert make_model("sparse:16", small_ensemble).name == "sparse-16"
