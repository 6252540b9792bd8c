"""The trainer of dictionary ensembles (``docs/method.md``, "Training").

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model". :func:`train_dictionaries`
learns K dictionaries (three orthonormal mode matrices each, see :class:`Ensemble`) for
one sparsity tau by minimising

    sum_i sum_k M_ik || X_i - S_ik x1 U1k x2 U2k x3 U3k ||_F^2,
    U_nk^T U_nk = I,  ||S_ik||_0 <= tau,  each X_i in exactly one cluster,

by alternating hard-thresholded sparse coding, clustering by least error and one
orthogonal-Procrustes update per mode (Gauss-Seidel over the modes, so no step can
raise the objective). :func:`train_ensemble` unites the dictionaries of several
sparsities (default 4 x 8 = 32); :func:`hosvd_ensemble` is the one-dictionary baseline.

Masked training (``masked=True``, the default): only valid bins count. Bins below the
horizon (shared by every tensor) and a material's unmeasured bins are free values: after
each tensor is coded they are set to its reconstruction (expectation-maximisation), so
the norm above runs over valid bins only and still cannot increase.

Where it runs: the per-tensor work of each step (sparse coding, clustering, the partial
Procrustes sums) runs on shards of the tensors (:class:`_Shards`) through an executor
(``parallel.py``): in this process by default, or on Dask workers, with the same results
bit for bit (``docs/scale-out.md``).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ..coords import geometric_valid
from ..errors import BRDFFileError, UsageError
from ..fileio import atomic_write
from ..parallel import Executor, InProcess
from ..parallel import executor as open_executor
from ..params import SEED, Interval, check, check_choice
from .ensemble import Ensemble
from .tensor import (
    hosvd_factors,
    mode_grams,
    parallel_map,
    procrustes,
    project,
    reconstruct_sparse,
    top_k,
)

DEFAULT_TAUS: tuple[int, ...] = (32, 64, 128, 256)
DEFAULT_N_DICTS = 8
#: Iteration cap, clustering cadence and stopping rule of a training run (docs/ensemble.md
#: gives the measurements behind them).
DEFAULT_N_ITER = 8
DEFAULT_REASSIGN_EVERY = 3
DEFAULT_TOL = 1e-4
DEFAULT_MAX_MOVED = 0.01
#: Initialisations (:func:`_init_state`): ``seeded`` (k-means++-style seeding in the
#: training error itself) and ``random`` (random balanced clusters, the first trainer's).
INITS: tuple[str, ...] = ("seeded", "random")
DEFAULT_INIT = "seeded"
#: The trainer's parameters a user sets, declared once (:mod:`sparse_brdf.params`; the
#: CLI's bounds): ``tau`` at most a tensor's entries and ``n_dicts`` at most the tensors,
#: checked against the data by :func:`_check_training_args`.
PARAMETERS = {
    "tau": Interval(int, 1), "n_dicts": Interval(int, 1), "n_iter": Interval(int, 0),
    "reassign_every": Interval(int, 1), "tol": Interval(float, 0.0),
    "max_moved": Interval(float, 0.0, 1.0), "init": INITS, "seed": SEED,
}


@dataclass
class TrainState:
    """What one sparsity's training has learned so far (checkpointed every iteration)."""

    u1: np.ndarray  # (K, n1, n1)
    u2: np.ndarray
    u3: np.ndarray
    labels: np.ndarray  # (N,) cluster of each tensor
    codes_idx: np.ndarray  # (N, tau) flat coefficient indices, int32
    codes_val: np.ndarray  # (N, tau) coefficient values, float32
    errors: np.ndarray  # (N,) squared error of each tensor under its dictionary
    iteration: int = 0
    history: list = field(default_factory=list)
    init_seconds: float = 0.0  # time taken by the initialisation


def _sq_norms(x: np.ndarray) -> np.ndarray:
    return np.array([float(np.dot(t.ravel(), t.ravel())) for t in x])


