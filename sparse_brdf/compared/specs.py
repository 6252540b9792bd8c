"""The model-spec grammar of a bench: one string per compared model.

A spec is ``KIND`` or ``KIND:ARGS``; each kind of :data:`KINDS` states its own grammar:

- ``sparse:N[:TRANSFORM][:OPTIONS]`` the paper's model
  (:class:`~sparse_brdf.compared.sparse_model.SparseModel`). N: coefficients per channel,
  or ``bN``: at most N bytes per ``.sbrdf`` file, header included (default: the default
  size, ``b1700``; 262 for the paper's encoder). TRANSFORM:
  auto (the default), lobe (the floor pair, the selector's choice) or one of
  :data:`~sparse_brdf.transforms.TRANSFORMS` (e.g.
  ``log-plus``, ``log-lobe-floor``), and may be left out before the options.
  OPTIONS: ``paper`` (the paper's encoder, ``PAPER_OPTIONS``) and/or ``KEY=VALUE`` pairs
  separated by commas, the keyword options of :func:`~sparse_brdf.coding.encode.encode`
  (``selector``, ``fill``, ``fill_iters``, ``basis``, ``budget``) and ``version`` (the
  ``.sbrdf`` version counted and rendered, 1 or 2). E.g. ``sparse:262``,
  ``sparse:262:paper``, ``sparse:262:log-plus``, ``sparse:262:auto:fill=missing``,
  ``sparse:b1600:basis=rgb,version=1``.
- ``nbrdf[:OPTIONS]`` Neural-BRDF (Sztrajman et al. 2021), a network trained per
  material (:class:`~sparse_brdf.compared.neural.NBRDFModel`); OPTIONS: ``KEY=VALUE`` pairs
  separated by commas, the options of :func:`~sparse_brdf.compared.neural.train_nbrdf`
  (``epochs``, ``batch_size``, ``learning_rate``, ``n_samples``, ``seed``,
  ``time_budget`` in seconds). E.g. ``nbrdf``, ``nbrdf:epochs=20,seed=1``.
- ``naive`` Bagher et al.'s separable model; ``cpd:L`` rank-L CPD (default 1);
  ``tucker:AxBxC`` Tucker ranks (default 1x1x1); ``pca:N`` N principal components
  (default 40); ``tabulated`` the full table.
- ``module:Class[:KEY=VALUE,...]`` a model from outside the package: ``Class`` of the
  Python module ``module`` (dotted), built with the options as keyword arguments (each
  value an integer, a float, ``true``/``false`` or else a string), which must follow the
  compared-model protocol (:mod:`sparse_brdf.compared.protocol`); imported by
  :func:`make_model` (:mod:`sparse_brdf.compared._outside`), not by :func:`parse_spec`. E.g.
  ``mymodels:QuantisedTable:bits=8``. A built-in kind's name is never read as a module.

:func:`parse_spec` reads a spec into a :class:`ModelSpec` (every value checked against
the models' declared parameters, no ensemble read, nothing trained); :func:`make_model`
builds the model. Both raise :class:`~sparse_brdf.errors.UsageError` naming the spec.
A new kind is one entry of :data:`KINDS`: its grammar, a parser of its arguments and a
builder.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

from ..coding.fileformat import VERSION, VERSIONS
from ..coding.spec import DEFAULT_N_BYTES, DEFAULT_N_COEFFS, PAPER_OPTIONS
from ..errors import UsageError
from ..params import check_choice
from ._outside import load_outside_model, parse_value
from .baselines import CPDModel, NaiveModel, PCAModel, TabulatedModel, TuckerModel
from .compact import BRDFModel
from .neural import PARAMETERS as NBRDF_PARAMETERS
from .neural import NBRDFModel, nbrdf_name
from .sparse_model import SparseModel, sparse_name

__all__ = ["KINDS", "OUTSIDE", "ModelSpec", "make_model", "parse_spec"]


@dataclass(frozen=True)
class ModelSpec:
    """A parsed spec: the model's ``kind``, its constructor's keyword arguments
    (``kwargs``), the model's ``name`` (the reports' label) and the ``text`` it was read
    from."""

    kind: str
    kwargs: dict = field(compare=False)
    name: str
    text: str


@dataclass(frozen=True)
class Kind:
    """One model kind of the grammar: ``grammar`` (as the error messages show it);
    ``parse(arg)`` -> the constructor's keyword arguments from what follows ``KIND:``
    (``""`` when nothing does), raising :class:`UsageError` on a bad argument; ``build(
    kwargs, ensemble)`` -> the model; ``name(kwargs)`` -> its name without building it."""

    grammar: str
    parse: Callable[[str], dict]
    build: Callable[[dict, object], BRDFModel]
    name: Callable[[dict], str]


def _no_argument(kind: str) -> Callable[[str], dict]:
    def parse(arg: str) -> dict:
        if arg:
            raise UsageError(f"{kind} takes no argument, got {arg!r}")
        return {}
    return parse


def _integer(text: str, what: str) -> int:
    if not (text.isascii() and text.isdigit()):
        raise UsageError(f"{what} must be an integer >= 1, got {text!r}")
    return int(text)


def _parse_cpd(arg: str) -> dict:
    return {"rank": _integer(arg or "1", "cpd rank")}


def _parse_tucker(arg: str) -> dict:
    ranks = (arg or "1x1x1").split("x")
    if len(ranks) != 3:
        raise UsageError(f"tucker ranks are AxBxC, got {arg!r}")
    return {"ranks": tuple(_integer(r, "tucker rank") for r in ranks)}


def _parse_pca(arg: str) -> dict:
    return {"n_coeffs": _integer(arg or "40", "pca components")}


def _parse_sparse(arg: str) -> dict:
    """``N[:TRANSFORM][:OPTIONS]`` -> SparseModel's keyword arguments (see module doc)."""
    n, *rest = arg.split(":") if arg else [""]
    transform, options = "auto", {}
    for part in rest:
        if part == "paper" and not options:  # the paper's encoder
            options = dict(PAPER_OPTIONS)
            continue
        if "=" not in part and not options and transform == "auto":
            transform = part or "auto"
            continue
        for item in filter(None, part.split(",")):
            key, eq, value = (x.strip() for x in item.partition("="))
            if not eq or key in options:
                raise UsageError(f"expected distinct KEY=VALUE options, got {item!r}")
            if key == "fill_iters":
                if not (value.isascii() and value.isdigit()):
                    raise UsageError(f"fill_iters must be an integer >= 0, got {value!r}")
                value = int(value)
            options[key] = value
    n_bytes = None
    if n.startswith("b"):
        if not (n[1:].isascii() and n[1:].isdigit()) or int(n[1:]) < 1:
            raise UsageError(f"a byte budget is bN with N >= 1 bytes per file, got {n!r}")
        n_bytes, n = int(n[1:]), ""
    version = options.pop("version", str(VERSION))
    if version not in tuple(map(str, VERSIONS)):
        raise UsageError(f"version must be one of {', '.join(map(str, VERSIONS))}, "
                         f"got {version!r}")
    if not n and n_bytes is None and options != PAPER_OPTIONS:  # the default size
        n_bytes = DEFAULT_N_BYTES
    return {"n_coeffs": _integer(n, "N") if n else DEFAULT_N_COEFFS, "transform": transform,
            "n_bytes": n_bytes, "version": int(version), **options}


