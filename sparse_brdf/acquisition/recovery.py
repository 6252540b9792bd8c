"""Encoding from samples: a sparse BRDF from a few measured direction pairs
(``docs/method.md``, "Encoding from samples").

The sensing operator and the pieces both recoveries share are in
:mod:`sparse_brdf.acquisition.sensing`. With an atom prior (the default of
``sparse_brdf.encode_samples``) each dictionary offers only the atoms training materials
use, :mod:`sparse_brdf.acquisition._pools`. Without one (``prior=None``) every atom of
every dictionary is a candidate and the sensing matrix is never formed:

Recovery is greedy (stagewise orthogonal matching pursuit): the atoms of largest
normalised correlation with the residual join the support in batches, and the values on
the support are the (slightly ridged) least squares fit to the samples. The path of
support sizes is scored on held-out samples (K-fold cross-validation), which picks the
size per channel, the dictionary among the candidates a screening keeps, and the
transform. The full table is never used.

:func:`encode_samples` is the one entry point (``sparse_brdf.encode_samples``): it
resolves the ensemble, checks the options and resolves the prior once (the trained
defaults of :mod:`sparse_brdf.acquisition.defaults`), and with a prior falls back to the
PCA baseline from the same samples (:mod:`sparse_brdf.acquisition.pca`) when that
predicts the held-out samples better.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..brdf import BRDF
from ..coding.budget import fit_bytes
from ..coding.coefficients import SparseBRDF
from ..coding.encode import encode_with
from ..coding.ensemble import Ensemble
from ..coding.spec import DEFAULT_N_COEFFS, ENCODE_OPTIONS, EncodeSpec
from ..coding.tensor import top_k
from ..errors import UsageError
from ..parallel import parallel_map
from ..params import SEED, Interval, check, check_choice
from ..transforms import TRANSFORMS, has_lobe
from . import _pools, defaults
from .defaults import PRIORS
from .measurements import Samples
from .pca import pca_fit
from .prior import AtomPrior
from .sensing import (
    DEFAULT_FOLDS,
    Atoms,
    Choice,
    Operator,
    coded_values,
    cosine_error,
    fold_of,
    linear_values,
    project,
    samples_gain,
    stage_sizes,
    trim_to_budget,
)

__all__ = ["GreedyPath", "Operator", "Atoms", "encode_samples", "stage_sizes"]

#: Every parameter of :func:`encode_samples` a user sets, declared once.
PARAMETERS = {
    "n_coeffs": Interval(int, 1),
    # the lobe transforms need a material's table to fit its lobe: not from samples
    "transform": ("auto", *(t for t in TRANSFORMS if not has_lobe(t))),
    "folds": Interval(int, 2, 20),
    "candidates": Interval(int, 1, 64),
    "seed": SEED,
}
#: Dictionaries per channel the screening keeps for cross-validation.
DEFAULT_CANDIDATES = 2
#: Largest support as a fraction of the training samples of a fit.
MAX_SUPPORT_FRACTION = 0.5
#: Ridge of each least-squares fit, relative to a column's mean squared norm over the
#: dictionary (the summed weights over the grid's bins): well-sampled coefficients shrink
#: by about this fraction, atoms the samples barely see are held near zero.
RIDGE = 1e-2


# ------------------------------------------------------------------ the greedy path


@dataclass
class GreedyPath:
    """A greedy path: the support in the order it grew, the values after each stage
    (``values[j]`` on ``support[:sizes[j]]``) and, when held-out rows were given, the
    predictions at them, (N_hold, stages)."""

    sizes: list[int]
    support: np.ndarray
    values: list[np.ndarray]
    held_out: np.ndarray | None = None


def _solve(gram: np.ndarray, rhs: np.ndarray, lam: float) -> np.ndarray:
    """The ridged least-squares values from the Gram matrix and A^T W y."""
    n = gram.shape[0]
    try:
        c = np.linalg.cholesky(gram + lam * np.eye(n))
        return np.linalg.solve(c.T, np.linalg.solve(c, rhs))
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(gram + lam * np.eye(n), rhs, rcond=None)[0]


def greedy_path(atoms: Atoms, y: np.ndarray, w: np.ndarray, train: np.ndarray,
                sizes: list[int], hold: np.ndarray | None = None) -> GreedyPath:
    """Stagewise OMP on the samples ``train`` (row indices): at each stage the atoms of
    largest |A^T W r| / ||column|| join until the support has ``sizes[j]`` atoms, then the
    values on the support are refitted (ridged least squares, the Gram matrix grown
    column block by column block)."""
    yt, wt = y[train], w[train]
    norms = atoms.norms(wt, train)
    mean_sq = float(np.sum(wt)) / norms.size  # a column's mean squared norm
    norms = np.sqrt(norms * norms + mean_sq)  # a soft floor: no atom wins by being unseen
    lam = RIDGE * mean_sq
    support = np.zeros(0, np.int64)
    cols = np.zeros((train.size, 0), np.float32)
    gram = np.zeros((0, 0))
    rhs = np.zeros(0)
    values, x = [], np.zeros(0)
    res = yt.copy()
    for size in sizes:
        score = np.abs(atoms.correlate(wt * res, train)) / norms
        score[support] = -1.0
        new = top_k(score, size - support.size)
        new = new[score[new] > 0]
        if new.size:
            nc = atoms.columns(new, train)
            wn = nc * wt[:, None].astype(np.float32)
            cross = (cols.T @ wn).astype(np.float64)
            gram = np.block([[gram, cross], [cross.T, (nc.T @ wn).astype(np.float64)]])
            rhs = np.concatenate([rhs, wn.T.astype(np.float64) @ yt])
            cols = np.concatenate([cols, nc], axis=1)
            support = np.concatenate([support, new])
            x = _solve(gram, rhs, lam)
            res = yt - cols.astype(np.float64) @ x
        values.append(np.pad(x, (0, 0)))
    pred = None
    if hold is not None and hold.size:
        hc = atoms.columns(support, hold).astype(np.float64)
        pred = np.stack([hc[:, :v.size] @ v for v in values], 1)
    return GreedyPath(sizes, support, values, pred)


# --------------------------------------------------------- screening and selection


def screen(op: Operator, y: np.ndarray, w: np.ndarray, ens: Ensemble, n: int,
           keep: int) -> list[list[int]]:
    """Per coded channel, the ``keep`` dictionaries to cross-validate: those whose ``n``
    largest coefficients of the back-projection A^T W y (the samples scattered onto the
    grid, ``Operator.scatter``, projected on the dictionary) keep the most energy, the
    full-table encoder's rule (with every bin sampled, A^T y is the coefficients)."""
    g = [op.scatter(w * y[c]) for c in range(3)]

    def kept(task):
        c, k = task
        e = np.square(project(g[c], *ens.dictionary(k)).ravel())
        return float(np.sum(e[top_k(e, n)], dtype=np.float64))

    tasks = [(c, k) for c in range(3) for k in range(ens.n_dicts)]
    energy = np.array(list(parallel_map(kept, tasks))).reshape(3, ens.n_dicts)
    return [[int(k) for k in np.argsort(-energy[c], kind="stable")[:keep]] for c in range(3)]


