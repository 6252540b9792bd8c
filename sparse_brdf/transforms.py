"""The BRDF transforms, with inverses: the paper's two (Tongbuasirilai et al., "A Sparse
Non-parametric BRDF Model", eq. 1 and 2) and their relative-precision twins
(``docs/method.md``, "Transforms").

- ``log-plus``:            t = ln(rho + 1),          rho = exp(t) - 1
- ``log-plus-cosine``:     t = ln(rho c + 1),        rho = (exp(t) - 1) / c,
  with c = clip(cos(theta_i) cos(theta_o), 0.01, 1) at the bin's angles;
- ``log-relative``:        t = ln(rho s + 1),        rho = (exp(t) - 1) / s,
- ``log-relative-cosine``: t = ln(rho c s + 1),      rho = (exp(t) - 1) / (c s),
  with s = :data:`RELATIVE_SCALE` (sr);
- ``log-level``:           t = ln(rho k / L + 1),    rho = (exp(t) - 1) L / k,
- ``log-level-cosine``:    t = ln(rho c k / L + 1),  rho = (exp(t) - 1) L / (c k),
  with k = :data:`LEVEL_KNEE` and L the material's own level (:func:`material_level`,
  1/sr), stored in its file. ln(1 + x) is linear for x much below 1, so the
  paper's transforms code dim values (rho << 1/sr) with absolute precision: a coding
  error that is small beside a highlight is a large relative error where the material is
  dim, and a hue shift where one colour channel is dim. With s the logarithm reaches down
  to rho = 1/s, so errors are relative over the values materials have. The level
transforms put that knee at a fixed fraction of each material's own level instead of at
one value for all, so that a bright material's dim lobe and a dim material's highlight are
coded alike.

Every transform is t = ln(rho w + 1) with a weight w (:func:`weight`), declared once as
data (:data:`TRANSFORM_SPECS`: its scale, whether the cosine weighs it and whether a
material's own gain 1/L multiplies it), which every implementation reads: numpy here, the
Dr.Jit kernels and the scalar variants' twins.

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
#: The level transforms' knee k: t = ln(1 + k rho / L) is linear below rho = L / k and
#: logarithmic above, L the material's level. Chosen in docs/method.md, "Transforms".
LEVEL_KNEE = 3.0
#: The smallest level L (1/sr) a material is given: a black material keeps a finite gain.
LEVEL_FLOOR = 1e-4
#: Luminance weights of linear R, G, B (Rec. 709) for a material's level.
LUMINANCE = (0.2126, 0.7152, 0.0722)
#: The range the cosine transforms clip cos_i cos_o to.
COS_CLIP = (0.01, 1.0)


@dataclass(frozen=True)
class TransformSpec:
    """One transform as data, t = ln(rho w + 1) with w = ``scale`` times, if ``cosine``,
    clip(cos_i cos_o, *COS_CLIP), times, if ``per_material``, the material's gain 1/L
    (stored in its file): every implementation of the forward, the inverse and the
    weight (numpy here and in ``decoders.buffers``, Dr.Jit and the scalar twins in
    ``mitsuba_plugin``) reads these numbers from :data:`TRANSFORM_SPECS` and the gain from
    the material."""

    name: str
    scale: float  # s (sr), 1 for the paper's transforms; k (no unit) for the level ones
    cosine: bool  # weighted by the clipped cos_i cos_o of the bin
    per_material: bool = False  # weighted by the material's gain 1/L (sr)


#: Every transform, in file-id order (a transform's index is its id in a ``.sbrdf``
#: header: append, never reorder).
TRANSFORM_SPECS: tuple[TransformSpec, ...] = (
    TransformSpec("log-plus", 1.0, False),
    TransformSpec("log-plus-cosine", 1.0, True),
    TransformSpec("log-relative", RELATIVE_SCALE, False),
    TransformSpec("log-relative-cosine", RELATIVE_SCALE, True),
    TransformSpec("log-level", LEVEL_KNEE, False, True),
    TransformSpec("log-level-cosine", LEVEL_KNEE, True, True),
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


def per_material(name: str) -> bool:
    """Whether transform ``name``'s weight holds the material's own gain 1/L."""
    return transform_spec(name).per_material


def material_level(rho: np.ndarray, valid: np.ndarray | None = None) -> float:
    """A material's level L (1/sr): the median luminance of its valid bins, at least
    :data:`LEVEL_FLOOR`.

    Parameters
    ----------
    rho : numpy.ndarray
        Linear R, G, B (1/sr), channel-first: shape (3, ...), e.g. (3, n_h, n_d, n_p)
        or the (3, N) values of N samples.
    valid : numpy.ndarray, optional
        Bool, the shape of one channel: the bins that count; None: all of them.
    """
    rho = np.asarray(rho, np.float32)
    if rho.ndim < 1 or rho.shape[0] != 3:
        raise ValueError(f"a material's level needs its R, G, B on the first axis, got an "
                         f"array of shape {rho.shape}")
    lum = LUMINANCE[0] * rho[0] + LUMINANCE[1] * rho[1] + LUMINANCE[2] * rho[2]
    if valid is not None:
        lum = lum[np.asarray(valid, bool)]
    level = float(np.median(lum)) if lum.size else 0.0
    return max(level, LEVEL_FLOOR) if np.isfinite(level) else LEVEL_FLOOR


def material_gain(name: str, rho: np.ndarray, valid: np.ndarray | None = None) -> float:
    """The gain g = 1/L that transform ``name`` gives the material ``rho`` (channel-first
    linear R, G, B, 1/sr; ``valid`` as :func:`material_level`): float32-exact, 1 for
    the transforms without a per-material gain."""
    if not per_material(name):
        return 1.0
    return float(np.float32(1.0 / material_level(rho, valid)))


def check_gain(name: str, gain: float) -> float:
    """``gain`` as a float if transform ``name`` can have it: finite and > 0 for a
    per-material transform, exactly 1 for the others (a ValueError otherwise)."""
    g = float(gain)
    if per_material(name):
        if not (np.isfinite(g) and g > 0):
            raise ValueError(f"transform {name!r}: the material's gain must be finite and "
                             f"> 0, got {gain!r}")
    elif g != 1.0:
        raise ValueError(f"transform {name!r} has no per-material gain, got {gain!r}")
    return g


def scale(name: str) -> float:
    """The constant factor of transform ``name``'s weight: :data:`RELATIVE_SCALE` for the
    relative transforms, 1 for the paper's."""
    return transform_spec(name).scale


