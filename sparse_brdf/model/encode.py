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

import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from ..brdf import BRDF
from ..coords import geometric_valid
from ..errors import EnsembleMismatchError, UsageError
from ..metrics import (
    cosine_weighted_snr,
    gamma_mse,
    make_render_proxy,
    mse,
    rae,
    render_proxy_error,
)
from ..parallel import parallel_map
from ..params import Interval, check, check_choice
from ..paths import DEFAULT_ENSEMBLE_ID, PAPER_ENSEMBLE_ID
from ..transforms import (
    COLOUR_BASES,
    TRANSFORMS,
    check_basis,
    check_transform,
    forward,
    inverse,
    to_basis,
)
from .ensemble import Ensemble, resolve_ensemble
from .pruning import PrunedSearch, slice_order
from .sparse import SparseBRDF
from .tensor import (
    phi_major_to_flat,
    project,
    project_phi_major,
    reconstruct_sparse,
    top_k,
)

DEFAULT_N_COEFFS = 262

#: How ``encode(transform="auto")`` picks the transform (``docs/method.md``, "Encoding").
SELECTORS: tuple[str, str] = ("gamma-mse", "render")
#: The ``stats["transforms"][t]`` entry each selector minimises.
SELECTOR_KEYS = {"gamma-mse": "gamma_mse", "render": "render_proxy"}
#: Which bins ``encode`` fills from the model instead of fitting them as zeros.
FILLS: tuple[str, str] = ("missing", "invalid")
#: Fill rounds when ``fill_iters`` is not given: full re-searches for "missing",
#: least-squares fits on the chosen dictionaries for "invalid" (:func:`_fill_invalid`).
DEFAULT_FILL_ITERS = {"missing": 3, "invalid": 3}
#: How the coefficients are budgeted: ``n_coeffs`` per channel, or 3 ``n_coeffs`` over
#: the three channels.
BUDGETS: tuple[str, str] = ("channel", "joint")
#: The keyword options of :func:`encode` beyond the paper's, with their defaults: the
#: render-proxy selector, free invalid bins and the opponent basis (docs/results.md,
#: "Accuracy at equal coefficients", measures each).
ENCODE_OPTIONS = {"selector": "render", "fill": "invalid", "fill_iters": None,
                  "basis": "opponent", "budget": None}
#: The paper's encoder as options of :func:`encode` (``sparse:N:paper`` in a bench).
PAPER_OPTIONS = {"selector": "gamma-mse", "fill": "missing", "basis": "rgb"}
#: Every parameter of :func:`encode` a user sets, declared once (:mod:`sparse_brdf.params`):
#: the CLI's choices and bounds, a bench spec's options and the checks below read it.
#: ``n_coeffs`` beyond a grid's entries per channel is capped to them.
PARAMETERS = {
    "n_coeffs": Interval(int, 1),
    "max_error": Interval(float, 0.0, 1.0, closed="left"),
    "transform": ("auto", *TRANSFORMS),
    "selector": SELECTORS,
    "fill": FILLS,
    "fill_iters": Interval(int, 0, 1000),
    "basis": COLOUR_BASES,
    "budget": BUDGETS,
}


@dataclass
class Projections:
    """The largest coefficients of each channel on each dictionary, for one transform.

    ``idx[c][k]``/``val[c][k]``: flat indices and values of the ``max_coeffs`` largest |s|
    of channel c on dictionary k, largest first; ``residual[c, k, m]``: squared residual
    after keeping the first m + 1 of them; ``norms[c]``: ||Y_c||^2.
    """

    transform: str
    shape: tuple[int, int, int]
    ensemble_id: str
    idx: list[list[np.ndarray]]
    val: list[list[np.ndarray]]
    residual: np.ndarray
    norms: np.ndarray
    #: (n_coeffs, max_error) if dictionaries that cannot win that selection were pruned
    #: (their residuals are inf); None if every dictionary was projected in full.
    exact_for: tuple[int, float | None] | None = None


def _energy(x: np.ndarray) -> float:
    """||x||^2, accumulated in float64 (a float32 dot product over 1.4 M entries is off by
    about 1e-5 relative, the size of the residuals compared here)."""
    return float(np.sum(np.square(x, dtype=np.float64)))


def _energies(y: np.ndarray) -> np.ndarray:
    """||Y_c||^2 of each channel (:func:`_energy`)."""
    return np.array([_energy(ch) for ch in y])


