"""A floor transform's floor: the level below which a material's decode is 0.

Measured tables hold exact zeros where a mirror-like or black material reflects nothing
(a fit's output clamped at 0). A log-domain code cannot reach 0: its small errors there
decode as small positive values, which HDR-FLIP under one light sees across the 18-28
stops it judges such a material over (``docs/method.md``, "Transforms"). The floor f (one
of :data:`~sparse_brdf.transforms.FLOORS`) sets every decoded value below f L to 0, L the
material's level; the encoder keeps the f whose decode is closest to the material in
relative terms, down to :data:`TAIL_REACH` L (:func:`choose_floor`).
"""

from __future__ import annotations

import numpy as np

from ..transforms import FLOORS, floor_value

#: How far below the material's level L the floor's criterion compares values: the
#: log ratio of a decoded value and the material's, each plus TAIL_REACH L.
TAIL_REACH = 1e-6


def tail_errors(ref: np.ndarray, dec: np.ndarray, gain: float,
                floors: tuple[float, ...] = FLOORS) -> np.ndarray:
    """The floor's criterion for each of ``floors``: the sum over the values of
    |ln((d + e) / (r + e))|, d the decode with that floor, r the material, e =
    :data:`TAIL_REACH` L (L = 1 / ``gain``).

    Only values that a floor can change (d below the largest floor) are read, so the
    cost is that of one comparison over the decode. The sums leave out the values no
    floor changes: they compare floors, they do not measure a model.

    Parameters
    ----------
    ref, dec : numpy.ndarray
        The material and its decode without a floor (1/sr), of one shape (e.g. the
        valid bins' R, G, B, (3, N)).
    gain : float
        The material's gain 1/L (sr).
    floors : tuple of float
        The floors compared, increasing.

    Returns
    -------
    numpy.ndarray
        float64 (len(floors),).
    """
    top = floor_value(max(floors), gain)
    low = dec < np.float32(top)
    d = dec[low].astype(np.float64)
    r = ref[low].astype(np.float64)
    e = TAIL_REACH / gain
    keep = np.abs(np.log((d + e) / (r + e)))
    zero = np.abs(np.log(e / (r + e)))
    order = np.argsort(d, kind="stable")
    # values below a floor's level become 0: the first of them in increasing order
    gain_of_zeroing = np.concatenate([[0.0], np.cumsum((zero - keep)[order])])
    cut = np.searchsorted(d[order], [floor_value(f, gain) for f in floors], side="left")
    return keep.sum() + gain_of_zeroing[cut]


def choose_floor(ref: np.ndarray, dec: np.ndarray, gain: float) -> float:
    """The floor (one of :data:`~sparse_brdf.transforms.FLOORS`) whose decode has the
    least :func:`tail_errors`; ties: the lowest. Arguments as :func:`tail_errors`."""
    return FLOORS[int(np.argmin(tail_errors(ref, dec, gain)))]


__all__ = ["TAIL_REACH", "choose_floor", "tail_errors"]