def _keep_largest(s: np.ndarray, tau: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``tau`` largest |s| of a projection: (flat indices, values, kept energy)."""
    flat = s.ravel()
    e = flat * flat
    idx = top_k(e, tau)
    return idx.astype(np.int32), flat[idx].astype(np.float32), float(e[idx].sum(dtype=np.float64))


def _sq64(v: np.ndarray) -> float:
    """Squared norm accumulated in float64."""
    return float(np.sum(np.square(v, dtype=np.float64)))


class _Tensors:
    """The training tensors as the trainer sees them (``docs/method.md``, Training).

    Unmasked: the tensors as given. Masked: each tensor's free bins -- below the horizon
    (one index set shared by every tensor) plus, rarely, its material's unmeasured bins --
    hold the reconstruction from the tensor's latest code (zero before the first).
    Only those values are stored (N x 24 % of the grid, float32); ``x`` is never
    written, so the caller's array is unchanged and a read-only memory map works.
    ``norms[i]`` is ||X~_i||^2 of the filled tensor, ``energy[i]`` its valid part.
    """

    def __init__(self, x: np.ndarray, masked: bool, missing: dict | None = None):
        self.x, self.masked = x, masked
        self.shape = tuple(int(n) for n in x.shape[1:])
        self.grams: list | None = None  # mode Gram matrices, during the initialisation
        self.cache: dict[int, np.ndarray] = {}  # mode-3 products (_shard_partials)
        self.raw_norms = _sq_norms(x)  # of x as given (the checkpoint fingerprint)
        self.extra: dict[int, np.ndarray] = {}
        if not masked:
            self.free = np.zeros(0, np.int64)
            self.energy = self.raw_norms
            self.norms = self.raw_norms
            return
        geo = geometric_valid(self.shape).reshape(-1)
        self.free = np.flatnonzero(~geo)
        by_mask: dict[int, np.ndarray] = {}  # a material's channels share one mask object
        for i, m in (missing or {}).items():
            if id(m) not in by_mask:
                mask = np.asarray(m, bool)
                if mask.shape != self.shape:
                    raise ValueError(f"missing-bin mask of tensor {i} has shape {mask.shape}, "
                                     f"expected {self.shape}")
                by_mask[id(m)] = np.flatnonzero(mask.reshape(-1) & geo)
            if by_mask[id(m)].size:
                self.extra[int(i)] = by_mask[id(m)]
        self.fill = np.zeros((len(x), self.free.size), np.float32)
        self.fill_extra = {i: np.zeros(e.size, np.float32) for i, e in self.extra.items()}

        def valid_energy(i):  # independent of what x holds in free bins
            flat = np.asarray(x[i], np.float32).reshape(-1)
            if i not in self.extra:
                return _sq64(flat[geo])
            keep = geo.copy()
            keep[self.extra[i]] = False
            return _sq64(flat[keep])

        self.energy = np.array(list(parallel_map(valid_energy, range(len(x)))))
        self.norms = self.energy.copy()

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> np.ndarray:
        """X~_i: tensor i with its free bins filled (a copy when masked)."""
        if not self.masked:
            return self.x[i]
        y = np.array(self.x[i], np.float32)
        flat = y.reshape(-1)
        flat[self.free] = self.fill[i]
        if i in self.extra:
            flat[self.extra[i]] = self.fill_extra[i]
        return y

    def reconstruct_free(self, i, idx, val, u) -> tuple[tuple, float]:
        """The free-bin values of the reconstruction of tensor i from the code (idx, val)
        in dictionary u, and their squared distance to the values held now."""
        rec = reconstruct_sparse(idx, val, self.shape, *u).reshape(-1)
        new = rec[self.free]
        change = _sq64(new - self.fill[i])
        new_extra = None
        if i in self.extra:
            new_extra = rec[self.extra[i]]
            change += _sq64(new_extra - self.fill_extra[i])
        return (new, new_extra), change

    def set_fill(self, i: int, fill: tuple) -> None:
        new, new_extra = fill
        self.fill[i] = new
        self.norms[i] = self.energy[i] + _sq64(new)
        if new_extra is not None:
            self.fill_extra[i] = new_extra
            self.norms[i] += _sq64(new_extra)


def _code_tensor(data: _Tensors, i: int, s: np.ndarray, tau: int, u) -> tuple:
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


#: Cumulative mode-3 atoms (phi_d slices of the coefficients) computed per dictionary in
#: the rounds of :func:`_search_codes`; the dictionaries still in the running are then
#: completed.
PRUNE_ROUNDS = (12, 36, 90)
#: Safety margin of the pruning bounds, relative to ||X||^2 (float32 rounding of the
#: energies is about 1e-6).
PRUNE_SLACK = 1e-5
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

    As the encoder's pruned search (``docs/benchmarks.md``): the coefficients are computed
    one phi_d slice (mode-3 atom) at a time, the slices of most energy first (from one
    n3 x n3 Gram matrix). After each round the kept energy of a dictionary lies between
    the tau largest coefficients computed (L) and L plus the energy not computed yet; a
    dictionary whose best case loses to another's worst case, or cannot beat ``floor``,
    is dropped (margin ``PRUNE_SLACK`` ||X||^2); the others are completed. ``gram``: the
    tensor's mode-3 Gram matrix if known; ``stats``, if given, counts the slices computed
    (``"slices"``) against a full search's (``"full"``). ``upto``: stop after that many
    slices of every candidate, without pruning: the codes are then the tau largest
    coefficients of those slices and the errors upper bounds of the exact ones.
    """
    n1, n2, n3 = xi.shape
    x3 = xi.reshape(n1 * n2, n3)
    if gram is None:
        gram = x3.T @ x3
    order = {k: np.argsort(-np.einsum("ij,ij->j", gram @ d.u3[k], d.u3[k]), kind="stable")
             for k in cands}
    done = dict.fromkeys(cands, 0)
    energy = dict.fromkeys(cands, 0.0)
    top = {k: (np.zeros(0, np.int64), np.zeros(0, np.float32)) for k in cands}
    alive = list(cands)
    kept: dict[int, float] = {}
    rounds = (min(upto, n3),) if upto else (*[r for r in PRUNE_ROUNDS if r < n3], n3)
    for hi in rounds:
        if not alive:
            break
        for k in alive:
            rows = order[k][done[k]:hi]
            r = rows.size
            t = d.u1t[k] @ (x3 @ d.u3t[k][rows].T).reshape(n1, n2 * r)
            # (n1, r, n2): coefficient (a, b, rows[slot]) at [a, slot, b]
            sv = np.tensordot(t.reshape(n1, n2, r), d.u2[k], axes=([1], [0])).reshape(-1)
            e = sv * sv
            loc = top_k(e, tau)
            a, slot, b = np.unravel_index(loc, (n1, r, n2))
            idx = np.concatenate([top[k][0], (a * n2 + b) * n3 + rows[slot]])
            val = np.concatenate([top[k][1], sv[loc]])
            keep = top_k(val * val, tau)
            top[k], done[k] = (idx[keep], val[keep]), hi
            energy[k] += float(e.sum(dtype=np.float64))
            if stats is not None:
                stats["slices"] = stats.get("slices", 0) + rows.size
        kept = {k: float(np.sum(np.square(top[k][1], dtype=np.float64))) for k in alive}
        if hi == rounds[-1]:
            break
        bar = max(max(kept.values()), norm - floor)  # kept energy a winner must reach
        alive = [k for k in alive
                 if kept[k] + max(norm - energy[k], 0.0) + PRUNE_SLACK * norm >= bar]
    if stats is not None:
        stats["full"] = stats.get("full", 0) + len(cands) * n3
    return {k: (top[k][0].astype(np.int32), top[k][1], norm - kept[k]) for k in alive}


def _assign_all(data: _Tensors, state_u, tau, progress, known=None) -> tuple[np.ndarray, ...]:
    """Cluster every tensor: its least-error dictionary, codes and errors.

    ``known``: optional (labels, codes_idx, codes_val, errors) already computed with the
    current dictionaries; each tensor's own dictionary is then not projected again. The
    other dictionaries are searched with pruning (:func:`_search_codes`; ``PRUNE``), so
    a dictionary that cannot win is not projected in full; its entry of the returned
    error matrix is inf. A tensor moves only if its error over the whole (filled) tensor
    there is below its current error, so masked training's objective cannot increase.
    Masked, the free bins of every tensor whose code changed are refilled.
    """
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
            _progress(parallel_map(one, range(n)), n, progress, "assign")):
        labels[i], idx_all[i], val_all[i], errors[i], all_err[i] = j, idx, val, err, errs
        if fill is not None:
            data.set_fill(i, fill)
    return labels, idx_all, val_all, errors, all_err