def _energies_many(ys: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """:func:`_energies` of each entry's channels, side by side on the thread pool."""
    tasks = [(t, c) for t in ys for c in range(3)]
    e = list(parallel_map(lambda tc: _energy(ys[tc[0]][tc[1]]), tasks))
    return {t: np.array(e[3 * i: 3 * i + 3]) for i, t in enumerate(ys)}


def _coded_many(models: list[SparseBRDF], ens: Ensemble) -> list[np.ndarray]:
    """``m.coded(ens)`` of each model, the 3 x len(models) channels side by side on the
    thread pool."""
    tasks = [(m, c) for m in models for c in range(3)]
    out = list(parallel_map(lambda mc: reconstruct_sparse(
        mc[0].locations[mc[1]], mc[0].values[mc[1]], mc[0].shape,
        *ens.dictionary(int(mc[0].dict_index[mc[1]]))), tasks))
    return [np.stack(out[3 * i: 3 * i + 3]) for i in range(len(models))]


def project_all(brdf: BRDF, ens: Ensemble, transform: str, max_coeffs: int,
                y: np.ndarray | None = None) -> Projections:
    """Transform ``brdf`` and project each channel on every dictionary (3 K projections).

    ``y``: the transformed tensor (3, n1, n2, n3) to project instead of ``brdf``'s own.
    """
    if y is None:
        y = forward(brdf.channel_first(), check_transform(transform), brdf.valid)
    norms = _energies(y)
    tasks = [(c, k) for c in range(3) for k in range(ens.n_dicts)]
    # every channel meets every dictionary: store the channels phi_d-major once
    yt = np.ascontiguousarray(np.moveaxis(y, -1, 1))  # (3, n3, n1, n2)
    shape = tuple(y.shape[1:])

    def one(task):
        c, k = task
        u1, u2, u3 = ens.dictionary(k)
        s = project_phi_major(yt[c], np.ascontiguousarray(u1.T), u2,
                              np.ascontiguousarray(u3.T)).ravel()
        e = s * s
        idx = top_k(e, max_coeffs)
        return (phi_major_to_flat(idx, shape), s[idx],
                norms[c] - np.cumsum(e[idx], dtype=np.float64))

    res = list(parallel_map(one, tasks))
    k = ens.n_dicts
    return Projections(
        transform, brdf.shape, ens.id,
        idx=[[res[c * k + j][0] for j in range(k)] for c in range(3)],
        val=[[res[c * k + j][1] for j in range(k)] for c in range(3)],
        residual=np.array([[res[c * k + j][2] for j in range(k)] for c in range(3)]),
        norms=norms)


def project_pruned(brdf: BRDF, ens: Ensemble, transform: str, n_coeffs: int,
                   max_error: float | None = None,
                   y: np.ndarray | None = None) -> Projections:
    """:func:`project_all`, skipping dictionaries that provably cannot be selected.

    Gives the selection of the full search (:func:`select` with the same ``n_coeffs`` and
    ``max_error``) at a fraction of its cost: each channel's tensor is projected slice by
    slice along phi_d, the slices of largest energy first, and a dictionary is dropped
    once the coefficients computed so far prove it cannot be selected (the pruned
    projection, :mod:`~sparse_brdf.model.pruning`); the survivors are completed, so their
    coefficients are exact.
    """
    if y is None:
        y = forward(brdf.channel_first(), check_transform(transform), brdf.valid)
    return project_pruned_many(brdf, ens, {transform: y}, n_coeffs, max_error)[transform]


def project_pruned_many(brdf: BRDF, ens: Ensemble, ys: dict[str, np.ndarray],
                        n_coeffs: int, max_error: float | None = None
                        ) -> dict[str, Projections]:
    """:func:`project_pruned` of several transformed tensors ``ys`` (transform name:
    channels (3, n1, n2, n3)) in one search: each tensor's channels are pruned on their
    own, as by separate calls, with the same result, but every round's slices of all of
    them share the thread pool, so that a round's few long tasks of one tensor overlap
    those of another."""
    names = list(ys)
    n1, n2, n3 = tuple(ys[names[0]].shape[1:])
    n_dicts = ens.n_dicts
    n = int(n_coeffs)
    channels = [(t, c) for t in names for c in range(3)]
    # each channel phi_d-major (n3, n1 n2), the copies side by side on the pool
    phi_major = dict(zip(channels, parallel_map(lambda tc: np.ascontiguousarray(
        np.moveaxis(ys[tc[0]][tc[1]], -1, 0)).reshape(n3, n1 * n2), channels,
        limit_blas=False), strict=True))
    yt = {t: [phi_major[(t, c)] for c in range(3)] for t in names}
    norms = dict(zip(channels, parallel_map(
        lambda tc: _energy(ys[tc[0]][tc[1]]), channels), strict=True))
    u1t = [np.ascontiguousarray(ens.u1[k].T) for k in range(n_dicts)]
    u3t = [np.ascontiguousarray(ens.u3[k].T) for k in range(n_dicts)]

    # slice order per (channel, dictionary): energy of Y along each row of U3^T
    def slice_orders(tc):  # on the workers: small products on threaded BLAS stall under load
        x = yt[tc[0]][tc[1]]
        g = x @ x.T
        return [slice_order(g, ens.u3[k]) for k in range(n_dicts)]

    order = dict(zip(channels, parallel_map(slice_orders, channels), strict=True))

    def chunk(key, lo, hi):
        t, c, k = key
        rows = order[(t, c)][k][lo:hi]
        m = (u3t[k][rows] @ yt[t][c]).reshape(rows.size, n1, n2)
        sv = np.matmul(np.matmul(u1t[k], m), ens.u2[k]).ravel()
        e = sv * sv
        loc = top_k(e, n)
        slot, ab = np.divmod(loc, n1 * n2)
        return ab * n3 + rows[slot], sv[loc], float(e.sum(dtype=np.float64))

    keys = [(t, c, k) for t, c in channels for k in range(n_dicts)]
    groups = [([(t, c, k) for k in range(n_dicts)], norms[(t, c)], np.inf)
              for t, c in channels]
    search = PrunedSearch.start(keys, n3, n, max_error).run(groups, chunk,
                                                            mapper=parallel_map)
    k_keep = min(n, n1 * n2 * n3)
    out = {}
    for t in names:
        norm = np.array([norms[(t, c)] for c in range(3)])
        residual = np.full((3, n_dicts, k_keep), np.inf)
        idx_out = [[np.zeros(0, np.int64) for _ in range(n_dicts)] for _ in range(3)]
        val_out = [[np.zeros(0, np.float32) for _ in range(n_dicts)] for _ in range(3)]
        for tt, c, k in search.survivors():
            if tt != t:
                continue
            idx, val = search.top[(t, c, k)]
            e = val.astype(np.float32) ** 2
            idx_out[c][k], val_out[c][k] = idx, val
            residual[c, k, :idx.size] = norm[c] - np.cumsum(e, dtype=np.float64)
        out[t] = Projections(t, brdf.shape, ens.id, idx=idx_out, val=val_out,
                             residual=residual, norms=norm, exact_for=(n_coeffs, max_error))
    return out


def select(p: Projections, n_coeffs: int, max_error: float | None = None,
           name: str = "brdf") -> SparseBRDF:
    """Per channel, the dictionary needing fewest coefficients, then least residual, then
    lowest index; coefficients kept up to ``n_coeffs`` or a relative residual ``max_error``."""
    if p.exact_for is not None and p.exact_for != (n_coeffs, max_error):
        raise ValueError(f"these projections were pruned for n_coeffs, max_error = "
                         f"{p.exact_for}; project again to select with "
                         f"{(n_coeffs, max_error)}")
    n_coeffs = min(n_coeffs, p.residual.shape[2])
    dicts, locs, vals, rel = [], [], [], []
    for c in range(3):
        norm = p.norms[c]
        best = None
        for k in range(p.residual.shape[1]):
            res = p.residual[c, k, :n_coeffs]
            need = n_coeffs
            if norm == 0:
                need = 0
            elif max_error is not None:
                ok = np.flatnonzero(res <= max_error * norm)
                if ok.size:
                    need = int(ok[0]) + 1
            r = max(float(res[need - 1]), 0.0) if need else float(norm)
            if best is None or (need, r, k) < best:
                best = (need, r, k)
        need, r, k = best
        dicts.append(k)
        locs.append(p.idx[c][k][:need])
        vals.append(p.val[c][k][:need])
        rel.append(r / norm if norm > 0 else 0.0)
    model = SparseBRDF(p.transform, p.shape, p.ensemble_id, dicts, locs, vals, name=name)
    model.stats = {"relative_residual": rel}
    return model


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
    proj = {t: project_all(brdf, ens, t, max(counts)) for t in ens.transforms}
    out: dict = {"counts": list(counts), "chosen": []}
    out.update({t: {"rae": [], "cos_snr": [], "gamma_mse": [], "mse": []}
                for t in ens.transforms})
    for n in counts:
        stats = {}
        for t in ens.transforms:
            rec = select(proj[t], n, name=brdf.name).decode(ens, valid=brdf.valid).values
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
    """The model that ``selector`` prefers (:func:`pick_transform`); ``stats`` gets every
    model's value of the selector's error, and the chosen model's errors in full
    (gamma-mapped MSE, MSE, RAE, render-proxy error on valid bins)."""
    key = SELECTOR_KEYS[check_choice("selector", selector, SELECTORS)]
    valid = brdf.valid
    ref_full = brdf.channel_first()
    ref = ref_full[:, valid]  # (3, n_valid): mask once, then flat metrics
    kernel = make_render_proxy(brdf.shape)
    full: dict[str, np.ndarray] = {}  # per model: its decode (3, n1, n2, n3)
    flat: dict[str, np.ndarray] = {}  # per model: its decode on the valid bins

    def errors(name: str, keys: tuple[str, ...]) -> dict:  # numpy only (no BLAS)
        if name not in full:
            full[name] = inverse(models[name].transformed(ens), name)
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
    chosen = pick_transform(sel, selector)
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
        ``"auto"`` (``selector`` picks), ``"log-plus"`` or ``"log-plus-cosine"``.
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
        filled channels (:func:`_fill_invalid`), fewer if the support repeats.
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
    """
    return encode_sized(brdf, ensemble, n_coeffs, None, max_error=max_error,
                        transform=transform, fill_iters=fill_iters, selector=selector,
                        fill=fill, basis=basis, budget=budget)


class SizeControl(Protocol):
    """What :func:`encode_sized` asks while the fill runs, of one transform's model (its
    support and fitted values)."""

    def recount(self, model: SparseBRDF) -> int:
        """The coefficient count (per channel, as ``n_coeffs``) of the next support."""

    def trim(self, model: SparseBRDF) -> SparseBRDF:
        """The model's final support: the model itself, or some of its coefficients."""


