"""Training: objective, orthonormality, determinism, resume, empty clusters, union;
resolving and sharing the default ensemble."""

import numpy as np
import pytest

from sparse_brdf.coding.ensemble import Ensemble, resolve_ensemble, shipped_ids
from sparse_brdf.coding.tensor import project
from sparse_brdf.errors import BRDFFileError
from sparse_brdf.training import _shards as shards_mod
from sparse_brdf.training.train import train_dictionaries, train_ensemble


@pytest.mark.train
def test_objective_never_increases(small_training):
    st = train_dictionaries(small_training, 32, n_dicts=3, n_iter=6, reassign_every=2,
                            tol=0, seed=0, progress=False)
    objs = [h["objective"] for h in st.history]
    before = [h["objective_before_update"] for h in st.history]
    assert len(objs) == 6
    for prev, cur, pre in zip(objs, objs[1:], before[1:], strict=False):
        assert pre <= prev * (1 + 1e-5)  # re-coding / re-clustering
        assert cur <= pre * (1 + 1e-5)  # Procrustes updates
    assert objs[-1] < objs[0]


def test_mode_matrices_orthonormal(small_ensemble):
    assert small_ensemble.n_dicts == 6
    assert small_ensemble.orthonormality_error() < 1e-5
    assert small_ensemble.taus.tolist() == [16, 16, 16, 64, 64, 64]


@pytest.mark.train
def test_same_seed_same_result(small_training):
    a = train_dictionaries(small_training, 16, n_dicts=2, n_iter=2, seed=5, progress=False)
    b = train_dictionaries(small_training, 16, n_dicts=2, n_iter=2, seed=5, progress=False)
    np.testing.assert_array_equal(a.u1, b.u1)
    np.testing.assert_array_equal(a.u3, b.u3)
    np.testing.assert_array_equal(a.labels, b.labels)


@pytest.mark.train
def test_resume_from_checkpoint_matches_uninterrupted(small_training, tmp_path):
    ck = tmp_path / "ck.npz"
    full = train_dictionaries(small_training, 16, n_dicts=2, n_iter=4, seed=2, tol=0,
                              progress=False)
    train_dictionaries(small_training, 16, n_dicts=2, n_iter=4, seed=2, tol=0,
                       checkpoint=ck, progress=False, callback=lambda s: s.iteration == 2)
    resumed = train_dictionaries(small_training, 16, n_dicts=2, n_iter=4, seed=2, tol=0,
                                 checkpoint=ck, progress=False)
    assert resumed.iteration == 4 and len(resumed.history) == 4
    np.testing.assert_allclose(resumed.u1, full.u1, atol=1e-6)
    with pytest.raises(ValueError, match="another training run"):
        train_dictionaries(small_training, 16, n_dicts=2, n_iter=4, seed=3, checkpoint=ck,
                           progress=False)


@pytest.mark.train
def test_shard_size_is_part_of_the_run(small_training, tmp_path):
    """The shard size fixes the summation order, so a checkpoint of one size is refused
    by a run of another; 0 (one shard of all tensors) is accepted and recorded, a
    negative size refused naming the parameter."""
    ck = tmp_path / "ck.npz"
    one = train_dictionaries(small_training, 16, n_dicts=2, n_iter=1, seed=2, tol=0,
                             checkpoint=ck, progress=False, shard_tensors=0)
    assert one.iteration == 1
    with pytest.raises(ValueError, match="another training run"):
        train_dictionaries(small_training, 16, n_dicts=2, n_iter=2, seed=2, tol=0,
                           checkpoint=ck, progress=False)
    resumed = train_dictionaries(small_training, 16, n_dicts=2, n_iter=2, seed=2, tol=0,
                                 checkpoint=ck, progress=False, shard_tensors=0)
    assert resumed.iteration == 2
    with pytest.raises(ValueError, match="shard_tensors"):
        train_dictionaries(small_training, 16, n_dicts=2, n_iter=1, progress=False,
                           shard_tensors=-1)


@pytest.mark.train
def test_empty_clusters_are_reseeded():
    # three identical tensors and one other: K = 3 leaves a cluster empty after assignment
    rng = np.random.default_rng(0)
    a = rng.random((6, 6, 12)).astype(np.float32)
    x = np.stack([a, a, a, rng.random((6, 6, 12)).astype(np.float32)])
    st = train_dictionaries(x, 4, n_dicts=3, n_iter=3, seed=0, progress=False)
    assert sum(h["reseeded"] for h in st.history) >= 1
    assert np.all(np.isfinite(st.u1))
    assert len(np.unique(st.labels)) >= 2


