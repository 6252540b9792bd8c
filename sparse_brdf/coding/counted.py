"""An encoding at a coefficient count: one encoding per candidate transform, and the
transform's choice among them.

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model"; ``docs/method.md``,
"Encoding". :func:`encode_at` runs a resolved request at ``spec.n_coeffs``;
:func:`~sparse_brdf.coding.encode.encode_with` calls it for a count and
:func:`~sparse_brdf.coding.budget.encode_to_bytes_with` for a byte budget, steering the
count while the fill runs.
"""

from __future__ import annotations

import numpy as np

from ..brdf import BRDF
from ..coords import geometric_valid
from ..errors import EnsembleMismatchError
from ..metrics import (
    albedo_proxy_error,
    gamma_mse,
    make_albedo_proxy,
    make_render_proxy,
    mse,
    rae,
    render_proxy_error,
)
from ..parallel import parallel_map
from ..transforms import has_floor, inverse
from .coefficients import SparseBRDF
from .ensemble import Ensemble
from .fill import SizeControl, fill_invalid
from .floor import choose_floor
from .projection import CodingOptions, coded_channels, materials_of, search_many
from .spec import EncodeSpec

#: The ``stats["transforms"][t]`` entry each selector minimises.
SELECTOR_KEYS = {"gamma-mse": "gamma_mse", "render": "render_proxy",
                 "render-albedo": "render_albedo"}
#: The entries of ``stats["transforms"][t]`` that need the whole decoded table, not
#: only its valid bins.
_TABLE_KEYS = ("render_proxy", "albedo_proxy", "render_albedo")
def check_grid_matches(brdf: BRDF, ens: Ensemble) -> None:
    """:class:`EnsembleMismatchError` naming the BRDF's file (or name) unless its grid is
    the ensemble's."""
    if brdf.shape != ens.shape:
        raise EnsembleMismatchError(f"{brdf.source or brdf.name}: BRDF grid {brdf.shape} "
                                    f"does not match the ensemble's {ens.shape}")


def choose_transform(brdf: BRDF, models: dict[str, SparseBRDF], ens: Ensemble,
                     selector: str = "gamma-mse") -> SparseBRDF:
    """The model that ``selector`` prefers (:func:`pick_transform`'s rule; ``selector`` as
    an :class:`~sparse_brdf.coding.spec.EncodeSpec` resolved it); ``stats`` gets every
    model's value of the selector's error, and the chosen model's errors in full
    (gamma-mapped MSE, MSE, RAE, render-proxy and albedo-proxy errors on valid bins). A
    floor transform's model then gets its floor
    (:func:`~sparse_brdf.coding.floor.choose_floor`; the errors are those of its decode
    without one)."""
    key = SELECTOR_KEYS[selector]
    valid = brdf.valid
    ref_full = brdf.channel_first()
    ref = ref_full[:, valid]  # (3, n_valid): mask once, then flat metrics
    kernel = make_render_proxy(brdf.shape)
    albedo_kernel = make_albedo_proxy(brdf.shape)
    full: dict[str, np.ndarray] = {}  # per model: its decode (3, n1, n2, n3)
    flat: dict[str, np.ndarray] = {}  # per model: its decode on the valid bins

    def errors(name: str, keys: tuple[str, ...]) -> dict:  # numpy only (no BLAS)
        if name not in full:
            m = models[name]
            full[name] = inverse(m.transformed(ens), name, m.gain, m.lobe)  # no floor
        if any(k not in _TABLE_KEYS for k in keys) and name not in flat:
            flat[name] = full[name][:, valid]
        metric = {"gamma_mse": lambda: gamma_mse(ref, flat[name]),
                  "mse": lambda: mse(ref, flat[name]), "rae": lambda: rae(ref, flat[name]),
                  "render_proxy": lambda: render_proxy_error(ref_full, full[name], kernel,
                                                             valid),
                  "albedo_proxy": lambda: albedo_proxy_error(ref_full, full[name],
                                                             albedo_kernel, valid)}
        out = {}
        for k in keys:
            if k == "render_albedo":  # the product: the geometric mean's choice
                for part in ("render_proxy", "albedo_proxy"):
                    out.setdefault(part, metric[part]())
                out[k] = out["render_proxy"] * out["albedo_proxy"]
            else:
                out.setdefault(k, metric[k]())
        return out

    names = list(models)
    sel = dict(zip(names, parallel_map(lambda t: errors(t, (key,)), names, limit_blas=False),
                   strict=True))
    chosen = min(sel, key=lambda t: sel[t][key])  # pick_transform, the selector checked
    rest = tuple(k for k in ("gamma_mse", "render_proxy", "albedo_proxy", "mse", "rae")
                 if k not in sel[chosen])
    if chosen not in flat:  # mask the chosen decode once, not per metric ("rest" has mse)
        flat[chosen] = full[chosen][:, valid]
    more = {}  # the chosen model's other errors, side by side
    for part in parallel_map(lambda k: errors(chosen, (k,)), rest, limit_blas=False):
        more.update(part)
    stats = {t: {**sel[t], **(more if t == chosen else {}),
                 **{k: models[t].stats[k] for k in _MODEL_STATS if k in models[t].stats}}
             for t in names}
    model = models[chosen]
    model.stats = {"transforms": stats, "chosen": chosen, "selector": selector}
    if has_floor(chosen):
        model.floor = choose_floor(ref, flat[chosen], model.gain)
        model.stats["floor"] = model.floor
    return model