def encode_sized(
    brdf: BRDF,
    ensemble: Ensemble | None,
    n_coeffs: int,
    size: SizeControl | None,
    **options,
) -> SparseBRDF:
    """:func:`encode`, with the coefficient count steered while the fill runs.

    With ``fill="invalid"`` and fill rounds to run, ``size.recount(model)`` is called for
    each transform's model after each least-squares fit but the last; the next round
    re-codes that transform's filled channels at the count it returns (smaller or larger
    than ``n_coeffs``), so the support that results is chosen and fitted for that count.
    After the last fit, ``size.trim(model)`` gives the final support; if it dropped
    coefficients, the values of the rest are fitted to the valid bins again, as every fill
    round fits them. This is how :func:`~sparse_brdf.model.budget.encode_to_bytes` meets a
    byte budget in one encoding: ``recount`` estimates from the file of the current fit
    the count that fills the budget (a little over it), and ``trim`` keeps the largest
    coefficients that fit. Otherwise (``fill="missing"``, ``fill_iters=0``, a BRDF without
    invalid bins, ``size=None``) this is :func:`encode`.

    Parameters
    ----------
    brdf, ensemble, n_coeffs
        As :func:`encode`; ``n_coeffs`` is the count of the search and the first fit.
    size : SizeControl or None
        ``recount(model) -> int`` (at least 1) and ``trim(model) -> SparseBRDF``.
    **options
        :func:`encode`'s other keywords.

    Returns
    -------
    SparseBRDF
        As :func:`encode`; with ``size`` and fill rounds, ``stats["recount"]`` holds each
        transform's counts from ``recount``, in order.
    """
    max_error = options.pop("max_error", None)
    transform = options.pop("transform", "auto")
    ens = encoder_ensemble(ensemble, options)
    check_grid_matches(brdf, ens)
    check("n_coeffs", n_coeffs, PARAMETERS["n_coeffs"])
    if max_error is not None:
        check("max_error", max_error, PARAMETERS["max_error"])
    kw = check_options(**options)
    opts = _Options(n_coeffs, max_error, kw["fill"], kw["fill_iters"], kw["basis"],
                    kw["budget"] == "joint")
    names = ens.transforms if transform == "auto" else (check_transform(transform),)
    if opts.fill == "invalid":
        models = _fill_invalid(brdf, ens, names, opts, size)
    else:
        models = {t: _encode_one(brdf, ens, t, opts) for t in names}
    model = choose_transform(brdf, models, ens, kw["selector"])
    model.stats["options"] = kw
    return model


