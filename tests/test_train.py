"""Training options: masked training (free bins below the horizon and unmeasured bins),
the colour basis of the training tensors, the seeded initialisation, the stopping rule
and the ``train`` command's new options."""

import json

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.brdf import BRDF
from sparse_brdf.cli import main
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coords import geometric_valid, grid_angles
from sparse_brdf.fingerprints import fingerprint_changes, fingerprint_list
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.dataset import (
    TrainingData,
    fingerprint_mismatches,
    training_data,
    training_fingerprint,
    training_tensors,
)
from sparse_brdf.training import _codes
from sparse_brdf.training._tensor_store import TensorStore
from sparse_brdf.training.train import _converged, train_dictionaries, train_ensemble
from sparse_brdf.transforms import forward, to_basis


def _family(n: int, rng: np.random.Generator) -> list[BRDF]:
    """A smooth family (Lambert + Beckmann-like lobe with Schlick Fresnel) on the small
    grid: nonzero up to the horizon, so each tensor has an edge where it drops to the 0 of
    the bins below it."""
    th, td, _ = grid_angles(SMALL)
    valid = geometric_valid(SMALL)
    out = []
    for k in range(n):
        kd = rng.uniform(0.05, 0.8, 3)
        a, ks = rng.uniform(0.08, 0.5), rng.uniform(0.05, 0.6)
        fresnel = 0.04 + 0.96 * (1 - np.cos(td)) ** 5
        spec = ks * fresnel * np.exp(-np.tan(th) ** 2 / a**2) / (np.pi * a**2 * np.cos(th) ** 4)
        out.append(BRDF((kd / np.pi + spec[..., None]).astype(np.float32), valid, name=f"m{k}"))
    return out


def _valid_error(brdf: BRDF, ens: Ensemble, n: int) -> float:
    """Relative squared error over valid bins (transformed domain) of ``brdf`` encoded
    with ``n`` coefficients per channel (log-plus; the encoder fills every invalid bin)."""
    m = encode(brdf, ens, n, transform="log-plus", fill="invalid")
    y = forward(brdf.channel_first(), "log-plus", brdf.valid)
    d = (y - m.transformed(ens))[:, brdf.valid].astype(np.float64)
    return float(np.sum(d**2) / np.sum(y[:, brdf.valid].astype(np.float64) ** 2))


@pytest.mark.train
def test_masked_training_codes_held_out_materials_better():
    """Dictionaries that do not spend atoms on the horizon edge code unseen materials of the
    family with less error over valid bins, with the same encoder for both."""
    rng = np.random.default_rng(0)
    train, test = _family(24, rng), _family(6, rng)
    x = np.concatenate([forward(b.channel_first(), "log-plus", b.valid) for b in train])
    ens = {masked: train_ensemble(x, taus=(16,), n_dicts=2, n_iter=4, seed=0, masked=masked,
                                  progress=False) for masked in (True, False)}
    for n in (8, 16):
        err = {m: np.mean([_valid_error(b, ens[m], n) for b in test]) for m in ens}
        assert err[True] < 0.8 * err[False], (n, err)
    # the training objective counts valid bins only
    h = {m: ens[m].meta["history"]["16"][-1]["relative_objective"] for m in ens}
    assert h[True] < 0.5 * h[False]
    assert ens[True].meta["masked"] is True and ens[False].meta["masked"] is False


