"""Encoding from measured samples: a sparse BRDF from a few direction pairs.

- ``measurements``: :class:`Samples`, N measured direction pairs and their values;
  ``files``: reading and writing them, and plans of directions to measure.
- ``sensing``: the sensing operator (the atoms interpolated at the samples), the
  transforms at the samples, folds and budgets.
- ``recovery``: :func:`encode_samples`, greedy recovery over every atom or, with a prior,
  over the prior's pools (``_pools``); ``prior``: :class:`AtomPrior`, the atoms training
  materials use; ``pca``: :func:`pca_from_samples`, the PCA baseline from samples.
- ``defaults``: the trained defaults, the training split's prior and PCA basis, cached.
"""

from .defaults import (
    PRIORS,
    TRAINING_CORPUS,
    TRAINING_STRIDE,
    default_prior,
    trained_pca,
    training_materials,
)
from .files import read_samples, write_samples
from .measurements import Samples
from .pca import pca_from_samples
from .planning import plan
from .prior import AtomPrior
from .recovery import encode_samples

__all__ = ["PRIORS", "TRAINING_CORPUS", "TRAINING_STRIDE", "AtomPrior", "Samples",
           "default_prior", "encode_samples", "pca_from_samples", "plan", "read_samples",
           "trained_pca", "training_materials", "write_samples"]
