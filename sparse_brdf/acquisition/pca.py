"""The PCA baseline from samples (Nielsen et al. 2015; ``docs/method.md``, "Encoding from
samples").

Principal components of training materials in the log-relative mapping
(:class:`~sparse_brdf.compared.baselines.PCAModel`, the same median, mean, basis and
mapping) are interpolated at the samples' continuous grid coordinates with the trilinear
weights of the sensing operator (:class:`~sparse_brdf.acquisition.sensing.Operator`;
invalid neighbours dropped and the weights renormalised), and the coefficients are the ridge
least-squares fit to the samples' mapped values (the three channels of a sample share
the coefficients, as the components span all three). The component count and the ridge
are chosen by K-fold cross-validation on held-out samples, scored by the cosine-weighted
error of the linear values (as :func:`~sparse_brdf.acquisition.recovery.encode_samples`).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence

import numpy as np

from ..compared.baselines import PCAModel, from_log_relative, log_relative
from ..compared.compact import Compact, require_fitted
from ..errors import UsageError
from ..parallel import blas_single_thread
from ..params import SEED, Interval, check
from ..transforms import COS_CLIP, cosine_weight
from .defaults import trained_pca
from .measurements import Samples
from .sensing import DEFAULT_FOLDS, Operator, cosine_error, fold_of

#: Every parameter of :func:`pca_from_samples` a user sets, declared once.
PARAMETERS = {"max_components": Interval(int, 1), "folds": Interval(int, 2, 20),
              "seed": SEED}
#: Ridges tried, relative to the mean diagonal of the components' Gram matrix at the
#: training samples.
RIDGES = (1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: The guard against overshoot where no sample lies: the reconstruction's mapped values
#: are clamped per channel to the samples' range widened by this fraction of it.
MARGIN = 0.1


def _at_samples(pca: PCAModel, op: Operator, samples: Samples):
    """The mean, components and median interpolated at the samples, per (sample,
    channel) row: mean (3N,), basis (3N, K), median (3N,), and the rows' usable mask."""
    mask = pca.mask_  # (n1, n2, n3, 3), the same for the three channels
    valid = mask[..., 0].ravel()
    row = np.full(valid.size, -1, np.int64)
    row[valid] = np.arange(int(valid.sum()))
    w = op.w8 * valid[op.flat]
    tot = w.sum(1, keepdims=True)
    ok = tot[:, 0] > 0
    w = np.where(ok[:, None], w / np.where(tot > 0, tot, 1), 0.0)
    r8 = np.maximum(row[op.flat], 0)  # (N, 8); invalid neighbours carry weight 0
    mean, med, basis = [], [], []
    med_grid = pca.median_.reshape(-1, 3)
    for ch in range(3):
        ent = 3 * r8 + ch  # masked entries are in C order of (bin, channel)
        mean.append(np.sum(w * pca.mean_[ent], 1))
        med.append(np.sum(w * med_grid[op.flat, ch], 1))
        basis.append(np.einsum("nj,knj->nk", w, pca.basis_[:, ent]))
    return (np.stack(mean, 1).ravel(), np.stack(basis, 1).reshape(-1, pca.basis_.shape[0]),
            np.stack(med, 1).ravel(), np.repeat(ok, 3))


def _normal(b, m, w):
    """The Gram matrix and right-hand side of weighted least squares on ``b``."""
    bw = b.T * w
    return bw @ b, bw @ m


def _solve(g, rhs, k, lam):
    """Ridge values on the first ``k`` components."""
    return np.linalg.solve(g[:k, :k] + lam * np.eye(k), rhs[:k])


def _to_linear(pred, med, c):
    return np.clip(from_log_relative(pred, c, med), 0.0, np.finfo(np.float32).max)


