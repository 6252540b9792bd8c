"""Fingerprints of computed arrays: tell a real change of the data from rounding.

Computed floats differ between machines in their last bits: numpy picks SIMD kernels for
the CPU it finds, OpenBLAS its BLAS kernels, and Dr.Jit's LLVM backend compiles for the
host's vector width. A hash of the bytes cannot tell that from a real change of the data.
A fingerprint keeps a few float64 statistics of an array instead, and two fingerprints
match when every statistic agrees within a relative tolerance of the array's scale:

- ``sum``: the sum of the values (scale: the L2 norm times sqrt(size), which bounds how
  far a change of that norm can move the sum);
- ``l2``: the L2 norm (scale: itself);
- ``max``: the largest value (scale: its magnitude);
- ``proj0`` .. ``proj3``: the values projected on four seeded random unit vectors (scale:
  the L2 norm, which bounds the change of a projection).

An array computed as a small difference of larger ones (an opponent colour channel)
rounds as they do: its comparison can take their scale instead of its own.

Rounding moves each float32 value by about 1e-7 of itself; measured on the shipped
default's training data with numpy, OpenBLAS and Dr.Jit on another CPU's kernels, it
moved the statistics by at most 2.6e-6 of their scale. :data:`FINGERPRINT_RTOL` allows
1e-4. A change of the data itself (another transform scale, another network, a lost
symmetrisation) moves most values by far more: a 0.1 % change of one tensor moves its
norm by 1e-3. A change confined to a few bins can hide below the tolerance: the
fingerprint is a check of the whole array, not of each bin.
"""

from __future__ import annotations

import functools

import numpy as np

#: The statistics of :func:`fingerprint`, in the order of :func:`fingerprint_list`.
FINGERPRINT_STATS: tuple[str, ...] = ("sum", "l2", "max", "proj0", "proj1", "proj2", "proj3")

#: Relative tolerance of :func:`fingerprint_changes`, of each statistic's scale (see the
#: module's doc): 40 times the largest rounding measured on another CPU's kernels, ten
#: times below a 0.1 % change of a tensor.
FINGERPRINT_RTOL = 1e-4

#: The seed of the random projections (fixed: fingerprints are compared across runs).
PROJECTION_SEED = 20261207


@functools.lru_cache(maxsize=4)
def _projections(size: int) -> np.ndarray:
    """Four seeded random unit vectors of ``size`` entries, (4, size) float64.

    numpy's PCG64 and its normal sampler give the same numbers on every machine.
    """
    r = np.random.default_rng(PROJECTION_SEED).standard_normal((4, size))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    r.flags.writeable = False
    return r


def fingerprint(x: np.ndarray) -> dict[str, float]:
    """The fingerprint of an array.

    Parameters
    ----------
    x : numpy.ndarray
        Any shape, real values (read as float64).

    Returns
    -------
    dict
        {statistic: float} for each of :data:`FINGERPRINT_STATS`.
    """
    v = np.asarray(x, np.float64).ravel()
    proj = _projections(v.size) @ v
    stats = (v.sum(), np.sqrt(v @ v), v.max(initial=0.0) if v.size else 0.0, *proj)
    return {k: float(s) for k, s in zip(FINGERPRINT_STATS, stats, strict=True)}


def fingerprint_list(x: np.ndarray) -> list[float]:
    """:func:`fingerprint` as a list, in the order of :data:`FINGERPRINT_STATS`, each
    statistic rounded to 9 significant digits (compact in JSON; 1e-9 is far below
    :data:`FINGERPRINT_RTOL`)."""
    return [float(f"{v:.9g}") for v in fingerprint(x).values()]


def _scales(scale: dict[str, float], size: int) -> dict[str, float]:
    """How far each statistic may move, per unit of relative tolerance, for an array of
    ``size`` values whose L2 norm and largest magnitude are ``scale["l2"]`` and
    ``scale["max"]``."""
    l2 = abs(scale["l2"])
    return {"sum": l2 * np.sqrt(max(size, 1)), "l2": l2, "max": abs(scale["max"]),
            **{k: l2 for k in FINGERPRINT_STATS if k.startswith("proj")}}


def fingerprint_changes(
    got: dict[str, float] | list[float],
    want: dict[str, float] | list[float],
    size: int,
    rtol: float = FINGERPRINT_RTOL,
    scale: dict[str, float] | None = None,
) -> list[str]:
    """The statistics that moved beyond the tolerance, each as a short phrase.

    Parameters
    ----------
    got, want : dict or list
        Fingerprints (:func:`fingerprint` or :func:`fingerprint_list`) of the array now
        and as stored.
    size : int
        The number of values of the array.
    rtol : float
        The relative tolerance, of each statistic's scale.
    scale : dict, optional
        ``{"l2": ..., "max": ...}``: the magnitudes the array was computed from, when
        larger than its own (a difference of two channels rounds as they do); default
        ``want``'s own L2 norm and largest magnitude.

    Returns
    -------
    list of str
        Empty when the fingerprints match; else one phrase per statistic that moved, e.g.
        ``"sum 1523.2 -> 1530.9 (5.1e-04 of its scale; tolerance 1e-05)"``.
    """
    got, want = (dict(zip(FINGERPRINT_STATS, f, strict=True)) if not isinstance(f, dict)
                 else f for f in (got, want))
    changes = []
    for k, unit in _scales(scale or want, size).items():
        moved = abs(got[k] - want[k])
        if not moved <= rtol * unit + 1e-30:  # also catches NaN
            rel = moved / unit if unit else float("inf")
            changes.append(f"{k} {want[k]:.9g} -> {got[k]:.9g} ({rel:.1e} of its scale; "
                           f"tolerance {rtol:.0e})")
    return changes