def _parse_nbrdf(arg: str) -> dict:
    """``KEY=VALUE[,KEY=VALUE...]`` -> NBRDFModel's keyword arguments, each value read and
    checked by its declaration (``neural.PARAMETERS``)."""
    out: dict = {}
    for item in filter(None, arg.split(",")):
        key, eq, value = (x.strip() for x in item.partition("="))
        if not eq or key in out:
            raise UsageError(f"expected distinct KEY=VALUE options, got {item!r}")
        check_choice("nbrdf option", key, tuple(NBRDF_PARAMETERS))
        out[key] = NBRDF_PARAMETERS[key].parse(value, f"nbrdf {key}")
    return out


def _sparse_name(kw: dict) -> str:
    kw = dict(kw)
    fixed = [kw.pop(k) for k in ("n_coeffs", "transform", "n_bytes", "version")]
    return sparse_name(*fixed, options=kw)[0]


#: Every model kind of the grammar, in the order the messages list them.
KINDS: dict[str, Kind] = {
    "sparse": Kind("sparse:N[:TRANSFORM][:OPTIONS]", _parse_sparse,
                   lambda kw, ens: SparseModel(ens, **kw), _sparse_name),
    "nbrdf": Kind("nbrdf[:OPTIONS]", _parse_nbrdf, lambda kw, ens: NBRDFModel(**kw),
                  nbrdf_name),
    "naive": Kind("naive", _no_argument("naive"), lambda kw, ens: NaiveModel(**kw),
                  lambda kw: NaiveModel(**kw).name),
    "cpd": Kind("cpd:L", _parse_cpd, lambda kw, ens: CPDModel(**kw),
                lambda kw: CPDModel(**kw).name),
    "tucker": Kind("tucker:AxBxC", _parse_tucker, lambda kw, ens: TuckerModel(**kw),
                   lambda kw: TuckerModel(**kw).name),
    "pca": Kind("pca:N", _parse_pca, lambda kw, ens: PCAModel(**kw),
                lambda kw: PCAModel(**kw).name),
    "tabulated": Kind("tabulated", _no_argument("tabulated"),
                      lambda kw, ens: TabulatedModel(), lambda kw: TabulatedModel.name),
}


