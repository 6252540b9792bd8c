"""Encoding a BRDF over an ensemble: projection, sparsification, model selection.

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model"; ``docs/method.md``,
"Encoding".

For each transform and colour channel, the transformed tensor Y is projected on every
dictionary; the largest |s| are kept until ``n_coeffs`` are kept or the relative residual
(||Y||^2 - sum of kept s^2) / ||Y||^2 falls to ``max_error``. The channel takes the
dictionary needing the fewest coefficients, then the least residual, then the lowest
index. The transform (the same for all channels) is the one whose reconstruction has
the smaller gamma-mapped MSE against the BRDF, unless forced.

Options beyond the paper (``encode(selector=, fill=, basis=, budget=)``), all on by
default: the transform chosen by the render-proxy error; every invalid bin a free value
(hard thresholding pursuit on the valid bins); the channels coded in an opponent colour
basis with a joint budget of 3 ``n_coeffs``. ``PAPER_OPTIONS`` gives the paper's encoder.
"""

from __future__ import annotations

import numpy as np

from ..brdf import BRDF
from ..coords import geometric_valid
from ..errors import EnsembleMismatchError
from ..metrics import (
    cosine_weighted_snr,
    gamma_mse,
    make_render_proxy,
    mse,
    rae,
    render_proxy_error,
)
from ..parallel import parallel_map
from ..params import check_choice
from ..transforms import inverse
from .coefficients import SparseBRDF
from .ensemble import Ensemble
from .fill import SizeControl, fill_invalid
from .projection import (
    CodingOptions,
    coded_channels,
    materials_of,
    project_all,
    search_many,
    select,
)
from .spec import DEFAULT_N_COEFFS, ENCODE_OPTIONS, SELECTORS, EncodeSpec, auto_transforms

#: The ``stats["transforms"][t]`` entry each selector minimises.
SELECTOR_KEYS = {"gamma-mse": "gamma_mse", "render": "render_proxy"}
def pick_transform(stats: dict[str, dict], selector: str = "gamma-mse") -> str:
    """The transform rule (``docs/method.md``, "Encoding"): the smaller gamma-mapped MSE
    (``selector="gamma-mse"``) or the smaller render-proxy error (``"render"``)."""
    key = SELECTOR_KEYS[check_choice("selector", selector, SELECTORS)]
    return min(stats, key=lambda t: stats[t][key])


def check_grid_matches(brdf: BRDF, ens: Ensemble) -> None:
    """:class:`EnsembleMismatchError` naming the BRDF's file (or name) unless its grid is
    the ensemble's."""
    if brdf.shape != ens.shape:
        raise EnsembleMismatchError(f"{brdf.source or brdf.name}: BRDF grid {brdf.shape} "
                                    f"does not match the ensemble's {ens.shape}")


def error_curve(brdf: BRDF, ens: Ensemble, counts: list[int]) -> dict:
    """Errors against the coefficient count, per transform, and the transform chosen.

    Returns ``{"counts": counts, "<transform>": {"rae": [...], "cos_snr": [...],
    "gamma_mse": [...], "mse": [...]}, "chosen": [...]}`` (one projection per transform).
    """
    check_grid_matches(brdf, ens)
    names = auto_transforms(ens)
    proj = {t: project_all(brdf, ens, t, max(counts)) for t in names}
    material = materials_of(brdf, names)
    out: dict = {"counts": list(counts), "chosen": []}
    out.update({t: {"rae": [], "cos_snr": [], "gamma_mse": [], "mse": []} for t in names})
    for n in counts:
        stats = {}
        for t in names:
            rec = select(proj[t], n, None, brdf.name, *material[t]).decode(
                ens, valid=brdf.valid).values
            ref, flat = brdf.values[brdf.valid], rec[brdf.valid]
            stats[t] = {"rae": rae(ref, flat), "gamma_mse": gamma_mse(ref, flat),
                        "mse": mse(ref, flat),
                        "cos_snr": cosine_weighted_snr(brdf.values, rec, brdf.valid)}
            for k, v in stats[t].items():
                out[t][k].append(v)
        out["chosen"].append(pick_transform(stats))
    return out


