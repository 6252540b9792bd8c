"""The paper's model as a compared model: a BRDF encoded over a dictionary ensemble.

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model": :class:`SparseModel`
compresses a BRDF to its ``.sbrdf`` file (:func:`~sparse_brdf.coding.encode.encode`, or to a
byte budget, :func:`~sparse_brdf.coding.budget.encode_to_bytes`), behind the interface of
:mod:`sparse_brdf.compared.compact`. Its spec in a bench is ``sparse:N[:TRANSFORM][:OPTIONS]``
(:mod:`sparse_brdf.compared.specs`).
"""

from __future__ import annotations

from ..brdf import BRDF
from ..coding.budget import PARAMETERS as BUDGET_PARAMETERS
from ..coding.budget import encode_to_bytes
from ..coding.encode import encode
from ..coding.fileformat import VERSION, as_stored, check_version, to_bytes
from ..coding.spec import (
    DEFAULT_N_COEFFS,
    ENCODE_OPTIONS,
    PAPER_OPTIONS,
    check_options,
    encoder_ensemble,
)
from ..coding.spec import PARAMETERS as ENCODE_PARAMETERS
from ..params import check, check_choice
from .compact import BRDFModel, Compact


def sparse_name(n_coeffs: int = DEFAULT_N_COEFFS, transform: str = "auto",
                n_bytes: int | None = None, version: int = VERSION,
                options: dict | None = None) -> tuple[str, dict]:
    """The name of the :class:`SparseModel` of these arguments, and its encoding options
    not at their defaults; every argument checked (:class:`~sparse_brdf.errors.UsageError`),
    no ensemble read.

    Parameters
    ----------
    n_coeffs, transform, n_bytes, version, options
        As :class:`SparseModel` takes them (``options``: its keyword options).

    Returns
    -------
    name : str
        ``sparse-N`` or ``sparse-bN``, then ``-TRANSFORM`` unless "auto", then
        ``-KEY=VALUE`` per option not at its default (or ``-paper``), then
        ``-version=V`` unless the default.
    options : dict
        The options not at their defaults, in ``ENCODE_OPTIONS`` order.
    """
    check_version(version)
    if n_bytes is not None:
        check("n_bytes", n_bytes, BUDGET_PARAMETERS["n_bytes"])
    check("n_coeffs", n_coeffs, ENCODE_PARAMETERS["n_coeffs"])
    check_choice("transform", transform, ENCODE_PARAMETERS["transform"])
    full = check_options(**(options or {}))
    implied = check_options(basis=full["basis"], fill=full["fill"])
    kept = {k: full[k] for k in ENCODE_OPTIONS
            if full[k] != (implied if k in ("fill_iters", "budget") else ENCODE_OPTIONS)[k]}
    suffix = ("-paper" if kept == PAPER_OPTIONS
              else "".join(f"-{k}={v}" for k, v in kept.items()))
    size = f"b{n_bytes}" if n_bytes is not None else str(n_coeffs)
    return (f"sparse-{size}" + ("" if transform == "auto" else f"-{transform}") + suffix
            + ("" if version == VERSION else f"-version={version}")), kept


class SparseModel(BRDFModel):
    """The sparse ensemble model at ``n_coeffs`` per channel (see :func:`encode`; the
    keyword options ``selector``, ``fill``, ``fill_iters``, ``basis``, ``budget`` are
    passed on). ``name``: ``sparse-N``, then ``-TRANSFORM`` unless "auto", then
    ``-KEY=VALUE`` for each option not at its default, in the order above (so that
    every option set has its own name, e.g. ``sparse-262-fill=missing``), or ``-paper``
    for the paper's encoder (``PAPER_OPTIONS``).

    ``n_bytes``: a byte budget per material instead of ``n_coeffs`` (each file holds at
    most that many bytes, :func:`~sparse_brdf.coding.budget.encode_to_bytes`; the name
    starts ``sparse-bN``). ``version``: the ``.sbrdf`` version whose bytes are counted
    and which is rendered (name suffix ``-version=1`` unless the default, 2). The model
    scored is the file's (values quantised for version 2); ``nbytes`` is the file's size."""

    def __init__(self, ensemble=None, n_coeffs: int = DEFAULT_N_COEFFS,
                 transform: str = "auto", n_bytes: int | None = None,
                 version: int = VERSION, **options):
        self.name, self.options = sparse_name(n_coeffs, transform, n_bytes, version, options)
        self.ensemble = encoder_ensemble(ensemble, check_options(**options))
        self.n_coeffs, self.n_bytes, self.version = n_coeffs, n_bytes, version
        self.transform = transform

    def compress(self, brdf: BRDF) -> Compact:
        """Encode ``brdf`` (:func:`~sparse_brdf.coding.encode.encode`, or
        :func:`~sparse_brdf.coding.budget.encode_to_bytes` with ``n_bytes``); the
        :class:`Compact` is what its ``.sbrdf`` file holds (``info["model"]``), and
        ``nbytes`` that file's size."""
        if self.n_bytes is None:
            m = encode(brdf, self.ensemble, self.n_coeffs, transform=self.transform,
                       **self.options)
        else:
            m = encode_to_bytes(brdf, self.ensemble, self.n_bytes, self.version,
                                transform=self.transform, **self.options)
        m = as_stored(m, self.version)  # what the file holds, and so what renders
        return Compact(self.name, len(to_bytes(m, self.version)),
                       lambda: m.decode(self.ensemble, valid=brdf.valid).values,
                       {"transform": m.transform, "model": m, "version": self.version})

    def __repr__(self) -> str:
        return f"SparseModel({self.name!r}, ensemble={self.ensemble.id[:8]})"
