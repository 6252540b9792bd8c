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
Procrustes sums) runs on shards of the tensors (:class:`Shards`) through an executor
(``parallel.py``): in this process by default, or on Dask workers, with the same results
bit for bit (``docs/scale-out.md``).
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..coding.ensemble import Ensemble
from ..coding.tensor import hosvd_factors, mode_grams, procrustes
from ..errors import UsageError
from ..parallel import Executor, InProcess, parallel_map
from ..parallel import executor as open_executor
from ..params import SEED, Interval, check, check_choice
from ._checkpoint import TrainState, fingerprint, load_checkpoint, run_options, save_checkpoint
from ._codes import shard_assign, shard_code, shard_reseed, shard_seed_errors
from ._shards import (
    SHARD_TENSORS,
    Shards,
    cat,
    shard_gram,
    shard_gram_sums,
    shard_grams,
    shard_partials,
    shard_refill,
    shard_set_fill,
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
    "shard_tensors": Interval(int, 0),
}


def _code_own(data: Shards, state: TrainState, tau, hs) -> None:
    """Sparse-code each tensor in its own cluster's dictionary (``hs``: the scattered
    mode matrices); masked, its free bins are then refilled from the new code."""
    out = data.run(shard_code, data.slices(state.labels), tau, *hs, desc="code")
    state.codes_idx, state.codes_val, state.errors = (cat(out, k) for k in range(3))


def _refill_all(data: Shards, state: TrainState) -> None:
    """Masked: set every tensor's free bins from its code in ``state`` (on resuming)."""
    if data.masked:
        hs = data.scatter(state.u1, state.u2, state.u3)
        data.run(shard_refill, data.slices(state.labels, state.codes_idx, state.codes_val),
                 *hs)
        data.release(hs)