# ------------------------------------------------------------ shards (docs/scale-out.md)
#: Tensors per shard (:class:`_Shards`). Fixed, not derived from the number of workers,
#: so that every sum over tensors is summed per shard and then over the shards in the
#: same order wherever the shards run: results are the same bit for bit in-process and
#: on any cluster.
SHARD_TENSORS = 32
#: Bytes of mode-3 partial products the dictionary update may keep, in one process,
#: between its first two passes (:func:`_shard_partials`); beyond this they are
#: recomputed instead (same results).
MAX_CACHE_BYTES = 3 * 1024**3
_cache_lock = threading.Lock()
_cache_used = [0]  # bytes of partial products cached in this process


def _shard_info(sh: _Tensors) -> tuple:
    return sh.raw_norms, sh.energy, sh.extra


def _shard_assign(sh: _Tensors, known, tau, u1, u2, u3) -> tuple:
    """Cluster the shard's tensors (:func:`_assign_all`), without the error matrix."""
    return _assign_all(sh, (u1, u2, u3), tau, False, known)[:4]


def _shard_code(sh: _Tensors, labels, tau, u1, u2, u3) -> tuple:
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


def _shard_refill(sh: _Tensors, labels, idx, val, u1, u2, u3) -> None:
    """Masked: set every tensor's free bins from its code (on resuming, to restore the
    filled tensors the checkpointed iteration ended with)."""
    if not sh.masked:
        return

    def one(i):
        j = labels[i]
        return sh.reconstruct_free(i, idx[i], val[i], (u1[j], u2[j], u3[j]))[0]

    for i, fill in enumerate(parallel_map(one, range(len(sh)))):
        sh.set_fill(i, fill)


def _drop_cache(sh: _Tensors) -> None:
    with _cache_lock:
        _cache_used[0] -= sum(a.nbytes for a in sh.cache.values())
    sh.cache = {}