def encoder_ensemble(ensemble: Ensemble | str | os.PathLike | None,
                     options: Mapping[str, object]) -> Ensemble:
    """The ensemble an encoding with ``options`` runs on.

    ``ensemble`` resolved (:func:`~sparse_brdf.model.ensemble.resolve_ensemble`); when
    none is named (None or ""), the shipped default, except for the paper's encoder
    (``options`` holding ``PAPER_OPTIONS``): it encodes over the shipped ensemble trained
    for the paper's transforms (``paths.PAPER_ENSEMBLE_ID``), so that ``--paper`` keeps
    the paper's model. A named ensemble is always the one used."""
    if (not ensemble and DEFAULT_ENSEMBLE_ID != PAPER_ENSEMBLE_ID
            and all(options.get(k) == v for k, v in PAPER_OPTIONS.items())):
        return Ensemble.shipped(PAPER_ENSEMBLE_ID)
    return resolve_ensemble(ensemble)


def check_n_coeffs(n_coeffs: int, ensemble: Ensemble) -> int:
    """``n_coeffs``, a maximum per channel, capped at the coefficients of one channel on
    the ensemble's grid (:func:`encode` keeps no more than a channel holds either).

    Raises
    ------
    UsageError
        If ``n_coeffs`` is below 1 (naming ``--coeffs``).
    """
    check("--coeffs", n_coeffs, PARAMETERS["n_coeffs"])
    return min(int(n_coeffs), int(np.prod(ensemble.shape)))