def pca_from_samples(samples: Samples, training: Sequence | PCAModel | None = None,
                     max_components: int | None = None, folds: int = DEFAULT_FOLDS,
                     seed: int = 0) -> Compact:
    """Reconstruct a BRDF from samples with the PCA baseline of Nielsen et al. 2015.

    Parameters
    ----------
    samples : Samples
        N measurements (``sparse_brdf.read_samples``).
    training : sequence of Material or BRDF, or PCAModel, optional
        The basis: a fitted :class:`~sparse_brdf.compared.baselines.PCAModel` used as it
        is, or the training materials to fit it on
        (:func:`~sparse_brdf.acquisition.defaults.trained_pca`); default the training
        split's (:func:`~sparse_brdf.acquisition.defaults.training_materials`).
    max_components : int, optional
        Components at most (default all, the training materials less one).
    folds : int
        Folds of the cross-validation of the component count and the ridge (2 to 20).
    seed : int
        Seed of the folds.

    Returns
    -------
    Compact
        ``reconstruct()`` gives linear RGB (n1, n2, n3, 3) on the basis's grid (MERL's);
        ``params["coef"]`` the coefficients (float32); ``info`` the chosen component
        count and ridge, the cross-validation errors and the seconds taken.

    Raises
    ------
    UsageError
        For an option out of range, fewer samples than folds, or an unfitted basis.
    MissingDataError
        For the default basis when the training corpus is not on this machine.
    """
    pca = training if isinstance(training, PCAModel) else trained_pca(training)
    check("folds", folds, PARAMETERS["folds"])
    check("seed", seed, PARAMETERS["seed"])
    if len(samples) < folds:
        raise UsageError(f"{samples.source or samples.name}: {len(samples)} samples, fewer "
                         f"than the {folds} folds of the cross-validation")
    require_fitted(pca, pca.basis_ is not None)
    kmax = pca.basis_.shape[0]
    if max_components is not None:
        kmax = min(kmax, check("max_components", max_components,
                               PARAMETERS["max_components"]))
    return pca_fit(samples, pca, kmax, folds, seed)


def pca_fit(samples: Samples, pca: PCAModel, kmax: int, folds: int, seed: int) -> Compact:
    """:func:`pca_from_samples` on checked options: a fitted basis ``pca``, at most
    ``kmax`` components."""
    t0 = time.perf_counter()
    op = Operator.of(samples.wi, samples.wo, pca.mask_.shape[:3])
    mean, basis, med, ok = _at_samples(pca, op, samples)
    basis = basis[:, :kmax].astype(np.float64)
    c = np.clip(samples.wi[:, 2] * samples.wo[:, 2], *COS_CLIP)
    m = log_relative(samples.rgb, c[:, None], med.reshape(-1, 3)).ravel() - mean
    w = np.repeat(samples.weight, 3) * ok
    fold = np.repeat(fold_of(len(samples), folds, seed), 3)
    scale = float(np.mean(np.sum(basis ** 2 * w[:, None], 0))) / max(1, len(samples))
    ks = list(range(1, kmax + 1))
    pred = np.zeros((len(RIDGES), len(ks), m.size))
    # small products (K x 3N): one BLAS thread, which a busy machine never has to wait for
    # (two threads stalled for up to 0.7 s a product on the shared 2-core machine)
    with blas_single_thread():
        for f in range(folds):
            tr, ho = fold != f, fold == f
            g, rhs = _normal(basis[tr], m[tr], w[tr])
            for i, r in enumerate(RIDGES):
                lam = r * scale * tr.sum() / 3
                for j, k in enumerate(ks):
                    pred[i, j, ho] = basis[ho, :k] @ _solve(g, rhs, k, lam)
        normal = _normal(basis, m, w)
    rows = np.arange(len(samples))
    err = np.array([[cosine_error(samples, rows, _to_linear(
        (p + mean).reshape(-1, 3), med.reshape(-1, 3), c[:, None])) for p in pr]
        for pr in pred])
    i, j = np.unravel_index(int(np.argmin(err)), err.shape)
    k, lam = ks[j], RIDGES[i] * scale * len(samples)
    coef = _solve(*normal, k, lam)
    model = PCAModel(k)
    model.basis_, model.mean_, model.median_, model.mask_ = (pca.basis_, pca.mean_,
                                                             pca.median_, pca.mask_)
    y = (m + mean).reshape(-1, 3)[ok[::3]]
    lo, hi = y.min(0), y.max(0)
    bounds = (lo - MARGIN * (hi - lo), hi + MARGIN * (hi - lo))
    out = functools.cache(lambda: _reconstruct(model, coef, bounds))  # the full table on use
    info = {"n_coeffs": k, "ridge": RIDGES[i], "components": ks,
            "cv_cosine_error": err.tolist(), "samples": len(samples),
            "seconds": time.perf_counter() - t0}
    return Compact(f"pca-samples-{k}", k * 4, out, info,
                   {"coef": coef.astype(np.float32)})


def _reconstruct(pca: PCAModel, coef: np.ndarray, bounds) -> np.ndarray:
    """Linear RGB on the grid of a PCA basis and coefficients (``PCAModel.compress``'s
    rule, with the given coefficients), the mapped values clamped per channel to
    ``bounds`` (lo, hi), each (3,)."""

    shape = pca.mask_.shape[:3]
    mm = np.zeros((*shape, 3))
    mm[pca.mask_] = pca.mean_ + coef.astype(np.float32) @ pca.basis_[:coef.size]
    mm = np.clip(mm, *bounds)
    rho = from_log_relative(mm, cosine_weight(shape)[..., None], pca.median_)
    return np.where(pca.mask_, np.maximum(rho, 0), 0).astype(np.float32)
