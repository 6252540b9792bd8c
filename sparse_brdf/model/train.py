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
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..fileio import atomic_write
from .ensemble import Ensemble
from .tensor import (
    hosvd_factors,
    mode_grams,
    parallel_map,
    procrustes,
    project,
    top_k,
)

DEFAULT_TAUS: tuple[int, ...] = (32, 64, 128, 256)
DEFAULT_N_DICTS = 8


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


def _sq_norms(x: np.ndarray) -> np.ndarray:
    return np.array([float(np.dot(t.ravel(), t.ravel())) for t in x])


def _code(s: np.ndarray, tau: int) -> tuple[np.ndarray, np.ndarray, float]:
    flat = s.ravel()
    e = flat * flat
    idx = top_k(e, tau)
    return idx.astype(np.int32), flat[idx].astype(np.float32), float(e[idx].sum(dtype=np.float64))


def _assign_all(x, norms, state_u, tau, progress, known=None) -> tuple[np.ndarray, ...]:
    """Project every tensor on every dictionary; return best labels, codes and errors.

    ``known``: optional (labels, codes_idx, codes_val, errors) already computed with the
    current dictionaries; each tensor's own dictionary is then not projected again.
    """
    u1, u2, u3 = state_u
    k = u1.shape[0]

    def one(i):
        best = None
        errs = np.empty(k)
        for j in range(k):
            if known is not None and known[0][i] == j:
                idx, val, err = known[1][i], known[2][i], known[3][i]
            else:
                idx, val, kept = _code(project(x[i], u1[j], u2[j], u3[j]), tau)
                err = norms[i] - kept
            errs[j] = err
            if best is None or errs[j] < errs[best[0]]:
                best = (j, idx, val)
        return best, errs

    res = list(_progress(parallel_map(one, range(len(x))), len(x), progress, "assign"))
    labels = np.array([r[0][0] for r in res])
    idx = np.stack([r[0][1] for r in res])
    val = np.stack([r[0][2] for r in res])
    all_err = np.stack([r[1] for r in res])
    return labels, idx, val, all_err[np.arange(len(x)), labels], all_err


def _code_own(x, norms, state: TrainState, tau, progress) -> None:
    """Sparse-code each tensor in its own cluster's dictionary (in place)."""

    def one(i):
        j = state.labels[i]
        return _code(project(x[i], state.u1[j], state.u2[j], state.u3[j]), tau)

    for i, (idx, val, kept) in enumerate(
        _progress(parallel_map(one, range(len(x))), len(x), progress, "code")
    ):
        state.codes_idx[i], state.codes_val[i] = idx, val
        state.errors[i] = norms[i] - kept


#: Bytes of mode-3 partial products the dictionary update may keep between its first two
#: passes; above this (a very large cluster) they are recomputed instead.
MAX_CACHE_BYTES = 3 * 1024**3


