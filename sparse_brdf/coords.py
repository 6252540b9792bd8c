"""Rusinkiewicz half/difference coordinates on the MERL grid (docs/method.md, "Grid").

All angles are in radians; all functions are vectorised over leading array axes.
The grid has ``shape = (n_h, n_d, n_p)`` bins, (90, 90, 180) for MERL; every function
takes the shape so that tests can use small grids (e.g. 18x18x36) with the same formulas.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .errors import UsageError
from .params import Interval, check

MERL_SHAPE: tuple[int, int, int] = (90, 90, 180)
#: A grid's side: at least 2 bins, at most 65535 (a ``.sbrdf`` header's 16 bits); a
#: grid holds at most the MERL grid's bins (:func:`check_grid`).
GRID_SIDE = Interval(int, 2, 0xFFFF)
#: Bins of a grid (and so coefficients of a channel): at most the MERL grid's.
GRID_BINS = Interval(int, 1, math.prod(MERL_SHAPE))


def check_grid(shape, name: str = "grid") -> tuple[int, int, int]:
    """``shape`` as a tuple of three ints if it is a usable grid (each side in
    :data:`GRID_SIDE`, at most :data:`GRID_BINS` bins), else a
    :class:`~sparse_brdf.errors.UsageError` naming ``name``."""
    shape = tuple(shape)
    if len(shape) != 3:
        raise UsageError(f"{name} must be three sides (n_h, n_d, n_p), got {shape!r}")
    out = tuple(check(f"{name} side", n, GRID_SIDE) for n in shape)
    if math.prod(out) not in GRID_BINS:
        raise UsageError(f"{name} {' '.join(map(str, out))}: {math.prod(out)} bins, at most "
                         f"{GRID_BINS.hi} (the MERL grid's)")
    return out  # type: ignore[return-value]
HALF_PI = np.pi / 2


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def dirs_to_angles(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wi, wo) unit vectors of shape (..., 3) in the local frame -> (theta_h, theta_d, phi_d).

    phi_d is returned in (-pi, pi]; :func:`angles_to_bins` folds it by reciprocity.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    h = _normalize(wi + wo)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    # d = R_y(-theta_h) R_z(-phi_h) wi
    cp, sp = np.cos(phi_h), np.sin(phi_h)
    x = cp * wi[..., 0] + sp * wi[..., 1]
    y = -sp * wi[..., 0] + cp * wi[..., 1]
    z = wi[..., 2]
    ct, st = np.cos(theta_h), np.sin(theta_h)
    dx = ct * x - st * z
    dz = st * x + ct * z
    theta_d = np.arccos(np.clip(dz, -1.0, 1.0))
    phi_d = np.arctan2(y, dx)
    return theta_h, theta_d, phi_d


def angles_to_dirs(
    theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(theta_h, theta_d, phi_d) -> (wi, wo), each of shape (..., 3), with phi_h = 0."""
    theta_h, theta_d, phi_d = np.broadcast_arrays(
        np.asarray(theta_h, dtype=np.float64),
        np.asarray(theta_d, dtype=np.float64),
        np.asarray(phi_d, dtype=np.float64),
    )
    h, d = half_diff_vectors(theta_h, theta_d, phi_d)
    ct, st = np.cos(theta_h), np.sin(theta_h)
    # wi = R_y(theta_h) d
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    wi = np.stack([ct * dx + st * dz, dy, -st * dx + ct * dz], -1)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def half_diff_vectors(
    theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian half vector h and difference vector d (phi_h = 0), each (..., 3)."""
    h = np.stack([np.sin(theta_h), np.zeros_like(theta_h), np.cos(theta_h)], -1)
    d = np.stack(
        [np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1
    )
    return h, d


def cos_io(
    theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """cos(theta_i), cos(theta_o) of a direction pair given by its angles."""
    a = np.cos(theta_d) * np.cos(theta_h)
    b = np.sin(theta_d) * np.cos(phi_d) * np.sin(theta_h)
    return a - b, a + b


def angles_to_bins(
    theta_h: np.ndarray,
    theta_d: np.ndarray,
    phi_d: np.ndarray,
    shape: tuple[int, int, int] = MERL_SHAPE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles -> integer bin indices (i_h, i_d, i_p), clamped; phi_d folded into [0, pi)."""
    n_h, n_d, n_p = shape
    th = np.maximum(np.asarray(theta_h, dtype=np.float64), 0.0)
    pd = np.asarray(phi_d, dtype=np.float64)
    pd = np.where(pd < 0.0, pd + np.pi, pd)
    x_h, x_d, x_p = grid_coords(th, np.asarray(theta_d, dtype=np.float64), pd, shape)
    i_h, i_d, i_p = np.floor(x_h), np.floor(x_d), np.floor(x_p)
    return (
        np.clip(i_h, 0, n_h - 1).astype(np.int64),
        np.clip(i_d, 0, n_d - 1).astype(np.int64),
        np.clip(i_p, 0, n_p - 1).astype(np.int64),
    )


def linear_neighbours(
    theta_h: np.ndarray,
    theta_d: np.ndarray,
    phi_d: np.ndarray,
    shape: tuple[int, int, int] = MERL_SHAPE,
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """The two grid samples around each angle, per axis, for trilinear interpolation.

    The grid's samples are the bins' lower-edge angles (:func:`grid_coords`); per axis
    ``(i0, i1, t)``: the samples below and above (int64) and the weight ``t`` of ``i1``
    (float64 in [0, 1]). theta_h and theta_d clamp at the grid's ends; phi_d (folded into
    [0, pi) by reciprocity first) wraps around with period pi, as the Mitsuba plugins'
    interpolated lookup does.
    """
    th = np.maximum(np.asarray(theta_h, dtype=np.float64), 0.0)
    pd = np.asarray(phi_d, dtype=np.float64)
    pd = np.where(pd < 0.0, pd + np.pi, pd)
    out = []
    for axis, (x, n) in enumerate(zip(grid_coords(th, np.asarray(theta_d, np.float64), pd,
                                                  shape), shape, strict=True)):
        if axis < 2:
            x = np.clip(x, 0.0, n - 1.0)
            i0 = np.minimum(np.floor(x), max(n - 2, 0))
            t = np.clip(x - i0, 0.0, 1.0)
            i0 = i0.astype(np.int64)
            i1 = np.minimum(i0 + 1, n - 1)
        else:
            x = np.clip(x, 0.0, float(n))
            f0 = np.floor(x)
            t = np.where(f0 >= n, 1.0, x - f0)  # x = n is the sample at 0
            i0 = np.minimum(f0, n - 1).astype(np.int64)
            i1 = (i0 + 1) % n
        out.append((i0, i1, t))
    return tuple(out)


def dirs_to_bins(
    wi: np.ndarray, wo: np.ndarray, shape: tuple[int, int, int] = MERL_SHAPE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wi, wo) of shape (..., 3) -> bin indices (i_h, i_d, i_p)."""
    return angles_to_bins(*dirs_to_angles(wi, wo), shape=shape)


def grid_coords(theta_h, theta_d, phi_d, shape=MERL_SHAPE, sqrt=np.sqrt):
    """Continuous grid coordinates (x_h, x_d, x_p) of angles: the inverse of :func:`bin_angles`.

    The bins' edges are theta_h = (i / n_h)^2 pi/2 (finer near the specular peak),
    theta_d = j / n_d pi/2 and phi_d = k / n_p pi, so x_h = sqrt(theta_h / (pi/2)) n_h,
    x_d = theta_d / (pi/2) n_d and x_p = phi_d / pi n_p: floor(x) is the bin (before
    clamping), x itself the position between the bins' lower-edge samples. Expects
    theta_h >= 0 and phi_d folded into [0, pi). Only arithmetic and ``sqrt``, so the
    Mitsuba plugins' lookup traces it on Dr.Jit arrays too (``sqrt=dr.sqrt``, ``shape``
    as three Dr.Jit scalars); :func:`angles_to_bins` is its numpy use.
    """
    n_h, n_d, n_p = shape
    return sqrt(theta_h / HALF_PI) * n_h, theta_d / HALF_PI * n_d, phi_d / np.pi * n_p


def bin_edges(
    shape: tuple[int, int, int] = MERL_SHAPE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges of the bins along each axis, three 1-D arrays of n_h + 1, n_d + 1, n_p + 1
    angles (radians): theta_h = (i / n_h)^2 pi/2, theta_d = j / n_d pi/2, phi_d = k / n_p pi."""
    n_h, n_d, n_p = shape
    theta_h = (np.arange(n_h + 1) / n_h) ** 2 * HALF_PI
    theta_d = np.arange(n_d + 1) / n_d * HALF_PI
    phi_d = np.arange(n_p + 1) / n_p * np.pi
    return theta_h, theta_d, phi_d


def bin_angles(
    shape: tuple[int, int, int] = MERL_SHAPE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower-edge angles of every bin, as three 1-D arrays (theta_h, theta_d, phi_d);
    :func:`grid_coords` is the inverse map."""
    return tuple(e[:-1] for e in bin_edges(shape))


def grid_angles(
    shape: tuple[int, int, int] = MERL_SHAPE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin angles broadcast to the full grid, each of shape ``shape``."""
    th, td, pd = bin_angles(shape)
    return np.meshgrid(th, td, pd, indexing="ij")


@functools.lru_cache(maxsize=8)
def _cosines(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    th, td, pd = bin_angles(shape)  # broadcast: the trigonometry runs on each axis once
    ci, co = cos_io(th[:, None, None], td[None, :, None], pd[None, None, :])
    prod, valid = ci * co, (ci > 0.0) & (co > 0.0)
    prod.flags.writeable = False
    valid.flags.writeable = False
    return prod, valid


def cosine_product(shape: tuple[int, int, int] = MERL_SHAPE) -> np.ndarray:
    """cos(theta_i) * cos(theta_o) at every bin's angles, float64 array of ``shape``
    (cached, read-only)."""
    return _cosines(tuple(shape))[0]


def geometric_valid(shape: tuple[int, int, int] = MERL_SHAPE) -> np.ndarray:
    """Bins whose two directions are both above the horizon, bool array of ``shape``
    (a fresh, writable copy)."""
    return _cosines(tuple(shape))[1].copy()


def bin_solid_angle(shape: tuple[int, int, int] = MERL_SHAPE) -> np.ndarray:
    """Measure of each grid bin in (wi, wo) space (sr^2), float64 array of ``shape``.

    d(wi) d(wo) = 4 cos(theta_d) sin(theta_h) sin(theta_d) d(theta_h) d(phi_h) d(theta_d)
    d(phi_d), integrated exactly over each bin's angle ranges (:func:`bin_edges`),
    phi_h over 2 pi and phi_d doubled for the reciprocal half folded onto [0, pi). The
    first theta_h bins of the MERL grid are tiny (the square-root spacing): bin 0
    measures ~1e-11 of bin 45.
    """
    return np.repeat(bin_solid_angle_hd(shape)[:, :, None], shape[2], axis=2)


def bin_solid_angle_hd(shape: tuple[int, int, int] = MERL_SHAPE) -> np.ndarray:
    """:func:`bin_solid_angle` of the bins (i_h, i_d, any i_p): it does not depend on
    phi_d. float64, shape (n_h, n_d) (sr^2)."""
    n3 = shape[2]
    th, td, _ = bin_edges(shape)
    per_h = np.cos(th[:-1]) - np.cos(th[1:])
    per_d = 0.5 * (np.sin(td[1:]) ** 2 - np.sin(td[:-1]) ** 2)
    return (4.0 * 2.0 * np.pi * 2.0 * np.pi / n3) * per_h[:, None] * per_d[None, :]


def linear_bins(wi: np.ndarray, wo: np.ndarray, shape: tuple[int, int, int] = MERL_SHAPE
                ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """Per mode (i0, i1, t): the two lower-edge samples around each direction pair and the
    weight of i1, for linear interpolation between the bins' samples (docs/method.md,
    "Interpolation between bins"); the numpy twin of the plugins' lookup.

    Parameters
    ----------
    wi, wo : numpy.ndarray
        Unit directions in the local frame (z up), shape (N, 3).
    shape : tuple of int
        The grid (n_h, n_d, n_p).

    Returns
    -------
    tuple of 3 (i0, i1, t)
        Int64 arrays i0, i1 and float64 t in [0, 1], each (N,), for theta_h, theta_d and
        phi_d: the value at a pair is (1 - t) v[i0] + t v[i1] along each mode. theta_h and
        theta_d clamp at the grid's ends; phi_d wraps around (period pi: phi_d = pi is
        phi_d = 0 by reciprocity).
    """
    return linear_neighbours(*dirs_to_angles(wi, wo), shape)
