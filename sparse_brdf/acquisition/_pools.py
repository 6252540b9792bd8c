"""Encoding from samples with an atom prior (``docs/method.md``, "Encoding from samples").

Per transform and coded channel, each dictionary offers only its pool: the atoms the
training materials use (:class:`~sparse_brdf.acquisition.prior.AtomPrior`, a thousand per
dictionary instead of 1.46 M). With the pool the sensing matrix A (N samples x P atoms,
the atoms interpolated at the samples, :class:`~sparse_brdf.acquisition.recovery.Operator`) is
formed explicitly, and everything after its Gram matrix G = A^T W A is P-sized. On a
support S the values minimise

    (y - A_S s)^T W (y - A_S s) + lambda (s - mu_S)^T D_S (s - mu_S)

(ridge toward the prior mean mu with the prior precisions D = 1 / var): an atom the
samples do not see keeps its training mean instead of an arbitrary value, which is what
keeps the reconstruction from overshooting where no sample lies. The support grows
along one of two orders, the pool's own (by the training materials' mean squared value)
or greedily (orthogonal matching pursuit in Gram form: the atom of largest
|c_j| / sqrt(G_jj + lambda D_jj), c = A^T W (y - A_S s)), in stages 4, 8, 16, ...
K-fold cross-validation on held-out samples picks, per channel, the dictionary (among
those a one-fold screening on the pool's head keeps), the order, lambda and the support
size; the transform is chosen on the held-out cosine-weighted error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..coding.ensemble import Ensemble
from ..parallel import parallel_map
from .measurements import Samples
from .prior import AtomPrior
from .sensing import (
    Atoms,
    Choice,
    Operator,
    coded_values,
    cosine_error,
    linear_values,
    stage_sizes,
    trim_to_budget,
)

#: Prior weights lambda tried (squared coded units per unit sample weight).
LAMBDAS = (1e-3, 1e-2, 1e-1, 1.0)
#: Orders in which the support grows.
ORDERS = ("prior", "greedy")
#: Pool atoms the screening fits (the pool's head).
SCREEN_ATOMS = 64
#: Pool atoms the cross-validation and the final fit use (at most the prior's pool).
FIT_ATOMS = 512
#: Floor of the prior variances, relative to their mean over the pool.
VAR_FLOOR = 1e-3


@dataclass
class _Pool:
    """One dictionary's pool seen through the samples: Gram matrix and A^T W y on all
    samples and per fold, the columns, the prior mean and precisions."""

    loc: np.ndarray
    cols: np.ndarray
    mu: np.ndarray
    prec: np.ndarray


def _pool(atoms: Atoms, prior: AtomPrior, transform: str, c: int, k: int,
          p: int | None = None) -> _Pool:
    loc, mu, var = (a[:p] for a in prior.pool(transform, c, k))
    var = np.maximum(var, VAR_FLOOR * float(np.mean(var)) + 1e-12)
    return _Pool(loc, atoms.columns(loc, slice(None)), mu, 1.0 / var)


def _solve(g, rhs, lam, prec, mu):
    """The values on a support: (G + lam D) s = A^T W y + lam D mu."""
    a = g + lam * np.diag(prec)
    b = rhs + lam * prec * mu
    try:
        return np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(a, b, rcond=None)[0]


def path(g: np.ndarray, rhs: np.ndarray, pool: _Pool, lam: float, order: str,
         sizes: list[int]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The support (in the order it grew) and the values after each stage, from the
    Gram matrix ``g`` (P, P) and ``rhs`` = A^T W y (P,) of the fitting samples."""
    p = g.shape[0]
    if order == "prior":
        support = np.arange(min(sizes[-1], p))
        return support, [_solve(g[np.ix_(support[:s], support[:s])], rhs[support[:s]], lam,
                                pool.prec[:s], pool.mu[:s]) for s in sizes]
    support = np.zeros(0, np.int64)
    x = np.zeros(0)
    values = []
    norm = np.sqrt(np.diag(g) + lam * pool.prec)
    for s in sizes:
        corr = rhs - g[:, support] @ x
        score = np.abs(corr) / norm
        score[support] = -1.0
        new = np.argsort(-score, kind="stable")[:s - support.size]
        support = np.concatenate([support, new])
        x = _solve(g[np.ix_(support, support)], rhs[support], lam, pool.prec[support],
                   pool.mu[support])
        values.append(x)
    return support, values


def normal_equations(cols: np.ndarray, y: np.ndarray, w: np.ndarray):
    """G = A^T W A (float32 product, float64 result) and A^T W y of columns (N, P)."""
    aw = cols * w[:, None].astype(np.float32)
    return (aw.T @ cols).astype(np.float64), aw.T.astype(np.float64) @ y


def _cross_validate(pool: _Pool, y, w, fold, sizes):
    """Held-out predictions (N, orders, lambdas, stages) of every path, each sample
    predicted by the fold that held it out (each fold's Gram matrix is the one of all
    samples less the held-out samples')."""
    g_all, rhs_all = normal_equations(pool.cols, y, w)
    pred = np.zeros((y.size, len(ORDERS), len(LAMBDAS), len(sizes)))
    for f in range(int(fold.max()) + 1):
        ho = fold == f
        g_h, rhs_h = normal_equations(pool.cols[ho], y[ho], w[ho])
        g, rhs = g_all - g_h, rhs_all - rhs_h
        for i, order in enumerate(ORDERS):
            for j, lam in enumerate(LAMBDAS):
                sup, vals = path(g, rhs, pool, lam * float(np.mean(w)), order, sizes)
                hc = pool.cols[ho][:, sup].astype(np.float64)
                pred[ho, i, j] = np.stack([hc[:, :v.size] @ v for v in vals], 1)
    return pred