def _shard_partials(sh: _Tensors, labels, codes_idx, codes_val, mode, n_dicts,
                    u1, u2, u3) -> list:
    """The shard's part of each cluster's Procrustes product Z for ``mode`` (0, 1, 2):
    a float64 (n, n) sum over the cluster's tensors in the shard, None for none.

    The passes for U1 and U2 both start from A = X x3 U3^T with the same U3, so A is
    kept from the first pass for the second (up to ``MAX_CACHE_BYTES`` per process);
    the results are the same as recomputing it.
    """
    n1, n2, n3 = shape = sh.shape

    def onehot(pos, val, n):
        m = np.zeros((len(pos), n), np.float32)
        np.add.at(m, (np.arange(len(pos)), pos), val)
        return m

    def mode3_product(i, u3j):
        """A = X_i x3 U3^T as an (n1 n2, n3) matrix, from the cache when there."""
        if i in sh.cache:
            a = sh.cache.pop(i)
            with _cache_lock:
                _cache_used[0] -= a.nbytes
            return a
        a = sh[i].reshape(n1 * n2, n3) @ u3j
        if mode == 0:
            with _cache_lock:
                keep = _cache_used[0] + a.nbytes <= MAX_CACHE_BYTES
                _cache_used[0] += a.nbytes if keep else 0
            if keep:
                sh.cache[i] = a
        return a

    def contrib(i):
        j = labels[i]
        a, b, c = np.unravel_index(codes_idx[i], shape)
        s = codes_val[i]
        if mode == 0:  # W1 = X x2 U2^T x3 U3^T, Z1[:, a_t] += s_t W1[:, b_t, c_t]
            w = np.matmul(u2[j].T, mode3_product(i, u3[j]).reshape(n1, n2, n3))
            return w[:, b, c] @ onehot(a, s, n1)
        if mode == 1:  # W2 = X x1 U1^T x3 U3^T, Z2[:, b_t] += s_t W2[a_t, :, c_t]
            w = (u1[j].T @ mode3_product(i, u3[j]).reshape(n1, n2 * n3)).reshape(n1, n2, n3)
            return w[a, :, c].T @ onehot(b, s, n2)
        # W3 = X x1 U1^T x2 U2^T, Z3[:, c_t] += s_t W3[a_t, b_t, :]
        w = np.matmul(u2[j].T, (u1[j].T @ sh[i].reshape(n1, n2 * n3)).reshape(n1, n2, n3))
        return w[a, b, :].T @ onehot(c, s, n3)

    if mode == 0:
        _drop_cache(sh)
    z: list = [None] * n_dicts
    order = np.argsort(labels, kind="stable")  # by cluster, then by tensor
    for i, part in zip(order, parallel_map(contrib, order), strict=True):
        j = labels[i]  # each cluster's sum in the order of its members, wherever it runs
        z[j] = part.astype(np.float64) if z[j] is None else z[j] + part
    if mode > 0:
        _drop_cache(sh)
    return z


def _shard_grams(sh: _Tensors) -> None:
    """Keep the mode Gram matrices of the shard's tensors (for the initialisation)."""
    sh.grams = list(parallel_map(lambda i: mode_grams(sh[i]), range(len(sh))))


def _shard_gram(sh: _Tensors, i: int) -> tuple:
    return sh.grams[i]


def _shard_gram_sums(sh: _Tensors, labels, n_dicts) -> list:
    """Per cluster, the sums of the Gram matrices of its tensors in the shard (float64);
    then forget the Gram matrices."""
    n1, n2, n3 = sh.shape
    sums = [[np.zeros((m, m)) for m in (n1, n2, n3)] for _ in range(n_dicts)]
    for i, g in enumerate(sh.grams):
        for m in range(3):
            sums[labels[i]][m] += g[m]
    sh.grams = None
    return sums


def _shard_seed_errors(sh: _Tensors, err, tau, upto, f1, f2, f3) -> np.ndarray:
    """Each tensor's error under a seed dictionary (f1, f2, f3), or inf when it cannot
    beat ``err`` (:func:`_seed_labels`)."""
    d = _Dicts.of(f1[None], f2[None], f3[None])

    def seed_error(i):
        found = _search_codes(sh[i], sh.norms[i], [0], d, tau, err[i], sh.grams[i][2],
                              upto=upto)
        return found[0][2] if found else np.inf

    return np.array(list(parallel_map(seed_error, range(len(sh)))), np.float64)


def _shard_reseed(sh: _Tensors, i: int, tau) -> tuple:
    """Tensor i's own HOSVD dictionary and its code there (for an empty cluster)."""
    with threadpool_limits(limits=1, user_api="blas"):  # the same bits in any process
        xi = sh[i]
        f = hosvd_factors(mode_grams(xi))
        return f, *_code_tensor(sh, i, project(xi, *f), tau, f)


def _shard_set_fill(sh: _Tensors, i: int, fill) -> None:
    sh.set_fill(i, fill)


class _Shards:
    """The training tensors as shards of ``SHARD_TENSORS`` consecutive tensors, each a
    :class:`_Tensors` kept where the executor runs it (``parallel.py``: here, or on one
    worker for the whole run, so the tensors and their free-bin values travel once).

    Each step of an iteration runs a shard function on every shard, with the shard's
    slice of the labels and codes and the dictionaries it needs (scattered once per
    step to each worker, not sent per tensor or per shard), and returns the per-tensor
    results in order; sums over tensors come back as one partial sum per shard, added
    here in shard order.
    """

    def __init__(self, x: np.ndarray, masked: bool, missing: dict | None, ex,
                 progress: bool):
        self.ex, self.masked, self.progress = ex, masked, progress
        self.shape = tuple(int(n) for n in x.shape[1:])
        self.n = n = len(x)
        self.bounds = [(lo, min(lo + SHARD_TENSORS, n)) for lo in range(0, n, SHARD_TENSORS)]
        args = []
        for lo, hi in self.bounds:
            part = np.ascontiguousarray(x[lo:hi]) if ex.distributed else x[lo:hi]
            local = {int(i) - lo: m for i, m in (missing or {}).items() if lo <= int(i) < hi}
            args.append((part, masked, local))
        self.handles = ex.place(_Tensors, args)
        info = self.run(_shard_info, None)
        self.raw_norms = np.concatenate([r[0] for r in info])
        self.energy = np.concatenate([r[1] for r in info])
        self.extra = {lo + i: e for (lo, _), r in zip(self.bounds, info, strict=True)
                      for i, e in r[2].items()}

    def __len__(self) -> int:
        return self.n

    def slices(self, *arrays) -> list[tuple]:
        """Each shard's slice of per-tensor ``arrays``."""
        return [tuple(a[lo:hi] for a in arrays) for lo, hi in self.bounds]

    def run(self, fn, arg_lists, *shared, desc: str | None = None) -> list:
        """``fn(shard, *args, *shared)`` on every shard (:meth:`InProcess.run_on`)."""
        bar = _bar(self.n, bool(self.progress and desc), desc, unit="tensor", leave=False)
        out = self.ex.run_on(self.handles, fn, arg_lists, *shared,
                             tick=lambda k: bar.update(self.bounds[k][1] - self.bounds[k][0]))
        bar.close()
        return out

    def run_one(self, i: int, fn, *args):
        """``fn(shard, local index of tensor i, *args)`` on the shard holding tensor i."""
        k = i // SHARD_TENSORS
        return self.ex.run_on([self.handles[k]], fn, [(i - self.bounds[k][0], *args)])[0]

    def scatter(self, *arrays) -> list:
        return [self.ex.scatter(a) for a in arrays]

    def release(self, handles) -> None:
        self.ex.release([h for h in handles if h is not None])

    def __enter__(self) -> _Shards:
        return self

    def __exit__(self, *exc) -> None:
        self.ex.release(self.handles)