def test_bad_training_arguments(small_training):
    with pytest.raises(ValueError, match="tau must be"):
        train_dictionaries(small_training, 0, progress=False)
    with pytest.raises(ValueError, match="n_dicts"):
        train_dictionaries(small_training[:2], 4, n_dicts=3, progress=False)
    with pytest.raises(ValueError, match="shape"):
        train_dictionaries(small_training[0], 4, progress=False)


def test_union_save_load(small_ensemble, tmp_path):
    u = small_ensemble.union(small_ensemble)
    assert u.n_dicts == 12 and u.id != small_ensemble.id
    p = u.save(tmp_path / "e.npz")
    v = Ensemble.load(p)
    assert v.id == u.id and v.taus.tolist() == u.taus.tolist()
    p.write_bytes(p.read_bytes()[:1000])
    with pytest.raises(BRDFFileError, match="e.npz"):
        Ensemble.load(p)


@pytest.mark.train
def test_extend_with_new_transform(small_training):
    a = train_ensemble(small_training[:36], taus=(16,), n_dicts=2, n_iter=1, progress=False)
    b = train_ensemble(small_training[36:], taus=(8,), n_dicts=2, n_iter=1, progress=False)
    u = a.union(b)
    assert u.n_dicts == 4 and u.taus.tolist() == [16, 16, 8, 8]
    assert "history" in u.meta["parts"][0]


def _dense_partials(x, labels, codes_idx, codes_val, mode, n_dicts, u1, u2, u3):
    """The Procrustes products Z of ``shard_partials`` from the whole products W (every
    atom of the other two modes), the way the trainer first computed them."""
    shape = x.shape[1:]
    z = [None] * n_dicts
    for i in range(len(x)):
        j = labels[i]
        us = [u1[j], u2[j], u3[j]]
        us[mode] = np.eye(shape[mode], dtype=np.float32)  # W: mode `mode` left as it is
        w = np.moveaxis(project(x[i], *us), mode, 0)  # (n_mode, the other two)
        at = np.unravel_index(codes_idx[i], shape)
        others = [at[k] for k in range(3) if k != mode]
        part = np.zeros((shape[mode], shape[mode]))
        for t in range(len(codes_val[i])):
            part[:, at[mode][t]] += codes_val[i][t] * w[:, others[0][t], others[1][t]]
        z[j] = part if z[j] is None else z[j] + part
    return z


def test_the_update_contracts_only_the_atoms_the_codes_use(small_training):
    """The dictionary update's products from the code's own atoms equal those from the
    whole mode products (to float32 rounding), in every mode."""
    from sparse_brdf.training._tensor_store import TensorStore

    x = small_training[:10]
    rng = np.random.default_rng(3)
    n_dicts, tau = 2, 20
    shape = x.shape[1:]
    us = [np.stack([np.linalg.qr(rng.standard_normal((n, n)))[0] for _ in range(n_dicts)]
                   ).astype(np.float32) for n in shape]
    labels = rng.integers(0, n_dicts, len(x))
    idx = np.stack([rng.choice(np.prod(shape), tau, replace=False) for _ in x]).astype(np.int32)
    val = rng.standard_normal((len(x), tau)).astype(np.float32)
    store = TensorStore(x, masked=False)
    for mode in range(3):
        got = shards_mod.shard_partials(store, labels, idx, val, mode, n_dicts, *us)
        want = _dense_partials(x, labels, idx, val, mode, n_dicts, *us)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(g, w, rtol=1e-4, atol=1e-4 * np.abs(w).max())


def test_default_ensemble_is_loaded_once_and_read_only():
    ens = Ensemble.default()
    assert Ensemble.default() is ens and resolve_ensemble() is ens
    assert resolve_ensemble("") is ens
    for a in (ens.u1, ens.u2, ens.u3, ens.taus):
        assert not a.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        ens.u1[0, 0, 0] = 0.0


def test_resolve_ensemble_passes_ensembles_and_loads_paths(small_ensemble, tmp_path):
    assert resolve_ensemble(small_ensemble) is small_ensemble
    p = small_ensemble.save(tmp_path / "e.npz")
    for given in (p, str(p)):
        loaded = resolve_ensemble(given)
        assert loaded.id == small_ensemble.id and loaded.u1.flags.writeable