@dataclass
class PoolChoice(Choice):
    """A channel's choice (:class:`~sparse_brdf.acquisition.recovery.Choice`) with its order
    and lambda."""

    order: str = "prior"
    lam: float = 0.0


def screen(samples: Samples, op: Operator, ens: Ensemble, prior: AtomPrior,
           transforms: tuple[str, ...], basis: str, fold: np.ndarray,
           keep: int) -> tuple[str, list[list[int]]]:
    """The transform and, per channel, the ``keep`` dictionaries to cross-validate: each
    dictionary's pool head (:data:`SCREEN_ATOMS` atoms, the middle lambda) is fitted on
    all folds but fold 0 and scored on fold 0; the transform is the one whose best
    dictionaries predict fold 0 with the smaller cosine-weighted error of the linear
    values (one pass over the dictionaries for every transform and channel)."""
    tr, ho = fold != 0, fold == 0
    w = samples.weight
    ys = {t: coded_values(samples, t, basis) for t in transforms}

    def one(k):
        atoms = Atoms(op, ens.dictionary(k))
        out = {}
        for t in transforms:
            for c in range(3):
                pool = _pool(atoms, prior, t, c, k, SCREEN_ATOMS)
                x = _solve(*normal_equations(pool.cols[tr], ys[t][c, tr], w[tr]),
                           1e-2 * float(np.mean(w)), pool.prec, pool.mu)
                out[t, c] = pool.cols[ho].astype(np.float64) @ x
        return out

    preds = list(parallel_map(one, range(ens.n_dicts)))
    best, score = {}, {}
    for t in transforms:
        err = np.array([[np.sum(w[ho] * (p[t, c] - ys[t][c, ho]) ** 2) for p in preds]
                        for c in range(3)])
        best[t] = [[int(k) for k in np.argsort(err[c], kind="stable")[:keep]]
                   for c in range(3)]
        coded = np.stack([preds[best[t][c][0]][t, c] for c in range(3)])
        score[t] = cosine_error(samples, np.flatnonzero(ho), linear_values(
            coded, samples.subset(ho), t, basis))
    chosen = min(transforms, key=lambda t: score[t])
    return chosen, best[chosen]


def _channel(op, ens, prior, transform, c, dicts, y, w, fold, t_max) -> PoolChoice:
    """The best (dictionary, order, lambda, size) of one channel by cross-validation."""
    zero = float(np.sum(w * y * y))
    best = PoolChoice(dicts[0], 0, zero, [zero], [0], np.zeros((y.size, 1)))
    sizes = stage_sizes(t_max)
    if not sizes:
        return best
    for k in dicts:
        pool = _pool(Atoms(op, ens.dictionary(k)), prior, transform, c, k, FIT_ATOMS)
        sz = [s for s in sizes if s <= pool.loc.size] or [pool.loc.size]
        pred = _cross_validate(pool, y, w, fold, sz)
        err = np.sum(w[:, None, None, None] * (pred - y[:, None, None, None]) ** 2, axis=0)
        i, j, s = np.unravel_index(int(np.argmin(err)), err.shape)
        if err[i, j, s] < best.error:
            best = PoolChoice(k, sz[s], float(err[i, j, s]), [zero, *map(float, err[i, j])],
                              [0, *sz], np.concatenate([np.zeros((y.size, 1)),
                                                        pred[:, i, j]], 1),
                              ORDERS[i], LAMBDAS[j])
    return best


def fit_transform(samples: Samples, op: Operator, ens: Ensemble, prior: AtomPrior,
                  transform: str, basis: str, n: int, fold: np.ndarray,
                  cands: list[list[int]]) -> dict:
    """Cross-validate one transform with the prior (the counterpart of the unrestricted
    search's) on the dictionaries ``cands`` of each channel (:func:`screen`): each
    channel's choice, the joint budget of 3 ``n`` and the held-out cosine-weighted
    error."""
    y = coded_values(samples, transform, basis)
    w = samples.weight
    t_max = max(0, min(n, int(0.5 * np.sum(fold != 0))))
    tasks = [(c, k) for c in range(3) for k in cands[c]]
    done = list(parallel_map(lambda task: _channel(op, ens, prior, transform, task[0],
                                                   [task[1]], y[task[0]], w, fold, t_max),
                             tasks))
    choices = [min((ch for (c2, _), ch in zip(tasks, done, strict=True) if c2 == c),
                   key=lambda ch: ch.error) for c in range(3)]
    idx = trim_to_budget(choices, 3 * n)
    pred = np.zeros_like(y)
    for c, (ch, i) in enumerate(zip(choices, idx, strict=True)):
        ch.size, ch.error = ch.sizes[i], ch.curve[i]
        pred[c] = ch.predicted[:, i]
    rgb = linear_values(pred, samples, transform, basis)
    return {"choices": choices, "y": y,
            "cv_error": cosine_error(samples, np.arange(len(samples)), rgb)}


def final_values(op: Operator, ens: Ensemble, prior: AtomPrior, transform: str,
                 fit: dict, w: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per channel the (locations, values) of the chosen path refitted on every sample,
    by decreasing magnitude."""
    def one(c):
        ch = fit["choices"][c]
        if ch.size == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float32)
        pool = _pool(Atoms(op, ens.dictionary(ch.dictionary)), prior, transform, c,
                     ch.dictionary, FIT_ATOMS)
        sizes = ch.sizes[1:ch.sizes.index(ch.size) + 1]
        sup, vals = path(*normal_equations(pool.cols, fit["y"][c], w), pool,
                         ch.lam * float(np.mean(w)), ch.order, sizes)
        v = vals[-1]
        order = np.argsort(-np.abs(v), kind="stable")
        return pool.loc[sup[:v.size]][order], v[order].astype(np.float32)

    return list(parallel_map(one, range(3)))
