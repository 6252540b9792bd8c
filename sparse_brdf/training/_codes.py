"""The trainer's sparse coding: each training tensor's hard-thresholded code in a
dictionary, the search for the dictionary that codes it best (pruned, as the encoder's),
and the per-shard tasks an executor runs (``docs/method.md``, "Training").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..coding.pruning import PrunedSearch, slice_order
from ..coding.tensor import hosvd_factors, mode_grams, project, top_k
from ..parallel import blas_single_thread, parallel_map
from ._tensor_store import TensorStore


def _keep_largest(s: np.ndarray, tau: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``tau`` largest |s| of a projection: (flat indices, values, kept energy)."""
    flat = s.ravel()
    e = flat * flat
    idx = top_k(e, tau)
    return idx.astype(np.int32), flat[idx].astype(np.float32), float(e[idx].sum(dtype=np.float64))


def _code_tensor(data: TensorStore, i: int, s: np.ndarray, tau: int, u) -> tuple:
    """Code tensor i from its coefficients ``s`` in dictionary ``u``.

    Returns (idx, val, error, fill): error is the squared error over the tensor's valid
    bins; masked, ``fill`` holds the free-bin values of the new reconstruction (once they
    are filled in, ``error`` is the error over the whole filled tensor)."""
    idx, val, kept = _keep_largest(s, tau)
    err = data.norms[i] - kept
    if not data.masked:
        return idx, val, err, None
    fill, change = data.reconstruct_free(i, idx, val, u)
    return idx, val, max(err - change, 0.0), fill


#: Clustering searches with pruning (False: every tensor projected on every dictionary in
#: full, the reference the tests compare it with).
PRUNE = True


@dataclass
class _Dicts:
    """Mode matrices laid out for :func:`_search_codes` (U1^T and U3^T contiguous)."""

    u1t: list
    u2: np.ndarray
    u3: np.ndarray
    u3t: list

    @classmethod
    def of(cls, u1, u2, u3) -> _Dicts:
        return cls([np.ascontiguousarray(u.T) for u in u1], u2, u3,
                   [np.ascontiguousarray(u.T) for u in u3])


def _search_codes(xi: np.ndarray, norm: float, cands: list[int], d: _Dicts, tau: int,
                  floor: float = np.inf, gram: np.ndarray | None = None,
                  stats: dict | None = None, upto: int | None = None) -> dict[int, tuple]:
    """The tau-sparse codes of tensor ``xi`` on the dictionaries of ``cands`` that may give
    it the least error, or an error below ``floor``: {k: (idx, val, error)}, exact.

    The pruned projection (:mod:`~sparse_brdf.coding.pruning`), shared with the encoder:
    a dictionary that provably cannot win, or cannot beat ``floor``, is not completed.
    ``gram``: the tensor's mode-3 Gram matrix if known; ``stats``, if given, counts the
    slices computed (``"slices"``) against a full search's (``"full"``). ``upto``: stop
    after that many slices of every candidate, without pruning: the codes are then the
    tau largest coefficients of those slices and the errors upper bounds of the exact ones.
    """
    n1, n2, n3 = xi.shape
    x3 = xi.reshape(n1 * n2, n3)
    if gram is None:
        gram = x3.T @ x3
    order = {k: slice_order(gram, d.u3[k]) for k in cands}

    def chunk(k, lo, hi):
        rows = order[k][lo:hi]
        r = rows.size
        t = d.u1t[k] @ (x3 @ d.u3t[k][rows].T).reshape(n1, n2 * r)
        # (n1, r, n2): coefficient (a, b, rows[slot]) at [a, slot, b]
        sv = np.tensordot(t.reshape(n1, n2, r), d.u2[k], axes=([1], [0])).reshape(-1)
        e = sv * sv
        loc = top_k(e, tau)
        a, slot, b = np.unravel_index(loc, (n1, r, n2))
        return (a * n2 + b) * n3 + rows[slot], sv[loc], float(e.sum(dtype=np.float64))

    search = PrunedSearch.start(cands, n3, tau).run([(cands, norm, floor)], chunk, upto=upto)
    if stats is not None:
        stats["slices"] = stats.get("slices", 0) + search.slices
        stats["full"] = stats.get("full", 0) + len(cands) * n3
    out = {}
    for k in search.survivors():
        idx, val = search.top[k]
        kept = float(np.sum(np.square(val, dtype=np.float64)))
        out[k] = (idx.astype(np.int32), val, norm - kept)
    return out


