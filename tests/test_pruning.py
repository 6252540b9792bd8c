"""The pruned projection (``model/pruning.py``): it keeps the dictionary a full search
selects, with that dictionary's exact coefficients, and computes fewer slices."""

import numpy as np
import pytest

from conftest import random_orthonormal
from sparse_brdf.coding.pruning import PRUNE_ROUNDS, PrunedSearch, search_rounds, slice_order
from sparse_brdf.coding.tensor import project, top_k

SHAPE = (6, 5, 120)


def _problem(seed: int, k: int = 5):
    """A tensor and ``k`` dictionaries; dictionary 2 is the tensor's own HOSVD-like basis
    (it wins clearly), the others are random."""
    rng = np.random.default_rng(seed)
    n1, n2, n3 = SHAPE
    core = rng.standard_normal(SHAPE).astype(np.float32) * np.exp(
        -np.arange(n3, dtype=np.float32) / 6)
    own = [random_orthonormal(n, rng) for n in SHAPE]
    x = project(core, own[0].T, own[1].T, own[2].T)  # coefficients `core` on `own`
    dicts = [[random_orthonormal(n, rng) for n in SHAPE] for _ in range(k)]
    dicts[2] = own
    return x, dicts


def _search(x, dicts, n, max_error=None, floor=np.inf, upto=None):
    n1, n2, n3 = SHAPE
    full = [project(x, *d) for d in dicts]  # (n1, n2, n3) each
    gram = x.reshape(-1, n3).T @ x.reshape(-1, n3)
    order = [slice_order(gram, d[2]) for d in dicts]

    def chunk(k, lo, hi):
        rows = order[k][lo:hi]
        sv = full[k][:, :, rows].reshape(-1)  # flat (a, b, slot)
        loc = top_k(sv * sv, n)
        ab, slot = np.divmod(loc, rows.size)
        return ab * n3 + rows[slot], sv[loc], float(np.sum(np.square(sv, dtype=np.float64)))

    keys = list(range(len(dicts)))
    norm = float(np.sum(np.square(x, dtype=np.float64)))
    search = PrunedSearch.start(keys, n3, n, max_error).run([(keys, norm, floor)], chunk,
                                                           upto=upto)
    return search, full, norm


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_winner_survives_with_its_exact_coefficients(seed):
    x, dicts = _problem(seed)
    n = 20
    search, full, _ = _search(x, dicts, n)
    kept = [float(np.sum(np.sort(s.ravel() ** 2)[-n:])) for s in full]
    best = int(np.argmax(kept))
    assert best == 2 and search.alive[best]
    idx, val = search.top[best]
    exact = top_k(full[best].ravel() ** 2, n)
    np.testing.assert_array_equal(np.sort(idx), np.sort(exact))
    np.testing.assert_array_equal(val, full[best].ravel()[idx])
    # and the losers were not all completed
    assert search.slices < len(dicts) * SHAPE[2]
    assert search.survivors() == [2]


def test_max_error_keeps_the_fewest_coefficient_dictionary():
    x, dicts = _problem(3)
    for max_error in (0.3, 0.6):  # reached by one dictionary, by all of them
        search, full, norm = _search(x, dicts, 60, max_error=max_error)
        rank = []  # the encoder's order: fewest coefficients, then least residual
        for s in full:
            res = norm - np.cumsum(np.sort(s.ravel().astype(np.float64) ** 2)[::-1][:60])
            ok = np.flatnonzero(res <= max_error * norm)
            need = int(ok[0]) + 1 if ok.size else 60
            rank.append((need, res[need - 1]))
        assert search.alive[min(range(len(full)), key=rank.__getitem__)]
        assert len(search.survivors()) < len(full)


def test_a_floor_nobody_beats_drops_every_dictionary():
    x, dicts = _problem(4)
    search, full, norm = _search(x, dicts, 20, floor=0.0)
    assert search.survivors() == []
    # a floor above every error keeps the winner
    search, _, _ = _search(x, dicts, 20, floor=2 * norm)
    assert 2 in search.survivors()


def test_upto_computes_that_many_slices_without_pruning():
    x, dicts = _problem(5)
    search, _, _ = _search(x, dicts, 20, upto=10)
    assert search.survivors() == list(range(len(dicts)))
    assert set(search.done.values()) == {10}
    assert search_rounds(180) == (*PRUNE_ROUNDS, 180)
    assert search_rounds(30) == (12, 30)
    assert search_rounds(180, upto=36) == (36,)
