"""The Neural-BRDF trainer (sparse_brdf.compared.neural), its shared forward pass
(sparse_brdf.mlp), the bench's ``nbrdf`` model and its Dr.Jit evaluator."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.brdf import BRDF
from sparse_brdf.compared import neural
from sparse_brdf.compared.neural import NBRDFModel, train_nbrdf
from sparse_brdf.compared.specs import make_model
from sparse_brdf.coords import bin_angles, dirs_to_angles
from sparse_brdf.errors import UsageError
from sparse_brdf.metrics import cosine_weighted_snr
from sparse_brdf.mlp import (
    N_WEIGHTS,
    evaluate,
    forward,
    layers_from_params,
    network_inputs,
    params_from_layers,
    tabulate,
)
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.nbrdf import read_nbrdf_weights

TEACHER = DEMO_MATERIALS_DIR / "red-specular-plastic.h5"


@pytest.fixture(scope="module")
def teacher():
    """A shipped network and its table on the small grid."""
    layers = read_nbrdf_weights(TEACHER)
    values, valid = tabulate(layers, SMALL)
    return layers, BRDF(values, valid, name="teacher")


def _float64(layers):
    return [(k.astype(np.float64), b.astype(np.float64)) for k, b in layers]


# ---------------------------------------------------------------------- the formulas


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    layers = [(k, rng.normal(0.0, 0.2, b.shape).astype(np.float32))
              for k, b in neural.glorot_layers(rng)]
    x = rng.normal(size=(48, 6)).astype(np.float32)
    cos_i = rng.uniform(0.1, 1.0, (48, 1)).astype(np.float32)
    target = rng.uniform(0.0, 0.6, (48, 3)).astype(np.float32)
    grads = neural.loss_gradient(layers, x, target, cos_i)
    wide = _float64(layers)
    h = 1e-4
    checked = 0
    for li, (k, b) in enumerate(wide):
        for which, arr in enumerate((k, b)):
            for idx in list(np.ndindex(arr.shape))[::5]:
                old = arr[idx]
                arr[idx] = old + h
                up = neural.loss(wide, x, target, cos_i)
                arr[idx] = old - h
                down = neural.loss(wide, x, target, cos_i)
                arr[idx] = old
                fd = (up - down) / (2 * h)
                assert abs(fd - grads[li][which][idx]) < 1e-4 * (1 + abs(fd)), (li, which, idx)
                checked += 1
    assert checked > 100
    assert max(float(np.abs(g).max()) for pair in grads for g in pair) > 1e-3


def test_forward_pass_is_the_shipped_networks():
    """The trainer's forward pass is the one that tabulates the shipped files."""
    layers = read_nbrdf_weights(TEACHER)
    th, td, pd = (a[::3] for a in bin_angles(SMALL))
    x = network_inputs(*np.meshgrid(th, td, pd, indexing="ij"))
    _, z = forward(layers, x)
    np.testing.assert_array_equal(evaluate(layers, x), np.maximum(np.expm1(z), 0.0))
    h = x
    for i, (k, b) in enumerate(layers):  # written out once more, independently
        h = h.astype(np.float64) @ k + b
        h = np.maximum(h, 0.0) if i < 2 else h
    np.testing.assert_allclose(evaluate(layers, x), np.maximum(np.expm1(h), 0.0),
                               rtol=1e-4, atol=1e-6)


def test_targets_interpolate_the_table(teacher):
    _, brdf = teacher
    th, td, pd = bin_angles(SMALL)
    i, j, k = 9, 4, 7
    at = brdf.values[i, j, k].astype(np.float64)
    rho, covered = neural.table_values(brdf, np.array([th[i]]), np.array([td[j]]),
                                       np.array([pd[k]]))
    assert covered.all()
    np.testing.assert_allclose(rho[0], at, rtol=1e-6)
    mid = 0.5 * (pd[k] + pd[k + 1])
    rho, _ = neural.table_values(brdf, np.array([th[i]]), np.array([td[j]]), np.array([mid]))
    np.testing.assert_allclose(rho[0], 0.5 * (at + brdf.values[i, j, k + 1]), rtol=1e-6)
    # phi_d wraps: halfway past the last sample is halfway to the first one
    last = pd[-1] + 0.5 * (pd[1] - pd[0])
    rho, _ = neural.table_values(brdf, np.array([th[i]]), np.array([td[j]]), np.array([last]))
    np.testing.assert_allclose(rho[0], 0.5 * (brdf.values[i, j, -1] + brdf.values[i, j, 0]),
                               rtol=1e-6)


