"""What an encoding is asked for: the encoder's parameters, their declarations and
defaults, and :class:`EncodeSpec`, the request resolved and checked once.

Each public way to encode (:func:`~sparse_brdf.encode`, :func:`~sparse_brdf.encode_to_bytes`,
:func:`~sparse_brdf.encode_samples`, the file and batch encoders) builds one
:class:`EncodeSpec` where it starts (:meth:`EncodeSpec.build`: the ensemble resolved, the
counts, the byte budget, the transforms and the options checked, every default filled
in) and passes it down; the functions below trust it, as scikit-learn's estimators
validate their parameters once, at ``fit``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import UsageError
from ..params import Interval, check, check_choice
from ..paths import DEFAULT_ENSEMBLE_ID, PAPER_ENSEMBLE_ID
from ..transforms import (
    COLOUR_BASES,
    LOBE_TRANSFORMS,
    PAPER_TRANSFORMS,
    TRANSFORMS,
    check_basis,
    check_transform,
)
from .ensemble import Ensemble, resolve_ensemble
from .fileformat import VERSION, check_version

#: The paper's coefficient count per channel: the size of an encoding asked for by count
#: without one (``n_coeffs``), and of the paper's model (``--paper``).
DEFAULT_N_COEFFS = 262
#: The default size of an encoding: a ``.sbrdf`` file (version 2) of at most this many
#: bytes, when neither a count nor a byte budget is given (``docs/results.md``, section 0).
DEFAULT_N_BYTES = 1700

#: How ``encode(transform="auto")`` picks the transform (``docs/method.md``, "Encoding").
SELECTORS: tuple[str, ...] = ("gamma-mse", "render", "render-albedo")
#: Which bins ``encode`` fills from the model instead of fitting them as zeros.
FILLS: tuple[str, str] = ("missing", "invalid")
#: Fill rounds when ``fill_iters`` is not given: full re-searches for "missing",
#: least-squares fits on the chosen dictionaries for "invalid"
#: (:func:`~sparse_brdf.coding.fill.fill_invalid`).
DEFAULT_FILL_ITERS = {"missing": 3, "invalid": 3}
#: How the coefficients are budgeted: ``n_coeffs`` per channel, or 3 ``n_coeffs`` over
#: the three channels.
BUDGETS: tuple[str, str] = ("channel", "joint")
#: The keyword options of :func:`~sparse_brdf.encode` beyond the paper's, with their
#: defaults: the render- and albedo-proxy selector, free invalid bins and the opponent
#: basis (docs/results.md, "Accuracy at equal coefficients", measures each; section 0 the
#: selector).
ENCODE_OPTIONS = {"selector": "render-albedo", "fill": "invalid", "fill_iters": None,
                  "basis": "opponent", "budget": None}
#: The paper's encoder as options of :func:`~sparse_brdf.encode` (``sparse:N:paper`` in a
#: bench).
PAPER_OPTIONS = {"selector": "gamma-mse", "fill": "missing", "basis": "rgb"}
#: Every parameter of :func:`~sparse_brdf.encode` a user sets, declared once
#: (:mod:`sparse_brdf.params`): the CLI's choices and bounds, a bench spec's options and
#: the checks below read it. ``n_coeffs`` beyond a grid's entries per channel is capped
#: to them.
PARAMETERS = {
    "n_coeffs": Interval(int, 1),
    "max_error": Interval(float, 0.0, 1.0, closed="left"),
    "transform": ("auto", "lobe", *TRANSFORMS),
    "selector": SELECTORS,
    "fill": FILLS,
    "fill_iters": Interval(int, 0, 1000),
    "basis": COLOUR_BASES,
    "budget": BUDGETS,
}
#: The byte budget of a file: at least 1 here; a file also needs room for its header,
#: name and checksum (:func:`~sparse_brdf.coding.budget.check_budget`, per material).
N_BYTES = Interval(int, 1)


@dataclass(frozen=True)
class EncodeSpec:
    """One encoding request, resolved and checked: what every encoder below the public
    functions takes, and trusts.

    Build it with :meth:`build` (which checks); the fields hold resolved values only.

    Attributes
    ----------
    ensemble : Ensemble
        The dictionaries, resolved (a path, an id or None became an :class:`Ensemble`).
    n_coeffs : int
        Coefficients per channel at most, capped at a channel's entries on the
        ensemble's grid; with a joint budget, 3 ``n_coeffs`` over the three channels. With
        ``n_bytes``, the encoder's counts come from the budget instead.
    n_bytes : int or None
        A byte budget for the whole ``.sbrdf`` file of ``version``, or None.
    version : int
        The ``.sbrdf`` version whose bytes a budget counts (``fileformat.VERSIONS``).
    max_error : float or None
        Relative squared residual at which coding stops adding coefficients, or None.
    transform : str
        ``"auto"``, ``"lobe"`` or the one transform asked for.
    transforms : tuple of str
        The transforms tried: :func:`auto_transforms` for ``"auto"`` (the lobe pair over
        the default ensemble), the lobe pair for ``"lobe"``, else ``(transform,)``.
    selector, fill, basis, budget : str
        The encoder's options (``SELECTORS``, ``FILLS``, ``COLOUR_BASES``, ``BUDGETS``),
        ``budget`` resolved from ``basis`` when not given.
    fill_iters : int
        Fill rounds, resolved from ``fill`` when not given (``DEFAULT_FILL_ITERS``).

    Examples
    --------
    >>> spec = EncodeSpec.build(n_coeffs=262, **PAPER_OPTIONS)
    >>> spec.budget, spec.fill_iters
    ('channel', 3)
    """

    ensemble: Ensemble
    n_coeffs: int
    transforms: tuple[str, ...]
    transform: str = "auto"
    max_error: float | None = None
    selector: str = ENCODE_OPTIONS["selector"]
    fill: str = ENCODE_OPTIONS["fill"]
    fill_iters: int = DEFAULT_FILL_ITERS[ENCODE_OPTIONS["fill"]]
    basis: str = ENCODE_OPTIONS["basis"]
    budget: str = "joint"
    n_bytes: int | None = None
    version: int = VERSION

    @classmethod
    def build(cls, ensemble: Ensemble | str | os.PathLike | None = None,
              n_coeffs: int | None = None, n_bytes: int | None = None, *,
              max_error: float | None = None, transform: str = "auto",
              version: int = VERSION, **options) -> EncodeSpec:
        """Resolve and check an encoding request, once.

        Parameters
        ----------
        ensemble : Ensemble, path, id or None
            Resolved by :func:`encoder_ensemble` (None: the shipped default, or for the
            paper's options the ensemble trained for the paper's transforms).
        n_coeffs : int, optional
            At least 1; capped at a channel's entries on the ensemble's grid. Not with
            ``n_bytes``.
        n_bytes : int, optional
            A byte budget (at least 1; whether a material's file fits a coefficient in it
            is checked per material, :func:`~sparse_brdf.coding.budget.check_budget`).
            Without either, ``DEFAULT_N_BYTES`` (then ``n_coeffs`` holds
            ``DEFAULT_N_COEFFS``, the count the byte budget's search starts from).
        max_error : float, optional
            In [0, 1).
        transform : str
            ``"auto"`` (:func:`auto_transforms`), ``"lobe"`` (the lobe pair,
            ``LOBE_TRANSFORMS``) or one of ``TRANSFORMS``.
        version : int
            The ``.sbrdf`` version of a byte budget.
        **options
            The encoder's options (``ENCODE_OPTIONS``: ``selector``, ``fill``,
            ``fill_iters``, ``basis``, ``budget``).

        Returns
        -------
        EncodeSpec

        Raises
        ------
        UsageError
            Naming the parameter, for a value out of its range or choices, or an unknown
            option.
        EnsembleMismatchError, MissingFileError
            For an ensemble that cannot be resolved.
        """
        if n_coeffs is not None and n_bytes is not None:
            raise UsageError("give a coefficient count n_coeffs or a byte budget n_bytes, "
                             "not both")
        if n_coeffs is None and n_bytes is None:
            n_bytes = DEFAULT_N_BYTES
        ens = encoder_ensemble(ensemble, options)
        n = min(check("n_coeffs", DEFAULT_N_COEFFS if n_coeffs is None else n_coeffs,
                      PARAMETERS["n_coeffs"]), int(np.prod(ens.shape)))
        if max_error is not None:
            check("max_error", max_error, PARAMETERS["max_error"])
        o = check_options(**options)
        names = (auto_transforms(ens) if transform == "auto" else LOBE_TRANSFORMS
                 if transform == "lobe" else (check_transform(transform),))
        if n_bytes is not None:
            check("n_bytes", n_bytes, N_BYTES)
            check_version(version)
        return cls(ens, n, tuple(names), transform, max_error, o["selector"], o["fill"],
                   o["fill_iters"], o["basis"], o["budget"], n_bytes, version)

    @property
    def options(self) -> dict:
        """The encoder's options, resolved, as :func:`check_options` gives them."""
        return {"selector": self.selector, "fill": self.fill, "fill_iters": self.fill_iters,
                "basis": self.basis, "budget": self.budget}

    @property
    def joint(self) -> bool:
        """Whether the budget is joint: 3 ``n_coeffs`` over the three channels."""
        return self.budget == "joint"

    def __repr__(self) -> str:
        size = f"n_bytes={self.n_bytes} (v{self.version})" if self.n_bytes else \
            f"n_coeffs={self.n_coeffs}"
        return (f"EncodeSpec(ensemble={self.ensemble.id}, {size}, transforms="
                f"{list(self.transforms)}, max_error={self.max_error}, {self.options})")


