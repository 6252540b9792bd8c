"""The glossy importance-sampling lobe the plugins fit at load time (their ``sampling``
``"lobe"``, :data:`~sparse_brdf.decoders.layouts.LOBES`): a theta_h profile of the BRDF,
from a sparse model without decoding it (:func:`sparse_profile`) or from a table
(:func:`table_profile`), and the lobe fitted to it (:func:`fit_lobe`)."""

from __future__ import annotations

import numpy as np

from ..coords import bin_angles
from ..transforms import floor_value, from_lobe, lobe_rows
from .buffers import bin_weight, mix_channels
from .layouts import channel_terms


def fit_lobe(profile: np.ndarray, shape: tuple[int, int, int]) -> tuple[float, float]:
    """Fit the glossy sampling lobe to a theta_h profile of the BRDF.

    ``profile[i]`` is the mean BRDF value (over R, G, B, phi_d and the first theta_d
    bins) at theta_h bin i. Model: ``base + peak * cos(theta_h)^n``; n comes from the
    half-width at half maximum of ``profile - base``. The lobe's share of the mixture is
    its albedo share, ``8 pi peak / (n + 2)`` (a normalised Blinn lobe) against
    ``pi * base``, clipped to [0.05, 0.95] so the cosine part always covers the
    hemisphere. Returns (exponent n in [1, 1e4], lobe probability); a profile whose
    peak rises less than 50 % above its minimum counts as flat and gives (1, 0.05).
    """
    th = bin_angles(shape)[0]
    use = th < np.radians(80.0)
    p = np.asarray(profile, np.float64)[use]
    t = th[use]
    if p.size < 4 or not np.all(np.isfinite(p)):
        return 1.0, 0.05
    # a 3-bin moving average keeps reconstruction ripples from posing as a peak
    p = np.convolve(np.pad(p, 1, mode="edge"), np.ones(3) / 3.0, mode="valid")
    base = max(float(p.min()), 0.0)
    spike = p - base
    peak = float(spike[0])
    # no specular peak: less than half the diffuse level above it
    if peak <= 0.5 * base or peak <= 0.0:
        return 1.0, 0.05
    below = np.flatnonzero(spike < 0.5 * peak)
    if below.size == 0:
        return 1.0, 0.05
    i = int(below[0])
    # linear interpolation of the half-maximum crossing between bins i - 1 and i
    s0, s1 = spike[i - 1], spike[i]
    f = (s0 - 0.5 * peak) / max(s0 - s1, 1e-30)
    t_half = t[i - 1] + f * (t[i] - t[i - 1])
    n = float(np.log(0.5) / np.log(max(np.cos(t_half), 1e-6)))
    n = float(np.clip(n, 1.0, 1e4))
    spec = 8.0 * np.pi * peak / (n + 2.0)
    diff = np.pi * base
    prob = float(np.clip(spec / max(spec + diff, 1e-30), 0.05, 0.95))
    return n, prob


def sparse_profile(model, ensemble, n_d: int = 3) -> np.ndarray:
    """theta_h profile of a sparse model for :func:`fit_lobe` (no full decode).

    Mean over R, G, B, phi_d and the first ``n_d`` theta_d bins of the model's BRDF (the
    coded channels mixed back to R, G, B first, :func:`mix_channels`). Each channel's
    slices ``X[:, j, :]`` (n1, n3) are contracted over its distinct atoms:
    ``U1[:, A] @ M_j @ U3[:, C]^T``, ``M_j[a, c] = sum_t s_t U2[j, b_t]`` over the terms
    on atoms (a, c), a few thousand flops per material where a product over the terms
    took 100 Mflop.

    Returns
    -------
    np.ndarray
        (n1,) float64, the mean BRDF value per theta_h bin (1/sr).
    """
    n1, n2, n3 = model.shape
    js = np.arange(min(n_d, n2))
    xs = np.stack([_channel_slices(*channel_terms(model, ensemble, c), js)
                   for c in range(3)])  # (3, len(js), n1, n3)
    xs = mix_channels(xs.reshape(3, -1), model.basis).reshape(xs.shape)
    w = bin_weight(np.arange(n1)[None, :, None], js[:, None, None],
                   np.arange(n3)[None, None, :], model.shape, model.transform,
                   model.gain)
    if model.lobe is not None:  # a lobe transform: x from the coded values and the lobe
        xs = from_lobe(xs, w, lobe_rows(model.lobe, model.shape)[:, None, :, None])
    with np.errstate(over="ignore"):  # fit_lobe treats a non-finite profile
        rho = np.maximum(np.expm1(xs) / w, 0.0)  # (3, len(js), n1, n3)
    if model.floor > 0.0:  # a floor transform: 0 below its floor, as the decoders compare
        rho[rho.astype(np.float32) < np.float32(floor_value(model.floor, model.gain))] = 0.0
    return rho.mean(axis=3).sum(axis=(0, 1)) / (3 * js.size)


def _channel_slices(s, modes, us, js) -> np.ndarray:
    """X[:, j, :] (n1, n3) of one coded channel for each j of ``js``, float64."""
    u1, u2, u3 = (np.asarray(u, np.float64) for u in us)
    if s.size == 0:
        return np.zeros((js.size, u1.shape[0], u3.shape[0]))
    a_ids, ra = np.unique(modes[0], return_inverse=True)
    c_ids, rc = np.unique(modes[2], return_inverse=True)
    cell = ra * c_ids.size + rc
    m = np.stack([np.bincount(cell, np.asarray(s, np.float64) * u2[j, modes[1]],
                              a_ids.size * c_ids.size) for j in js])
    m = m.reshape(js.size, a_ids.size, c_ids.size)
    return u1[:, a_ids] @ m @ u3[:, c_ids].T


def table_profile(values: np.ndarray, n_d: int = 3) -> np.ndarray:
    """theta_h profile of tabulated values (n1, n2, n3, 3) for :func:`fit_lobe`."""
    return np.asarray(values[:, :n_d], np.float64).mean(axis=(1, 2, 3))