def _cat(parts: list, k: int) -> np.ndarray:
    return np.concatenate([p[k] for p in parts])


def _code_own(data: _Shards, state: TrainState, tau, hs) -> None:
    """Sparse-code each tensor in its own cluster's dictionary (``hs``: the scattered
    mode matrices); masked, its free bins are then refilled from the new code."""
    out = data.run(_shard_code, data.slices(state.labels), tau, *hs, desc="code")
    state.codes_idx, state.codes_val, state.errors = (_cat(out, k) for k in range(3))


def _refill_all(data: _Shards, state: TrainState) -> None:
    """Masked: set every tensor's free bins from its code in ``state`` (on resuming)."""
    if data.masked:
        hs = data.scatter(state.u1, state.u2, state.u3)
        data.run(_shard_refill, data.slices(state.labels, state.codes_idx, state.codes_val),
                 *hs)
        data.release(hs)


def _update_dictionaries(data: _Shards, state: TrainState, hs: list, n_dicts) -> list:
    """Gauss-Seidel Procrustes update of the three modes of every dictionary with members.

    Each mode's product Z of every cluster is summed over the shards (a map-reduce); its
    Procrustes solution replaces the mode matrix, which is scattered again for the next
    mode. Returns the handles of the new mode matrices.
    """
    stacks = (state.u1, state.u2, state.u3)
    for mode in range(3):
        parts = data.run(_shard_partials,
                         data.slices(state.labels, state.codes_idx, state.codes_val),
                         mode, n_dicts, *hs, desc=f"update mode {mode + 1}")
        for j in range(n_dicts):
            z = None
            for p in parts:  # shard order
                if p[j] is not None:
                    z = p[j] if z is None else z + p[j]
            if z is not None:
                stacks[mode][j] = procrustes(z)
        data.release([hs[mode]])
        hs[mode] = data.ex.scatter(stacks[mode])
    return hs


def _reseed_empty(data: _Shards, state: TrainState, tau) -> int:
    """Give every empty cluster the worst-represented tensor of a cluster with >= 2 members."""
    k = state.u1.shape[0]
    reseeded = 0
    for j in range(k):
        if np.any(state.labels == j):
            continue
        counts = np.bincount(state.labels, minlength=k)
        donors = np.flatnonzero(counts[state.labels] >= 2)
        if donors.size == 0:
            break
        i = int(donors[np.argmax(state.errors[donors])])
        (f1, f2, f3), idx, val, err, fill = data.run_one(i, _shard_reseed, tau)
        state.u1[j], state.u2[j], state.u3[j] = f1, f2, f3
        if err <= state.errors[i]:
            state.labels[i] = j
            state.codes_idx[i], state.codes_val[i] = idx, val
            state.errors[i] = err
            if fill is not None:
                data.run_one(i, _shard_set_fill, fill)
        reseeded += 1
    return reseeded


def _init_state(data: _Shards, tau, n_dicts, rng, init: str = "random") -> TrainState:
    """The first clusters, each initialised with its HOSVD: random balanced clusters
    (``random``) or :func:`_seed_labels` (``seeded``)."""
    n = len(data)
    n1, n2, n3 = data.shape
    data.run(_shard_grams, None, desc="init")
    if init == "random":
        labels = rng.permutation(np.arange(n) % n_dicts)
    elif init == "seeded":
        labels = _seed_labels(data, tau, n_dicts, rng)
    else:
        check_choice("init", init, INITS)
    sums = [[np.zeros((m, m)) for m in (n1, n2, n3)] for _ in range(n_dicts)]
    for part in data.run(_shard_gram_sums, data.slices(labels), n_dicts):  # shard order
        for j in range(n_dicts):
            for m in range(3):
                sums[j][m] += part[j][m]
    factors = [hosvd_factors(tuple(g)) if np.any(labels == j) else
               [np.eye(m, dtype=np.float32) for m in (n1, n2, n3)]
               for j, g in enumerate(sums)]
    return TrainState(
        u1=np.stack([f[0] for f in factors]), u2=np.stack([f[1] for f in factors]),
        u3=np.stack([f[2] for f in factors]), labels=labels,
        codes_idx=np.zeros((n, tau), np.int32), codes_val=np.zeros((n, tau), np.float32),
        errors=np.zeros(n),
    )


