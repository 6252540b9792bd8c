"""The BRDF transforms, with inverses: the paper's two (Tongbuasirilai et al., "A Sparse
Non-parametric BRDF Model", eq. 1 and 2) and their relative-precision twins
(``docs/method.md``, "Transforms").

- ``log-plus``:            t = ln(rho + 1),          rho = exp(t) - 1
- ``log-plus-cosine``:     t = ln(rho c + 1),        rho = (exp(t) - 1) / c,
  with c = clip(cos(theta_i) cos(theta_o), 0.01, 1) at the bin's angles;
- ``log-relative``:        t = ln(rho s + 1),        rho = (exp(t) - 1) / s,
- ``log-relative-cosine``: t = ln(rho c s + 1),      rho = (exp(t) - 1) / (c s),
  with s = :data:`RELATIVE_SCALE` (sr). ln(1 + x) is linear for x much below 1, so the
  paper's transforms code dim values (rho << 1/sr) with absolute precision: a coding
  error that is small beside a highlight is a large relative error where the material is
  dim, and a hue shift where one colour channel is dim. With s the logarithm reaches down
  to rho = 1/s, so errors are relative over the values materials have.

Every transform is t = ln(rho w + 1) with a weight w (:func:`weight`), declared once as
data (:data:`TRANSFORM_SPECS`: its scale and whether the cosine weighs it), which every
implementation reads: numpy here, the Dr.Jit kernels and the scalar variants' twins.

Arrays are channel-first, ``(..., n_h, n_d, n_p)``: the trailing three axes are the grid.
Invalid bins are set to rho = 0 before transforming; inverses clamp rho >= 0.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .coords import cosine_product
from .params import check_choice

#: The relative transforms' scale s (sr): values are coded relative to each other down to
#: rho = 1/s. Chosen by the one-light study of docs/method.md, "Transforms".
RELATIVE_SCALE = 300.0
#: The range the cosine transforms clip cos_i cos_o to.
COS_CLIP = (0.01, 1.0)


@dataclass(frozen=True)
class TransformSpec:
    """One transform as data, t = ln(rho w + 1) with w = ``scale`` times, if ``cosine``,
    clip(cos_i cos_o, *COS_CLIP): every implementation of the forward, the inverse and
    the weight (numpy here and in ``decoders.buffers``, Dr.Jit and the scalar twins in
    ``mitsuba_plugin``) reads these two numbers from :data:`TRANSFORM_SPECS`."""

    name: str
    scale: float  # s (sr), 1 for the paper's transforms
    cosine: bool  # weighted by the clipped cos_i cos_o of the bin


#: Every transform, in file-id order (a transform's index is its id in a ``.sbrdf``
#: header: append, never reorder).
TRANSFORM_SPECS: tuple[TransformSpec, ...] = (
    TransformSpec("log-plus", 1.0, False),
    TransformSpec("log-plus-cosine", 1.0, True),
    TransformSpec("log-relative", RELATIVE_SCALE, False),
    TransformSpec("log-relative-cosine", RELATIVE_SCALE, True),
)
_SPECS = {t.name: t for t in TRANSFORM_SPECS}
#: The transforms (declared choices of every ``transform`` parameter; ``encode`` adds
#: "auto", the one its selector prefers among those its ensemble was trained for).
TRANSFORMS: tuple[str, ...] = tuple(_SPECS)
#: The paper's two transforms: those of the ensembles trained before the relative ones.
PAPER_TRANSFORMS: tuple[str, str] = ("log-plus", "log-plus-cosine")


def transform_spec(name: str) -> TransformSpec:
    """The :class:`TransformSpec` of transform ``name`` (a UsageError if unknown)."""
    return _SPECS[check_transform(name)]


def uses_cosine(name: str) -> bool:
    """Whether transform ``name`` weighs rho by clip(cos_i cos_o, 0.01, 1)."""
    return transform_spec(name).cosine


def scale(name: str) -> float:
    """The constant factor of transform ``name``'s weight: :data:`RELATIVE_SCALE` for the
    relative transforms, 1 for the paper's."""
    return transform_spec(name).scale


def check_transform(name: str) -> str:
    """``name`` if it is one of :data:`TRANSFORMS`, else a
    :class:`~sparse_brdf.errors.UsageError` naming them."""
    return check_choice("transform", name, TRANSFORMS)


@functools.lru_cache(maxsize=8)
def cosine_weight(shape: tuple[int, int, int]) -> np.ndarray:
    """c = clip(cos_i cos_o, 0.01, 1) on the grid, float32, read-only."""
    c = np.clip(cosine_product(shape), *COS_CLIP).astype(np.float32)
    c.flags.writeable = False
    return c


def weight(name: str, shape: tuple[int, int, int]) -> np.ndarray | float:
    """The weight w of transform ``name`` (t = ln(rho w + 1)) on the grid ``shape``: a
    float32 array (n1, n2, n3) for the cosine transforms (read-only), else a float."""
    s = scale(name)
    if not uses_cosine(name):
        return s
    return cosine_weight(shape) if s == 1.0 else _scaled_cosine_weight(shape, s)