#: Per-transform statistics of :func:`_encode_one` carried into ``stats["transforms"]``.
_MODEL_STATS = ("relative_residual", "projections_completed", "budget", "fill", "recount")


def encode_at(brdf: BRDF, spec: EncodeSpec, size: SizeControl | None = None) -> SparseBRDF:
    """An encoding at ``spec.n_coeffs`` (``spec.n_bytes`` is not read), in each of
    ``spec.transforms``, and the transform ``spec.selector`` prefers; the coefficient
    count can be steered while the fill runs.

    ``spec`` is trusted (:meth:`~sparse_brdf.coding.spec.EncodeSpec.build` checked it);
    only the BRDF's grid is checked against its ensemble. With ``fill="invalid"`` and fill
    rounds to run, ``size.recount(model)`` is called for each transform's model after each
    least-squares fit but the last; the next round re-codes that transform's filled
    channels at the count it returns (smaller or larger than ``spec.n_coeffs``), so the
    support that results is chosen and fitted for that count. After the last fit,
    ``size.trim(model)`` gives the final support; if it dropped coefficients, the values of
    the rest are fitted to the valid bins again, as every fill round fits them. This is
    how :func:`~sparse_brdf.coding.budget.encode_to_bytes_with` meets a byte budget in one
    encoding: ``recount`` estimates from the file of the current fit the count that fills
    the budget (a little over it), and ``trim`` keeps the largest coefficients that fit.
    Otherwise (``fill="missing"``, ``fill_iters=0``, a BRDF without invalid bins,
    ``size=None``) this is :func:`~sparse_brdf.coding.encode.encode` at that count.

    Parameters
    ----------
    brdf : BRDF
        As :func:`~sparse_brdf.coding.encode.encode`.
    spec : EncodeSpec
        The request; ``spec.n_coeffs`` is the count of the search and the first fit.
    size : SizeControl or None
        ``recount(model) -> int`` (at least 1) and ``trim(model) -> SparseBRDF``.

    Returns
    -------
    SparseBRDF
        As :func:`~sparse_brdf.coding.encode.encode`; with ``size`` and fill rounds,
        ``stats["recount"]`` holds each transform's counts from ``recount``, in order.
    """
    ens = spec.ensemble
    check_grid_matches(brdf, ens)
    opts = CodingOptions(spec.n_coeffs, spec.max_error, spec.fill, spec.fill_iters, spec.basis,
                    spec.joint)
    if opts.fill == "invalid":
        models = fill_invalid(brdf, ens, spec.transforms, opts, size)
    else:
        models = {t: _encode_one(brdf, ens, t, opts) for t in spec.transforms}
    model = choose_transform(brdf, models, ens, spec.selector)
    model.stats["options"] = spec.options
    return model


def _encode_one(brdf: BRDF, ens: Ensemble, transform: str, o: CodingOptions) -> SparseBRDF:
    """Encode with one transform; unmeasured bins above the horizon are filled from the
    model (EM, ``fill="missing"``)."""
    mats = materials_of(brdf, (transform,))
    y = coded_channels(brdf, transform, o.basis, mats[transform])
    model = search_many(brdf, ens, {transform: y}, o, mats)[transform]
    missing = geometric_valid(brdf.shape) & ~brdf.valid
    if not missing.any():
        return model
    # Bins above the horizon without a measurement would act as zeros in the projection;
    # replace them by the current reconstruction and re-encode (expectation-maximisation).
    # The mask is the same for the three channels, so filling the coded channels is
    # filling the transformed R, G, B (the basis is a per-bin 3 x 3 mix).
    for _ in range(o.fill_iters):
        y[:, missing] = model.coded(ens)[:, missing]
        model = search_many(brdf, ens, {transform: y}, o, mats)[transform]
    model.stats["fill"] = {"rounds": o.fill_iters}
    return model


__all__ = ["SELECTOR_KEYS", "check_grid_matches", "choose_transform", "encode_at"]