#: Fraction of the mode-3 atoms of a seed dictionary that :func:`_seed_labels` projects
#: each tensor on (the leading ones by the tensor's energy along them); None: all, with
#: pruning (exact errors, about four times the cost).
SEED_FRACTION: float | None = 0.2


def _seed_labels(data: _Shards, tau, n_dicts, rng) -> np.ndarray:
    """k-means++ seeding in the training error itself.

    The first seed is drawn with probability proportional to tensor energy, each further
    one proportional to the error of each tensor under the best seed dictionary so far
    (a seed's dictionary: its own HOSVD; error: tau-sparse coding, as in training). Each
    tensor then joins the seed that represents it best. The errors come from the
    ``SEED_FRACTION`` leading slices of each seed's coefficients (upper bounds of the
    exact errors, :func:`_search_codes`): with 0.2, K seeds cost about 1.6 projections
    per tensor.
    """
    upto = None if SEED_FRACTION is None else max(1, int(np.ceil(SEED_FRACTION * data.shape[2])))
    n = len(data)
    err = np.full(n, np.inf)
    labels = np.zeros(n, np.int64)
    weights = np.asarray(data.energy, np.float64)  # ||X~_i||^2 before any fill
    for j in range(n_dicts):
        p = weights / weights.sum() if weights.sum() > 0 else None
        s = int(rng.choice(n, p=p))
        hs = data.scatter(*hosvd_factors(data.run_one(s, _shard_gram)))
        e = np.concatenate(data.run(_shard_seed_errors, data.slices(err), tau, upto, *hs,
                                    desc=f"seed {j + 1}"))
        data.release(hs)
        e[s] = -1.0  # a seed stays with its own dictionary
        better = e < err
        labels[better], err[better] = j, e[better]
        weights = np.maximum(err, 0.0)
    return labels


def _check_training_args(x, tau: int, n_dicts: int, init: str = DEFAULT_INIT,
                         reassign_every: int = 1) -> np.ndarray:
    """``x`` as an array (a memory map stays one); raise on unusable arguments."""
    x = np.asarray(x) if not isinstance(x, np.memmap) else x
    if x.ndim != 4:
        raise UsageError(f"training tensors must have shape (N, n1, n2, n3), got {x.shape}")
    check("tau", tau, PARAMETERS["tau"].capped(int(np.prod(x.shape[1:]))))
    check("n_dicts (one tensor per cluster at least)", n_dicts,
          PARAMETERS["n_dicts"].capped(len(x)))
    check_choice("init", init, INITS)
    check("reassign_every", reassign_every, PARAMETERS["reassign_every"])
    return x


def _recluster(data: _Shards, state: TrainState, tau, hs) -> int:
    """Cluster every tensor against every dictionary (in place); return how many moved."""
    old = state.labels.copy()
    # after the first iteration the state's codes belong to the current dictionaries
    known = (data.slices(state.labels, state.codes_idx, state.codes_val, state.errors)
             if state.iteration > 0 else [None] * len(data.bounds))
    out = data.run(_shard_assign, [(k,) for k in known], tau, *hs, desc="assign")
    state.labels, state.codes_idx, state.codes_val, state.errors = (
        _cat(out, k) for k in range(4))
    return int(np.sum(old != state.labels))


def _iterate(data: _Shards, total: float, state: TrainState, tau, n_dicts,
             reassign_every) -> dict:
    """One training iteration (clustering or not, reseeding, dictionary updates, re-coding)
    on ``state`` in place; returns its history record. The dictionaries are scattered to
    the workers once at the start, and each updated mode matrix once after its update."""
    t0 = time.perf_counter()
    stats0 = dict(data.ex.stats)
    it = state.iteration
    do_assign = it % reassign_every == 0
    hs = data.scatter(state.u1, state.u2, state.u3)
    # without clustering, the codes in the state are those of the current dictionaries
    # (re-coded at the end of the previous iteration, or read from its checkpoint)
    moved = _recluster(data, state, tau, hs) if do_assign else 0
    reseeded = _reseed_empty(data, state, tau)
    if reseeded:
        data.release(hs)
        hs = data.scatter(state.u1, state.u2, state.u3)
    obj_before_update = float(state.errors.sum())
    t1 = time.perf_counter()
    hs = _update_dictionaries(data, state, hs, n_dicts)
    t2 = time.perf_counter()
    _code_own(data, state, tau, hs)
    data.release(hs)
    obj = float(state.errors.sum())
    t3 = time.perf_counter()
    record = {
        "iteration": it, "objective": obj, "relative_objective": obj / total,
        "objective_before_update": obj_before_update, "assigned": bool(do_assign),
        "moved": moved, "moved_fraction": moved / len(data), "reseeded": reseeded,
        "seconds": t3 - t0, "seconds_cluster": t1 - t0, "seconds_update": t2 - t1,
        "seconds_code": t3 - t2,
    }
    if data.ex.distributed:  # what this iteration moved between this process and workers
        moved_bytes = {k: data.ex.stats[k] - stats0[k] for k in stats0}
        record.update(bytes_to_workers=moved_bytes["bytes_scattered"]
                      + moved_bytes["bytes_sent"],
                      bytes_from_workers=moved_bytes["bytes_received"],
                      tasks=moved_bytes["tasks"])
    return record