def material_scale(name: str, gain: float = 1.0) -> float:
    """The constant factor of transform ``name``'s weight for a material of gain ``gain``
    (:func:`check_gain`): its scale times the gain, rounded to float32 (the value every
    implementation multiplies by)."""
    return float(np.float32(scale(name) * check_gain(name, gain)))


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


def weight(name: str, shape: tuple[int, int, int], gain: float = 1.0
           ) -> np.ndarray | float:
    """The weight w of transform ``name`` (t = ln(rho w + 1)) on the grid ``shape`` for a
    material of gain ``gain`` (1/L, sr; 1 for the transforms without one): a float32
    array (n1, n2, n3) for the cosine transforms (read-only), else a float."""
    s = material_scale(name, gain)
    if not uses_cosine(name):
        return s
    return cosine_weight(shape) if s == 1.0 else _scaled_cosine_weight(shape, s)


@functools.lru_cache(maxsize=8)
def _scaled_cosine_weight(shape: tuple[int, int, int], s: float) -> np.ndarray:
    w = cosine_weight(shape) * np.float32(s)
    w.flags.writeable = False
    return w



def forward(rho: np.ndarray, name: str, valid: np.ndarray | None = None,
            gain: float | None = None) -> np.ndarray:
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
    gain : float, optional
        The material's gain 1/L for the level transforms; None: ``rho``'s own
        (:func:`material_gain`, ``rho`` then being one material's R, G, B).

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
    if gain is None:
        gain = material_gain(name, rho, valid)
    w = weight(name, rho.shape[-3:], gain)
    if valid is None:
        t = rho * w
    else:  # invalid bins stay 0 (rho = 0 there), without a masked copy of rho
        t = np.zeros(rho.shape, np.float32)
        np.multiply(rho, w, out=t, where=np.asarray(valid, bool))
    return np.log1p(t, out=t)  # float32: rho and the weight are


def inverse(t: np.ndarray, name: str, gain: float = 1.0) -> np.ndarray:
    """Inverse of :func:`forward`: transformed values back to linear BRDF values.

    Parameters
    ----------
    t : numpy.ndarray
        Transformed values, channel-first: shape (..., n_h, n_d, n_p).
    name : str
        The transform they are in, one of :data:`TRANSFORMS`.
    gain : float
        The material's gain 1/L (sr) for the level transforms; 1 for the others.

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
    return _inverse(t, weight(name, t.shape[-3:], gain))


def inverse_at_bins(
    t: np.ndarray, name: str, bins: tuple[np.ndarray, ...], shape: tuple[int, int, int],
    gain: float = 1.0,
) -> np.ndarray:
    """Inverse transform of values ``t`` (..., ) that belong to the bins ``(i, j, k)``,
    for a material of gain ``gain`` (:func:`inverse`)."""
    w = weight(name, shape, gain)
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