def cross_validate(atoms: Atoms, y: np.ndarray, w: np.ndarray, fold: np.ndarray,
                   t_max: int) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The greedy path fitted on all folds but one, for each fold: the path's sizes, the
    held-out squared error at each size (summed over the folds) and the held-out
    predictions at each size, (N, stages)."""
    folds = int(fold.max()) + 1
    sizes = stage_sizes(t_max)
    pred = np.zeros((y.size, len(sizes)))

    def one(f):
        return greedy_path(atoms, y, w, np.flatnonzero(fold != f), sizes,
                           np.flatnonzero(fold == f))

    for f, path in enumerate(parallel_map(one, range(folds))):
        hold = np.flatnonzero(fold == f)
        pred[hold] = path.held_out
    err = np.sum(w[:, None] * (pred - y[:, None]) ** 2, axis=0)
    return sizes, err, pred


def _channel(op: Operator, ens: Ensemble, dicts: list[int], y: np.ndarray, w: np.ndarray,
             fold: np.ndarray, t_max: int) -> Choice:
    """The best (dictionary, support size) of one coded channel by cross-validation; size 0
    (the channel left empty) is a candidate too."""
    zero = float(np.sum(w * y * y))
    best = Choice(dicts[0], 0, zero, [zero], [0], np.zeros((y.size, 1)))
    if zero == 0.0 or t_max < 1:
        return best
    for k in dicts:
        sizes, err, pred = cross_validate(Atoms(op, ens.dictionary(k)), y, w, fold, t_max)
        j = int(np.argmin(err))
        if err[j] < best.error:
            best = Choice(k, sizes[j], float(err[j]), [zero, *map(float, err)],
                           [0, *sizes], np.concatenate([np.zeros((y.size, 1)), pred], 1))
    return best


def _fit_transform(samples: Samples, op: Operator, ens: Ensemble, transform: str,
                   basis: str, n: int, fold: np.ndarray, candidates: int) -> dict:
    """Cross-validate one transform: each channel's dictionary and size, the joint budget,
    and the held-out cosine-weighted error of the three channels together."""
    y = coded_values(samples, transform, basis)
    w = samples.weight
    n_train = int(np.sum(fold != 0))
    t_max = max(0, min(3 * n, int(MAX_SUPPORT_FRACTION * n_train)))
    cands = screen(op, y, w, ens, max(t_max, 1), candidates)
    choices = [_channel(op, ens, cands[c], y[c], w, fold, t_max) for c in range(3)]
    idx = trim_to_budget(choices, 3 * n)
    pred = np.zeros_like(y)
    for c, (ch, i) in enumerate(zip(choices, idx, strict=True)):
        ch.size, ch.error = ch.sizes[i], ch.curve[i]
        pred[c] = ch.predicted[:, i]
    rgb = linear_values(pred, samples, transform, basis)
    all_rows = np.arange(len(samples))
    return {"choices": choices, "cv_error": cosine_error(samples, all_rows, rgb), "y": y}


def encode_samples(samples: Samples, ensemble: Ensemble | str | None = None,
                   n_coeffs: int = DEFAULT_N_COEFFS, n_bytes: int | None = None,
                   transform: str = "auto", folds: int = DEFAULT_FOLDS,
                   candidates: int = DEFAULT_CANDIDATES, seed: int = 0,
                   prior: AtomPrior | str | None = "default", pca_fallback: bool = True,
                   training: Sequence | None = None) -> SparseBRDF:
    """Encode measured samples as a :class:`SparseBRDF` over ``ensemble`` (compressed
    sensing with the ensemble's separable dictionaries and an atom prior;
    ``docs/method.md``, "Encoding from samples").

    Per coded channel (the encoder's opponent colour basis of the transformed R, G, B),
    the coefficients are found by greedy sparse recovery (stagewise orthogonal matching
    pursuit with least-squares refits) through the sensing operator, whose atoms are
    interpolated linearly between the bins' lower-edge samples, so samples may lie
    anywhere. The support size of each channel, its dictionary (among ``candidates``
    that a screening keeps) and the transform are chosen by ``folds``-fold
    cross-validation on held-out samples; the full table is never used. The result is an
    ordinary model: ``save_sbrdf``, ``decode``, ``blend`` and the plugins read it.

    The ensemble, the coefficient count, the byte budget and the transforms (an
    :class:`~sparse_brdf.coding.spec.EncodeSpec`), the other options and the prior are
    resolved and checked here, once; everything below takes the resolved objects.

    Parameters
    ----------
    samples : Samples
        N measurements: unit directions ``wi``, ``wo`` (N, 3) in the local frame (z up),
        linear RGB values (N, 3) in 1/sr, weights (N,) (``sparse_brdf.read_samples``
        reads them from a CSV or ``.npz`` file).
    ensemble : Ensemble, path or id, optional
        The dictionaries; default the shipped default ensemble.
    n_coeffs : int
        Coefficients per channel at most, spent as a joint budget of 3 ``n_coeffs`` over
        the channels; fewer when held-out samples say more would overfit (at most half
        the training samples of a fold per channel).
    n_bytes : int, optional
        A byte budget for the ``.sbrdf`` file instead: the largest coefficients over the
        channels that fit (``encode_to_bytes``'s rule).
    transform : str
        ``"auto"`` (the one of smaller held-out error), ``"log-plus"`` or
        ``"log-plus-cosine"``.
    folds : int
        Folds of the cross-validation (2 to 20).
    candidates : int
        Dictionaries per channel compared by cross-validation (1 to 64).
    seed : int
        Seed of the folds: the result is the same for the same seed.
    prior : AtomPrior, "default", "none" or None
        Restrict each dictionary to the atoms training materials use and fit toward
        their training values (:mod:`sparse_brdf.acquisition._pools`); ``"default"`` is
        :func:`~sparse_brdf.acquisition.defaults.default_prior` of the ensemble (computed
        once from the training split and cached); ``"none"`` or None makes every atom of
        every dictionary a candidate.
    pca_fallback : bool
        With a prior, also fit the PCA baseline (:func:`~sparse_brdf.acquisition.pca.
        pca_from_samples`, same folds) and, when its held-out cosine-weighted error is
        the smaller (few samples), return the full-table encoding of its reconstruction
        instead (``stats["fallback"]``); only when the PCA basis is on the ensemble's
        grid.
    training : sequence of Material or BRDF, optional
        The PCA basis's training materials
        (:func:`~sparse_brdf.acquisition.defaults.trained_pca`; default
        :func:`~sparse_brdf.acquisition.defaults.training_materials`).

    Returns
    -------
    SparseBRDF
        The model; ``stats`` holds per transform the held-out cosine-weighted error, per
        channel the dictionary, size and cross-validation curve, and the seconds taken.

    Raises
    ------
    UsageError
        For an option out of its range, fewer samples than folds, or a prior of another
        ensemble.
    EnsembleMismatchError
        For an ensemble that cannot be resolved.
    MissingDataError
        For the default prior when the training corpus is not on this machine.
    """
    check_choice("transform", transform, PARAMETERS["transform"])
    spec = EncodeSpec.build(ensemble, None if n_bytes is not None else n_coeffs, n_bytes,
                            transform=transform, basis=ENCODE_OPTIONS["basis"])
    ens, n = spec.ensemble, spec.n_coeffs
    check("folds", folds, PARAMETERS["folds"])
    check("candidates", candidates, PARAMETERS["candidates"])
    check("seed", seed, PARAMETERS["seed"])
    if not isinstance(samples, Samples):
        raise UsageError(f"encode_samples: expected Samples, got {type(samples).__name__} "
                         "(read a file with sparse_brdf.read_samples)")
    if len(samples) < folds:
        raise UsageError(f"{samples.source or samples.name}: {len(samples)} samples, fewer "
                         f"than the {folds} folds of the cross-validation")
    if isinstance(prior, str):
        prior = (defaults.prior_of(ens) if check_choice("prior", prior, PRIORS) == "default"
                 else None)
    if prior is not None and prior.ensemble_id != ens.id:
        raise UsageError(f"encode_samples: the atom prior is of ensemble "
                         f"{prior.ensemble_id}, not {ens.id}")
    t0 = time.perf_counter()
    # "auto" from samples: the ensemble's own pair (a lobe needs the material's table)
    names = ens.transforms if transform == "auto" else spec.transforms
    model = _recover(samples, ens, n, names, folds, candidates, seed, prior)
    if n_bytes is not None:
        model = fit_bytes(model, n_bytes, spec.version)
    model.stats["seconds"] = time.perf_counter() - t0
    if prior is None or not pca_fallback:
        return model
    return _pca_fallback(model, samples, spec, folds, seed, training)


def _recover(samples: Samples, ens: Ensemble, n: int, names: tuple[str, ...], folds: int,
             candidates: int, seed: int, prior: AtomPrior | None) -> SparseBRDF:
    """:func:`encode_samples` on checked options and resolved objects: the transforms
    ``names`` cross-validated, the chosen one refitted on every sample, its ``stats``."""
    basis = ENCODE_OPTIONS["basis"]
    op = Operator.of(samples.wi, samples.wo, ens.shape)
    fold = fold_of(len(samples), folds, seed)
    if prior is None:
        fits = {t: _fit_transform(samples, op, ens, t, basis, n, fold, candidates)
                for t in names}
    else:
        t, cands = _pools.screen(samples, op, ens, prior, names, basis, fold, candidates)
        fits = {t: _pools.fit_transform(samples, op, ens, prior, t, basis, n, fold, cands)}
    chosen = min(fits, key=lambda t: fits[t]["cv_error"])
    if prior is None:
        model = _final(samples, op, ens, chosen, basis, fits[chosen])
    else:
        out = _pools.final_values(op, ens, prior, chosen, fits[chosen], samples.weight)
        model = SparseBRDF(chosen, ens.shape, ens.id,
                           [ch.dictionary for ch in fits[chosen]["choices"]],
                           [a for a, _ in out], [v for _, v in out], name=samples.name,
                           basis=basis, gain=samples_gain(samples, chosen))
    model.stats = {
        "chosen": chosen, "samples": len(samples), "folds": folds,
        "transforms": {t: {"cv_cosine_error": f["cv_error"],
                           "channels": [{"dictionary": ch.dictionary, "size": ch.size,
                                         "sizes": ch.sizes, "cv_error": ch.curve,
                                         **({"order": ch.order, "lambda": ch.lam}
                                            if prior is not None else {})}
                                        for ch in f["choices"]]}
                       for t, f in fits.items()}}
    return model


def _pca_fallback(model: SparseBRDF, samples: Samples, spec: EncodeSpec, folds: int,
                  seed: int, training: Sequence | None) -> SparseBRDF:
    """``model``, or the full-table encoding of the PCA baseline's reconstruction from the
    same samples when its held-out cosine-weighted error is the smaller (the encoder's
    defaults, the transform chosen among the ensemble's)."""
    ens = spec.ensemble
    basis = defaults.trained_pca(training)
    if basis.mask_.shape[:3] != ens.shape:
        return model
    pca = pca_fit(samples, basis, basis.basis_.shape[0], folds, seed)
    pca_error = min(min(r) for r in pca.info["cv_cosine_error"])
    own = model.stats["transforms"][model.transform]["cv_cosine_error"]
    model.stats["pca_cv_cosine_error"] = pca_error
    if pca_error >= own:
        return model
    table = BRDF(pca.reconstruct(), np.array(basis.mask_[..., 0]), name=samples.name)
    full = replace(spec, transform="auto", transforms=ens.transforms)
    alt = encode_with(table, full)
    alt.stats = {**model.stats, "fallback": {"model": "pca", "n_coeffs": pca.info["n_coeffs"],
                                             "cv_cosine_error": pca_error,
                                             "sparse_cv_cosine_error": own}}
    return alt


def _final(samples: Samples, op: Operator, ens: Ensemble, transform: str, basis: str,
           fit: dict) -> SparseBRDF:
    """The chosen channels refitted on every sample, along the same path to the size
    cross-validation chose."""
    y, w, rows = fit["y"], samples.weight, np.arange(len(samples))

    def one(c):
        ch = fit["choices"][c]
        if ch.size == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float32)
        sizes = ch.sizes[1:ch.sizes.index(ch.size) + 1]
        path = greedy_path(Atoms(op, ens.dictionary(ch.dictionary)), y[c], w, rows, sizes)
        v = path.values[-1]
        order = np.argsort(-np.abs(v), kind="stable")
        return path.support[:v.size][order], v[order].astype(np.float32)

    out = list(parallel_map(one, range(3)))
    return SparseBRDF(transform, ens.shape, ens.id, [ch.dictionary for ch in fit["choices"]],
                      [a for a, _ in out], [v for _, v in out], name=samples.name,
                      basis=basis, gain=samples_gain(samples, transform))