def auto_transforms(ens: Ensemble) -> tuple[str, ...]:
    """The transforms ``encode(transform="auto")`` chooses among over ``ens``: the lobe
    pair (``docs/method.md``, "Transforms"), whose log ratios to a material's own lobe
    have the relative precision that ensembles trained for the relative or level pairs
    code; over an ensemble trained for the paper's transforms alone (or one that does not
    say, :attr:`Ensemble.transforms`), those, so that ``--paper`` keeps the paper's
    model."""
    own = ens.transforms
    return own if set(own) <= set(PAPER_TRANSFORMS) else LOBE_TRANSFORMS


def encoder_ensemble(ensemble: Ensemble | str | os.PathLike | None,
                     options: Mapping[str, object]) -> Ensemble:
    """The ensemble an encoding with ``options`` runs on.

    ``ensemble`` resolved (:func:`~sparse_brdf.coding.ensemble.resolve_ensemble`); when
    none is named (None or ""), the shipped default, except for the paper's encoder
    (``options`` holding ``PAPER_OPTIONS``): it encodes over the shipped ensemble trained
    for the paper's transforms (``paths.PAPER_ENSEMBLE_ID``), so that ``--paper`` keeps
    the paper's model. A named ensemble is always the one used."""
    if (not ensemble and DEFAULT_ENSEMBLE_ID != PAPER_ENSEMBLE_ID
            and all(options.get(k) == v for k, v in PAPER_OPTIONS.items())):
        return Ensemble.shipped(PAPER_ENSEMBLE_ID)
    return resolve_ensemble(ensemble)