def _update_dictionary(x, members, state: TrainState, j, progress) -> None:
    """Gauss-Seidel Procrustes update of the three modes of dictionary j.

    The passes for U1 and U2 both start from A = X x3 U3^T with the same U3, so A is
    computed once per tensor and kept for the second pass (when the cluster's products fit
    in ``MAX_CACHE_BYTES``); the results are the same as recomputing it.
    """
    n1, n2, n3 = x.shape[1:]
    shape = (n1, n2, n3)
    cache: dict[int, np.ndarray] | None = (
        {} if len(members) * n1 * n2 * n3 * 4 <= MAX_CACHE_BYTES else None)

    def onehot(pos, val, n):
        m = np.zeros((len(pos), n), np.float32)
        np.add.at(m, (np.arange(len(pos)), pos), val)
        return m

    def mode3_product(i, u3):
        """A = X_i x3 U3^T as an (n1 n2, n3) matrix, from the cache when there."""
        if cache is not None and i in cache:
            return cache.pop(i)
        a = x[i].reshape(n1 * n2, n3) @ u3
        if cache is not None:
            cache[i] = a
        return a

    for mode in range(3):
        u1, u2, u3 = state.u1[j], state.u2[j], state.u3[j]

        def contrib(i, mode=mode, u1=u1, u2=u2, u3=u3):
            a, b, c = np.unravel_index(state.codes_idx[i], shape)
            s = state.codes_val[i]
            if mode == 0:  # W1 = X x2 U2^T x3 U3^T, Z1[:, a_t] += s_t W1[:, b_t, c_t]
                w = np.matmul(u2.T, mode3_product(i, u3).reshape(n1, n2, n3))
                return w[:, b, c] @ onehot(a, s, n1)
            if mode == 1:  # W2 = X x1 U1^T x3 U3^T, Z2[:, b_t] += s_t W2[a_t, :, c_t]
                w = (u1.T @ mode3_product(i, u3).reshape(n1, n2 * n3))
                w = w.reshape(n1, n2, n3)
                return w[a, :, c].T @ onehot(b, s, n2)
            # W3 = X x1 U1^T x2 U2^T, Z3[:, c_t] += s_t W3[a_t, b_t, :]
            w = np.matmul(u2.T, (u1.T @ x[i].reshape(n1, n2 * n3)).reshape(n1, n2, n3))
            return w[a, b, :].T @ onehot(c, s, n3)

        z = None
        for part in _progress(parallel_map(contrib, members), len(members), progress,
                              f"dict {j} mode {mode + 1}"):
            z = part.astype(np.float64) if z is None else z + part
        if z is None:
            continue
        u_new = procrustes(z)
        (state.u1, state.u2, state.u3)[mode][j] = u_new


def _reseed_empty(x, norms, state: TrainState, tau) -> int:
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
        i = donors[np.argmax(state.errors[donors])]
        f1, f2, f3 = hosvd_factors(mode_grams(x[i]))
        state.u1[j], state.u2[j], state.u3[j] = f1, f2, f3
        idx, val, kept = _code(project(x[i], f1, f2, f3), tau)
        if norms[i] - kept <= state.errors[i]:
            state.labels[i] = j
            state.codes_idx[i], state.codes_val[i] = idx, val
            state.errors[i] = norms[i] - kept
        reseeded += 1
    return reseeded


def _init_state(x, tau, n_dicts, rng, progress) -> TrainState:
    """Random balanced clusters, each initialised with its HOSVD."""
    n = len(x)
    labels = rng.permutation(np.arange(n) % n_dicts)
    n1, n2, n3 = x.shape[1:]
    grams = [[np.zeros((m, m)) for m in (n1, n2, n3)] for _ in range(n_dicts)]
    for i, g in enumerate(_progress(parallel_map(lambda i: mode_grams(x[i]), range(n)), n,
                                    progress, "init")):
        for m in range(3):
            grams[labels[i]][m] += g[m]
    factors = [hosvd_factors(tuple(g)) if np.any(labels == j) else
               [np.eye(m, dtype=np.float32) for m in (n1, n2, n3)]
               for j, g in enumerate(grams)]
    return TrainState(
        u1=np.stack([f[0] for f in factors]), u2=np.stack([f[1] for f in factors]),
        u3=np.stack([f[2] for f in factors]), labels=labels,
        codes_idx=np.zeros((n, tau), np.int32), codes_val=np.zeros((n, tau), np.float32),
        errors=np.zeros(n),
    )


def _check_training_args(x, tau: int, n_dicts: int) -> np.ndarray:
    """``x`` as an array (a memory map stays one); raise on unusable arguments."""
    x = np.asarray(x) if not isinstance(x, np.memmap) else x
    if x.ndim != 4:
        raise ValueError(f"training tensors must have shape (N, n1, n2, n3), got {x.shape}")
    if tau < 1 or tau > np.prod(x.shape[1:]):
        raise ValueError(f"tau must be in [1, {np.prod(x.shape[1:])}], got {tau}")
    if n_dicts < 1 or n_dicts > len(x):
        raise ValueError(f"n_dicts must be in [1, {len(x)}] (one tensor per cluster at least), "
                         f"got {n_dicts}")
    return x


