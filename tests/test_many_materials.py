"""Scenes with many materials: the ensemble's atom rows shared by every strict-decoded
material, the scene's memory budget and its choice of decoder per material
(sparse_brdf.decoders.scene, mitsuba_plugin.budget)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.decoders.lookups import model_x
from sparse_brdf.decoders.scene import (
    MaterialCost,
    ensemble_rows,
    material_cost,
    plan_decoders,
    strict_shared_bytes,
    strict_shared_layout,
)
from sparse_brdf.metrics import render_snr
from sparse_brdf.mitsuba_env import set_variant

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")
import mitsuba_plugin  # noqa: E402
from mitsuba_plugin import budget  # noqa: E402

pytestmark = pytest.mark.numerics

N_MATERIALS = 50
#: The bound on a material's own decoder data in a scene of many (docs/rendering.md).
PER_MATERIAL_BYTES = 100_000


def random_models(ens: Ensemble, n: int, terms: int, atoms=(12, 12, 8), seed: int = 0):
    """``n`` distinct sparse models over ``ens``: per channel ``terms`` coefficients on
    the first ``atoms`` atoms of each mode (as encoded materials concentrate on the
    low-order atoms), one large term on atom (0, 0, 0)."""
    rng = np.random.default_rng(seed)
    shape = ens.shape
    out = []
    for m in range(n):
        locs, vals = [], []
        for _ in range(3):
            idx = rng.choice(int(np.prod(atoms)), terms, replace=False)
            a, b, c = np.unravel_index(idx, atoms)
            loc = np.ravel_multi_index((a, b, c), shape)
            val = rng.normal(0.0, 0.3, terms)
            val[loc == 0] = 0.0
            locs.append(np.concatenate([[0], loc[loc != 0]]))
            vals.append(np.concatenate([[np.sqrt(np.prod(shape)) * 0.01],
                                        val[loc != 0]]).astype(np.float32))
        dicts = rng.integers(0, ens.n_dicts, 3)
        out.append(SparseBRDF("log-relative", shape, ens.id, dicts, locs, vals,
                              name=f"random-{m}"))
    return out


@pytest.fixture(scope="module")
def small_library(tmp_path_factory):
    """50 distinct materials on the small grid over a random 3-dictionary ensemble."""
    folder = tmp_path_factory.mktemp("many")
    rng = np.random.default_rng(3)
    ens = Ensemble(*(np.stack([random_orthonormal(n, rng) for _ in range(3)])
                     for n in SMALL), taus=np.zeros(3))
    models = random_models(ens, N_MATERIALS, 60)
    files = [str(save_sbrdf(folder / f"m{i}.sbrdf", m)) for i, m in enumerate(models)]
    return {"ensemble": str(ens.save(folder / "ens.npz")), "ens": ens, "files": files}


@pytest.fixture
def llvm():
    set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()


def test_shared_rows_hold_every_atom_once(small_library):
    ens = small_library["ens"]
    rows = ensemble_rows(ens)
    assert rows.rows.size == sum(u.size for u in (ens.u1, ens.u2, ens.u3))
    for d in range(ens.n_dicts):
        for m, u in enumerate(ens.dictionary(d)):
            n = u.shape[0]
            atom = rows.rows[rows.offsets[d, m] + 5 * n: rows.offsets[d, m] + 6 * n]
            np.testing.assert_array_equal(atom, u[:, 5])


def test_shared_strict_layout_decodes_the_model(small_library):
    """The packed indices name dictionary atoms; read from the shared rows they give the
    model's coded channels at every bin (the kernel's arithmetic, in numpy)."""
    from sparse_brdf.decoders.layouts import END_B, PACK_BITS

    ens = small_library["ens"]
    model = load_sbrdf(small_library["files"][7], ens)
    rows = ensemble_rows(ens)
    lay = strict_shared_layout(model, ens, rows)
    assert lay.rows.size == 0 and lay.values.nbytes + lay.packed.nbytes == (
        strict_shared_bytes(model))
    bins = tuple(a.ravel() for a in np.indices(SMALL))
    mask = (1 << PACK_BITS) - 1
    coded = model.coded(ens)
    for c in range(3):
        s0, n = lay.term_offsets[c], lay.n_terms[c]
        p = lay.packed[s0:s0 + n].astype(np.int64)
        x = np.zeros(bins[0].size)
        for v, q in zip(lay.values[s0:s0 + n], p, strict=True):
            term = float(v)
            for m in range(3):
                off = lay.row_offsets[c][m] + ((q >> (m * PACK_BITS)) & mask) * SMALL[m]
                term = term * rows.rows[off + bins[m]]
            x += term
        np.testing.assert_allclose(x, coded[c].ravel(), atol=2e-5)
        assert (p[-1] & END_B) if n else True


def test_plan_gives_the_fast_tables_largest_gain_per_byte_first():
    costs = [MaterialCost(1000, 10, 100.0), MaterialCost(1000, 10, 900.0),
             MaterialCost(500, 10, 400.0), MaterialCost(10**9, 10, 1e9)]
    # per extra byte: 0.10, 0.91, 0.82; the last is past the per-material cap
    assert plan_decoders(costs, 10**12, max_fast_bytes=10**6) == [
        "grouped", "grouped", "grouped", "strict"]
    assert plan_decoders(costs, 40 + 990 + 490) == ["strict", "grouped", "grouped", "strict"]
    assert plan_decoders(costs, 40 + 990) == ["strict", "grouped", "strict", "strict"]
    assert plan_decoders(costs, 0) == ["strict"] * 4
    assert plan_decoders([], 0) == []


@pytest.mark.render
def test_every_decoder_renders_the_dense_decode(small_library, llvm):
    """50 materials at 32 x 32: grouped, strict and auto under a budget that gives the
    fast tables to some of them render what the dense decode of each file renders."""
    files, ens_path = small_library["files"], small_library["ensemble"]
    ens = small_library["ens"]
    models = [load_sbrdf(f, ens) for f in files]
    costs = [material_cost(m, ens) for m in models]
    fast = sorted(c.fast_bytes for c in costs)
    budget_mib = (sum(fast[:10]) + sum(c.compact_bytes for c in costs)) / 2**20

    def scene(kind, **opts):
        bsdfs = [mi.load_dict({"type": kind, "filename": f, "ensemble": ens_path,
                               "sampling": "cosine", **opts}) for f in files]
        mitsuba_plugin.resolve()
        d = {"type": "scene", "integrator": {"type": "direct"},
             "sensor": {"type": "perspective", "fov": 45, "to_world":
                        mi.ScalarTransform4f().look_at(origin=[0, 0, 9], target=[0, 0, 0],
                                                       up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": 32, "height": 32}},
             "light": {"type": "directional", "direction": [0.2, -0.3, -1.0],
                       "irradiance": 2.0},
             "env": {"type": "constant", "radiance": 0.3}}
        for i, b in enumerate(bsdfs):
            r, c = divmod(i, 8)
            d[f"s{i}"] = {"type": "sphere", "center": [c - 3.5, r - 3.0, 0.0],
                          "radius": 0.45, "bsdf": b}
        img = np.array(mi.render(mi.load_dict(d), spp=8, seed=1))
        return img, bsdfs

    ref, _ = scene("tabulated_brdf")
    for opts in ({"decoder": "grouped"}, {"decoder": "strict"},
                 {"decoder": "auto", "memory_budget": budget_mib}):
        img, bsdfs = scene("sparse_brdf", **opts)
        assert render_snr(ref, img) >= 100.0, opts
        decs = [b.decoder for b in bsdfs]
        if opts["decoder"] == "auto":
            assert 0 < decs.count("grouped") < len(files)
            assert sum(b.memory_bytes for b in bsdfs) <= budget_mib * 2**20
            assert budget.LAST_PLAN[0][:2] == (len(files), decs.count("grouped"))


def test_memory_per_material_on_the_merl_grid(llvm, tmp_path):
    """50 materials of 262 coefficients per channel over the shipped ensemble: on the
    strict decoder each holds its terms only (the atom rows are the ensemble's, held
    once), and under a budget of 100 kB per material the scene's auto materials hold
    at most that, the fast tables going where they gain most."""
    ens = Ensemble.default()
    models = random_models(ens, N_MATERIALS, 262, atoms=(26, 19, 9), seed=5)
    files = [str(save_sbrdf(tmp_path / f"m{i}.sbrdf", m)) for i, m in enumerate(models)]
    strict = [mi.load_dict({"type": "sparse_brdf", "filename": f, "decoder": "strict"})
              for f in files]
    assert all(b.memory_bytes <= 8 * 3 * 263 for b in strict)
    assert {b.shared_bytes for b in strict} == {ensemble_rows(ens).nbytes}
    budget_mib = N_MATERIALS * PER_MATERIAL_BYTES / 2**20
    auto = [mi.load_dict({"type": "sparse_brdf", "filename": f,
                          "memory_budget": budget_mib}) for f in files]
    held = [b.memory_bytes for b in auto]  # reading one decides the scene's pool
    assert sum(held) <= N_MATERIALS * PER_MATERIAL_BYTES
    assert 0 < [b.decoder for b in auto].count("grouped") < N_MATERIALS
    # the default budget: every material fast where the tables fit
    with mitsuba_plugin.memory_budget(None):
        few = [mi.load_dict({"type": "sparse_brdf", "filename": f}) for f in files[:3]]
    assert [b.decoder for b in few] == ["grouped"] * 3


def test_memory_budget_property_is_checked(small_library, llvm):
    with pytest.raises(Exception, match="memory_budget"):
        mi.load_dict({"type": "sparse_brdf", "filename": small_library["files"][0],
                      "ensemble": small_library["ensemble"], "memory_budget": -1.0})


def test_numpy_twin_agrees_with_shared_rows(small_library):
    """The strict decoder's numpy twin (its own rows) and the grouped one agree."""
    ens = small_library["ens"]
    model = load_sbrdf(small_library["files"][3], ens)
    bins = tuple(a.ravel() for a in np.indices(SMALL))
    np.testing.assert_allclose(model_x(model, ens, bins, "strict"),
                               model_x(model, ens, bins, "grouped"), atol=3e-5)