def check_options(**options) -> dict:
    """:func:`encode`'s options (``ENCODE_OPTIONS``), checked, with every default
    resolved: ``budget`` from ``basis``, ``fill_iters`` from ``fill``. Unknown names and
    values raise ValueError."""
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


@dataclass(frozen=True)
class _Options:
    """The coding options of one :func:`encode` call."""

    n: int
    max_error: float | None
    fill: str
    fill_iters: int
    basis: str
    joint: bool


def _coded_channels(brdf: BRDF, transform: str, basis: str) -> np.ndarray:
    """The channels to code: ``to_basis`` of the transformed R, G, B, a fresh array."""
    return to_basis(forward(brdf.channel_first(), transform, brdf.valid), basis)


def _encode_one(brdf: BRDF, ens: Ensemble, transform: str, o: _Options) -> SparseBRDF:
    """Encode with one transform; unmeasured bins above the horizon are filled from the
    model (EM, ``fill="missing"``)."""
    y = _coded_channels(brdf, transform, o.basis)
    model = _search(brdf, ens, transform, y, o)
    missing = geometric_valid(brdf.shape) & ~brdf.valid
    if not missing.any():
        return model
    # Bins above the horizon without a measurement would act as zeros in the projection;
    # replace them by the current reconstruction and re-encode (expectation-maximisation).
    # The mask is the same for the three channels, so filling the coded channels is
    # filling the transformed R, G, B (the basis is a per-bin 3 x 3 mix).
    for _ in range(o.fill_iters):
        y[:, missing] = model.coded(ens)[:, missing]
        model = _search(brdf, ens, transform, y, o)
    model.stats["fill"] = {"rounds": o.fill_iters}
    return model


def _search(brdf: BRDF, ens: Ensemble, transform: str, y: np.ndarray,
            o: _Options) -> SparseBRDF:
    """Each coded channel's dictionary by the (pruned) search over the ensemble, and its
    coefficients: the selection's own, or with a joint budget, re-coded on the chosen
    dictionaries (:func:`_code_many`)."""
    return _search_many(brdf, ens, {transform: y}, o)[transform]


def _search_many(brdf: BRDF, ens: Ensemble, ys: dict[str, np.ndarray],
                 o: _Options) -> dict[str, SparseBRDF]:
    """:func:`_search` of the channels of several transforms (name: channels), their
    projections side by side on the thread pool."""
    ps = project_pruned_many(brdf, ens, ys, o.n, o.max_error)
    models = {}
    for t, p in ps.items():
        models[t] = select(p, o.n, o.max_error, brdf.name)
        models[t].basis = o.basis
    if o.joint:
        coded = _code_many([(ys[t], models[t], ps[t].norms) for t in ys], ens, o)
        models = dict(zip(ys, coded, strict=True))
    else:
        for t, m in models.items():
            m.stats["budget"] = _budget_stats(m, ps[t].norms)
    for t, m in models.items():
        # (channel, dictionary) projections completed; the others were pruned
        m.stats["projections_completed"] = int(np.isfinite(ps[t].residual[:, :, 0]).sum())
    return models