def _recluster(x, norms, state: TrainState, tau, progress) -> int:
    """Cluster every tensor against every dictionary (in place); return how many moved."""
    old = state.labels.copy()
    # after the first iteration the state's codes belong to the current dictionaries
    known = ((state.labels, state.codes_idx, state.codes_val, state.errors)
             if state.iteration > 0 else None)
    (state.labels, state.codes_idx, state.codes_val, state.errors,
     _) = _assign_all(x, norms, (state.u1, state.u2, state.u3), tau, progress, known)
    return int(np.sum(old != state.labels))


def _iterate(x, norms, total: float, state: TrainState, tau, n_dicts, reassign_every,
             progress) -> dict:
    """One training iteration (clustering or not, reseeding, dictionary updates, re-coding)
    on ``state`` in place; returns its history record."""
    t0 = time.perf_counter()
    it = state.iteration
    do_assign = it % reassign_every == 0
    # without clustering, the codes in the state are those of the current dictionaries
    # (re-coded at the end of the previous iteration, or read from its checkpoint)
    moved = _recluster(x, norms, state, tau, progress) if do_assign else 0
    reseeded = _reseed_empty(x, norms, state, tau)
    obj_before_update = float(state.errors.sum())
    for j in range(n_dicts):
        members = np.flatnonzero(state.labels == j)
        if members.size:
            _update_dictionary(x, members, state, j, progress)
    _code_own(x, norms, state, tau, progress)
    obj = float(state.errors.sum())
    return {
        "iteration": it, "objective": obj, "relative_objective": obj / total,
        "objective_before_update": obj_before_update, "assigned": bool(do_assign),
        "moved": moved, "reseeded": reseeded, "seconds": time.perf_counter() - t0,
    }


def _converged(history: list, tol: float) -> bool:
    """The last iteration moved nothing and lowered the objective by less than ``tol``."""
    if len(history) < 2:
        return False
    prev, last = history[-2]["objective"], history[-1]
    return prev > 0 and (prev - last["objective"]) / prev < tol and last["moved"] == 0


def train_dictionaries(
    x: np.ndarray,
    tau: int,
    n_dicts: int = DEFAULT_N_DICTS,
    n_iter: int = 8,
    tol: float = 1e-4,
    seed: int = 0,
    reassign_every: int = 3,
    checkpoint: str | os.PathLike | None = None,
    progress: bool = True,
    callback: Callable[[TrainState], bool | None] | None = None,
) -> TrainState:
    """Train ``n_dicts`` dictionaries under sparsity ``tau`` on tensors ``x``.

    Parameters
    ----------
    x : ndarray of shape (N, n1, n2, n3), float32
        Training tensors (transformed BRDF channels); may be a memory map.
    tau : int
        Coefficients kept per tensor in sparse coding.
    n_iter, tol : stop after ``n_iter`` iterations or when the relative decrease of the
        total error falls below ``tol``.
    reassign_every : int
        Clustering against every dictionary (K projections per tensor, the dominant cost)
        happens at every ``reassign_every``-th iteration, starting with the first;
        otherwise tensors are re-coded in their own dictionary only. The history records
        how many tensors each clustering moved. Each step is optimal for its own
        variables, so the objective never increases either way.
    checkpoint : path, optional
        ``.npz`` written after every iteration; if it exists and matches the run's
        fingerprint, training resumes from it.
    callback : called with the state after every iteration; returning True stops.

    Returns the final :class:`TrainState`; ``state.history`` has one dict per iteration
    (objective, relative objective, tensors moved, seconds).
    """
    x = _check_training_args(x, tau, n_dicts)
    norms = _sq_norms(x)
    total = float(norms.sum())
    fingerprint = _fingerprint(x, norms, tau, n_dicts, seed)
    state = _load_checkpoint(checkpoint, fingerprint) if checkpoint else None
    if state is None:
        state = _init_state(x, tau, n_dicts, np.random.default_rng(seed), progress)
    bar = _bar(n_iter, progress, f"tau={tau}")
    bar.update(state.iteration)
    while state.iteration < n_iter:
        record = _iterate(x, norms, total, state, tau, n_dicts, reassign_every, progress)
        state.history.append(record)
        state.iteration += 1
        if checkpoint:
            _save_checkpoint(checkpoint, state, fingerprint)
        bar.set_postfix(rel_err=f"{record['objective'] / total:.3e}", moved=record["moved"])
        bar.update(1)
        if callback is not None and callback(state):
            break
        if _converged(state.history, tol):
            break
    bar.close()
    return state


