"""The trained defaults of encoding from samples: the atom prior and the PCA basis of the
training materials (``docs/method.md``, "Encoding from samples").

:func:`~sparse_brdf.acquisition.recovery.encode_samples` and
:func:`~sparse_brdf.acquisition.pca.pca_from_samples` take what they learned from
explicitly or, by default, from here: learned from the training split of the merl corpus
only (every :data:`TRAINING_STRIDE`-th material), the prior computed on first use and
cached on disk (``sources.cache``, keyed by all it is computed from; once: about 2 CPU
minutes, with a progress bar), the PCA basis likewise (about 15 s once; read back
memory-mapped, kept for the process). ``docs/benchmarks.md``, "encode-samples' first
run", has the measured times.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..coding.ensemble import Ensemble, resolve_ensemble
from ..coding.spec import ENCODE_OPTIONS
from ..compared.baselines import PCAModel
from ..errors import MissingDataError
from ..sources.cache import cache_dir, content_key
from ..sources.corpora import get_corpus
from ..transforms import TRANSFORMS
from .prior import (
    POOL_SIZE,
    PRIOR_COEFFS,
    PRIOR_VERSION,
    AtomPrior,
    compute_prior,
    load_prior,
    save_prior,
)

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
    return prior_of(resolve_ensemble(ensemble))


def prior_path(ens: Ensemble, mats: Sequence) -> Path:
    """Where the cache keeps the prior of ``ens`` on corpus materials ``mats``: keyed by
    all that :func:`~sparse_brdf.acquisition.prior.compute_prior` reads (the ensemble,
    the materials' sources, the coefficients and pool size, the transforms, the coded
    channels' basis) and the version of its computation."""
    key = content_key("atom-prior", PRIOR_VERSION, ens.id, [m.source for m in mats],
                      PRIOR_COEFFS, POOL_SIZE, list(TRANSFORMS), ENCODE_OPTIONS["basis"])
    return cache_dir() / f"{key}.npz"


def prior_of(ens: Ensemble) -> AtomPrior:
    """:func:`default_prior` of a resolved ensemble."""
    mats = training_materials()
    path = prior_path(ens, mats)
    prior = load_prior(path) if path.is_file() else None
    if prior is None:
        print(f"sparse-brdf: computing the atom prior of ensemble {ens.id} on {len(mats)} "
              "training materials (once: 2-4 min on 2 cores shared with other jobs, the "
              f"bar below estimates the rest; then cached in {cache_dir()})", file=sys.stderr)
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
                  f"materials (once, about 15 s on 2 cores; then cached in {cache_dir()})",
                  file=sys.stderr)
            with tqdm(mats, desc="PCA basis", unit="material", leave=False) as bar:
                brdfs = [m.load() for m in bar]
                bar.set_postfix_str("fitting")  # the fit: about a third of the time
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