#: The kind of a model from outside the package, and its grammar.
OUTSIDE = "module:Class[:KEY=VALUE,...]"
_OUTSIDE_SPEC = re.compile(r"([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*):([A-Za-z_]\w*)(?::(.*))?",
                           re.ASCII)


def _parse_outside(spec: str) -> ModelSpec | None:
    """The :class:`ModelSpec` of an outside model's spec (kind ``"outside"``; its name
    until built: ``Class-KEY=VALUE...``), or None when ``spec`` is not of that form."""
    m = _OUTSIDE_SPEC.fullmatch(spec)
    if m is None:
        return None
    module, cls, arg = m.groups()
    options: dict = {}
    for item in filter(None, (arg or "").split(",")):
        key, eq, value = (x.strip() for x in item.partition("="))
        if not eq or not key.isidentifier() or key in options:
            raise UsageError(f"model {spec!r}: expected distinct KEY=VALUE options, got "
                             f"{item!r}")
        options[key] = parse_value(value)
    name = cls + "".join(f"-{k}={v}" for k, v in options.items())
    return ModelSpec("outside", {"module": module, "cls": cls, "options": options}, name, spec)


def parse_spec(spec: str) -> ModelSpec:
    """Read and check a model spec (see the module doc); no ensemble is read.

    Parameters
    ----------
    spec : str
        E.g. ``"sparse:262:paper"``, ``"tucker:2x2x2"``, ``"pca:40"``.

    Returns
    -------
    ModelSpec
        Its kind, the model's keyword arguments and the model's name.

    Raises
    ------
    UsageError
        ``model '<spec>': ...`` for an unknown kind or a bad argument.
    """
    if not isinstance(spec, str):
        raise UsageError(f"model {spec!r}: a model spec is a string")
    kind, _, arg = spec.partition(":")
    if kind not in KINDS:
        outside = _parse_outside(spec)
        if outside is not None:
            return outside
        raise UsageError(f"unknown model {spec!r}: the models are "
                         f"{', '.join(k.grammar for k in KINDS.values())}, or {OUTSIDE}")
    try:
        kwargs = KINDS[kind].parse(arg)
        name = KINDS[kind].name(kwargs)
    except UsageError as exc:
        raise UsageError(f"model {spec!r}: {exc}") from None
    return ModelSpec(kind, kwargs, name, spec)


def make_model(spec: str | ModelSpec, ensemble=None) -> BRDFModel:
    """The model of ``spec`` (a string, see the module doc, or a parsed :class:`ModelSpec`).

    Parameters
    ----------
    spec : str or ModelSpec
        The model's spec.
    ensemble : Ensemble, path or None
        The sparse model's ensemble (None: the shipped default); other kinds ignore it.

    Returns
    -------
    ComparedModel
        Unfitted; a built-in model's ``name`` is ``parse_spec(spec).name``, an outside
        model's is its own.

    Raises
    ------
    UsageError
        A bad spec; for an outside model, also a module or class that cannot be imported
        or built, or an object that does not follow the protocol.
    """
    s = parse_spec(spec) if isinstance(spec, str) else spec
    if s.kind == "outside":
        return load_outside_model(s.kwargs["module"], s.kwargs["cls"], s.kwargs["options"],
                                  s.text)
    return KINDS[s.kind].build(s.kwargs, ensemble)