def _update_dictionaries(data: Shards, state: TrainState, hs: list, n_dicts) -> list:
    """Gauss-Seidel Procrustes update of the three modes of every dictionary with members.

    Each mode's product Z of every cluster is summed over the shards (a map-reduce); its
    Procrustes solution replaces the mode matrix, which is scattered again for the next
    mode. Returns the handles of the new mode matrices.
    """
    stacks = (state.u1, state.u2, state.u3)
    for mode in range(3):
        parts = data.run(shard_partials,
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


def _reseed_empty(data: Shards, state: TrainState, tau) -> int:
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
        (f1, f2, f3), idx, val, err, fill = data.run_one(i, shard_reseed, tau)
        state.u1[j], state.u2[j], state.u3[j] = f1, f2, f3
        if err <= state.errors[i]:
            state.labels[i] = j
            state.codes_idx[i], state.codes_val[i] = idx, val
            state.errors[i] = err
            if fill is not None:
                data.run_one(i, shard_set_fill, fill)
        reseeded += 1
    return reseeded


def _init_state(data: Shards, tau, n_dicts, rng, init: str = "random") -> TrainState:
    """The first clusters, each initialised with its HOSVD: random balanced clusters
    (``random``) or :func:`_seed_labels` (``seeded``)."""
    n = len(data)
    n1, n2, n3 = data.shape
    data.run(shard_grams, None, desc="init")
    if init == "random":
        labels = rng.permutation(np.arange(n) % n_dicts)
    elif init == "seeded":
        labels = _seed_labels(data, tau, n_dicts, rng)
    else:
        check_choice("init", init, INITS)
    sums = [[np.zeros((m, m)) for m in (n1, n2, n3)] for _ in range(n_dicts)]
    for part in data.run(shard_gram_sums, data.slices(labels), n_dicts):  # shard order
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


def _seed_labels(data: Shards, tau, n_dicts, rng) -> np.ndarray:
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
        hs = data.scatter(*hosvd_factors(data.run_one(s, shard_gram)))
        e = np.concatenate(data.run(shard_seed_errors, data.slices(err), tau, upto, *hs,
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


def _recluster(data: Shards, state: TrainState, tau, hs) -> int:
    """Cluster every tensor against every dictionary (in place); return how many moved."""
    old = state.labels.copy()
    # after the first iteration (or a warm start) the state's codes belong to the
    # current dictionaries
    known = (data.slices(state.labels, state.codes_idx, state.codes_val, state.errors)
             if state.iteration > 0 or state.coded else [None] * len(data.bounds))
    out = data.run(shard_assign, [(k,) for k in known], tau, *hs, desc="assign")
    state.labels, state.codes_idx, state.codes_val, state.errors = (
        cat(out, k) for k in range(4))
    return int(np.sum(old != state.labels))


def _iterate(data: Shards, total: float, state: TrainState, tau, n_dicts,
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
    shard_tensors: int = SHARD_TENSORS,
    start: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> TrainState:
    """Train ``n_dicts`` dictionaries under sparsity ``tau`` on tensors ``x``.

    Parameters
    ----------
    x : ndarray of shape (N, n1, n2, n3), float32
        Training tensors (transformed BRDF channels); may be a memory map. Never written.
    tau : int
        Coefficients kept per tensor in sparse coding.
    n_dicts : int
        Dictionaries to learn (K).
    n_iter, tol, max_moved : int, float, float
        Stop after ``n_iter`` iterations, or earlier once the latest clustering moved at
        most a fraction ``max_moved`` of the tensors and an iteration lowered the
        objective by less than ``tol`` (relative).
    seed : int
        Seed of the initial clustering; the same seed, data, options and thread count
        give the same dictionaries.
    reassign_every : int
        Clustering against every dictionary (K projections per tensor, the dominant cost)
        happens at every ``reassign_every``-th iteration, starting with the first;
        otherwise tensors are re-coded in their own dictionary only. The history records
        how many tensors each clustering moved. Each step is optimal for its own
        variables, so the objective never increases either way.
    checkpoint : path, optional
        ``.npz`` written after every iteration; if it exists and matches the run's
        fingerprint, training resumes from it (a larger ``n_iter`` continues a run).
    progress : bool
        Show a tqdm progress bar per iteration.
    callback : callable, optional
        Called with the state after every iteration; returning True stops.
    masked : bool
        Fit valid bins only: bins below the horizon (``coords.geometric_valid``) and the
        bins in ``missing`` are free values, refilled from each tensor's reconstruction
        after it is coded (module docstring). False fits them as the zeros ``x`` holds
        there (the paper; the first shipped ensemble).
    missing : {tensor index: bool array (n1, n2, n3)}, optional
        Unmeasured bins of the tensors that have any (``sources.dataset.training_data``);
        the channels of one material may share one array. Used only when masked.
    init : str
        ``"seeded"`` or ``"random"`` initial clusters (:func:`_init_state`).
    executor : Executor, optional
        Where the per-tensor work runs (``parallel.executor``; default: here).
    shard_tensors : int
        Tensors per shard (default ``SHARD_TENSORS``, 32): sums over tensors are summed
        per shard, then over the shards, so the shard size fixes the floating-point
        summation order (the result is the same on any executor for one size). 0: one
        shard of every tensor, the order of the trainer before shards existed, which
        trained the shipped default ensemble (``docs/ensemble.md``).
    start : (u1, u2, u3, labels), optional
        Start from these dictionaries (K mode matrices of each mode) and clusters (N,)
        instead of ``init``: a warm start, as :func:`train_ensemble` gives each sparsity
        the previous one's result. The tensors are first coded at ``tau`` in their own
        dictionaries, so the first clustering is pruned against known errors.

    Returns
    -------
    TrainState
        The final state: the mode matrices, each tensor's dictionary and code, and
        ``state.history``, one dict per iteration (objective -- squared error over valid
        bins when masked --, relative objective, tensors moved and their fraction,
        seconds).

    Raises
    ------
    UsageError
        For arguments out of range (``tau``, ``n_dicts``, ``init``, ``reassign_every``,
        the tensors' shape), or a checkpoint of another training run.
    BRDFFileError
        For a checkpoint file that cannot be read.
    """
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    x = _check_training_args(x, tau, n_dicts, init, reassign_every)
    check("shard_tensors", shard_tensors, PARAMETERS["shard_tensors"])
    with Shards(x, masked, missing, executor or InProcess(), progress,
                shard_tensors) as data:
        total = float(data.energy.sum())
        options = run_options(data.extra, masked, init)
        if shard_tensors != SHARD_TENSORS:  # (the default keeps earlier checkpoints valid)
            options = {**(options or {}), "shard_tensors": int(shard_tensors)}
        if start is not None:
            start = _check_start(start, len(x), n_dicts, data.shape)
            options = {**(options or {}), "start": _digest_arrays(start)}
        run = fingerprint(x, data.raw_norms, tau, n_dicts, seed, options)
        state = _start(data, checkpoint, run, tau, n_dicts, seed, init, start)
        bar = tqdm(total=n_iter, initial=state.iteration, desc=f"tau={tau}", unit="it",
                   disable=not progress)
        while state.iteration < n_iter and not _converged(state.history, tol, max_moved,
                                                          len(x)):
            record = _iterate(data, total, state, tau, n_dicts, reassign_every)
            state.history.append(record)
            state.iteration += 1
            if checkpoint:
                save_checkpoint(checkpoint, state, run)
            bar.set_postfix(rel_err=f"{record['objective'] / total:.3e}", moved=record["moved"])
            bar.update(1)
            if callback is not None and callback(state):
                break
        bar.close()
    return state


def _start(data: Shards, checkpoint, run: str, tau, n_dicts, seed, init,
           start=None) -> TrainState:
    """The state a run starts from: its checkpoint (the tensors' fills restored), a warm
    ``start`` coded at ``tau``, or a new initialisation."""
    state = load_checkpoint(checkpoint, run) if checkpoint else None
    if state is not None:
        _refill_all(data, state)
        return state
    t0 = time.perf_counter()
    if start is None:
        state = _init_state(data, tau, n_dicts, np.random.default_rng(seed), init)
    else:
        u1, u2, u3, labels = (np.array(a) for a in start)
        n = len(data)
        state = TrainState(u1, u2, u3, labels.astype(np.int64),
                           np.zeros((n, tau), np.int32), np.zeros((n, tau), np.float32),
                           np.zeros(n))
        hs = data.scatter(state.u1, state.u2, state.u3)
        _code_own(data, state, tau, hs)
        data.release(hs)
        state.coded = True
    state.init_seconds = time.perf_counter() - t0
    return state


def _check_start(start, n: int, n_dicts: int, shape) -> tuple:
    """A warm start's arrays as float32 mode matrices and int64 labels; raise on ones that
    do not fit the data or ``n_dicts``."""
    u1, u2, u3, labels = start
    u = [np.asarray(a, np.float32) for a in (u1, u2, u3)]
    labels = np.asarray(labels, np.int64)
    for m, (a, size) in enumerate(zip(u, shape, strict=True)):
        if a.shape != (n_dicts, size, size):
            raise UsageError(f"start: mode-{m + 1} matrices of shape {a.shape}, expected "
                             f"{(n_dicts, size, size)}")
    if labels.shape != (n,) or (n and (labels.min() < 0 or labels.max() >= n_dicts)):
        raise UsageError(f"start: labels must be {n} cluster numbers in [0, {n_dicts})")
    return (*u, labels)


def _digest_arrays(arrays) -> str:
    """sha256 of arrays' bytes (a warm start, in a checkpoint's fingerprint)."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


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
    warm_start: bool = False,
    **kwargs,
) -> Ensemble:
    """Train ``n_dicts`` dictionaries per sparsity in ``taus`` and unite them.

    The sparsities are trained one after another, each with its own seed derived from
    ``seed``.

    Parameters
    ----------
    x : ndarray of shape (N, n1, n2, n3), float32
        Training tensors (transformed BRDF channels, e.g. from
        ``sources.dataset.training_tensors``); may be a memory map. Never written.
    taus : sequence of int
        The training sparsities (coefficients per tensor), default (32, 64, 128, 256).
    n_dicts : int
        Dictionaries per sparsity.
    n_iter : int
        Iterations per sparsity (at most; see :func:`train_dictionaries`).
    seed : int
        The base seed.
    checkpoint_dir : path, optional
        Each sparsity writes ``tau-<tau>.npz`` there after every iteration and resumes
        from it.
    progress : bool
        Show tqdm progress bars.
    meta : dict, optional
        Stored in the ensemble's ``meta`` with the training options, history and time
        taken.
    workers, scheduler : int, str, optional
        Where the per-tensor work runs (``parallel.executor``: N local Dask workers, or a
        scheduler's address; default: in this process).
    warm_start : bool
        Start each sparsity after the first from the previous one's dictionaries and
        clusters (``start`` of :func:`train_dictionaries`) instead of a new
        initialisation: no seeding and no unpruned first clustering, and a lower
        training objective, but no better renders of unseen materials and larger files
        at a fixed coefficient count (``docs/ensemble.md`` measures both).
    **kwargs
        Passed to :func:`train_dictionaries` (``masked``, ``missing``, ``init``,
        ``reassign_every``, ``tol``, ``max_moved``).

    Returns
    -------
    Ensemble
        ``len(taus) * n_dicts`` dictionaries, sparsity by sparsity.

    Raises
    ------
    UsageError, BRDFFileError
        As :func:`train_dictionaries`.
    """
    seeds = np.random.SeedSequence(seed).generate_state(len(taus))
    parts, histories, init_seconds = [], {}, {}
    t0 = time.perf_counter()
    with open_executor(workers, scheduler) as ex:
        where = ex.describe()
        st = None
        for tau, s in zip(taus, seeds, strict=True):
            ckpt = Path(checkpoint_dir) / f"tau-{tau}.npz" if checkpoint_dir else None
            start = (st.u1, st.u2, st.u3, st.labels) if warm_start and st else None
            st = train_dictionaries(x, int(tau), n_dicts, n_iter, seed=int(s),
                                    checkpoint=ckpt, progress=progress, executor=ex,
                                    start=start, **kwargs)
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
               "max_moved": float(kwargs.get("max_moved", DEFAULT_MAX_MOVED)),
               "shard_tensors": int(kwargs.get("shard_tensors", SHARD_TENSORS)),
               "warm_start": bool(warm_start)}
    ens.meta = {**(meta or {}), "taus": list(map(int, taus)), "n_dicts_per_tau": n_dicts,
                "n_iter": n_iter, "seed": seed, "n_tensors": int(len(x)), **options,
                "seconds": time.perf_counter() - t0, "init_seconds": init_seconds,
                "where": where, "history": histories}
    return ens


def hosvd_ensemble(x: np.ndarray, progress: bool = True) -> Ensemble:
    """One dictionary: the HOSVD of all tensors ``x`` (N, n1, n2, n3) (a baseline)."""
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    n1, n2, n3 = x.shape[1:]
    grams = [np.zeros((m, m)) for m in (n1, n2, n3)]
    for g in tqdm(parallel_map(lambda i: mode_grams(x[i]), range(len(x))), total=len(x),
                  desc="hosvd", unit="tensor", leave=False, disable=not progress):
        for m in range(3):
            grams[m] += g[m]
    f = hosvd_factors(tuple(grams))
    return Ensemble(f[0][None], f[1][None], f[2][None], np.zeros(1),
                    {"kind": "hosvd", "n_tensors": int(len(x))})


# ----------------------------------------------------------------------- helpers

