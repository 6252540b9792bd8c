"""Measured BRDF samples: direction pairs and their linear RGB values (``docs/method.md``,
"Encoding from samples").

A :class:`Samples` holds N measurements, each a pair of unit directions (wi, wo) in the
local shading frame (z is the normal) and the BRDF's linear RGB value there (1/sr), with
an optional non-negative weight. Construction checks every row once (:func:`check`), so
that the encoders trust what they are given; the files they come from are read by
:mod:`sparse_brdf.acquisition.files`.

Duplicates: a direction pair that occurs more than once (the same wi and wo, or the pair
swapped, which reciprocity makes the same measurement) is kept, each row an independent
measurement: a least-squares fit then weighs their mean by their summed weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UsageError, short

#: How far from unit length a direction may be (relative): such directions are
#: normalised; farther ones are refused (a wrong column, degrees for cosines...).
UNIT_TOL = 1e-3
#: The largest sample value accepted (1/sr): far above any measured BRDF (grazing peaks of
#: the published fits reach about 1e6), and far enough below float32's range that the
#: decoded table of a fit through such values stays finite.
MAX_VALUE = 1e12


@dataclass
class Samples:
    """N BRDF measurements at arbitrary direction pairs.

    Attributes
    ----------
    wi, wo : ndarray of shape (N, 3), float64
        Unit directions of incidence and exit in the local frame (z up), both above the
        horizon (z > 0).
    rgb : ndarray of shape (N, 3), float64
        Linear RGB BRDF values (1/sr), finite and >= 0.
    weight : ndarray of shape (N,), float64
        Non-negative weight of each measurement in the fits (default 1); not all zero.
    name : str
        What the samples are of (a material name or file stem).
    source : str
        Where they came from (a file path), for messages.

    Raises
    ------
    UsageError
        On construction, for a row below the horizon, NaN or inf, a negative value or
        weight, a direction far from unit length, mismatched shapes or no samples; the
        message names ``source`` and the first bad row (rows count from 1).
    """

    wi: np.ndarray
    wo: np.ndarray
    rgb: np.ndarray
    weight: np.ndarray | None = None
    name: str = "samples"
    source: str = ""

    def __post_init__(self) -> None:
        self.wi, self.wo, self.rgb, self.weight = check(
            self.wi, self.wo, self.rgb, self.weight, self.source or self.name)

    def __len__(self) -> int:
        return int(self.wi.shape[0])

    def __repr__(self) -> str:
        return (f"Samples({short(self.name)!r}, {len(self)} pairs, "
                f"weighted={bool(np.any(self.weight != 1.0))})")

    def subset(self, rows: np.ndarray) -> Samples:
        """The samples of some rows.

        Parameters
        ----------
        rows : numpy.ndarray
            Row indices (int) or a bool mask of length N.

        Returns
        -------
        Samples
            Those rows, same name and source.
        """
        return Samples(self.wi[rows], self.wo[rows], self.rgb[rows], self.weight[rows],
                       self.name, self.source)


def _first_bad(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0]) + 1


def check(wi, wo, rgb, weight=None, source: str = "samples"):
    """The arrays of :class:`Samples`, checked and as float64 (directions normalised).

    Returns ``(wi, wo, rgb, weight)``; raises :class:`~sparse_brdf.errors.UsageError`
    naming ``source``, the problem and the first bad row (counted from 1).
    """
    arrays = {}
    for key, a, width in (("wi", wi, 3), ("wo", wo, 3), ("rgb", rgb, 3)):
        a = np.asarray(a, np.float64)
        if a.ndim != 2 or a.shape[1] != width:
            raise UsageError(f"{source}: {key} must have shape (N, {width}), got {a.shape}")
        arrays[key] = a
    n = arrays["wi"].shape[0]
    if n == 0:
        raise UsageError(f"{source}: no samples")
    w = np.ones(n) if weight is None else np.asarray(weight, np.float64).reshape(-1)
    for key, a in (*arrays.items(), ("weight", w)):
        if a.shape[0] != n:
            raise UsageError(f"{source}: {key} has {a.shape[0]} rows, wi has {n}")
        bad = ~np.isfinite(a).reshape(n, -1).all(axis=1)
        if bad.any():
            raise UsageError(f"{source}: row {_first_bad(bad)}: {key} is NaN or inf")
    for key in ("wi", "wo"):
        norm = np.linalg.norm(arrays[key], axis=1)
        bad = np.abs(norm - 1.0) > UNIT_TOL
        if bad.any():
            r = _first_bad(bad)
            raise UsageError(f"{source}: row {r}: {key} is not a unit vector (length "
                             f"{norm[r - 1]:.4g})")
        arrays[key] = arrays[key] / norm[:, None]
        bad = arrays[key][:, 2] <= 0.0
        if bad.any():
            raise UsageError(f"{source}: row {_first_bad(bad)}: {key} is below the horizon "
                             "(z <= 0; directions are in the local frame, z the normal)")
    for key, a in (("rgb", arrays["rgb"]), ("weight", w)):
        bad = (a.reshape(n, -1) < 0).any(axis=1)
        if bad.any():
            raise UsageError(f"{source}: row {_first_bad(bad)}: negative {key} value")
        bad = (a.reshape(n, -1) > MAX_VALUE).any(axis=1)
        if bad.any():
            r = _first_bad(bad)
            raise UsageError(f"{source}: row {r}: {key} value {a.reshape(n, -1)[r - 1].max():.3g}"
                             f" out of range (at most {MAX_VALUE:.0e}; a BRDF value is in 1/sr)")
    if not np.any(w > 0):
        raise UsageError(f"{source}: every weight is 0")
    return arrays["wi"], arrays["wo"], arrays["rgb"], w
