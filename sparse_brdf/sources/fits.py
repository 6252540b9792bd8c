"""Two published analytic fits of the MERL materials, tabulated on the grid.

- ``abc``: the ABC microfacet model of Löw, Kronander, Ynnerman and Unger, "BRDF Models
  for Accurate and Efficient Rendering of Glossy Surfaces" (ACM TOG 31(1), 2012).
- ``sgd``: the shifted gamma distribution model of Bagher, Soler and Holzschuch,
  "Accurate fitting of measured reflectances using a Shifted Gamma micro-facet
  distribution" (CGF 31(4), EGSR 2012).

The per-material parameters are those J. Dupuy's public-domain BRDF toolkit ``dj_brdf``
publishes (contributed by the two papers' authors), read from
``<shared data>/fits/abc_merl.csv`` and ``sgd_merl.csv``; they are never copied into the
package. They were fitted to MERL values with the MERL channel scales (1, 1.15, 1.66) /
1500 already applied, so the models give linear-RGB BRDF values in 1/sr, the units of
every other source (a diffuse albedo kD gives kD / pi): far from the specular peak they
agree with the Neural-BRDF fits of the same materials to about 10 % (tests/test_fits.py).

With ``i``, ``o`` the two directions, ``h`` their half vector, ``cos_d = i . h`` and every
parameter per colour channel unless said otherwise:

- ABC: ``f = kD / pi + F(cos_d) D(h) G / (pi cos_i cos_o)``, with
  ``D = A / (1 + B (1 - cos_h))^C`` (B and C shared by the channels), Cook and Torrance's
  shadowing ``G = min(1, 2 cos_h cos_i / cos_d, 2 cos_h cos_o / cos_d)``, and the exact
  unpolarised dielectric Fresnel factor of one index of refraction ``ior`` (all channels).
- SGD: ``f = (rhoD + rhoS F(cos_d) D(h) G1(i) G1(o) / (cos_i cos_o)) / pi``, with
  ``F = f0 - f1 cos_d + (1 - cos_d)^5 (1 - f0)``,
  ``D = kap exp(-x) / (pi x^p cos_h^4)`` where ``x = alpha + tan^2(theta_h) / alpha``,
  and ``G1(k) = clip(1 + lambda (1 - exp(c max(0, theta_k - theta0)^k)), 0, 1)``.

Values are taken at the bins' lower-edge angles, as for every other source; bins below
the horizon are invalid. Values are clamped at 0 so that a BRDF stays non-negative (the
SGD's Fresnel polynomial is negative near normal incidence where f1 > f0), though no
fit's value was negative on the MERL grid. Both models divide by
``cos_i cos_o``, so near grazing in the mirror configuration a glossy fit is far larger
than the measurement-derived networks (ABC ``blue-acrylic`` at theta_h = 0, theta_d =
89 degrees: about 1e6 1/sr, its network about 200): that is the published models' own
behaviour, kept as is.
"""

from __future__ import annotations

import csv
import functools
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coords import MERL_SHAPE, angles_to_dirs, geometric_valid, grid_angles
from ..errors import BRDFFileError, MissingDataError, UnknownNameError
from ..params import check_choice
from ..paths import shared_data_dir

#: The analytic fits there are (``abc:<name>``, ``sgd:<name>`` sources, and corpora).
FIT_MODELS: tuple[str, ...] = ("abc", "sgd")
#: Each model's parameter file in ``<shared data>/fits``.
FIT_FILES: dict[str, str] = {"abc": "abc_merl.csv", "sgd": "sgd_merl.csv"}
#: Each model's parameters; a CSV column ``P`` is shared by the channels, columns
#: ``P_r``, ``P_g``, ``P_b`` give one value per channel.
FIT_PARAMETERS: dict[str, tuple[str, ...]] = {
    "abc": ("kD", "A", "B", "C", "ior"),
    "sgd": ("rhoD", "rhoS", "alpha", "p", "f0", "f1", "kap", "lambda", "c", "k", "theta0"),
}
_CHANNELS = ("r", "g", "b")
#: Version of the tabulation below, part of its cache key: raise it when a formula changes.
FITS_VERSION = 1


def fits_file(model: str) -> Path:
    """The parameter file of one model.

    Parameters
    ----------
    model : str
        ``"abc"`` or ``"sgd"`` (:data:`FIT_MODELS`).

    Returns
    -------
    Path
        ``<shared data>/fits/<model>_merl.csv``.

    Raises
    ------
    MissingDataError
        If the shared data folder or the file is not on this machine.
    UsageError
        For a model not in :data:`FIT_MODELS`.
    """
    check_choice("fit model", model, FIT_MODELS)
    data = shared_data_dir()
    path = data / "fits" / FIT_FILES[model] if data else None
    if path is None or not path.is_file():
        raise MissingDataError(f"../shared/data/fits/{FIT_FILES[model]} (or under "
                               f"SPARSE_BRDF_DATA) is not on this machine: the {model} fits "
                               "need it")
    return path


