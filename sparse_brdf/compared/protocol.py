"""The protocol of a compared model: what the bench asks of any BRDF representation.

A bench compares models it knows only through this protocol, so a model from outside
the package (``sparse-brdf bench`` with a ``module:Class`` spec,
:mod:`sparse_brdf.compared.specs`) is measured exactly like the built-in ones, which follow
it too (:class:`~sparse_brdf.compared.compact.BRDFModel` and every model of
:mod:`~sparse_brdf.compared.specs`). Two parts, both :class:`typing.Protocol` classes:

:class:`ComparedModel`, the model:

- ``name`` (str): its label in results and reports, one per configuration;
- ``learns`` (bool): True when ``fit`` learns from training BRDFs (the bench then fits
  it on training materials it never scores);
- ``fit(brdfs)``: learns shared state from training BRDFs, returns the model (does
  nothing for a per-material model);
- ``compress(brdf)``: fits one material (a :class:`~sparse_brdf.brdf.BRDF`) and returns
  its :class:`CompressedBRDF`.

:class:`CompressedBRDF`, one fitted material:

- ``nbytes`` (int): the bytes stored for this material (what is shared by every
  material, such as a learned basis, is not counted);
- ``reconstruct()``: the decoded table, linear RGB (1/sr), the BRDF's grid shape
  (n1, n2, n3, 3); or, for a model that only evaluates at directions,
  ``evaluate(wi, wo)``: unit direction pairs in the local frame (z the normal), each
  (N, 3) float64, to linear RGB values (N, 3) without the cosine factor. The bench
  tabulates such a model on the reference's grid (:func:`table_of`) to render and score it;
- optionally ``drjit_evaluator()``: an object whose ``eval(wi, wo)`` takes Dr.Jit
  ``mi.Vector3f`` direction pairs (local frame) and returns ``mi.Color3f`` BRDF values,
  in the current Mitsuba variant; the bench times it for the speed axis (evaluations per
  second, :mod:`sparse_brdf.benchmark.speed`). Without it the model has no speed figure.

:func:`check_model` tells whether an object follows the protocol.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from ..brdf import BRDF
from ..coords import angles_to_dirs, grid_angles

__all__ = ["ComparedModel", "CompressedBRDF", "check_compressed", "check_model", "table_of"]


@runtime_checkable
class CompressedBRDF(Protocol):
    """One material as a compared model stores it (see the module doc): ``nbytes``,
    and ``reconstruct()`` or ``evaluate(wi, wo)``; optionally ``drjit_evaluator()``.
    Only ``nbytes`` is declared here (an ``isinstance`` check needs no more); the bench
    checks the rest with :func:`check_compressed`.

    Attributes
    ----------
    nbytes : int
        Bytes stored for this material; state shared by every material is not counted.
    """

    nbytes: int


@runtime_checkable
class ComparedModel(Protocol):
    """A model a bench compares (see the module doc): ``name``, ``learns``,
    ``fit(brdfs)`` and ``compress(brdf)``.

    Attributes
    ----------
    name : str
        The model's label in results and reports, one per configuration.
    learns : bool
        True when ``fit`` learns from training BRDFs.
    """

    name: str
    learns: bool

    def fit(self, brdfs: Sequence[BRDF]) -> ComparedModel:
        """Learn shared state from training BRDFs.

        Parameters
        ----------
        brdfs : sequence of BRDF
            Training materials, none of them scored by the bench.

        Returns
        -------
        ComparedModel
            The model itself.
        """
        ...

    def compress(self, brdf: BRDF) -> CompressedBRDF:
        """Fit one material.

        Parameters
        ----------
        brdf : BRDF
            The material: linear RGB values (1/sr), shape (n1, n2, n3, 3), and its valid
            bins.

        Returns
        -------
        CompressedBRDF
            What the model stores of it.
        """
        ...


def check_model(obj) -> str | None:
    """Why ``obj`` does not follow :class:`ComparedModel`, or None when it does.

    Returns
    -------
    str or None
        E.g. ``"no method compress"``, ``"name is not a string"``.
    """
    for method in ("fit", "compress"):
        if not callable(getattr(obj, method, None)):
            return f"no method {method}(...)"
    if not isinstance(getattr(obj, "name", None), str) or not obj.name:
        return "no name (a non-empty string attribute)"
    if not isinstance(getattr(obj, "learns", None), bool):
        return "no learns attribute (True or False)"
    return None


def check_compressed(obj) -> str | None:
    """Why ``obj`` (what a model's ``compress`` returned) does not follow
    :class:`CompressedBRDF`, or None when it does."""
    nbytes = getattr(obj, "nbytes", None)
    if isinstance(nbytes, bool) or not isinstance(nbytes, (int, np.integer)) or nbytes < 0:
        return f"nbytes must be a byte count (an integer >= 0), got {nbytes!r}"
    if not (callable(getattr(obj, "reconstruct", None))
            or callable(getattr(obj, "evaluate", None))):
        return "neither reconstruct() nor evaluate(wi, wo)"
    return None


def table_of(compressed, brdf: BRDF) -> np.ndarray:
    """The decoded table of a compressed material on ``brdf``'s grid: its
    ``reconstruct()``, or its ``evaluate(wi, wo)`` at every valid bin's direction pair
    (the bins' lower-edge angles, as the grid's samples; 0 elsewhere).

    Parameters
    ----------
    compressed : CompressedBRDF
        What a model's ``compress(brdf)`` returned.
    brdf : BRDF
        The material it was fitted to (its grid and valid bins).

    Returns
    -------
    numpy.ndarray
        Linear RGB values, shape (n1, n2, n3, 3).

    Raises
    ------
    ValueError
        If the table or the evaluated values have the wrong shape.
    """
    if callable(getattr(compressed, "reconstruct", None)):
        table = np.asarray(compressed.reconstruct())
    else:
        th, td, pd = grid_angles(brdf.shape)
        wi, wo = angles_to_dirs(th[brdf.valid], td[brdf.valid], pd[brdf.valid])
        vals = np.asarray(compressed.evaluate(wi, wo))
        if vals.shape != wi.shape:
            raise ValueError(f"evaluate(wi, wo) returned shape {vals.shape} for {len(wi)} "
                             f"direction pairs; expected {wi.shape}")
        table = np.zeros(brdf.values.shape, np.float32)
        table[brdf.valid] = vals
    if table.shape != brdf.values.shape:
        raise ValueError(f"reconstruct() returned shape {table.shape}; expected the "
                         f"BRDF's {brdf.values.shape}")
    return table