def _converged(history: list, tol: float, max_moved: float, n: int) -> bool:
    """Memberships and objective have settled: the latest clustering after the first
    iteration moved at most a fraction ``max_moved`` of the ``n`` tensors, and the last
    iteration lowered the objective by less than ``tol`` (relative)."""
    if len(history) < 2:
        return False
    clusterings = [h for h in history[1:] if h["assigned"]]
    if not clusterings or clusterings[-1]["moved"] > max_moved * n:
        return False
    prev, last = history[-2]["objective"], history[-1]["objective"]
    return prev > 0 and (prev - last) / prev < tol


def train_dictionaries(
    x: np.ndarray,
    tau: int,
    n_dicts: int = DEFAULT_N_DICTS,
    n_iter: int = DEFAULT_N_ITER,
    tol: float = DEFAULT_TOL,
    seed: int = 0,
    reassign_every: int = DEFAULT_REASSIGN_EVERY,
    checkpoint: str | os.PathLike | None = None,
    progress: bool = True,
    callback: Callable[[TrainState], bool | None] | None = None,
    masked: bool = True,
    missing: dict[int, np.ndarray] | None = None,
    init: str = DEFAULT_INIT,
    max_moved: float = DEFAULT_MAX_MOVED,
    executor: Executor | None = None,
) -> TrainState:
    """Train ``n_dicts`` dictionaries under sparsity ``tau`` on tensors ``x``.

    Parameters
    ----------
    x : ndarray of shape (N, n1, n2, n3), float32
        Training tensors (transformed BRDF channels); may be a memory map. Never written.
    tau : int
        Coefficients kept per tensor in sparse coding.
    n_iter, tol, max_moved : stop after ``n_iter`` iterations, or earlier once the latest
        clustering moved at most a fraction ``max_moved`` of the tensors and an iteration
        lowered the objective by less than ``tol`` (relative).
    reassign_every : int
        Clustering against every dictionary (K projections per tensor, the dominant cost)
        happens at every ``reassign_every``-th iteration, starting with the first;
        otherwise tensors are re-coded in their own dictionary only. The history records
        how many tensors each clustering moved. Each step is optimal for its own
        variables, so the objective never increases either way.
    checkpoint : path, optional
        ``.npz`` written after every iteration; if it exists and matches the run's
        fingerprint, training resumes from it (a larger ``n_iter`` continues a run).
    callback : called with the state after every iteration; returning True stops.
    masked : bool
        Fit valid bins only: bins below the horizon (``coords.geometric_valid``) and the
        bins in ``missing`` are free values, refilled from each tensor's reconstruction
        after it is coded (module docstring). False fits them as the zeros ``x`` holds
        there (the paper; the first shipped ensemble).
    missing : {tensor index: bool array (n1, n2, n3)}, optional
        Unmeasured bins of the tensors that have any (``sources.dataset.training_data``);
        the channels of one material may share one array. Used only when masked.
    init : ``"seeded"`` or ``"random"`` (:func:`_init_state`).
    executor : where the per-tensor work runs (``parallel.executor``; default: here).

    Returns the final :class:`TrainState`; ``state.history`` has one dict per iteration
    (objective -- squared error over valid bins when masked --, relative objective,
    tensors moved and their fraction, seconds).
    """
    x = _check_training_args(x, tau, n_dicts, init, reassign_every)
    with _Shards(x, masked, missing, executor or InProcess(), progress) as data:
        total = float(data.energy.sum())
        fingerprint = _fingerprint(x, data.raw_norms, tau, n_dicts, seed,
                                   _run_options(data, masked, init))
        state = _load_checkpoint(checkpoint, fingerprint) if checkpoint else None
        if state is None:
            t0 = time.perf_counter()
            state = _init_state(data, tau, n_dicts, np.random.default_rng(seed), init)
            state.init_seconds = time.perf_counter() - t0
        else:
            _refill_all(data, state)
        bar = _bar(n_iter, progress, f"tau={tau}")
        bar.update(state.iteration)
        while state.iteration < n_iter and not _converged(state.history, tol, max_moved,
                                                          len(x)):
            record = _iterate(data, total, state, tau, n_dicts, reassign_every)
            state.history.append(record)
            state.iteration += 1
            if checkpoint:
                _save_checkpoint(checkpoint, state, fingerprint)
            bar.set_postfix(rel_err=f"{record['objective'] / total:.3e}", moved=record["moved"])
            bar.update(1)
            if callback is not None and callback(state):
                break
        bar.close()
    return state