def _budget_stats(m: SparseBRDF, norms: np.ndarray) -> dict:
    total = float(np.sum(norms))
    return {"coefficients": m.n_coeffs.tolist(),
            "energy_share": [float(x / total) if total > 0 else 0.0 for x in norms]}


def _code_many(jobs: list[tuple[np.ndarray, SparseBRDF, np.ndarray | None]], ens: Ensemble,
               o: _Options, counts: list[int] | None = None) -> list[SparseBRDF]:
    """Re-code each job's channels y (3, n1, n2, n3) on the dictionaries its model m chose
    (a job: y, m, the channels' energies or None): each channel projected on its own
    dictionary, then the largest |s| kept, ``o.n`` per channel, or with a joint budget 3
    ``o.n`` over the channels (largest first across them). With ``o.max_error``,
    coefficients are added until the relative residual (per channel, or of the total for a
    joint budget) is reached. The 3 x len(jobs) projections run side by side on the
    thread pool. ``counts``: per job, its own ``o.n``."""
    opts = [o] * len(jobs) if counts is None else [replace(o, n=int(n)) for n in counts]

    def one(task):
        j, c = task
        y, m, norms = jobs[j]
        s = project(y[c], *ens.dictionary(int(m.dict_index[c]))).ravel()
        idx = top_k(s * s, 3 * opts[j].n if opts[j].joint else opts[j].n)
        return idx, s[idx], _energy(y[c]) if norms is None else float(norms[c])

    tasks = [(j, c) for j in range(len(jobs)) for c in range(3)]
    done = list(parallel_map(one, tasks))
    return [_keep(y, m, done[3 * j: 3 * j + 3], opts[j]) for j, (y, m, _) in enumerate(jobs)]


def _keep(y: np.ndarray, m: SparseBRDF, top: list, o: _Options) -> SparseBRDF:
    """The coefficients :func:`_code_many` keeps of each channel's largest (``top``: per
    channel, flat indices, values and the channel's energy)."""
    shape = tuple(y.shape[1:])
    norms = np.array([e for _, _, e in top])
    cap = 3 * o.n if o.joint else o.n
    if o.joint:
        val = np.concatenate([v for _, v, _ in top])
        chan = np.concatenate([np.full(v.size, c) for c, (_, v, _) in enumerate(top)])
        order = np.argsort(-(val * val), kind="stable")[:cap]
        need = _needed(np.cumsum(val[order].astype(np.float64) ** 2), float(norms.sum()),
                       o.max_error)
        keep = [np.sort(order[:need][chan[order[:need]] == c]) for c in range(3)]
        starts = np.cumsum([0] + [v.size for _, v, _ in top])
        locs = [top[c][0][keep[c] - starts[c]] for c in range(3)]
        vals = [top[c][1][keep[c] - starts[c]] for c in range(3)]
    else:
        locs, vals = [], []
        for c, (idx, v, _) in enumerate(top):
            need = _needed(np.cumsum(v.astype(np.float64) ** 2), norms[c], o.max_error)
            locs.append(idx[:need])
            vals.append(v[:need])
    out = SparseBRDF(m.transform, shape, m.ensemble_id, m.dict_index, locs, vals,
                     name=m.name, basis=o.basis)
    kept = np.array([float(np.sum(v.astype(np.float64) ** 2)) for v in vals])
    out.stats = {"relative_residual": [max(float(n - k), 0.0) / n if n > 0 else 0.0
                                       for n, k in zip(norms, kept, strict=True)],
                 "budget": _budget_stats(out, norms)}
    return out


def _needed(cum: np.ndarray, norm: float, max_error: float | None) -> int:
    """How many of the coefficients (cumulative kept energies ``cum``, largest first) to
    keep: all, or the fewest whose residual norm - cum is within ``max_error`` norm."""
    if norm <= 0:
        return 0
    if max_error is None:
        return cum.size
    ok = np.flatnonzero(norm - cum <= max_error * norm)
    return int(ok[0]) + 1 if ok.size else cum.size


