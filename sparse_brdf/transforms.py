"""The two BRDF transforms of the paper (Tongbuasirilai et al., "A Sparse Non-parametric
BRDF Model", eq. 1 and 2; ``docs/method.md``, "Transforms"), with inverses.

- ``log-plus``:        t = ln(rho + 1),      rho = exp(t) - 1
- ``log-plus-cosine``: t = ln(rho * c + 1),  rho = (exp(t) - 1) / c,
  with c = clip(cos(theta_i) cos(theta_o), 0.01, 1) at the bin's angles.

Arrays are channel-first, ``(..., n_h, n_d, n_p)``: the trailing three axes are the grid.
Invalid bins are set to rho = 0 before transforming; inverses clamp rho >= 0.
"""

from __future__ import annotations

import functools

import numpy as np

from .coords import cosine_product

TRANSFORMS: tuple[str, str] = ("log-plus", "log-plus-cosine")
COS_CLIP = (0.01, 1.0)


def check_transform(name: str) -> str:
    if name not in TRANSFORMS:
        raise ValueError(f"unknown transform {name!r}: expected one of {', '.join(TRANSFORMS)}")
    return name


@functools.lru_cache(maxsize=8)
def cosine_weight(shape: tuple[int, int, int]) -> np.ndarray:
    """c = clip(cos_i cos_o, 0.01, 1) on the grid, float32, read-only."""
    c = np.clip(cosine_product(shape), *COS_CLIP).astype(np.float32)
    c.flags.writeable = False
    return c


def _weight(name: str, shape: tuple[int, int, int]) -> np.ndarray | float:
    return cosine_weight(shape) if check_transform(name) == "log-plus-cosine" else 1.0


def forward(rho: np.ndarray, name: str, valid: np.ndarray | None = None) -> np.ndarray:
    """Transform linear BRDF values ``rho`` (..., n_h, n_d, n_p) -> float32 array."""
    rho = np.asarray(rho, dtype=np.float32)
    if valid is not None:
        rho = np.where(valid, rho, np.float32(0))
    return np.log1p(rho * _weight(name, rho.shape[-3:])).astype(np.float32)


def inverse(t: np.ndarray, name: str) -> np.ndarray:
    """Inverse transform: (..., n_h, n_d, n_p) -> linear BRDF values, clamped to >= 0."""
    t = np.asarray(t)
    return _inverse(t, _weight(name, t.shape[-3:]))


def inverse_at_bins(
    t: np.ndarray, name: str, bins: tuple[np.ndarray, ...], shape: tuple[int, int, int]
) -> np.ndarray:
    """Inverse transform of values ``t`` (..., ) that belong to the bins ``(i, j, k)``."""
    w = _weight(name, shape)
    return _inverse(np.asarray(t), w[bins] if isinstance(w, np.ndarray) else w)


def _inverse(t: np.ndarray, weight: np.ndarray | float) -> np.ndarray:
    return np.maximum(np.expm1(t) / weight, 0.0).astype(np.float32)