def check_options(**options) -> dict:
    """The encoder's options (``ENCODE_OPTIONS``), checked, with every default
    resolved: ``budget`` from ``basis``, ``fill_iters`` from ``fill``. Unknown names and
    values raise :class:`~sparse_brdf.errors.UsageError` (a ValueError)."""
    unknown = sorted(set(options) - set(ENCODE_OPTIONS))
    if unknown:
        raise UsageError(f"unknown encoding option(s) {', '.join(unknown)}: expected "
                         f"{', '.join(ENCODE_OPTIONS)}")
    o = {**ENCODE_OPTIONS, **options}
    check_choice("selector", o["selector"], SELECTORS)
    check_choice("fill", o["fill"], FILLS)
    check_basis(o["basis"])
    o["budget"] = check_choice(
        "budget", o["budget"] or ("channel" if o["basis"] == "rgb" else "joint"), BUDGETS)
    if o["fill_iters"] is None:
        o["fill_iters"] = DEFAULT_FILL_ITERS[o["fill"]]
    o["fill_iters"] = check("fill_iters", o["fill_iters"], PARAMETERS["fill_iters"])
    return o


__all__ = ["BUDGETS", "DEFAULT_FILL_ITERS", "DEFAULT_N_BYTES", "DEFAULT_N_COEFFS",
           "ENCODE_OPTIONS", "FILLS", "EncodeSpec", "PAPER_OPTIONS", "PARAMETERS", "SELECTORS",
           "auto_transforms", "check_options", "encoder_ensemble"]