def _fill_invalid(brdf: BRDF, ens: Ensemble, transforms: tuple[str, ...],
                  o: _Options, size: SizeControl | None = None) -> dict[str, SparseBRDF]:
    """Encode with every invalid bin a free value (``docs/method.md``, "Encoding"), one
    model per transform.

    Minimises the residual on valid bins only, ||P_V (Y - U S)||^2 over sparse S, by hard
    thresholding pursuit on the dictionaries the search chose (:func:`_search`, run
    once on the zero-filled channels): the values of the current support are the least
    squares fit to the valid bins (:func:`_fit_supports`, conjugate gradients); the
    invalid bins of Y are then set to that reconstruction, the channels re-projected on
    their dictionaries and the largest |s| kept (:func:`_code_many`) as the next support.
    Stops when the support repeats or after ``o.fill_iters`` fits. The mask is the same
    for the three channels, so filling the coded channels is filling the transformed
    R, G, B (the basis is a per-bin 3 x 3 mix), and the channels' least squares
    problems are independent: the fits of every transform and channel run side by side.
    ``size`` (:func:`encode_sized`) revises each transform's count between fits (a
    revised support is never taken as settled) and trims the last fit's support.
    """
    invalid = ~brdf.valid
    ys = dict(zip(transforms, parallel_map(  # invalid bins are 0
        lambda t: _coded_channels(brdf, t, o.basis), transforms), strict=True))
    valid_energies = _energies_many(ys)  # before any filling
    models = _search_many(brdf, ens, ys, o)
    if not invalid.any() or o.fill_iters == 0:
        return models
    searched = {t: m.stats for t, m in models.items()}
    history: dict[str, list[float]] = {t: [] for t in transforms}
    residual: dict[str, np.ndarray] = {}
    active = list(transforms)
    counts = {t: o.n for t in transforms}
    recounts: dict[str, list[int]] = {t: [] for t in transforms}
    for fit in range(o.fill_iters):
        fitted = _fit_supports([(ys[t], models[t]) for t in active], invalid, ens)
        for t, (m, r) in zip(active, fitted, strict=True):
            models[t], residual[t] = m, r
            history[t].append(float(r.sum()))
        if fit == o.fill_iters - 1:
            break
        for t, coded in zip(active, _coded_many([models[t] for t in active], ens),
                            strict=True):
            np.copyto(ys[t], coded, where=invalid)  # fill the invalid bins
        revised = set()
        if size is not None:
            for t in active:
                n = max(int(size.recount(models[t])), 1)
                recounts[t].append(n)
                if n != counts[t]:
                    counts[t] = n
                    revised.add(t)
        recoded = _code_many([(ys[t], models[t], None) for t in active], ens, o,
                             [counts[t] for t in active])
        for t, new in zip(list(active), recoded, strict=True):
            if t not in revised and all(np.array_equal(np.sort(a), np.sort(b))
                   for a, b in zip(models[t].locations, new.locations, strict=True)):
                active.remove(t)  # the support has settled: its fit is done
            else:
                models[t] = new
        if not active:
            break
    if size is not None:  # the final support: trimmed to size, its values fitted again
        trimmed = dict(zip(transforms, parallel_map(  # LZMA releases the GIL
            lambda t: size.trim(models[t]), transforms, limit_blas=False), strict=True))
        cut = [t for t in transforms
               if int(trimmed[t].n_coeffs.sum()) < int(models[t].n_coeffs.sum())]
        for t, (m, r) in zip(cut, _fit_supports([(ys[t], trimmed[t]) for t in cut],
                                                invalid, ens), strict=True):
            models[t], residual[t] = m, r
            history[t].append(float(r.sum()))
    filled_energies = _energies_many(ys)
    for t, m in models.items():
        valid_energy = valid_energies[t]
        m.stats = {
            "relative_residual": [float(r / n) if n > 0 else 0.0
                                  for r, n in zip(residual[t], valid_energy, strict=True)],
            "budget": _budget_stats(m, filled_energies[t]),
            "projections_completed": searched[t]["projections_completed"],
            "fill": {"fits": len(history[t]), "valid_residual": history[t],
                     "valid_residual_unfilled": float(np.sum(
                         np.asarray(searched[t]["relative_residual"]) * valid_energy))},
        }
        if size is not None:
            m.stats["recount"] = recounts[t]
    return models


#: Conjugate-gradient iterations of each least-squares fit of :func:`_fit_supports`, at
#: most; a fit stops early once a step lowers the residual by less than FIT_CG_RTOL of it.
FIT_CG_ITERS = 10
FIT_CG_RTOL = 1e-3