def choose_transform(brdf: BRDF, models: dict[str, SparseBRDF], ens: Ensemble,
                     selector: str = "gamma-mse") -> SparseBRDF:
    """The model that ``selector`` prefers (:func:`pick_transform`'s rule; ``selector`` as
    an :class:`~sparse_brdf.coding.spec.EncodeSpec` resolved it); ``stats`` gets every
    model's value of the selector's error, and the chosen model's errors in full
    (gamma-mapped MSE, MSE, RAE, render-proxy error on valid bins)."""
    key = SELECTOR_KEYS[selector]
    valid = brdf.valid
    ref_full = brdf.channel_first()
    ref = ref_full[:, valid]  # (3, n_valid): mask once, then flat metrics
    kernel = make_render_proxy(brdf.shape)
    full: dict[str, np.ndarray] = {}  # per model: its decode (3, n1, n2, n3)
    flat: dict[str, np.ndarray] = {}  # per model: its decode on the valid bins

    def errors(name: str, keys: tuple[str, ...]) -> dict:  # numpy only (no BLAS)
        if name not in full:
            m = models[name]
            full[name] = inverse(m.transformed(ens), name, m.gain, m.lobe)
        if keys != ("render_proxy",) and name not in flat:
            flat[name] = full[name][:, valid]
        metric = {"gamma_mse": lambda: gamma_mse(ref, flat[name]),
                  "mse": lambda: mse(ref, flat[name]), "rae": lambda: rae(ref, flat[name]),
                  "render_proxy": lambda: render_proxy_error(ref_full, full[name], kernel,
                                                             valid)}
        return {k: metric[k]() for k in keys}

    names = list(models)
    sel = dict(zip(names, parallel_map(lambda t: errors(t, (key,)), names, limit_blas=False),
                   strict=True))
    chosen = min(sel, key=lambda t: sel[t][key])  # pick_transform, the selector checked
    rest = tuple(k for k in SELECTOR_KEYS.values() if k != key) + ("mse", "rae")
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
    return model


#: Per-transform statistics of :func:`_encode_one` carried into ``stats["transforms"]``.
_MODEL_STATS = ("relative_residual", "projections_completed", "budget", "fill", "recount")


