"""Where to measure, and simulated measurements (``docs/method.md``, "Encoding from
samples").

- Placements (:data:`PLACEMENTS`, :func:`plan`): ``uniform`` direction pairs (each
  direction uniform in solid angle over the hemisphere), ``stratified`` (jittered strata of
  the grid's own coordinates: theta_h on its square-root scale, so dense near the specular
  peak where the atoms vary fastest, theta_d and phi_d uniform) and ``bins`` (random valid
  bins at their lower-edge angles, the grid's sample positions). Each pair is rotated by a
  random phi_h, as a measurement would be (``bins`` keeps one pair of the degenerate bins
  at theta_d = 0, where every phi_d is the same pair).
- Simulated measurements: :func:`measure_table` (a tabulated BRDF at the pairs' bins),
  :func:`measure_nbrdf` (a Neural-BRDF network at the pairs themselves), :func:`add_noise`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coords import (
    MERL_SHAPE,
    angles_to_dirs,
    bin_angles,
    cos_io,
    dirs_to_angles,
    geometric_valid,
    half_diff_vectors,
    linear_bins,
)
from ..errors import UsageError
from ..mlp import evaluate
from ..params import check_choice
from ..sources.nbrdf import read_nbrdf_weights
from .measurements import Samples

#: Where :func:`plan` puts direction pairs.
PLACEMENTS = ("uniform", "stratified", "bins")


# ------------------------------------------------------------------------ placements


def _rotate(wi: np.ndarray, wo: np.ndarray, rng: np.random.Generator):
    """Both directions of each pair rotated about the normal by one random angle; pairs
    whose half vector is the normal are left as they are (their phi_h is undefined, so a
    rotation would move phi_d instead: the same value for an isotropic BRDF, another bin
    of a table)."""
    a = rng.uniform(0.0, 2 * np.pi, wi.shape[0])
    h = wi + wo
    a = np.where(np.hypot(h[:, 0], h[:, 1]) <= 1e-12 * np.linalg.norm(h, axis=1), 0.0, a)
    c, s = np.cos(a), np.sin(a)

    def rot(v):
        return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], 1)

    return rot(wi), rot(wo)


def _hemisphere(n: int, rng: np.random.Generator) -> np.ndarray:
    z = 1.0 - rng.random(n)  # (0, 1]: uniform in solid angle, never on the horizon
    phi = rng.uniform(0.0, 2 * np.pi, n)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _stratified(n: int, shape: tuple[int, int, int], rng: np.random.Generator):
    """Jittered strata of the grid coordinates (x_h, x_d, x_p), each axis's strata
    shuffled independently (a Latin hypercube), pairs below the horizon drawn again."""
    out = []
    while sum(len(a) for a, _ in out) < n:
        m = 2 * n
        x = [(rng.permutation(m) + rng.random(m)) / m for _ in range(3)]
        th, td, pd = (x[0] ** 2) * np.pi / 2, x[1] * np.pi / 2, x[2] * np.pi
        ci, co = cos_io(th, td, pd)
        keep = (ci > 1e-3) & (co > 1e-3)
        wi, wo = angles_to_dirs(th[keep], td[keep], pd[keep])
        out.append((wi, wo))
    wi, wo = (np.concatenate(a)[:n] for a in zip(*out, strict=True))
    return wi, wo


def _bins(n: int, shape: tuple[int, int, int], rng: np.random.Generator):
    """Random valid bins at their lower-edge angles; of the bins at theta_d = 0 (wi = wo,
    the same pair at every phi_d) only phi_d = 0."""
    ok = geometric_valid(shape)
    ok[:, 0, 1:] = False
    valid = np.flatnonzero(ok.ravel())
    pick = rng.choice(valid, size=min(n, valid.size), replace=False)
    i, j, k = np.unravel_index(pick, shape)
    th, td, pd = bin_angles(shape)
    return angles_to_dirs(th[i], td[j], pd[k])


def plan(n: int, placement: str = "stratified", seed: int = 0,
         shape: tuple[int, int, int] = MERL_SHAPE) -> tuple[np.ndarray, np.ndarray]:
    """Direction pairs to measure.

    Parameters
    ----------
    n : int
        How many pairs (at least 1; ``bins`` gives at most the grid's valid bins).
    placement : str
        ``"uniform"``, ``"stratified"`` or ``"bins"`` (:data:`PLACEMENTS`, module doc).
    seed : int
        The same seed gives the same pairs.
    shape : tuple of int
        The grid the ``stratified`` and ``bins`` placements follow.

    Returns
    -------
    (wi, wo) : two ndarrays of shape (n, 3), float64
        Unit directions above the horizon, in the local frame (z up).
    """
    check_choice("placement", placement, PLACEMENTS)
    if n < 1:
        raise UsageError(f"placement of {n} samples: at least 1")
    rng = np.random.default_rng(seed)
    if placement == "uniform":
        wi, wo = _hemisphere(n, rng), _hemisphere(n, rng)
    elif placement == "stratified":
        wi, wo = _stratified(n, shape, rng)
    else:
        wi, wo = _bins(n, shape, rng)
    wi, wo = _rotate(wi, wo, rng)
    # rotation keeps z; clip rounding so that every direction stays above the horizon
    return wi / np.linalg.norm(wi, axis=1, keepdims=True), wo / np.linalg.norm(
        wo, axis=1, keepdims=True)


# ------------------------------------------------------------ simulated measurements


def measure_table(brdf: BRDF, wi: np.ndarray, wo: np.ndarray) -> Samples:
    """A tabulated BRDF's values at direction pairs: each pair's bin (the grid's lookup),
    as measured samples (exact at the bins' lower-edge angles, ``plan(placement="bins")``:
    a pair within 1e-6 of a bin's lower edge, in grid units, belongs to that bin, so that
    rounding in the angles does not move it to the bin below).

    Parameters
    ----------
    brdf : BRDF
        The material.
    wi, wo : numpy.ndarray
        Unit directions (N, 3) above the horizon.

    Returns
    -------
    Samples
        The pairs with the table's values, named after the material.
    """
    b = tuple(np.where(t > 1.0 - 1e-6, i1, i0) for i0, i1, t in linear_bins(wi, wo, brdf.shape))
    return Samples(wi, wo, brdf.values[b].astype(np.float64), name=brdf.name,
                   source=brdf.source)


def measure_nbrdf(path: str | os.PathLike, wi: np.ndarray, wo: np.ndarray) -> Samples:
    """A Neural-BRDF network's values at direction pairs themselves (not at their bins).

    Parameters
    ----------
    path : str or path-like
        The network's ``.h5`` file.
    wi, wo : numpy.ndarray
        Unit directions (N, 3) above the horizon.

    Returns
    -------
    Samples
        The pairs with the network's values, named by the file's stem.
    """
    layers = read_nbrdf_weights(path)
    th, td, pd = dirs_to_angles(wi, wo)
    pd = np.where(pd < 0.0, pd + np.pi, pd)  # the network was tabulated on [0, pi)
    h, d = half_diff_vectors(th, td, pd)
    rgb = evaluate(layers, np.concatenate([h, d], axis=-1)).astype(np.float64)
    return Samples(wi, wo, rgb, name=Path(path).stem, source=os.fspath(path))


def add_noise(samples: Samples, relative: float, seed: int = 0) -> Samples:
    """Samples with multiplicative Gaussian noise: each value times (1 + relative z),
    z ~ N(0, 1), clamped at 0.

    Parameters
    ----------
    samples : Samples
        The measurements.
    relative : float
        The noise's standard deviation relative to each value (e.g. 0.02).
    seed : int
        The noise's seed.

    Returns
    -------
    Samples
        The same pairs, noisy values.
    """
    rng = np.random.default_rng(seed)
    rgb = np.maximum(samples.rgb * (1.0 + relative * rng.standard_normal(samples.rgb.shape)),
                     0.0)
    return Samples(samples.wi, samples.wo, rgb, samples.weight, samples.name, samples.source)