def train_ensemble(
    x: np.ndarray,
    taus: Sequence[int] = DEFAULT_TAUS,
    n_dicts: int = DEFAULT_N_DICTS,
    n_iter: int = 8,
    seed: int = 0,
    checkpoint_dir: str | os.PathLike | None = None,
    progress: bool = True,
    meta: dict | None = None,
    **kwargs,
) -> Ensemble:
    """Train ``n_dicts`` dictionaries per sparsity in ``taus`` and unite them.

    The sparsities are trained one after another, each with its own seed derived from
    ``seed``; with ``checkpoint_dir`` each writes ``tau-<tau>.npz`` there and resumes.
    ``meta`` is stored in the ensemble with the training history and time taken.
    """
    seeds = np.random.SeedSequence(seed).generate_state(len(taus))
    parts, histories = [], {}
    t0 = time.perf_counter()
    for tau, s in zip(taus, seeds, strict=True):
        ckpt = Path(checkpoint_dir) / f"tau-{tau}.npz" if checkpoint_dir else None
        st = train_dictionaries(x, int(tau), n_dicts, n_iter, seed=int(s), checkpoint=ckpt,
                                progress=progress, **kwargs)
        parts.append(Ensemble(st.u1, st.u2, st.u3, np.full(n_dicts, tau)))
        histories[str(tau)] = st.history
    ens = parts[0]
    for p in parts[1:]:
        ens = ens.union(p)
    ens.meta = {**(meta or {}), "taus": list(map(int, taus)), "n_dicts_per_tau": n_dicts,
                "n_iter": n_iter, "seed": seed, "n_tensors": int(len(x)),
                "seconds": time.perf_counter() - t0, "history": histories}
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


def _fingerprint(x, norms, tau, n_dicts, seed) -> str:
    h = hashlib.sha256(json.dumps([list(x.shape), tau, n_dicts, seed]).encode())
    h.update(np.asarray(norms, "<f8").tobytes())
    return h.hexdigest()


def _save_checkpoint(path, state: TrainState, fingerprint: str) -> None:
    with atomic_write(path) as f:
        np.savez(f, u1=state.u1, u2=state.u2, u3=state.u3, labels=state.labels,
                 codes_idx=state.codes_idx, codes_val=state.codes_val, errors=state.errors,
                 iteration=state.iteration, history=json.dumps(state.history),
                 fingerprint=fingerprint)


def _load_checkpoint(path, fingerprint: str) -> TrainState | None:
    path = Path(path)
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if str(z["fingerprint"]) != fingerprint:
            raise ValueError(f"{path}: checkpoint belongs to another training run "
                             "(different data, tau, K or seed); delete it or use another folder")
        return TrainState(z["u1"], z["u2"], z["u3"], z["labels"], z["codes_idx"],
                          z["codes_val"], z["errors"], int(z["iteration"]),
                          json.loads(str(z["history"])))


class _NoBar:
    def update(self, n=1):
        pass

    def set_postfix(self, **kw):
        pass

    def close(self):
        pass


def _bar(total, enabled, desc):
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    return tqdm(total=total, desc=desc, unit="it")


def _progress(it, total, enabled, desc):
    if not enabled:
        return it
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    return tqdm(it, total=total, desc=desc, leave=False, unit="tensor")