def encode(
    brdf: BRDF,
    ensemble: Ensemble | None = None,
    n_coeffs: int = DEFAULT_N_COEFFS,
    max_error: float | None = None,
    transform: str = "auto",
    fill_iters: int | None = None,
    selector: str = ENCODE_OPTIONS["selector"],
    fill: str = ENCODE_OPTIONS["fill"],
    basis: str = ENCODE_OPTIONS["basis"],
    budget: str | None = None,
) -> SparseBRDF:
    """Encode ``brdf`` as a :class:`SparseBRDF` over ``ensemble``.

    Parameters
    ----------
    brdf : BRDF
        The material: linear RGB values (n1, n2, n3, 3) on the ensemble's grid.
    ensemble : Ensemble, optional
        The dictionaries; default: the shipped default ensemble.
    n_coeffs : int
        At most this many coefficients per channel (default DEFAULT_N_COEFFS = 262, the
        paper's); with a joint budget, at most 3 ``n_coeffs`` over the three channels.
    max_error : float, optional
        Relative squared residual in the transformed domain at which coding stops adding
        coefficients (e.g. 1e-4), in [0, 1); None keeps ``n_coeffs``. Per channel,
        relative to the channel's ||Y_c||^2; with a joint budget, the total residual
        relative to the total ||Y||^2 (the basis is orthonormal, so that is the
        transformed R, G, B energy in either basis).
    transform : str
        ``"auto"`` (``selector`` picks among :func:`~sparse_brdf.coding.spec.
        auto_transforms`: the lobe pair over the default ensemble, the paper's pair over
        the paper's), ``"lobe"`` (the lobe pair over any ensemble) or one of
        ``TRANSFORMS``.
    fill_iters : int, optional
        Rounds of filling (see ``fill``); None: ``DEFAULT_FILL_ITERS[fill]`` (3 for
        either); 0 disables filling (the paper fits every invalid bin as zero).
    selector : str
        How "auto" picks the transform (``SELECTORS``): ``"render"``, the smaller
        :func:`~sparse_brdf.metrics.render_proxy_error` (the default), or
        ``"gamma-mse"``, the smaller gamma-mapped MSE (the paper's).
    fill : str
        Which bins are filled from the model instead of being fitted as zeros
        (``FILLS``). ``"missing"`` (the paper's, plus filling): unmeasured bins above
        the horizon (negative entries in a MERL file), each round re-running the full
        dictionary search; a BRDF without such bins is encoded as in the paper.
        ``"invalid"`` (the default): every invalid bin (below the horizon too) is a free
        value; one dictionary search, then ``fill_iters`` least-squares fits to the
        valid bins on the chosen dictionaries, each followed by a new support from the
        filled channels (:func:`~sparse_brdf.coding.fill.fill_invalid`), fewer if the
        support repeats.
    basis : str
        Colour basis of the coded channels (``transforms.COLOUR_BASES``):
        ``"opponent"`` (the default: luminance / red-green / yellow-blue of the
        transformed channels) or ``"rgb"`` (the paper's).
    budget : str, optional
        ``"channel"`` (``n_coeffs`` per channel) or ``"joint"`` (3 ``n_coeffs`` over the
        three channels, largest |s| first across the channels' chosen dictionaries);
        None: "joint" for the opponent basis, "channel" for rgb (``BUDGETS``).

    Returns
    -------
    SparseBRDF
        The encoding. ``result.stats`` holds, per transform tried: gamma-mapped MSE,
        plain MSE, RAE, the render-proxy error, the relative residual per channel, how
        many of the 3 K (channel, dictionary) projections were completed (the others
        were pruned, see :func:`project_pruned`), ``budget`` (coefficients per channel
        and the coded channels' share of the energy) and, when filling, ``fill``
        (rounds; for "invalid" the fits run and the valid-bin residual after each, and
        before the first). Beside them: ``chosen``, ``selector`` and ``options`` (every
        option, defaults resolved).

    Raises
    ------
    EnsembleMismatchError
        If the BRDF's grid is not the ensemble's.
    UsageError
        For an option out of its range or choices.

    See Also
    --------
    EncodeSpec.build : the request resolved and checked, once; :func:`encode_with` runs it.
    """
    spec = EncodeSpec.build(ensemble, n_coeffs, max_error=max_error, transform=transform,
                            fill_iters=fill_iters, selector=selector, fill=fill,
                            basis=basis, budget=budget)
    return encode_with(brdf, spec)


def encode_with(brdf: BRDF, spec: EncodeSpec, size: SizeControl | None = None) -> SparseBRDF:
    """:func:`encode` on a resolved request, with the coefficient count steered while the
    fill runs.

    ``spec`` is trusted (:meth:`EncodeSpec.build` checked it); only the BRDF's grid is
    checked against its ensemble. With ``fill="invalid"`` and fill rounds to run,
    ``size.recount(model)`` is called for each transform's model after each least-squares
    fit but the last; the next round re-codes that transform's filled channels at the
    count it returns (smaller or larger than ``spec.n_coeffs``), so the support that
    results is chosen and fitted for that count. After the last fit, ``size.trim(model)``
    gives the final support; if it dropped coefficients, the values of the rest are fitted
    to the valid bins again, as every fill round fits them. This is how
    :func:`~sparse_brdf.coding.budget.encode_to_bytes` meets a byte budget in one
    encoding: ``recount`` estimates from the file of the current fit the count that fills
    the budget (a little over it), and ``trim`` keeps the largest coefficients that fit.
    Otherwise (``fill="missing"``, ``fill_iters=0``, a BRDF without invalid bins,
    ``size=None``) this is :func:`encode`.

    Parameters
    ----------
    brdf : BRDF
        As :func:`encode`.
    spec : EncodeSpec
        The request; ``spec.n_coeffs`` is the count of the search and the first fit.
    size : SizeControl or None
        ``recount(model) -> int`` (at least 1) and ``trim(model) -> SparseBRDF``.

    Returns
    -------
    SparseBRDF
        As :func:`encode`; with ``size`` and fill rounds, ``stats["recount"]`` holds each
        transform's counts from ``recount``, in order.
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

