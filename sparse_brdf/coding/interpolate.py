"""Interpolating two encoded BRDFs in coefficient space.

As in the TOG version of Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model".

Per channel, B's coefficients are brought into A's dictionary mode by mode,
R_n = U_nA^T U_nB and S_B' = S_B x1 R1 x2 R2 x3 R3 (exact, the bases being orthonormal),
then blended, S(alpha) = (1 - alpha) S_A + alpha S_B', and re-sparsified to the budget
by keeping the largest |s|. The result uses A's dictionaries, transform and colour basis.

Colour bases: if B's basis differs from A's, B's coded channels are first brought into
A's, S_B'[c] = sum_c' R[c, c'] S_B[c'] (each in A's dictionary of channel c) with
R = M_A M_B^T (``transforms.colour_matrix``): exact, the bases being linear maps of the
same transformed R, G, B. The two transforms are not linearly related, so materials with
different transforms are refused.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from ..errors import EnsembleMismatchError, UsageError
from ..fileio import check_new_output
from ..params import Interval, check
from ..transforms import colour_matrix
from .coefficients import SparseBRDF
from .ensemble import Ensemble, resolve_ensemble
from .fileformat import SBRDF_FILE, load_sbrdf, save_sbrdf
from .tensor import reconstruct, sparse_to_dense, top_k

#: The blend's parameters: ``alpha`` in [0, 1]; ``n_coeffs`` at most the grid's entries.
PARAMETERS = {"alpha": Interval(float, 0.0, 1.0), "n_coeffs": Interval(int, 1)}


def interpolate(
    a: SparseBRDF,
    b: SparseBRDF,
    alpha: float,
    ensemble: Ensemble | None = None,
    n_coeffs: int | None = None,
) -> SparseBRDF:
    """Blend two encoded materials in coefficient space.

    Parameters
    ----------
    a, b : SparseBRDF
        The two materials, encoded over the same ensemble with the same transform (their
        colour bases may differ). The result uses ``a``'s dictionaries, transform and
        colour basis.
    alpha : float
        The blend weight in [0, 1]: 0 gives ``a``, 1 gives ``b`` (in ``a``'s dictionaries).
    ensemble : Ensemble, optional
        The ensemble both were encoded with; default: the shipped default
        (:meth:`Ensemble.default`).
    n_coeffs : int, optional
        Coefficients per channel of the result, in [1, grid entries]. Default: per channel
        the larger of the two inputs' counts (if ``b``'s basis differs, its mean count per
        channel stands for its count). In the "opponent" basis the budget is joint, as
        encoded: the largest |s| over the three channels, 3 ``n_coeffs`` in all (default:
        the sum of the per-channel defaults).

    Returns
    -------
    SparseBRDF
        The blend, named ``"<a>+<b>@<alpha>"``.

    Raises
    ------
    UsageError
        If the transforms differ, ``alpha`` is outside [0, 1] or ``n_coeffs`` is out of
        range.
    EnsembleMismatchError
        If either material was encoded over another ensemble.
    """
    ens = resolve_ensemble(ensemble)
    a.check_ensemble(ens)
    b.check_ensemble(ens)
    _check_transforms(a, a.name, b, b.name)
    check("alpha", alpha, PARAMETERS["alpha"])
    if n_coeffs is not None:
        check("n_coeffs (at most the grid's entries)", n_coeffs,
              PARAMETERS["n_coeffs"].capped(int(np.prod(a.shape))))
    return _blend(a, b, alpha, ens, n_coeffs)


def blend_files(a: str | os.PathLike, b: str | os.PathLike, output: str | os.PathLike,
                alpha: float, ensemble: Ensemble | str | os.PathLike | None = None,
                n_coeffs: int | None = None) -> tuple[Path, SparseBRDF]:
    """Blend two ``.sbrdf`` files (:func:`interpolate`) into the ``.sbrdf`` file ``output``
    (``sparse-brdf blend``), every input checked once, before the work; errors name the
    files.

    Parameters
    ----------
    a, b : path
        The two coefficient files, of one ensemble and one transform.
    output : path
        The result's ``.sbrdf`` file (written atomically); refused if it is not named
        ``.sbrdf``, is a folder, is one of the inputs or cannot be written.
    alpha : float
        As :func:`interpolate`.
    ensemble : Ensemble, path or id, optional
        Default: the shipped ensemble ``a`` names.
    n_coeffs : int, optional
        As :func:`interpolate`, but a count beyond the grid's entries is capped to them.

    Returns
    -------
    (Path, SparseBRDF)
        The file written and the blend.
    """
    out = check_new_output(output, *SBRDF_FILE, [a, b, None if isinstance(
        ensemble, Ensemble) else ensemble])
    try:  # the shipped ensemble A names, unless one is given
        ens = resolve_ensemble(ensemble, for_id=load_sbrdf(a).ensemble_id)
    except EnsembleMismatchError as exc:
        raise EnsembleMismatchError(f"{a}: {exc}") from exc
    if n_coeffs is not None:
        n_coeffs = min(check("--coeffs", n_coeffs, PARAMETERS["n_coeffs"]),
                       int(np.prod(ens.shape)))
    check("alpha", alpha, PARAMETERS["alpha"])
    first = load_sbrdf(a, ens)
    try:
        second = load_sbrdf(b, ens)
    except EnsembleMismatchError as exc:
        raise EnsembleMismatchError(
            f"{b}: encoded with another ensemble than {a} ({ens.id}): blending needs one "
            f"ensemble; re-encode the material of {b} with it (sparse-brdf encode SOURCE -o "
            f"NEW.sbrdf --ensemble {ensemble or ens.id})") from exc
    _check_transforms(first, a, second, b)
    model = _blend(first, second, alpha, ens, n_coeffs)
    return save_sbrdf(out, model), model


def _check_transforms(a: SparseBRDF, a_name, b: SparseBRDF, b_name) -> None:
    """UsageError unless the two materials share their transform (named as given)."""
    if a.transform != b.transform:
        raise UsageError(f"cannot blend {a_name} ({a.transform}) with {b_name} "
                         f"({b.transform}): encode both with the same --transform")



def _blend(a: SparseBRDF, b: SparseBRDF, alpha: float, ens: Ensemble,
           n_coeffs: int | None) -> SparseBRDF:
    """:func:`interpolate` on checked inputs."""
    same = a.basis == b.basis
    # B's coded channels -> A's: R = M_A M_B^T (the identity, exactly, for one basis)
    mix = np.eye(3) if same else colour_matrix(a.basis) @ colour_matrix(b.basis).T
    b_count = [int(n) for n in b.n_coeffs] if same else [-(-int(b.n_coeffs.sum()) // 3)] * 3
    b_in = functools.cache(lambda d, k: _in_dictionary(b, d, k, ens))  # (channel, dict)
    blends, budgets = [], []
    for c in range(3):
        ka = int(a.dict_index[c])
        sa = sparse_to_dense(a.locations[c], a.values[c], a.shape)
        if same:
            sb = b_in(c, ka)
        else:
            sb = sum(float(mix[c, d]) * b_in(d, ka) for d in range(3) if abs(mix[c, d]) > 1e-12)
        blends.append(((1.0 - alpha) * sa + alpha * sb).ravel())
        budgets.append(int(n_coeffs if n_coeffs is not None
                           else max(int(a.n_coeffs[c]), b_count[c])))
    if a.basis == "opponent":
        locs, vals = _joint_top(blends, sum(budgets))
    else:
        idxs = [top_k(s * s, budget) for s, budget in zip(blends, budgets, strict=True)]
        locs, vals = idxs, [s[idx] for s, idx in zip(blends, idxs, strict=True)]
    name = f"{a.name}+{b.name}@{alpha:g}"
    # the level transforms: ln(rho g) blends linearly where the logarithm dominates, so the
    # blend's gain is the gains' geometric blend (1 for the other transforms)
    gain = float(np.float32(a.gain ** (1.0 - alpha) * b.gain ** alpha))
    return SparseBRDF(a.transform, a.shape, a.ensemble_id, a.dict_index.copy(), locs, vals,
                      name=name[:255], basis=a.basis, gain=gain, lobe=_blend_lobe(a, b, alpha),
                      floor=_blend_floor(a, b, alpha))


def _blend_floor(a: SparseBRDF, b: SparseBRDF, alpha: float) -> float:
    """The blend's floor (0 for the transforms without one): the floors' linear blend,
    as float16; each end's own at alpha 0 and 1."""
    if alpha in (0.0, 1.0):
        return a.floor if alpha == 0.0 else b.floor
    return float(np.float16((1.0 - alpha) * a.floor + alpha * b.floor))


