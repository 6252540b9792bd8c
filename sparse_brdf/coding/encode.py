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
default: the transform chosen by the render- and albedo-proxy errors; every invalid bin
a free value (hard thresholding pursuit on the valid bins); the channels coded in an
opponent colour basis with a joint budget of 3 ``n_coeffs``. ``PAPER_OPTIONS`` gives
the paper's encoder.

The size: a count (``n_coeffs``, the paper's) or a byte budget (``n_bytes``,
:mod:`~sparse_brdf.coding.budget`); by default files of at most ``DEFAULT_N_BYTES`` =
1,700 bytes. The encoding at a count is :mod:`~sparse_brdf.coding.counted`'s.
"""

from __future__ import annotations

from ..brdf import BRDF
from ..metrics import cosine_weighted_snr, gamma_mse, mse, rae
from ..params import check_choice
from .budget import encode_to_bytes_with
from .coefficients import SparseBRDF
from .counted import SELECTOR_KEYS, check_grid_matches, encode_at
from .ensemble import Ensemble
from .projection import materials_of, project_all, select
from .spec import ENCODE_OPTIONS, SELECTORS, EncodeSpec, auto_transforms


def pick_transform(stats: dict[str, dict], selector: str = "gamma-mse") -> str:
    """The transform rule (``docs/method.md``, "Encoding"): the smaller gamma-mapped MSE
    (``selector="gamma-mse"``), the smaller render-proxy error (``"render"``) or the
    smaller product of the render- and albedo-proxy errors (``"render-albedo"``)."""
    key = SELECTOR_KEYS[check_choice("selector", selector, SELECTORS)]
    return min(stats, key=lambda t: stats[t][key])


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


def encode(
    brdf: BRDF,
    ensemble: Ensemble | None = None,
    n_coeffs: int | None = None,
    max_error: float | None = None,
    transform: str = "auto",
    fill_iters: int | None = None,
    selector: str = ENCODE_OPTIONS["selector"],
    fill: str = ENCODE_OPTIONS["fill"],
    basis: str = ENCODE_OPTIONS["basis"],
    budget: str | None = None,
    n_bytes: int | None = None,
) -> SparseBRDF:
    """Encode ``brdf`` as a :class:`SparseBRDF` over ``ensemble``.

    Its size is a coefficient count (``n_coeffs``) or the bytes of its ``.sbrdf`` file
    (``n_bytes``); without either, the default size: a file of at most
    ``DEFAULT_N_BYTES`` = 1,700 bytes (:func:`~sparse_brdf.coding.budget.encode_to_bytes`).

    Parameters
    ----------
    brdf : BRDF
        The material: linear RGB values (n1, n2, n3, 3) on the ensemble's grid.
    ensemble : Ensemble, optional
        The dictionaries; default: the shipped default ensemble.
    n_coeffs : int, optional
        At most this many coefficients per channel (the paper's count: DEFAULT_N_COEFFS =
        262); with a joint budget, at most 3 ``n_coeffs`` over the three channels. Not
        with ``n_bytes``.
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
        How "auto" picks the transform (``SELECTORS``): ``"render-albedo"`` (the
        default), the smaller product of :func:`~sparse_brdf.metrics.render_proxy_error`
        (point lights) and :func:`~sparse_brdf.metrics.albedo_proxy_error` (uniform
        light); ``"render"``, the smaller render-proxy error alone (the default until
        2026-12-08); or ``"gamma-mse"``, the smaller gamma-mapped MSE (the paper's).
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
    n_bytes : int, optional
        The file's size in bytes, at most (header, name and checksum included; file
        version 2): the largest encoding that fits, its coefficients the largest over the
        channels (``docs/file-format.md``, "Byte budgets"). Not with ``n_coeffs``.

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
        For an option out of its range or choices, or both ``n_coeffs`` and ``n_bytes``.

    See Also
    --------
    EncodeSpec.build : the request resolved and checked, once; :func:`encode_with` runs it.
    """
    spec = EncodeSpec.build(ensemble, n_coeffs, n_bytes, max_error=max_error,
                            transform=transform, fill_iters=fill_iters, selector=selector,
                            fill=fill, basis=basis, budget=budget)
    return encode_with(brdf, spec)


def encode_with(brdf: BRDF, spec: EncodeSpec) -> SparseBRDF:
    """:func:`encode` on a resolved request (``spec`` trusted: :meth:`EncodeSpec.build`
    checked it): to a byte budget if ``spec.n_bytes`` is set
    (:func:`~sparse_brdf.coding.budget.encode_to_bytes_with`), else at ``spec.n_coeffs``
    (:func:`~sparse_brdf.coding.counted.encode_at`). Only the BRDF's grid is checked
    against the ensemble."""
    if spec.n_bytes is not None:
        return encode_to_bytes_with(brdf, spec)
    return encode_at(brdf, spec)