def _assign_all(data: TensorStore, state_u, tau, progress, known=None) -> tuple[np.ndarray, ...]:
    """Cluster every tensor: its least-error dictionary, codes and errors.

    ``known``: optional (labels, codes_idx, codes_val, errors) already computed with the
    current dictionaries; each tensor's own dictionary is then not projected again. The
    other dictionaries are searched with pruning (:func:`_search_codes`; ``PRUNE``), so
    a dictionary that cannot win is not projected in full; its entry of the returned
    error matrix is inf. A tensor moves only if its error over the whole (filled) tensor
    there is below its current error, so masked training's objective cannot increase.
    Masked, the free bins of every tensor whose code changed are refilled.
    """
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    u1, u2, u3 = state_u
    k = u1.shape[0]
    n = len(data)
    dicts = _Dicts.of(u1, u2, u3)

    def one(i):
        xi = data[i]
        own = int(known[0][i]) if known is not None else -1
        cands = [j for j in range(k) if j != own]
        if PRUNE:
            found = _search_codes(xi, data.norms[i], cands, dicts, tau,
                                  known[3][i] if own >= 0 else np.inf)
        else:
            found = {}
            for j in cands:
                idx, val, kept = _keep_largest(project(xi, u1[j], u2[j], u3[j]), tau)
                found[j] = (idx, val, data.norms[i] - kept)
        if own >= 0:
            found[own] = (known[1][i], known[2][i], known[3][i])
        errs = np.full(k, np.inf)
        best = None
        for j in sorted(found):
            errs[j] = found[j][2]
            if best is None or errs[j] < errs[best]:
                best = j
        idx, val, err = found[best]
        fill = None
        if data.masked and best != own:
            fill, change = data.reconstruct_free(i, idx, val, (u1[best], u2[best], u3[best]))
            err = max(err - change, 0.0)
        return best, idx, val, err, fill, errs

    labels = np.zeros(n, np.int64)
    idx_all, val_all = np.zeros((n, tau), np.int32), np.zeros((n, tau), np.float32)
    errors, all_err = np.zeros(n), np.zeros((n, k))
    for i, (j, idx, val, err, fill, errs) in enumerate(
            tqdm(parallel_map(one, range(n)), total=n, desc="assign", unit="tensor",
                 leave=False, disable=not progress)):
        labels[i], idx_all[i], val_all[i], errors[i], all_err[i] = j, idx, val, err, errs
        if fill is not None:
            data.set_fill(i, fill)
    return labels, idx_all, val_all, errors, all_err


def shard_assign(sh: TensorStore, known, tau, u1, u2, u3) -> tuple:
    """Cluster the shard's tensors (:func:`_assign_all`), without the error matrix."""
    return _assign_all(sh, (u1, u2, u3), tau, False, known)[:4]


def shard_code(sh: TensorStore, labels, tau, u1, u2, u3) -> tuple:
    """Sparse-code each tensor of the shard in its own cluster's dictionary; masked, then
    refill its free bins from the new code. Returns the codes and errors."""

    def one(i):
        j = labels[i]
        u = (u1[j], u2[j], u3[j])
        return _code_tensor(sh, i, project(sh[i], *u), tau, u)

    n = len(sh)
    idx, val, err = np.zeros((n, tau), np.int32), np.zeros((n, tau), np.float32), np.zeros(n)
    for i, (a, v, e, fill) in enumerate(parallel_map(one, range(n))):
        idx[i], val[i], err[i] = a, v, e
        if fill is not None:
            sh.set_fill(i, fill)
    return idx, val, err


def shard_seed_errors(sh: TensorStore, err, tau, upto, f1, f2, f3) -> np.ndarray:
    """Each tensor's error under a seed dictionary (f1, f2, f3), or inf when it cannot
    beat ``err`` (:func:`_seed_labels`)."""
    d = _Dicts.of(f1[None], f2[None], f3[None])

    def seed_error(i):
        found = _search_codes(sh[i], sh.norms[i], [0], d, tau, err[i], sh.grams[i][2],
                              upto=upto)
        return found[0][2] if found else np.inf

    return np.array(list(parallel_map(seed_error, range(len(sh)))), np.float64)


def shard_reseed(sh: TensorStore, i: int, tau) -> tuple:
    """Tensor i's own HOSVD dictionary and its code there (for an empty cluster)."""
    with blas_single_thread():  # the same bits in any process
        xi = sh[i]
        f = hosvd_factors(mode_grams(xi))
        return f, *_code_tensor(sh, i, project(xi, *f), tau, f)