def _blend_lobe(a: SparseBRDF, b: SparseBRDF, alpha: float) -> tuple[float, ...] | None:
    """The blend's base lobe (the lobe transforms; None for the others): roughness
    blended geometrically, kd and ks linearly, as float16. The coded values, log ratios
    to each material's own lobe, blend linearly against it: the blend is each end exactly
    (``b`` in ``a``'s dictionaries) and between them a geometric blend of the two ratios
    over the blended lobe."""
    if a.lobe is None:
        return None
    la, lb = np.asarray(a.lobe, np.float64), np.asarray(b.lobe, np.float64)
    out = (1.0 - alpha) * la + alpha * lb
    out[0] = la[0] ** (1.0 - alpha) * lb[0] ** alpha
    if alpha in (0.0, 1.0):  # exact ends (float16 values already)
        out = la if alpha == 0.0 else lb
    return tuple(float(v) for v in out.astype(np.float16))


def _in_dictionary(model: SparseBRDF, c: int, k: int, ens: Ensemble) -> np.ndarray:
    """Dense coefficients of ``model``'s channel ``c`` in dictionary ``k``: rotated mode
    by mode, R_n = U_nk^T U_n (exact, the bases being orthonormal)."""
    s = sparse_to_dense(model.locations[c], model.values[c], model.shape)
    kb = int(model.dict_index[c])
    if kb != k:
        rot = [x.T @ y for x, y in zip(ens.dictionary(k), ens.dictionary(kb), strict=True)]
        s = reconstruct(s, *rot)
    return s


def _joint_top(blends: list[np.ndarray], budget: int) -> tuple[list, list]:
    """(locations, values) per channel of the ``budget`` largest |s| over the three
    channels together (the least squared error in the transformed R, G, B, the colour
    basis and the dictionaries being orthonormal), each channel's sorted by decreasing
    |s|."""
    flat = np.concatenate(blends)
    idx = top_k(flat * flat, budget)
    size = blends[0].size
    chan, loc = np.divmod(idx, size)
    return ([loc[chan == c] for c in range(3)],
            [blends[c][loc[chan == c]] for c in range(3)])