@pytest.mark.train
def test_masked_training_ignores_free_bins(small_training):
    """Masked, whatever the tensors hold below the horizon or in unmeasured bins changes
    nothing: those bins are free values, refilled from the model."""
    x = small_training[:24]
    rng = np.random.default_rng(1)
    below = ~geometric_valid(SMALL)
    holes = np.zeros(SMALL, bool)
    holes[5:8, 3:6, 10:20] = True
    holes &= ~below
    junk = x.copy()
    junk[:, below] = rng.random((len(x), int(below.sum())), dtype=np.float32)
    junk[3:6, holes] = 7.0
    zeroed = x.copy()
    zeroed[3:6, holes] = 0.0
    missing = {i: holes for i in range(3, 6)}
    kw = dict(tau=12, n_dicts=2, n_iter=3, tol=0, seed=3, progress=False, missing=missing)
    given = junk.copy()
    a = train_dictionaries(zeroed, **kw)
    b = train_dictionaries(junk, **kw)
    for name in ("u1", "u2", "u3", "labels", "codes_idx", "errors"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
    np.testing.assert_array_equal(junk, given)  # the tensors are never written
    c = train_dictionaries(junk, **{**kw, "masked": False})
    assert not np.allclose(a.u1, c.u1)


@pytest.mark.train
@pytest.mark.parametrize("masked, init", [(True, "seeded"), (False, "random")])
def test_objective_never_increases_in_each_mode(small_training, masked, init):
    st = train_dictionaries(small_training, 24, n_dicts=3, n_iter=5, reassign_every=2,
                            tol=0, seed=4, progress=False, masked=masked, init=init)
    objs = [h["objective"] for h in st.history]
    before = [h["objective_before_update"] for h in st.history]
    for prev, cur, pre in zip(objs, objs[1:], before[1:], strict=False):
        assert pre <= prev * (1 + 1e-5)
        assert cur <= pre * (1 + 1e-5)
    assert objs[-1] < objs[0]
    assert all(0 <= h["moved_fraction"] <= 1 for h in st.history)


@pytest.mark.train
def test_seeded_init_is_deterministic_and_resumes(small_training, tmp_path):
    kw = dict(tau=16, n_dicts=3, n_iter=3, tol=0, seed=7, progress=False, init="seeded")
    a = train_dictionaries(small_training, **kw)
    ck = tmp_path / "ck.npz"
    train_dictionaries(small_training, checkpoint=ck, callback=lambda s: s.iteration == 1, **kw)
    b = train_dictionaries(small_training, checkpoint=ck, **kw)
    assert b.iteration == 3
    np.testing.assert_allclose(a.u1, b.u1, atol=1e-6)
    np.testing.assert_array_equal(a.labels, b.labels)
    with pytest.raises(ValueError, match="another training run"):
        train_dictionaries(small_training, checkpoint=ck, **{**kw, "init": "random"})
    with pytest.raises(ValueError, match="unknown init"):
        train_dictionaries(small_training, 16, init="kmeans", progress=False)


@pytest.mark.train
def test_warm_start_begins_where_the_previous_sparsity_ended(small_training, tmp_path):
    """A warm-started sparsity starts from the previous one's dictionaries and clusters,
    coded at its own tau: it ends below a cold start's objective in as many iterations,
    its objective never rises, and a run cut after its first iteration resumes to the
    same dictionaries."""
    x = small_training
    kw = dict(taus=(8, 24), n_dicts=3, n_iter=3, seed=2, progress=False, tol=0)
    cold = train_ensemble(x, **kw)  # the default
    warm = train_ensemble(x, warm_start=True, **kw)
    assert warm.meta["warm_start"] is True and cold.meta["warm_start"] is False
    # the first sparsity is trained as without a warm start
    assert ([h["objective"] for h in cold.meta["history"]["8"]]
            == [h["objective"] for h in warm.meta["history"]["8"]])
    hw, hc = warm.meta["history"]["24"], cold.meta["history"]["24"]
    assert hw[-1]["objective"] < 0.95 * hc[-1]["objective"]  # measured: 0.88
    objs = [h["objective"] for h in hw]
    assert all(b <= a * (1 + 1e-5) for a, b in zip(objs, objs[1:], strict=False))
    # the tau-8 state, then tau 24 started from it: a checkpointed, resumed run matches
    st8 = train_dictionaries(x, 8, n_dicts=3, n_iter=3, seed=1, progress=False, tol=0)
    start = (st8.u1, st8.u2, st8.u3, st8.labels)
    one = dict(n_dicts=3, n_iter=3, seed=3, progress=False, tol=0, start=start)
    a = train_dictionaries(x, 24, **one)
    ck = tmp_path / "ck.npz"
    train_dictionaries(x, 24, checkpoint=ck, callback=lambda s: s.iteration == 1, **one)
    b = train_dictionaries(x, 24, checkpoint=ck, **one)
    np.testing.assert_array_equal(a.u1, b.u1)
    np.testing.assert_array_equal(a.labels, b.labels)
    # another start is another run: its checkpoint is refused
    other = (st8.u1, st8.u2, st8.u3, (st8.labels + 1) % 3)
    with pytest.raises(ValueError, match="another training run"):
        train_dictionaries(x, 24, checkpoint=ck, **{**one, "start": other})


def test_a_warm_start_that_does_not_fit_is_refused(small_training):
    x = small_training[:6]
    n1, n2, n3 = x.shape[1:]
    eye = [np.broadcast_to(np.eye(n, dtype=np.float32), (2, n, n)) for n in (n1, n2, n3)]
    with pytest.raises(ValueError, match="mode-2 matrices"):
        train_dictionaries(x, 4, n_dicts=2, progress=False,
                           start=(eye[0], eye[2], eye[2], np.zeros(6, int)))
    with pytest.raises(ValueError, match="labels"):
        train_dictionaries(x, 4, n_dicts=2, progress=False,
                           start=(*eye, np.full(6, 2)))


def test_stopping_rule():
    def h(obj, moved=0, assigned=False):
        return {"objective": obj, "moved": moved, "assigned": assigned}

    n = 100
    # the first iteration's clustering does not count
    assert not _converged([h(10.0, 90, True), h(9.9999)], 1e-4, 0.01, n)
    # latest clustering moved 1 of 100 and the decrease is below tol
    assert _converged([h(10.0, 90, True), h(9.0, 1, True), h(8.9999)], 1e-4, 0.01, n)
    assert not _converged([h(10.0, 90, True), h(9.0, 2, True), h(8.9999)], 1e-4, 0.01, n)
    assert not _converged([h(10.0, 90, True), h(9.0, 1, True), h(8.9)], 1e-4, 0.01, n)


@pytest.mark.train
def test_training_stops_when_settled(small_training):
    st = train_dictionaries(small_training, 16, n_dicts=2, n_iter=30, reassign_every=1,
                            tol=1.0, max_moved=1.0, seed=0, progress=False)
    assert st.iteration == 2  # the second clustering satisfies the (loose) rule
    st = train_dictionaries(small_training, 16, n_dicts=2, n_iter=3, reassign_every=1,
                            tol=0.0, seed=0, progress=False)
    assert st.iteration == 3  # tol 0: only the cap stops


def test_training_data_in_opponent_basis():
    mats = get_corpus("mitsuba").split("train")[:2]
    rgb = training_data(mats, shape=SMALL, progress=False)
    opp = training_data(mats, shape=SMALL, progress=False, basis="opponent")
    assert rgb.missing == {} and opp.basis == "opponent"
    assert opp.labels[:3] == [f"mitsuba/{mats[0].name}:log-relative:{c}"
                              for c in ("L", "RG", "YB")]
    np.testing.assert_allclose(opp.x[:3], to_basis(rgb.x[:3], "opponent"), atol=1e-6)
    # an orthonormal mix: the three channels' energy is unchanged
    assert np.isclose(np.sum(opp.x[:3].astype(np.float64) ** 2),
                      np.sum(rgb.x[:3].astype(np.float64) ** 2), rtol=1e-5)
    x, labels = training_tensors(mats, shape=SMALL, progress=False)
    np.testing.assert_array_equal(x, rgb.x)
    with pytest.raises(ValueError, match="colour basis"):
        training_data(mats, shape=SMALL, progress=False, basis="xyz")


def test_training_data_records_unmeasured_bins(monkeypatch):
    mats = get_corpus("mitsuba").split("train")[:2]
    real_load = type(mats[0]).load

    def load_with_holes(self, shape, symmetrize=None):
        b = real_load(self, shape, symmetrize)
        if self.name == mats[1].name:
            b.valid[4:6, 2:4, :] = False
            b.values[~b.valid] = 0.0
        return b

    monkeypatch.setattr(type(mats[0]), "load", load_with_holes)
    d = training_data(mats, shape=SMALL, progress=False)
    assert sorted(d.missing) == list(range(6, 12))  # the second material's 6 tensors
    m = d.missing[6]
    assert all(d.missing[i] is m for i in range(6, 12))  # one shared array
    assert m.sum() == (geometric_valid(SMALL)[4:6, 2:4, :]).sum()


@pytest.mark.train
def test_train_command_options(tmp_path):
    out = tmp_path / "e.npz"
    assert main(["train", "--corpus", "mitsuba", "--grid", "18", "18", "36", "--taus", "8",
                 "--dicts", "2", "--iterations", "2", "--basis", "opponent", "--no-masked",
                 "--init", "seeded", "-o", str(out)]) == 0
    meta = Ensemble.load(out).meta
    assert meta["basis"] == "opponent" and meta["masked"] is False
    assert meta["init"] == "seeded" and meta["corpora"] == ["mitsuba"]
    assert len(meta["history"]["8"]) == 2
    assert json.loads(json.dumps(meta))["max_moved"] == 0.01
    # the data's digest: what the run read, so that a rebuild can tell same data from other
    data = training_data(get_corpus("mitsuba").split("train"), shape=SMALL, progress=False,
                         basis="opponent")
    assert meta["data_sha256"] == data.digest() and len(data.digest()) == 64
    fp = meta["data_fingerprint"]
    assert fp["data_sha256"] == data.digest()
    assert len(fp["tensors"]) == len(data.labels) == 6 * len(fp["inputs"])
    assert fingerprint_mismatches(training_fingerprint(
        get_corpus("mitsuba").split("train"), shape=SMALL, progress=False, basis="opponent"),
        fp) == []


def test_training_data_digest_sees_one_ulp(small_training):
    x = small_training[:6].copy()
    a = TrainingData(x, [f"m:{i}" for i in range(6)])
    b = TrainingData(x.copy(), list(a.labels))
    assert a.digest() == b.digest()
    b.x.flat[1234] = np.nextafter(b.x.flat[1234], np.float32(np.inf))
    assert a.digest() != b.digest()
    c = TrainingData(x, list(a.labels), missing={2: geometric_valid(SMALL)})
    assert c.digest() != a.digest()


@pytest.fixture(scope="module")
def two_fingerprinted():
    """Two mitsuba materials on the small grid, and the fingerprint of their data."""
    mats = get_corpus("mitsuba").split("train")[:2]
    data = training_data(mats, shape=SMALL, progress=False)
    return mats, data, training_fingerprint(mats, shape=SMALL, data=data)


@pytest.mark.numerics
def test_fingerprint_streams_what_training_data_stacks(two_fingerprinted):
    mats, data, fp = two_fingerprinted
    streamed = training_fingerprint(mats, shape=SMALL, progress=False)
    assert streamed == fp and fp["data_sha256"] == data.digest()
    assert list(fp["tensors"]) == data.labels and fp["size"] == data.x[0].size


@pytest.mark.numerics
def test_fingerprint_forgives_rounding_and_names_what_moved(two_fingerprinted):
    """A last-bit change of every value (another CPU's rounding) changes the bit digest
    but not the fingerprint; a 0.1 % change of one tensor, a changed value of the largest
    bin, another transform or another material's file are named."""
    mats, data, fp = two_fingerprinted
    rounded = TrainingData(np.nextafter(data.x, np.float32(np.inf)), data.labels)
    got = training_fingerprint(mats, shape=SMALL, data=rounded)
    assert got["data_sha256"] != fp["data_sha256"]
    assert fingerprint_mismatches(got, fp) == []

    drift = data.x.copy()
    drift[4] *= 1.001
    got = training_fingerprint(mats, shape=SMALL, data=TrainingData(drift, data.labels))
    lines = fingerprint_mismatches(got, fp)
    assert len(lines) == 1 and lines[0].startswith(data.labels[4] + ": sum ")
    assert "l2" in lines[0] and "tolerance 1e-04" in lines[0]

    peak = data.x.copy()
    peak[0].flat[np.argmax(peak[0])] += 0.01
    got = training_fingerprint(mats, shape=SMALL, data=TrainingData(peak, data.labels))
    assert [line.split(": ")[1].split()[0] for line in fingerprint_mismatches(got, fp)] == [
        "max"]

    other = training_fingerprint(mats, ("log-plus", "log-plus-cosine"), SMALL,
                                 progress=False)
    assert fingerprint_mismatches(other, fp)[0].startswith("settings: ")
    swapped = training_fingerprint([mats[0], get_corpus("mitsuba").split("train")[5]],
                                   shape=SMALL, progress=False)
    named = fingerprint_mismatches(swapped, fp)
    assert any(line.startswith(f"mitsuba/{mats[1].name}: missing now") for line in named)


@pytest.mark.numerics
def test_a_colour_channel_rounds_at_its_material_s_scale():
    """An opponent colour channel of a grey material is a difference of nearly equal
    transformed channels: a rounding of those moves it by a large fraction of its own tiny
    norm, and is forgiven at the material's scale; a real change of hue is named."""
    mats = [m for m in get_corpus("mitsuba").split("train") if m.name == "diffuse-grey"]
    data = training_data(mats, shape=SMALL, progress=False, basis="opponent")
    fp = training_fingerprint(mats, shape=SMALL, basis="opponent", data=data)
    lum, rg = data.x[0], data.x[1]
    assert np.linalg.norm(rg) < 1e-3 * np.linalg.norm(lum)  # grey: almost no chroma

    def moved(shift: float) -> list[str]:
        x = data.x.copy()
        x[1] += np.float32(shift * float(np.abs(lum).max()))
        return fingerprint_mismatches(training_fingerprint(
            mats, shape=SMALL, basis="opponent",
            data=TrainingData(x, data.labels, basis="opponent")), fp)

    label = data.labels[1]
    own = fingerprint_changes(
        fingerprint_list(data.x[1] + np.float32(1e-6 * float(np.abs(lum).max()))),
        fp["tensors"][label], data.x[1].size)
    assert own  # at the channel's own scale, a luminance-sized rounding would be named
    assert moved(1e-6) == []  # at the material's, it is forgiven
    assert [line.split(":")[2] for line in moved(1e-2)] == ["RG"]


@pytest.mark.train
def test_pruned_clustering_matches_full_search(small_training, monkeypatch):
    """The pruned search (``train.PRUNE``) clusters and codes as projecting every tensor on
    every dictionary does, with and without known codes of the own dictionaries."""
    st = train_dictionaries(small_training, 16, n_dicts=4, n_iter=2, tol=0, seed=2,
                            init="seeded", progress=False)
    u = (st.u1, st.u2, st.u3)
    for known in (None, (st.labels, st.codes_idx, st.codes_val, st.errors)):
        out = {}
        for prune in (True, False):
            monkeypatch.setattr(_codes, "PRUNE", prune)
            data = TensorStore(small_training, masked=False)
            out[prune] = _codes._assign_all(data, u, 16, False, known)
        np.testing.assert_array_equal(out[True][0], out[False][0])
        # errors are ||X||^2 - kept energy: both searches agree to float32 rounding of ||X||^2
        assert np.all(np.abs(out[True][3] - out[False][3]) <= 1e-5 * data.norms)
        same = [set(a) == set(b) for a, b in zip(out[True][1], out[False][1], strict=True)]
        assert np.mean(same) > 0.95
    stats = {}
    data = TensorStore(small_training, masked=False)
    d = _codes._Dicts.of(*u)
    for i in range(len(small_training)):
        _codes._search_codes(data[i], data.norms[i], [0, 1, 2, 3], d, 16, stats=stats)
    assert stats["slices"] < stats["full"]