def test_training_set_is_above_the_horizon(teacher):
    _, brdf = teacher
    x, target, cos_i = neural.training_set(brdf, 5000, np.random.default_rng(0))
    assert x.shape == (5000, 6) and target.shape == (5000, 3) and cos_i.shape == (5000, 1)
    assert x.dtype == target.dtype == cos_i.dtype == np.float32
    assert np.all(cos_i > 0) and np.all(target >= 0) and np.all(x[:, 1] == 0)
    np.testing.assert_allclose(np.linalg.norm(x[:, :3], axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(x[:, 3:], axis=1), 1.0, rtol=1e-6)
    assert np.all(x[:, 4] >= 0)  # phi_d in [0, pi)


# ---------------------------------------------------------------------- training


def test_same_seed_same_weights(teacher):
    _, brdf = teacher
    runs = [train_nbrdf(brdf, epochs=2, n_samples=3000, seed=s, progress=False)
            for s in (4, 4, 5)]
    for (k0, b0), (k1, b1) in zip(runs[0].layers, runs[1].layers, strict=True):
        np.testing.assert_array_equal(k0, k1)
        np.testing.assert_array_equal(b0, b1)
    assert runs[0].loss == runs[1].loss
    assert not np.array_equal(runs[0].layers[0][0], runs[2].layers[0][0])


def test_training_reproduces_a_known_network():
    """A network trained on a shipped network's table on the small grid (blue-fabric,
    25 epochs of 40,000 samples): the loss falls to a fifth of the first epoch's and the
    table is matched to a cosine-weighted SNR above 12 dB (measured: loss 0.017 ->
    0.0012, 17.2 dB)."""
    values, valid = tabulate(read_nbrdf_weights(DEMO_MATERIALS_DIR / "blue-fabric.h5"), SMALL)
    brdf = BRDF(values, valid, name="blue-fabric")
    fit = train_nbrdf(brdf, epochs=25, n_samples=40_000, progress=False)
    assert fit.epochs == 25 and fit.steps == 25 * -(-40_000 // 512)
    assert not fit.stopped_early
    assert fit.loss[-1] < 0.2 * fit.loss[0]
    rec, _ = tabulate(fit.layers, SMALL)
    assert cosine_weighted_snr(brdf.values, rec, brdf.valid) > 12.0


def test_time_budget_stops_training(teacher):
    _, brdf = teacher
    fit = train_nbrdf(brdf, epochs=100_000, n_samples=2000, time_budget=0.3, progress=False)
    assert fit.stopped_early and fit.epochs < 100_000 and fit.steps >= 1
    assert len(fit.loss) == fit.epochs
    assert all(np.all(np.isfinite(k)) for k, _ in fit.layers)
    assert "stopped early" in repr(fit)


def test_bad_options_are_usage_errors(teacher):
    _, brdf = teacher
    for kwargs, match in (({"epochs": 0}, "nbrdf epochs"), ({"batch_size": 2.5}, "batch_size"),
                          ({"learning_rate": 0.0}, "learning_rate"),
                          ({"time_budget": -1.0}, "time_budget"), ({"seed": -1}, "seed"),
                          ({"n_samples": True}, "n_samples")):
        with pytest.raises(UsageError, match=match):
            train_nbrdf(brdf, progress=False, **kwargs)
        with pytest.raises(UsageError, match=match):
            NBRDFModel(**kwargs)
    for spec in ("nbrdf:epochs=0", "nbrdf:width=30", "nbrdf:time_budget=x", "nbrdf:20"):
        with pytest.raises(UsageError, match="model 'nbrdf"):
            make_model(spec)


# ---------------------------------------------------------------------- the bench model


def test_nbrdf_model_stores_675_float32(teacher):
    _, brdf = teacher
    model = make_model("nbrdf:epochs=1,n_samples=2000")
    model.progress = False
    c = model.compress(brdf)
    assert (c.kind, c.nbytes, c.param_nbytes()) == ("nbrdf", 2700, 2700)
    assert sum(p.size for p in c.params.values()) == N_WEIGHTS == 675
    assert all(p.dtype == np.float32 for p in c.params.values())
    rec = c.reconstruct()
    assert rec.shape == (*SMALL, 3) and np.all(rec[~brdf.valid] == 0) and rec.max() > 0
    np.testing.assert_array_equal(rec, tabulate(layers_from_params(c.params), SMALL)[0])
    assert c.info["epochs"] == 1 and not c.info["stopped_early"]


# ---------------------------------------------------------------------- the evaluator


@pytest.fixture
def llvm():
    pytest.importorskip("mitsuba")
    from sparse_brdf.mitsuba_env import set_variant

    return set_variant("llvm_ad_rgb")


def test_drjit_evaluator_equals_the_numpy_pass(llvm):
    import mitsuba as mi

    from mitsuba_plugin.evaluators import make_evaluator

    layers = read_nbrdf_weights(TEACHER)
    ev = make_evaluator("nbrdf", params_from_layers(layers))
    assert ev.material_bytes == 2700
    rng = np.random.default_rng(2)
    v = rng.standard_normal((2, 20000, 3))
    v[..., 2] = np.abs(v[..., 2])
    v = (v / np.linalg.norm(v, axis=-1, keepdims=True)).astype(np.float32)
    th, td, pd = dirs_to_angles(v[0].astype(np.float64), v[1].astype(np.float64))
    x = network_inputs(th, td, np.where(pd < 0, pd + np.pi, pd))
    # the same inputs: float32 arithmetic, fused multiply-adds in another order
    z = ev.network([mi.Float(x[:, 0].copy()), None, *(mi.Float(x[:, c].copy())
                                                      for c in range(2, 6))])
    _, want_z = forward(layers, x)
    np.testing.assert_allclose(np.stack([np.asarray(c) for c in z], 1), want_z,
                               rtol=1e-5, atol=2e-6)
    # from the directions: the evaluator's own float32 half and difference vectors
    want = evaluate(layers, x)
    got = ev.eval_numpy(v[0], v[1])
    assert np.count_nonzero(want) > 0.9 * want.size
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-5)
    w = rng.standard_normal((2, 4000, 3)).astype(np.float32)
    w /= np.linalg.norm(w, axis=-1, keepdims=True)
    below = (w[0][:, 2] <= 0) | (w[1][:, 2] <= 0)
    assert np.all(ev.eval_numpy(w[0], w[1])[below] == 0)


def test_evaluator_speed_axis_and_one_kernel(llvm, teacher):
    """The speed axis times the evaluator; a second network compiles no new kernel."""
    import math

    import drjit as dr

    from mitsuba_plugin.evaluators import evaluator_for
    from sparse_brdf.benchmark.speed import evals_per_second

    _, brdf = teacher
    model = NBRDFModel(epochs=1, n_samples=1000, progress=False)
    first = model.compress(brdf)
    other = NBRDFModel(epochs=1, n_samples=1000, seed=1, progress=False).compress(brdf)
    rate = evals_per_second(first, n=4096, repeats=1)
    assert math.isfinite(rate) and rate > 0
    wi = np.tile(np.float32([[0.3, 0.1, 0.95]]), (1024, 1))
    wo = np.tile(np.float32([[-0.2, 0.4, 0.89]]), (1024, 1))
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        hashes = []
        for c in (first, other):
            ev = evaluator_for(c)
            dr.kernel_history()  # clear
            ev.eval_numpy(wi, wo)
            hashes.append({k["hash"] for k in dr.kernel_history()
                           if k["type"] == dr.KernelType.JIT and k["operation_count"] > 100})
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert hashes[0] and hashes[1] <= hashes[0]


def test_recipe_is_the_defaults():
    """The published recipe, the trainer's defaults and the model's are one set."""
    import inspect

    assert neural.RECIPE == {"epochs": 100, "batch_size": 512, "learning_rate": 5e-4,
                             "n_samples": 800_000}
    for func in (train_nbrdf, NBRDFModel.__init__):
        sig = inspect.signature(func).parameters
        assert {k: sig[k].default for k in neural.RECIPE} == neural.RECIPE, func
        assert sig["seed"].default == 0 and sig["time_budget"].default is None
    assert set(neural.PARAMETERS) == {*neural.RECIPE, "seed", "time_budget"}