def fit_parameters(model: str) -> dict[str, dict[str, np.ndarray]]:
    """Every material's parameters of one model, read from :func:`fits_file`.

    Parameters
    ----------
    model : str
        ``"abc"`` or ``"sgd"``.

    Returns
    -------
    dict
        Material name -> parameter name (:data:`FIT_PARAMETERS`) -> float64 array of
        shape (3,), one value per RGB channel (a shared parameter repeated). Read once
        per file version and shared: do not modify the arrays.

    Raises
    ------
    MissingDataError
        If the file is absent.
    BRDFFileError
        If it lacks a parameter's column or holds a value that is not a finite number.
    """
    path = fits_file(model)
    stat = path.stat()
    return _read_parameters(str(path), model, stat.st_mtime_ns, stat.st_size)


def fit_names(model: str) -> list[str]:
    """The materials one model has parameters for, in name order (see
    :func:`fit_parameters`; same errors)."""
    return sorted(fit_parameters(model))


def material_parameters(model: str, name: str) -> dict[str, np.ndarray]:
    """One material's parameters of one model.

    Parameters
    ----------
    model : str
        ``"abc"`` or ``"sgd"``.
    name : str
        A MERL material's name, e.g. ``"blue-acrylic"``.

    Returns
    -------
    dict
        Parameter name -> read-only float64 array of shape (3,) (:func:`fit_parameters`).

    Raises
    ------
    MissingDataError
        If the model's parameter file is absent.
    UnknownNameError
        If the file has no material ``name``; the message says how to list the names.
    """
    params = fit_parameters(model)
    if name not in params:
        raise UnknownNameError(f"{model}:{name}: no {model} fit of that name in "
                               f"{fits_file(model)} (see `sparse-brdf corpus list {model}`)")
    return params[name]


@functools.lru_cache(maxsize=4)
def _read_parameters(path: str, model: str, _mtime: int, _size: int) -> dict:
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise BRDFFileError(f"{path}: unreadable parameter file: {exc}") from exc
    columns = set(rows[0]) if rows else set()
    out: dict[str, dict[str, np.ndarray]] = {}
    for row in rows:
        name = (row.get("name") or "").strip()
        params = {}
        for p in FIT_PARAMETERS[model]:
            keys = [p] * 3 if p in columns else [f"{p}_{c}" for c in _CHANNELS]
            missing = [k for k in keys if k not in columns]
            if not name or missing:
                raise BRDFFileError(f"{path}: no column {missing[0] if missing else 'name'} "
                                    f"(the {model} model needs {p} or {p}_r, {p}_g, {p}_b)")
            try:
                params[p] = np.array([float(row[k]) for k in keys])
            except (TypeError, ValueError) as exc:
                raise BRDFFileError(f"{path}: {name}: {p} is not a number") from exc
            if not np.all(np.isfinite(params[p])):
                raise BRDFFileError(f"{path}: {name}: {p} is not finite")
            params[p].flags.writeable = False
        out[name] = params
    if not out:
        raise BRDFFileError(f"{path}: no materials in this parameter file")
    return out


def _geometry(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, ...]:
    """cos_h, cos_d, cos_i, cos_o of direction pairs (n, 3), each (n, 1) for broadcasting
    against per-channel parameters of shape (3,)."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    cos_d = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
    return tuple(x[:, None] for x in (h[:, 2], cos_d, wi[:, 2], wo[:, 2]))


def fresnel_dielectric(cos_d: np.ndarray, ior: np.ndarray) -> np.ndarray:
    """The exact Fresnel reflectance of unpolarised light on a dielectric.

    Parameters
    ----------
    cos_d : numpy.ndarray
        Cosine of the angle between the incident direction and the (micro)normal, in
        [0, 1].
    ior : numpy.ndarray
        Relative index of refraction (>= 1), broadcast against ``cos_d``.

    Returns
    -------
    numpy.ndarray
        ``(g - c)^2 / (2 (g + c)^2) (1 + (c (g + c) - 1)^2 / (c (g - c) + 1)^2)`` with
        ``c = cos_d`` and ``g = sqrt(ior^2 + c^2 - 1)``: 1 at grazing incidence,
        ``((ior - 1) / (ior + 1))^2`` at normal incidence.
    """
    c = np.asarray(cos_d, dtype=np.float64)
    g = np.sqrt(np.maximum(np.square(ior) + c * c - 1.0, 0.0))
    a = np.square((g - c) / (g + c))
    b = np.square((c * (g + c) - 1.0) / (c * (g - c) + 1.0))
    return 0.5 * a * (1.0 + b)


def eval_abc(params: dict[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The ABC model (Löw et al. 2012) at direction pairs above the horizon.

    Parameters
    ----------
    params : dict
        ``kD``, ``A``, ``B``, ``C``, ``ior``: arrays of shape (3,) (:func:`fit_parameters`).
    wi, wo : numpy.ndarray
        Unit directions of shape (n, 3) in the local frame (z the normal), z > 0.

    Returns
    -------
    numpy.ndarray
        Linear RGB BRDF values (1/sr), float64 of shape (n, 3) (formula in the module's
        docstring).
    """
    cos_h, cos_d, cos_i, cos_o = _geometry(wi, wo)
    d = params["A"] / np.power(1.0 + params["B"] * (1.0 - cos_h), params["C"])
    g = np.minimum(1.0, 2.0 * cos_h * np.minimum(cos_i, cos_o) / cos_d)
    f = fresnel_dielectric(cos_d, params["ior"])
    return params["kD"] / np.pi + f * d * g / (np.pi * cos_i * cos_o)


