"""The interface every compared BRDF model follows, and what it compresses a BRDF to.

The convention, scikit-learn's:

- ``model.fit(brdfs)`` learns the model's shared state from training BRDFs (a PCA
  basis) and returns the model itself; a per-material model's ``fit`` does nothing.
- ``model.compress(brdf)`` compresses one BRDF and returns a :class:`Compact`: the numbers
  kept for that material (``params``), their storage (``nbytes``) and ``reconstruct()``.
  A model that needs ``fit`` raises :class:`~sparse_brdf.errors.UsageError` when it is
  used unfitted.

This is the compared-model protocol of :mod:`sparse_brdf.compared.protocol` (a
:class:`BRDFModel` is a :class:`~sparse_brdf.compared.protocol.ComparedModel`, a
:class:`Compact` a :class:`~sparse_brdf.compared.protocol.CompressedBRDF`), with what the
built-in models share. The models:
:class:`~sparse_brdf.compared.sparse_model.SparseModel` (the paper's), the baselines of
:mod:`sparse_brdf.compared.baselines` and Neural-BRDF
(:class:`~sparse_brdf.compared.neural.NBRDFModel`); a bench builds them from their specs
(:mod:`sparse_brdf.compared.specs`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..brdf import BRDF
from ..errors import UsageError


@dataclass(repr=False)
class Compact:
    """A compressed model of one BRDF.

    Attributes
    ----------
    model : str
        The model's name (``"naive"``, ``"cpd-1"``, ``"tucker-1x1x1"``, ``"pca-40"``,
        ``"tabulated"``, ``"sparse-262"``, ``"nbrdf"``, ...); the part before the first
        ``-`` is its kind.
    nbytes : int
        Storage of the numbers kept per material (float32): the bytes of the arrays in
        ``params`` whose keys do not start with ``shared_``.
    reconstruct : callable
        Returns the dense linear RGB tensor, shape (n1, n2, n3, 3).
    info : dict or None
        Extra results (e.g. the sparse model itself under ``"model"``).
    params : dict of str to ndarray, or None
        Exactly the numbers the model stores per material, as float32 arrays (see each
        model's ``compress``); shared state the model needs to evaluate (e.g. a PCA basis)
        is referenced under keys prefixed ``shared_`` and not counted in ``nbytes``. What
        :mod:`mitsuba_plugin.evaluators` evaluates from. None for the sparse model (its
        :class:`~sparse_brdf.coding.coefficients.SparseBRDF` is ``info["model"]``).
    """

    model: str
    nbytes: int
    reconstruct: Callable[[], np.ndarray]
    info: dict | None = None
    params: dict[str, np.ndarray] | None = None

    @property
    def kind(self) -> str:
        """The model family: ``naive``, ``cpd``, ``tucker``, ``pca``, ``tabulated``,
        ``sparse``, ``nbrdf`` (the name up to its first ``-``)."""
        return self.model.split("-", 1)[0]

    def param_nbytes(self) -> int:
        """Bytes of the per-material arrays in ``params`` (keys not prefixed ``shared_``)."""
        if self.params is None:
            raise ValueError(f"{self.model}: this compact model has no params")
        return sum(int(v.nbytes) for k, v in self.params.items()
                   if not k.startswith("shared_"))

    def __repr__(self) -> str:
        own = ("" if self.params is None else
               f", params={sorted(k for k in self.params if not k.startswith('shared_'))}")
        return f"Compact({self.model!r}, nbytes={self.nbytes}{own})"


class BRDFModel(ABC):
    """A BRDF model: ``fit(brdfs)`` learns (returns self), ``compress(brdf)`` gives a
    :class:`Compact` (see the module doc)."""

    name: str = "model"
    #: True when ``fit`` learns from training BRDFs (a bench then fits it on materials
    #: it does not score); False when ``fit`` does nothing.
    learns: bool = False

    def fit(self, brdfs: Sequence[BRDF]) -> BRDFModel:  # noqa: B027 - optional hook
        """Learn shared state from training BRDFs (nothing for per-material models).

        Parameters
        ----------
        brdfs : sequence of BRDF
            Training materials, all on one grid.

        Returns
        -------
        BRDFModel
            ``self``.
        """
        return self

    @abstractmethod
    def compress(self, brdf: BRDF) -> Compact:
        """Compress ``brdf``.

        Parameters
        ----------
        brdf : BRDF
            The material, on any grid the model supports.

        Returns
        -------
        Compact
            Its compressed model.
        """

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


def require_fitted(model: BRDFModel, fitted: bool) -> None:
    """:class:`~sparse_brdf.errors.UsageError` unless ``fitted`` (a model that learns
    from training BRDFs, used before ``fit``)."""
    if not fitted:
        raise UsageError(f"{model.name}: call fit() with training BRDFs before compress()")