@functools.lru_cache(maxsize=8)
def _scaled_cosine_weight(shape: tuple[int, int, int], s: float) -> np.ndarray:
    w = cosine_weight(shape) * np.float32(s)
    w.flags.writeable = False
    return w



def forward(rho: np.ndarray, name: str, valid: np.ndarray | None = None) -> np.ndarray:
    """Transform linear BRDF values into the domain the dictionaries code.

    Parameters
    ----------
    rho : numpy.ndarray
        Linear BRDF values (1/sr), channel-first: shape (..., n_h, n_d, n_p).
    name : str
        One of :data:`TRANSFORMS`: ``"log-plus"`` (t = ln(rho + 1)), ``"log-plus-cosine"``
        (t = ln(rho c + 1), c = clip(cos_i cos_o, 0.01, 1) at each bin), or their
        relative twins ``"log-relative"`` (t = ln(rho s + 1)) and
        ``"log-relative-cosine"`` (t = ln(rho c s + 1)).
    valid : numpy.ndarray, optional
        Bool (n_h, n_d, n_p), broadcast over the leading axes: invalid bins are set to
        rho = 0 first. None: every bin as given.

    Returns
    -------
    numpy.ndarray
        float32, the shape of ``rho``.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`TRANSFORMS`.
    """
    rho = np.asarray(rho, dtype=np.float32)
    w = weight(name, rho.shape[-3:])
    if valid is None:
        t = rho * w
    else:  # invalid bins stay 0 (rho = 0 there), without a masked copy of rho
        t = np.zeros(rho.shape, np.float32)
        np.multiply(rho, w, out=t, where=np.asarray(valid, bool))
    return np.log1p(t, out=t)  # float32: rho and the weight are


def inverse(t: np.ndarray, name: str) -> np.ndarray:
    """Inverse of :func:`forward`: transformed values back to linear BRDF values.

    Parameters
    ----------
    t : numpy.ndarray
        Transformed values, channel-first: shape (..., n_h, n_d, n_p).
    name : str
        The transform they are in, one of :data:`TRANSFORMS`.

    Returns
    -------
    numpy.ndarray
        Linear BRDF values (1/sr), the shape of ``t``, clamped to >= 0.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`TRANSFORMS`.
    """
    t = np.asarray(t)
    return _inverse(t, weight(name, t.shape[-3:]))


def inverse_at_bins(
    t: np.ndarray, name: str, bins: tuple[np.ndarray, ...], shape: tuple[int, int, int]
) -> np.ndarray:
    """Inverse transform of values ``t`` (..., ) that belong to the bins ``(i, j, k)``."""
    w = weight(name, shape)
    return _inverse(np.asarray(t), w[bins] if isinstance(w, np.ndarray) else w)


#: Largest linear value an inverse gives: float32's largest. A model's overshoot beyond
#: it (an extreme but finite material) is clamped there instead of becoming inf.
RHO_MAX = float(np.finfo(np.float32).max)


def _inverse(t: np.ndarray, weight: np.ndarray | float) -> np.ndarray:
    with np.errstate(over="ignore"):  # clamped on the next line
        rho = np.expm1(t) / weight
    return np.clip(rho, 0.0, RHO_MAX).astype(np.float32)


#: Bases in which the three transformed colour channels can be coded: ``rgb`` codes R, G, B
#: as they are (the paper); ``opponent`` codes an orthonormal luminance / red-green /
#: yellow-blue mix of them, so most of a material's energy lands in one channel.
COLOUR_BASES: tuple[str, str] = ("rgb", "opponent")

_OPPONENT = np.array([[1, 1, 1], [1, -1, 0], [1, 1, -2]], np.float64) / np.sqrt(
    [[3.0], [2.0], [6.0]])


def check_basis(name: str) -> str:
    """``name`` if it is one of :data:`COLOUR_BASES`, else a
    :class:`~sparse_brdf.errors.UsageError` naming them."""
    return check_choice("colour basis", name, COLOUR_BASES)


def colour_matrix(basis: str) -> np.ndarray:
    """Orthonormal 3 x 3 matrix M (float64) of a colour basis: coded channels are
    M @ (transformed R, G, B) and back, (transformed R, G, B) = M.T @ coded."""
    return np.eye(3) if check_basis(basis) == "rgb" else _OPPONENT.copy()


def to_basis(t: np.ndarray, basis: str) -> np.ndarray:
    """Transformed channels (3, ...) -> coded channels (3, ...) in ``basis``, float32."""
    if basis == "rgb":
        return np.asarray(t, np.float32)
    m = colour_matrix(basis).astype(np.float32)
    return np.tensordot(m, np.asarray(t, np.float32), axes=1)


def from_basis(c: np.ndarray, basis: str) -> np.ndarray:
    """Coded channels (3, ...) in ``basis`` -> transformed channels (3, ...), float32."""
    if basis == "rgb":
        return np.asarray(c, np.float32)
    m = colour_matrix(basis).astype(np.float32)
    return np.tensordot(m.T, np.asarray(c, np.float32), axes=1)