def eval_sgd(params: dict[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The shifted gamma distribution model (Bagher et al. 2012) at direction pairs.

    Parameters
    ----------
    params : dict
        ``rhoD``, ``rhoS``, ``alpha``, ``p``, ``f0``, ``f1``, ``kap``, ``lambda``, ``c``,
        ``k``, ``theta0``: arrays of shape (3,) (:func:`fit_parameters`).
    wi, wo : numpy.ndarray
        Unit directions of shape (n, 3) in the local frame (z the normal), z > 0.

    Returns
    -------
    numpy.ndarray
        Linear RGB BRDF values (1/sr), float64 of shape (n, 3), before clamping at 0
        (formula in the module's docstring).
    """
    cos_h, cos_d, cos_i, cos_o = _geometry(wi, wo)
    fresnel = params["f0"] - cos_d * params["f1"] + (1.0 - cos_d) ** 5 * (1.0 - params["f0"])
    c2 = cos_h * cos_h
    x = params["alpha"] + (1.0 - c2) / c2 / params["alpha"]
    ndf = params["kap"] * np.exp(-x) / (np.pi * np.power(x, params["p"]) * c2 * c2)
    g = _sgd_g1(params, cos_i) * _sgd_g1(params, cos_o)
    return (params["rhoD"] + params["rhoS"] * fresnel * ndf * g / (cos_i * cos_o)) / np.pi


def _sgd_g1(params: dict[str, np.ndarray], cos_k: np.ndarray) -> np.ndarray:
    """The SGD's one-direction shadowing term, shape (n, 3)."""
    t = np.maximum(np.arccos(np.clip(cos_k, -1.0, 1.0)) - params["theta0"], 0.0)
    with np.errstate(over="ignore"):  # e.g. c = 1e38 in some fits: G1 saturates at 0
        e = np.minimum(params["c"] * np.power(t, params["k"]), 700.0)
        return np.clip(1.0 + params["lambda"] * (1.0 - np.exp(e)), 0.0, 1.0)


_EVAL = {"abc": eval_abc, "sgd": eval_sgd}


def tabulate_fit(model: str, name: str, shape: tuple[int, int, int] = MERL_SHAPE) -> BRDF:
    """Tabulate one material's analytic fit on a grid.

    Parameters
    ----------
    model : str
        ``"abc"`` or ``"sgd"`` (:data:`FIT_MODELS`).
    name : str
        A MERL material's name (:func:`fit_names`), e.g. ``"blue-acrylic"``.
    shape : tuple of 3 int
        The (theta_h, theta_d, phi_d) grid; default MERL's (90, 90, 180).

    Returns
    -------
    BRDF
        Linear-RGB values in 1/sr at the bins' lower-edge angles, float32 of shape
        (n_h, n_d, n_p, 3); bins below the horizon invalid. Its source is
        ``"<model>:<name>"``.

    Raises
    ------
    MissingDataError
        If the model's parameter file is absent.
    UnknownNameError
        If the file has no material ``name``.
    """
    params = material_parameters(model, name)
    valid = geometric_valid(shape)
    th, td, pd = grid_angles(shape)
    wi, wo = angles_to_dirs(th[valid], td[valid], pd[valid])
    values = np.zeros((*shape, 3), np.float32)
    values[valid] = np.maximum(_EVAL[model](params, wi, wo), 0.0)
    return BRDF(values=values, valid=valid, name=name, source=f"{model}:{name}")
