"""The command line's file layer: one material, or a samples file, to a ``.sbrdf`` file;
a plan of directions to measure to a CSV file.

``sparse-brdf encode SOURCE -o OUT.sbrdf`` (:func:`encode_file`) loads one material,
encodes it (at a coefficient count, or to a byte budget) and writes its file atomically;
it checks its inputs first (the output: a ``.sbrdf`` name, neither a folder nor one of
the inputs, writable; the request as an :class:`~sparse_brdf.coding.spec.EncodeSpec`:
the ensemble resolved once, the counts and options checked once). A folder or glob goes
to the batch encoder, :func:`sparse_brdf.batch.encode_batch`.

``sparse-brdf encode-samples`` (:func:`encode_samples_file`) and ``sparse-brdf
plan-samples`` (:func:`plan_samples_file`) read and write samples files.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..acquisition.files import read_samples, write_samples
from ..acquisition.measurements import Samples
from ..acquisition.planning import plan
from ..acquisition.recovery import encode_samples
from ..coding.coefficients import SparseBRDF
from ..coding.encode import encode_with
from ..coding.ensemble import Ensemble
from ..coding.fileformat import SBRDF_FILE, save_sbrdf
from ..coding.spec import DEFAULT_N_COEFFS, EncodeSpec
from ..errors import UsageError
from ..fileio import check_new_output, check_output
from ..params import Interval, check
from ..sources.load import load_brdf


def encode_file(source: str | os.PathLike, output: str | os.PathLike,
                ensemble: Ensemble | str | os.PathLike | None = None,
                n_coeffs: int | None = None, n_bytes: int | None = None,
                symmetrize: bool | None = None, **options) -> tuple[Path, SparseBRDF]:
    """Encode one material ``source`` (any BRDF source, ``sources.load``) into the
    ``.sbrdf`` file ``output`` (written atomically).

    Parameters
    ----------
    source : path or ``mitsuba:<name>``
        The material.
    output : path
        The ``.sbrdf`` file; refused if it is not named ``.sbrdf``, is a folder, is one of
        the inputs or cannot be written.
    ensemble : Ensemble, path or id, optional
        Resolved once (:meth:`~sparse_brdf.coding.spec.EncodeSpec.build`; default: the
        shipped one).
    n_coeffs : int, optional
        Coefficients per channel, at most (capped at the ensemble's grid).
    n_bytes : int, optional
        A byte budget for the whole file (``coding.budget.encode_to_bytes``) instead of
        ``n_coeffs``; without either, the default size (``coding.spec.DEFAULT_N_BYTES``).
    symmetrize : bool, optional
        As :func:`~sparse_brdf.sources.load.load_brdf` (None: a network is symmetrised).
    **options
        The other keyword arguments of :func:`~sparse_brdf.coding.encode.encode`
        (``max_error``, ``transform``, ``selector``, ...).

    Returns
    -------
    (Path, SparseBRDF)
        The file written and the model it holds (with the encoder's ``stats``).
    """
    out = check_new_output(output, *SBRDF_FILE, [source, None if isinstance(
        ensemble, Ensemble) else ensemble])
    spec = EncodeSpec.build(ensemble, n_coeffs, n_bytes, **options)
    brdf = load_brdf(source, symmetrize=symmetrize)
    model = encode_with(brdf, spec)
    return save_sbrdf(out, model), model


#: Direction pairs a plan may hold (a CSV of 2^22 rows is about 0.7 GB).
PLAN_PAIRS = Interval(int, 1, 1 << 22)


def samples_constant(samples: Samples) -> bool:
    """Whether every sample has the same RGB value (all zeros, a plan not filled in, or a
    value copied into every row; also a perfectly Lambertian material)."""
    return bool(np.all(samples.rgb == samples.rgb[:1]))


def encode_samples_file(source: str | os.PathLike | Samples, output: str | os.PathLike,
                        ensemble: Ensemble | str | os.PathLike | None = None,
                        n_coeffs: int = DEFAULT_N_COEFFS, n_bytes: int | None = None,
                        seed: int = 0, prior: str = "default") -> tuple[Path, SparseBRDF]:
    """Encode a samples file (``acquisition.files.read_samples``: CSV or ``.npz``) into the
    ``.sbrdf`` file ``output`` (written atomically), by
    :func:`~sparse_brdf.acquisition.defaults.encode_samples`.

    Parameters
    ----------
    source : path or Samples
        The samples file, or samples it was read into (``read_samples``).
    output : path
        The ``.sbrdf`` file; refused if it is not named ``.sbrdf``, is a folder, is one of
        the inputs or cannot be written.
    ensemble : Ensemble, path or id, optional
        Resolved once, by ``encode_samples`` (default: the shipped one).
    n_coeffs : int
        Coefficients per channel, at most (a joint budget of 3 ``n_coeffs``).
    n_bytes : int, optional
        A byte budget for the whole file instead.
    seed : int
        Seed of the cross-validation folds.
    prior : str
        ``"default"`` (the training split's atom prior) or ``"none"`` (every atom of
        every dictionary, no prior).

    Returns
    -------
    (Path, SparseBRDF)
        The file written and the model it holds (with its ``stats``).
    """
    given = isinstance(source, Samples)
    out = check_new_output(output, *SBRDF_FILE, [source.source if given else source,
                                                 None if isinstance(ensemble, Ensemble)
                                                 else ensemble])
    samples = source if given else read_samples(source)
    check_measured(samples)
    # encode_samples resolves the ensemble, checks the counts and resolves the prior, once
    model = encode_samples(samples, ensemble, n_coeffs, n_bytes, seed=seed, prior=prior)
    return save_sbrdf(out, model), model


def check_measured(samples: Samples) -> None:
    """:class:`~sparse_brdf.errors.UsageError` when every sample value is 0 (a plan whose
    values were not filled in): nothing to encode."""
    if not np.any(samples.rgb):
        raise UsageError(f"{samples.source or samples.name}: every sample value is 0: nothing "
                         "to encode (fill in the measured r,g,b of the plan)")


def plan_samples_file(output: str | os.PathLike, n: int, placement: str = "stratified",
                      seed: int = 0) -> Path:
    """Write the direction pairs to measure (``acquisition.planning.plan``) as a CSV samples file
    whose values are 0, to be replaced by the measurements.

    Parameters
    ----------
    output : path
        The CSV file (written atomically).
    n : int
        Direction pairs.
    placement : str
        ``"uniform"``, ``"stratified"`` or ``"bins"``.
    seed : int
        The same seed gives the same pairs.

    Returns
    -------
    Path
        The file written.
    """
    out = check_output(output, [])
    n = check("n", n, PLAN_PAIRS)
    wi, wo = plan(n, placement, seed)
    return write_samples(out, Samples(wi, wo, np.zeros((n if placement != "bins" else
                                                          wi.shape[0], 3)), name=out.stem))