def _tiny_model(ensemble_id: str):
    from sparse_brdf.coding.coefficients import SparseBRDF
    from sparse_brdf.coords import MERL_SHAPE

    locs = [np.array([0, 5, 700]), np.array([0, 9]), np.array([0])]
    vals = [np.array([2.0, -0.3, 0.1]), np.array([1.5, 0.2]), np.array([1.0])]
    return SparseBRDF("log-plus", MERL_SHAPE, ensemble_id, np.array([0, 1, 2]), locs, vals,
                      name="tiny")


@pytest.mark.parametrize("ensemble_id", shipped_ids())
def test_files_find_the_shipped_ensemble_they_name(ensemble_id, tmp_path):
    """A file encoded with any shipped ensemble (older defaults included) decodes without
    ``--ensemble``, with exactly that ensemble."""
    from sparse_brdf.coding.fileformat import decode_file, load_sbrdf, save_sbrdf

    model = _tiny_model(ensemble_id)
    path = save_sbrdf(tmp_path / "m.sbrdf", model)
    got = decode_file(path)
    want = load_sbrdf(path).decode(Ensemble.shipped(ensemble_id))  # the file's values
    np.testing.assert_array_equal(got.values, want.values)
    assert Ensemble.shipped(ensemble_id).id == ensemble_id


def test_a_file_naming_an_unknown_ensemble_says_which_it_needs(tmp_path):
    from sparse_brdf.coding.fileformat import decode_file, save_sbrdf
    from sparse_brdf.errors import EnsembleMismatchError

    path = save_sbrdf(tmp_path / "m.sbrdf", _tiny_model("ab" * 16))
    with pytest.raises(EnsembleMismatchError, match=f"m.sbrdf: ensemble {'ab' * 16} is not "
                       "shipped.*--ensemble"):
        decode_file(path)
    other = shipped_ids()[-1]
    with pytest.raises(EnsembleMismatchError, match=f"encoded with ensemble {'ab' * 16}, but "
                       f"ensemble {other} was given"):
        decode_file(path, Ensemble.shipped(other))


def test_the_default_is_the_first_shipped_ensemble():
    from sparse_brdf.paths import DEFAULT_ENSEMBLE_ID

    assert shipped_ids()[0] == DEFAULT_ENSEMBLE_ID == Ensemble.default().id
    assert len(shipped_ids()) >= 2  # the previous default stays loadable


def test_an_id_names_a_shipped_ensemble():
    for ensemble_id in shipped_ids():
        assert resolve_ensemble(ensemble_id) is Ensemble.shipped(ensemble_id)
    with pytest.raises(ValueError, match=f"ensemble {'cd' * 16} is not shipped"):
        resolve_ensemble("cd" * 16)


@pytest.mark.shared
@pytest.mark.train
@pytest.mark.numerics
def test_the_default_ensemble_was_trained_on_the_data_its_rebuild_reads(shared_data):
    """The training data the documented rebuild reads match the shipped default's
    ``meta["data_fingerprint"]``: the exact inputs (each network's bytes, Mitsuba's BSDFs
    and version, the transforms, the colour basis, the grid, the symmetrisation) and every
    tensor's statistics within the stated tolerance, which rounding on another CPU stays
    far inside (docs/ensemble.md, "Rebuilding the default"). A failure names each
    material and statistic that moved. The bit-exact digest (``meta["data_sha256"]``) is
    not compared: it holds only on the machine that trained the ensemble."""
    from sparse_brdf.sources.corpora import get_corpus
    from sparse_brdf.sources.dataset import fingerprint_mismatches, training_fingerprint

    ens = Ensemble.default()
    meta = ens.meta
    materials = [m for c in meta["corpora"] for m in get_corpus(c).split(meta["split"])]
    assert [f"{m.corpus}/{m.name}" for m in materials] == meta["data"]
    assert ens.transforms == tuple(meta["transforms"])
    got = training_fingerprint(materials, meta["transforms"], tuple(meta["grid"]),
                               progress=False, basis=meta["basis"])
    mismatches = fingerprint_mismatches(got, meta["data_fingerprint"])
    assert not mismatches, "\n".join(mismatches[:20])