def test_sparse_profile_matches_the_product_over_terms(small_library):
    """The lobe's theta_h profile, contracted over distinct atoms, equals the product
    over every term it replaced (the first theta_d bins, mean over phi_d and R, G, B)."""
    from sparse_brdf.decoders.buffers import bin_weight, mix_channels
    from sparse_brdf.decoders.layouts import channel_terms
    from sparse_brdf.decoders.lobe import sparse_profile

    ens = small_library["ens"]
    for f in small_library["files"][:5]:
        model = load_sbrdf(f, ens)
        n1, n2, n3 = model.shape
        ii, kk = np.arange(n1)[:, None], np.arange(n3)[None, :]
        terms = [channel_terms(model, ens, c) for c in range(3)]
        want = np.zeros(n1)
        for j in range(3):
            xs = mix_channels(np.stack([
                (u1[:, a].astype(np.float64) * (s * u2[j, b])) @ u3[:, k].T
                for s, (a, b, k), (u1, u2, u3) in terms]), model.basis)
            w = bin_weight(ii, np.full_like(ii, j), kk, model.shape, model.transform)
            want += np.maximum(np.expm1(xs) / w, 0.0).mean(axis=2).sum(axis=0)
        np.testing.assert_allclose(sparse_profile(model, ens), want / 9, rtol=1e-6)