def train_ensemble(
    x: np.ndarray,
    taus: Sequence[int] = DEFAULT_TAUS,
    n_dicts: int = DEFAULT_N_DICTS,
    n_iter: int = DEFAULT_N_ITER,
    seed: int = 0,
    checkpoint_dir: str | os.PathLike | None = None,
    progress: bool = True,
    meta: dict | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    **kwargs,
) -> Ensemble:
    """Train ``n_dicts`` dictionaries per sparsity in ``taus`` and unite them.

    The sparsities are trained one after another, each with its own seed derived from
    ``seed``; with ``checkpoint_dir`` each writes ``tau-<tau>.npz`` there and resumes.
    ``kwargs`` go to :func:`train_dictionaries` (``masked``, ``missing``, ``init``,
    ``reassign_every``, ``tol``, ``max_moved``). ``meta`` is stored in the ensemble with
    the training options, history and time taken. ``workers``/``scheduler``: where the
    per-tensor work runs (``parallel.executor``; default: in this process).
    """
    seeds = np.random.SeedSequence(seed).generate_state(len(taus))
    parts, histories, init_seconds = [], {}, {}
    t0 = time.perf_counter()
    with open_executor(workers, scheduler) as ex:
        where = ex.describe()
        for tau, s in zip(taus, seeds, strict=True):
            ckpt = Path(checkpoint_dir) / f"tau-{tau}.npz" if checkpoint_dir else None
            st = train_dictionaries(x, int(tau), n_dicts, n_iter, seed=int(s),
                                    checkpoint=ckpt, progress=progress, executor=ex, **kwargs)
            parts.append(Ensemble(st.u1, st.u2, st.u3, np.full(n_dicts, tau)))
            histories[str(tau)] = st.history
            init_seconds[str(tau)] = st.init_seconds
    ens = parts[0]
    for p in parts[1:]:
        ens = ens.union(p)
    options = {"masked": bool(kwargs.get("masked", True)),
               "n_missing_tensors": len(kwargs.get("missing") or {}),
               "init": kwargs.get("init", DEFAULT_INIT),
               "reassign_every": int(kwargs.get("reassign_every", DEFAULT_REASSIGN_EVERY)),
               "tol": float(kwargs.get("tol", DEFAULT_TOL)),
               "max_moved": float(kwargs.get("max_moved", DEFAULT_MAX_MOVED))}
    ens.meta = {**(meta or {}), "taus": list(map(int, taus)), "n_dicts_per_tau": n_dicts,
                "n_iter": n_iter, "seed": seed, "n_tensors": int(len(x)), **options,
                "seconds": time.perf_counter() - t0, "init_seconds": init_seconds,
                "where": where, "history": histories}
    return ens


def hosvd_ensemble(x: np.ndarray, progress: bool = True) -> Ensemble:
    """One dictionary: the HOSVD of all tensors ``x`` (N, n1, n2, n3) (a baseline)."""
    n1, n2, n3 = x.shape[1:]
    grams = [np.zeros((m, m)) for m in (n1, n2, n3)]
    for g in _progress(parallel_map(lambda i: mode_grams(x[i]), range(len(x))), len(x),
                       progress, "hosvd"):
        for m in range(3):
            grams[m] += g[m]
    f = hosvd_factors(tuple(grams))
    return Ensemble(f[0][None], f[1][None], f[2][None], np.zeros(1),
                    {"kind": "hosvd", "n_tensors": int(len(x))})


# ----------------------------------------------------------------------- helpers


def _run_options(data: _Tensors, masked: bool, init: str) -> dict | None:
    """What besides data, tau, K and seed defines a run (None: the first trainer's
    options, whose checkpoints keep their fingerprints)."""
    if not masked and init == "random":
        return None
    h = hashlib.sha256()
    for i in sorted(data.extra):
        h.update(np.asarray([i], "<i8").tobytes())
        h.update(np.asarray(data.extra[i], "<i8").tobytes())
    return {"masked": masked, "init": init, "missing": h.hexdigest()}


def _fingerprint(x, norms, tau, n_dicts, seed, options: dict | None = None) -> str:
    h = hashlib.sha256(json.dumps([list(x.shape), tau, n_dicts, seed]).encode())
    h.update(np.asarray(norms, "<f8").tobytes())
    if options is not None:
        h.update(json.dumps(options, sort_keys=True).encode())
    return h.hexdigest()


def _save_checkpoint(path, state: TrainState, fingerprint: str) -> None:
    with atomic_write(path) as f:
        np.savez(f, u1=state.u1, u2=state.u2, u3=state.u3, labels=state.labels,
                 codes_idx=state.codes_idx, codes_val=state.codes_val, errors=state.errors,
                 iteration=state.iteration, history=json.dumps(state.history),
                 init_seconds=state.init_seconds, fingerprint=fingerprint)


def _load_checkpoint(path, fingerprint: str) -> TrainState | None:
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            stored = str(z["fingerprint"])
            state = None if stored != fingerprint else TrainState(
                z["u1"], z["u2"], z["u3"], z["labels"], z["codes_idx"], z["codes_val"],
                z["errors"], int(z["iteration"]), json.loads(str(z["history"])),
                float(z["init_seconds"]) if "init_seconds" in z else 0.0)
    except Exception as exc:  # noqa: BLE001 - numpy and zipfile raise many kinds
        raise BRDFFileError(f"{path}: not a readable training checkpoint "
                            f"({type(exc).__name__}: {exc}); delete it to redo its "
                            "sparsity") from exc
    if state is None:
        raise UsageError(f"{path}: checkpoint belongs to another training run "
                         "(different data, tau, K, seed, masking or initialisation); "
                         "delete it or use another folder")
    return state


class _NoBar:
    def update(self, n=1):
        pass

    def set_postfix(self, **kw):
        pass

    def close(self):
        pass


def _bar(total, enabled, desc, unit="it", leave=True):
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    return tqdm(total=total, desc=desc, unit=unit, leave=leave)


def _progress(it, total, enabled, desc):
    if not enabled:
        return it
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    return tqdm(it, total=total, desc=desc, leave=False, unit="tensor")
