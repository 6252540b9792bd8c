"""Encoding from samples with the trained defaults: the atom prior and the PCA basis of
the training materials (``docs/method.md``, "Encoding from samples").

The model-level functions take what they learned from explicitly
(:func:`sparse_brdf.model.acquire.encode_samples` an
:class:`~sparse_brdf.model.prior.AtomPrior`,
:func:`sparse_brdf.model.acquire_pca.pca_from_samples` a fitted
:class:`~sparse_brdf.model.baselines.PCAModel`); this module supplies the defaults,
learned from the training split of the merl corpus only (every
:data:`TRAINING_STRIDE`-th material): the prior computed on first use and cached on
disk (``sources.cache``, keyed by the ensemble and the materials; a few minutes once),
the PCA basis likewise (about 30 s once; read back memory-mapped, kept for the process).
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..errors import MissingDataError
from ..model import acquire, acquire_pca
from ..model.baselines import PCAModel
from ..model.budget import encode_to_bytes
from ..model.compact import Compact
from ..model.encode import DEFAULT_N_COEFFS, encode
from ..model.ensemble import Ensemble, resolve_ensemble
from ..model.prior import (
    POOL_SIZE,
    PRIOR_COEFFS,
    PRIOR_VERSION,
    AtomPrior,
    compute_prior,
    load_prior,
    save_prior,
)
from ..model.sparse import SparseBRDF
from ..params import check_choice
from ..samples import Samples
from ..sources.cache import cache_dir, content_key
from ..sources.corpora import get_corpus
from ..transforms import TRANSFORMS

#: The named atom priors (``prior=``): the training split's, or none.
PRIORS = ("default", "none")
#: The training corpus and the stride through its training split.
TRAINING_CORPUS, TRAINING_STRIDE = "merl", 2

_PCA: dict = {}


def training_materials() -> list:
    """The defaults' training materials: every :data:`TRAINING_STRIDE`-th material of
    the :data:`TRAINING_CORPUS` training split (never a test-split material).

    Raises
    ------
    MissingDataError
        If the corpus has no training materials on this machine.
    """
    mats = get_corpus(TRAINING_CORPUS).split("train")[::TRAINING_STRIDE]
    if len(mats) < 2:
        raise MissingDataError(f"encoding from samples: the {TRAINING_CORPUS} corpus has "
                               f"{len(mats)} training materials here; its prior needs the "
                               "shared measured data (README, Data), or encode without it: "
                               "--prior none (prior=\"none\")")
    return mats


def default_prior(ensemble: Ensemble | str | None = None) -> AtomPrior:
    """The atom prior of ``ensemble`` (default the shipped one) on
    :func:`training_materials`, from the disk cache or computed and cached."""
    ens = resolve_ensemble(ensemble)
    mats = training_materials()
    key = content_key("atom-prior", PRIOR_VERSION, ens.id, [m.source for m in mats],
                      PRIOR_COEFFS, POOL_SIZE, list(TRANSFORMS))
    path = cache_dir() / f"{key}.npz"
    prior = load_prior(path) if path.is_file() else None
    if prior is None:
        print(f"sparse-brdf: computing the atom prior of ensemble {ens.id} on {len(mats)} "
              "training materials (once, about 3 min on 2 cores; then cached in "
              f"{cache_dir()})", file=sys.stderr)
        prior = compute_prior(ens, mats)
        try:
            save_prior(path, prior)
        except OSError:
            pass  # a read-only or full cache folder only costs time
    return prior


def trained_pca(training: Sequence | None = None) -> PCAModel:
    """A PCA basis (all components) fitted on ``training`` (corpus materials or BRDFs;
    default :func:`training_materials`). For corpus materials it is remembered for the
    process and cached on disk like the atom prior (``sources.cache``, keyed by the
    materials; about 13 MB per training material), and read back memory-mapped."""
    mats = list(training_materials() if training is None else training)
    if not all(hasattr(m, "load") for m in mats):  # BRDFs given: nothing to remember
        return PCAModel(max(1, len(mats) - 1)).fit(mats)
    key = tuple(m.source for m in mats)
    if key not in _PCA:
        _PCA.clear()  # one basis at a time: ~15 MB per training material
        folder = cache_dir() / f"{content_key('pca-basis', PCA_VERSION, list(key))}.pca"
        pca = _load_pca(folder, len(mats))
        if pca is None:
            from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

            print(f"sparse-brdf: fitting the PCA fallback's basis on {len(mats)} training "
                  f"materials (once, about 30 s on 2 cores; then cached in {cache_dir()})",
                  file=sys.stderr)
            brdfs = [m.load() for m in tqdm(mats, desc="PCA basis", unit="material",
                                             leave=False)]
            pca = PCAModel(max(1, len(mats) - 1)).fit(brdfs)
            _save_pca(folder, pca)
        _PCA[key] = pca
    return _PCA[key]


#: Version of the cached PCA basis's layout (part of its cache key).
PCA_VERSION = 1
_PCA_ARRAYS = ("basis_", "mean_", "median_", "mask_")


def _save_pca(folder: Path, pca: PCAModel) -> None:
    """Write a fitted basis as one ``.npy`` per array into ``folder`` (built beside it,
    then renamed: readers see all of it or none); a read-only or full cache folder only
    costs time."""
    tmp = folder.with_name(f".{folder.name}.{os.getpid()}")
    try:
        tmp.mkdir(parents=True, exist_ok=True)
        for name in _PCA_ARRAYS:
            np.save(tmp / f"{name.rstrip('_')}.npy", np.ascontiguousarray(getattr(pca, name)))
        os.replace(tmp, folder)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)


def _load_pca(folder: Path, n_materials: int) -> PCAModel | None:
    """A basis written by :func:`_save_pca` (the components memory-mapped), or None when
    absent or damaged."""
    if not folder.is_dir():
        return None
    pca = PCAModel(max(1, n_materials - 1))
    try:
        for name in _PCA_ARRAYS:
            mode = "r" if name == "basis_" else None
            setattr(pca, name, np.load(folder / f"{name.rstrip('_')}.npy", mmap_mode=mode,
                                       allow_pickle=False))
    except (OSError, ValueError):
        return None
    ok = (pca.basis_.ndim == 2 and pca.mask_.ndim == 4
          and pca.basis_.shape[1] == pca.mean_.size == int(pca.mask_.sum()))
    return pca if ok else None


def encode_samples(samples: Samples, ensemble: Ensemble | str | None = None,
                   n_coeffs: int = DEFAULT_N_COEFFS, n_bytes: int | None = None,
                   transform: str = "auto", folds: int = acquire.DEFAULT_FOLDS,
                   candidates: int = acquire.DEFAULT_CANDIDATES, seed: int = 0,
                   prior: AtomPrior | str | None = "default",
                   pca_fallback: bool = True, training: Sequence | None = None) -> SparseBRDF:
    """Encode measured samples as a sparse BRDF over ``ensemble`` (compressed sensing with
    the ensemble and an atom prior; ``docs/method.md``, "Encoding from samples").

    Parameters
    ----------
    samples : Samples
        N measurements (``sparse_brdf.read_samples``): directions (N, 3) in the local
        frame, linear RGB (N, 3) in 1/sr, weights (N,).
    ensemble : Ensemble, path or id, optional
        The dictionaries; default the shipped ensemble.
    n_coeffs : int
        Coefficients per channel at most (a joint budget of 3 ``n_coeffs``).
    n_bytes : int, optional
        A byte budget for the ``.sbrdf`` file instead.
    transform : str
        ``"auto"`` (chosen on held-out samples), ``"log-plus"`` or ``"log-plus-cosine"``.
    folds : int
        Folds of the cross-validation (2 to 20).
    candidates : int
        Dictionaries per channel compared by cross-validation.
    seed : int
        Seed of the folds.
    prior : AtomPrior, "default", "none" or None
        The atom prior; ``"default"`` is :func:`default_prior` of the ensemble (computed
        once from the training split and cached); ``"none"`` or None searches every atom
        of every dictionary without a prior
        (:func:`sparse_brdf.model.acquire.encode_samples`).
    pca_fallback : bool
        With a prior, also fit the PCA baseline (:func:`pca_from_samples`, same folds)
        and, when its held-out cosine-weighted error is the smaller (few samples), return
        the full-table encoding of its reconstruction instead (``stats["fallback"]``);
        only when the PCA basis is on the ensemble's grid.
    training : sequence of Material or BRDF, optional
        The PCA basis's training materials (:func:`trained_pca`; default
        :func:`training_materials`).

    Returns
    -------
    SparseBRDF
        An ordinary model (``save_sbrdf``, ``decode``, the plugins); ``stats`` holds the
        cross-validation's choices and the seconds taken.

    Raises
    ------
    UsageError
        For an option out of range or fewer samples than folds.
    MissingDataError
        For the default prior when the training corpus is not on this machine.
    """
    ens = resolve_ensemble(ensemble)
    if isinstance(prior, str):
        prior = default_prior(ens) if check_choice("prior", prior, PRIORS) == "default" \
            else None
    model = acquire.encode_samples(samples, ens, n_coeffs, n_bytes, transform, folds,
                                   candidates, seed, prior=prior)
    if prior is None or not pca_fallback:
        return model
    basis = trained_pca(training)
    if basis.mask_.shape[:3] != ens.shape:
        return model
    pca = acquire_pca.pca_from_samples(samples, basis, folds=folds, seed=seed)
    pca_error = min(min(r) for r in pca.info["cv_cosine_error"])
    own = model.stats["transforms"][model.transform]["cv_cosine_error"]
    model.stats["pca_cv_cosine_error"] = pca_error
    if pca_error >= own:
        return model
    table = BRDF(pca.reconstruct(), np.array(basis.mask_[..., 0]), name=samples.name)
    alt = (encode_to_bytes(table, ens, n_bytes) if n_bytes is not None
           else encode(table, ens, n_coeffs))
    alt.stats = {**model.stats, "fallback": {"model": "pca", "n_coeffs": pca.info["n_coeffs"],
                                             "cv_cosine_error": pca_error,
                                             "sparse_cv_cosine_error": own}}
    return alt


def pca_from_samples(samples: Samples, training: Sequence | None = None,
                     max_components: int | None = None, folds: int = acquire.DEFAULT_FOLDS,
                     seed: int = 0) -> Compact:
    """The PCA baseline from samples (Nielsen et al. 2015,
    :func:`sparse_brdf.model.acquire_pca.pca_from_samples`) on the basis of ``training``.

    Parameters
    ----------
    samples : Samples
        N measurements.
    training : sequence of Material or BRDF, optional
        The basis's training materials; default :func:`training_materials` (training
        split only).
    max_components : int, optional
        Components at most (default all).
    folds : int
        Folds of the cross-validation of the component count and the ridge.
    seed : int
        Seed of the folds.

    Returns
    -------
    Compact
        ``reconstruct()`` gives linear RGB (n1, n2, n3, 3) on the MERL grid; ``info``
        the chosen component count and ridge.
    """
    return acquire_pca.pca_from_samples(samples, trained_pca(training), max_components,
                                        folds, seed)