def _fit_supports(jobs: list[tuple[np.ndarray, SparseBRDF]], invalid: np.ndarray,
                  ens: Ensemble) -> list[tuple[SparseBRDF, np.ndarray]]:
    """For each (channels y, model m): the values on m's support (its coefficient
    locations and dictionaries) that fit y on the valid bins in least squares,
    ``FIT_CG_ITERS`` conjugate-gradient steps on the normal equations from m's values.
    Returns, per job, the model (sorted by decreasing |value|) and each channel's
    residual on valid bins (3,). The 3 x len(jobs) channels run on the thread pool."""
    keep = (~invalid).astype(np.float32)  # masks by a product: cheaper than fancy indexing

    def one(task):
        y, m, c = task
        if m.locations[c].size == 0:  # nothing to fit (a joint budget spent elsewhere)
            res = y[c] * keep
            return m.locations[c], m.values[c], float(np.sum(np.square(res, dtype=np.float64)))
        sup = _Support(m.locations[c], m.shape, ens.dictionary(int(m.dict_index[c])))
        s = m.values[c].astype(np.float32)  # a copy, updated in place
        res = y[c] - sup.expand(s)
        res *= keep
        energy = float(np.dot(res.ravel(), res.ravel()))  # ||res||^2, tracked below
        r = sup.gather(res)
        p, rr = r.copy(), float(r @ r)
        for _ in range(FIT_CG_ITERS):
            q = sup.expand(p)
            q *= keep
            qq = float(np.dot(q.ravel(), q.ravel()))  # float32 BLAS dot: enough for steps
            if rr <= 0.0 or qq <= 0.0:
                break
            alpha = rr / qq
            s += np.float32(alpha) * p
            q *= np.float32(alpha)
            res -= q
            energy -= alpha * rr  # the step lowers ||res||^2 by exactly alpha rr
            if alpha * rr <= FIT_CG_RTOL * energy:
                break
            r = sup.gather(res)
            rr_new = float(r @ r)
            p = r + np.float32(rr_new / rr) * p
            rr = rr_new
        order = np.argsort(-np.abs(s), kind="stable")
        return m.locations[c][order], s[order], float(np.sum(np.square(res, dtype=np.float64)))

    # the largest supports first, so that the pool's last tasks are short
    tasks = sorted(((y, m, c) for y, m in jobs for c in range(3)),
                   key=lambda t: -t[1].locations[t[2]].size)
    done = {(id(m), c): out for (y, m, c), out in zip(tasks, parallel_map(one, tasks),
                                                      strict=True)}
    out = []
    for _, m in jobs:
        res = [done[(id(m), c)] for c in range(3)]
        fitted = SparseBRDF(m.transform, m.shape, m.ensemble_id, m.dict_index,
                            [a for a, _, _ in res], [v for _, v, _ in res], name=m.name,
                            basis=m.basis)
        out.append((fitted, np.array([e for _, _, e in res])))
    return out


class _Support:
    """The atoms of a set of coefficient locations on one dictionary: ``expand`` maps
    their values to the tensor (as :func:`tensor.reconstruct_sparse`), ``gather`` is its
    adjoint (the projection of a tensor on those atoms only), each about n1 n2 n3 K3
    multiply-adds for K3 distinct mode-3 atoms (a full projection: n1 n2 n3 (n1+n2+n3))."""

    def __init__(self, flat: np.ndarray, shape: tuple[int, int, int], u) -> None:
        self.shape = shape
        a, b, c = np.unravel_index(np.asarray(flat, np.int64), shape)
        (ka, self.ia), (kb, self.ib), (kc, self.ic) = (
            np.unique(x, return_inverse=True) for x in (a, b, c))
        self.u1 = np.ascontiguousarray(u[0][:, ka])
        self.u2 = np.ascontiguousarray(u[1][:, kb])
        self.u3 = np.ascontiguousarray(u[2][:, kc])
        self.core = (ka.size, kb.size, kc.size)

    def expand(self, v: np.ndarray) -> np.ndarray:
        n1, n2, n3 = self.shape
        ka, kb, kc = self.core
        core = np.zeros(self.core, np.float32)
        core[self.ia, self.ib, self.ic] = v  # the locations are distinct
        t = (self.u1 @ core.reshape(ka, -1)).reshape(n1, kb, kc)
        t = np.matmul(self.u2, t)  # (n1, n2, Kc)
        return (t.reshape(n1 * n2, kc) @ self.u3.T).reshape(n1, n2, n3)

    def gather(self, x: np.ndarray) -> np.ndarray:
        n1, n2, n3 = self.shape
        ka, kb, kc = self.core
        t = (x.reshape(n1 * n2, n3) @ self.u3).reshape(n1, n2 * kc)
        t = (self.u1.T @ t).reshape(ka, n2, kc)
        t = np.matmul(self.u2.T, t)  # (Ka, Kb, Kc)
        return t[self.ia, self.ib, self.ic]
