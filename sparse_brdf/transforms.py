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
  1/sr), stored in its file;
- ``log-lobe``:            t = m (ln(rho W + 1) - ln(b W + 1)),  m = ((b W + 1) / K)^G,
- ``log-lobe-cosine``:     the same with W holding c,
  with W = K [c] / L, K = :data:`LOBE_KNEE`, G = :data:`LOBE_POWER` and b the material's
  base lobe (:func:`fit_base_lobe`: b = kd + ks D(theta_h; alpha), GGX, per channel),
  stored in its file with L;
- ``log-lobe-floor``, ``log-lobe-floor-cosine``: the lobe pair, whose inverse gives 0
  where rho < f L, f the material's floor (one of :data:`FLOORS`, stored in its file).
  Measured tables hold exact zeros (a fit's output clamped at 0) where a mirror-like
  material reflects nothing; a log-domain code cannot reach 0, and under one light its
  small positive errors there show across the 18-28 stops HDR-FLIP judges.

ln(1 + x) is linear for x much below 1, so the paper's transforms code dim values (rho <<
1/sr) with absolute precision: a coding error that is small beside a highlight is a large
relative error where the material is dim, and a hue shift where one colour channel is dim.
With s the logarithm reaches down to rho = 1/s, so errors are relative over the values
materials have. The level transforms put that knee at a fixed fraction of each material's
own level instead of at one value for all, so that a bright material's dim lobe and a dim
material's highlight are coded alike. The lobe transforms code each material relative to a
lobe fitted to it: the lobe carries the narrow bright peak that dictionaries code least
compactly, the ratio keeps coding errors relative down to L / K, and m weighs them toward
where the lobe is bright, where light reflected from an environment is.

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

from .coords import bin_angles, cosine_product
from .params import check_choice

#: The relative transforms' scale s (sr): values are coded relative to each other down to
#: rho = 1/s. Chosen by the one-light study of docs/method.md, "Transforms".
RELATIVE_SCALE = 300.0
#: The level transforms' knee k: t = ln(1 + k rho / L) is linear below rho = L / k and
#: logarithmic above, L the material's level. Chosen in docs/method.md, "Transforms".
LEVEL_KNEE = 3.0
#: The lobe transforms' knee K: their ratio is logarithmic down to L / K, L the material's
#: level. Chosen in docs/method.md, "Transforms".
LOBE_KNEE = 100.0
#: The lobe transforms' power G: a coded value is the log ratio times ((b W + 1) / K)^G.
LOBE_POWER = 0.35
#: The roughness values among which a material's base lobe takes its alpha.
LOBE_ALPHAS = tuple(float(a) for a in np.geomspace(0.003, 0.6, 30))
#: Numbers of a base lobe, in its file's order: alpha, kd (R, G, B), ks (R, G, B).
LOBE_SIZE = 7
#: The floors f a floor transform's material can have (float16-exact): its inverse gives 0
#: where rho < f L. Chosen per material by the encoder (``coding.floor``).
FLOORS = tuple(float(np.float16(f)) for f in (0.0, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1))
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
    lobe: bool = False  # coded relative to the material's base lobe (its file holds it)
    floor: bool = False  # values below the material's floor f L decode as 0 (file holds f)


#: Every transform, in file-id order (a transform's index is its id in a ``.sbrdf``
#: header: append, never reorder).
TRANSFORM_SPECS: tuple[TransformSpec, ...] = (
    TransformSpec("log-plus", 1.0, False),
    TransformSpec("log-plus-cosine", 1.0, True),
    TransformSpec("log-relative", RELATIVE_SCALE, False),
    TransformSpec("log-relative-cosine", RELATIVE_SCALE, True),
    TransformSpec("log-level", LEVEL_KNEE, False, True),
    TransformSpec("log-level-cosine", LEVEL_KNEE, True, True),
    TransformSpec("log-lobe", LOBE_KNEE, False, True, True),
    TransformSpec("log-lobe-cosine", LOBE_KNEE, True, True, True),
    TransformSpec("log-lobe-floor", LOBE_KNEE, False, True, True, True),
    TransformSpec("log-lobe-floor-cosine", LOBE_KNEE, True, True, True, True),
)
_SPECS = {t.name: t for t in TRANSFORM_SPECS}
#: The transforms (declared choices of every ``transform`` parameter; ``encode`` adds
#: "auto", the one its selector prefers among those its ensemble was trained for).
TRANSFORMS: tuple[str, ...] = tuple(_SPECS)
#: The paper's two transforms: those of the ensembles trained before the relative ones.
PAPER_TRANSFORMS: tuple[str, str] = ("log-plus", "log-plus-cosine")
#: The lobe pair: what ``encode(transform="lobe")`` chooses between, over any ensemble
#: (with a floor since 2026-12-08; ``log-lobe`` and ``log-lobe-cosine`` are the pair
#: without one, as files written before hold).
LOBE_TRANSFORMS: tuple[str, str] = ("log-lobe-floor", "log-lobe-floor-cosine")


def transform_spec(name: str) -> TransformSpec:
    """The :class:`TransformSpec` of transform ``name`` (a UsageError if unknown)."""
    return _SPECS[check_transform(name)]


def uses_cosine(name: str) -> bool:
    """Whether transform ``name`` weighs rho by clip(cos_i cos_o, 0.01, 1)."""
    return transform_spec(name).cosine


def per_material(name: str) -> bool:
    """Whether transform ``name``'s weight holds the material's own gain 1/L."""
    return transform_spec(name).per_material


def has_lobe(name: str) -> bool:
    """Whether transform ``name`` codes a material relative to its base lobe."""
    return transform_spec(name).lobe


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


# ---------------------------------------------------------------------- the base lobe


def has_floor(name: str) -> bool:
    """Whether transform ``name``'s inverse gives 0 below the material's floor."""
    return transform_spec(name).floor


def check_floor(name: str, floor: float) -> float:
    """``floor`` as a float if transform ``name`` can have it: finite, in [0, 1) and
    float16-exact for a floor transform, 0 for the others. A ValueError otherwise."""
    f = float(floor)
    if not has_floor(name):
        if f != 0.0:
            raise ValueError(f"transform {name!r} has no floor, got {floor!r}")
        return 0.0
    if not (0.0 <= f < 1.0) or float(np.float16(f)) != f:
        raise ValueError(f"transform {name!r}: a floor is a float16 value in [0, 1), "
                         f"got {floor!r}")
    return f


def floor_value(floor: float, gain: float) -> float:
    """The linear value (1/sr) below which a material of floor ``floor`` and gain ``gain``
    (1/L) decodes as 0: f L, rounded to float32 once, as every decoder compares it."""
    return float(np.float32(floor / gain))


def apply_floor(rho: np.ndarray, floor: float, gain: float) -> np.ndarray:
    """``rho`` (float32, any shape) with every value below :func:`floor_value` set to 0,
    in place; unchanged for ``floor`` 0."""
    if floor > 0.0:
        rho[rho < np.float32(floor_value(floor, gain))] = 0.0
    return rho


def ggx(theta_h, alpha):
    """The GGX (Trowbridge-Reitz) distribution D(theta_h; alpha) = alpha^2 / (pi
    (alpha^2 cos^2 theta_h + sin^2 theta_h)^2) (1/sr), at the angles ``theta_h`` (rad,
    broadcast with ``alpha``). Written with the sine, as the kernels read it from their
    angle tables: near theta_h = 0 a float32 cosine rounds to 1."""
    a2 = np.asarray(alpha, np.float64) ** 2
    th = np.asarray(theta_h, np.float64)
    den = a2 * np.cos(th) ** 2 + np.sin(th) ** 2
    return a2 / (np.pi * den * den)


def lobe_rows(lobe, shape: tuple[int, int, int]) -> np.ndarray:
    """The base lobe b = kd + ks D(theta_h; alpha) of each channel at each theta_h row
    of the grid (its lower-edge angle, as every bin's weight): float64 (3, n1), 1/sr.

    Parameters
    ----------
    lobe : sequence of 7 floats
        alpha, kd (R, G, B), ks (R, G, B) (:func:`check_lobe`).
    shape : tuple of int
        The grid (n1, n2, n3).
    """
    alpha, kd, ks = float(lobe[0]), np.asarray(lobe[1:4], np.float64), \
        np.asarray(lobe[4:7], np.float64)
    return kd[:, None] + ks[:, None] * ggx(bin_angles(shape)[0], alpha)[None, :]


def fit_base_lobe(rho: np.ndarray, valid: np.ndarray | None = None,
                  level: float | None = None) -> tuple[float, ...]:
    """A material's base lobe: per channel b = kd + ks D(theta_h; alpha), kd, ks >= 0,
    one alpha of :data:`LOBE_ALPHAS`, rounded to float16 (as stored). For each alpha, kd
    and ks are the least-squares fit relative to the material's brightness (weights
    1 / (mean_c rho + L) per bin); the alpha kept is the one whose lobe is closest to the
    material in the lobe transforms' logarithm: the least sum over the valid bins of
    (ln(rho W + 1) - ln(b W + 1))^2, W = K / L. The relative fit alone keeps the broad
    shoulder of a mirror-like material and misses its peak by a factor of 600
    (``docs/method.md``, "Transforms").

    The lobe depends on theta_h only, so both steps reduce each theta_h row to a few sums
    and solve the two-unknown nonnegative problems exactly, every alpha at once.

    Parameters
    ----------
    rho : numpy.ndarray
        Linear R, G, B (1/sr), channel-first: (3, n1, n2, n3).
    valid : numpy.ndarray, optional
        Bool (n1, n2, n3): the bins fitted; None: all.
    level : float, optional
        The material's level L (1/sr); None: :func:`material_level`.

    Returns
    -------
    tuple of 7 floats
        alpha, kd (R, G, B), ks (R, G, B), float16-exact.
    """
    rho = np.asarray(rho, np.float32)
    mask = np.ones(rho.shape[1:], bool) if valid is None else np.asarray(valid, bool)
    if level is None:
        level = material_level(rho, mask)
    n1 = rho.shape[1]
    r = np.where(mask, np.maximum(rho, np.float32(0)), np.float32(0)).reshape(3, n1, -1)
    w2 = r.mean(0) + np.float32(level)
    w2 = np.where(mask.reshape(n1, -1), np.float32(1) / (w2 * w2), np.float32(0))
    rows_w = w2.sum(axis=1, dtype=np.float64)  # (n1,)
    r *= w2  # float32 products, float64 sums
    rows_s = r.sum(axis=2, dtype=np.float64)  # (3, n1)
    d = ggx(bin_angles(rho.shape[1:])[0][None, :], np.asarray(LOBE_ALPHAS)[:, None])  # (A, n1)
    a00, a01, a11 = rows_w.sum(), d @ rows_w, (d * d) @ rows_w  # (), (A,), (A,)
    b0, b1 = rows_s.sum(1)[None, :], (d @ rows_s.T)  # (1, 3), (A, 3)
    a01, a11 = a01[:, None], a11[:, None]
    # the best x >= 0 of 2 b.x - x'Ax: the free optimum, or either unknown alone, or 0
    det = a00 * a11 - a01 * a01
    with np.errstate(divide="ignore", invalid="ignore"):
        cands = [((a11 * b0 - a01 * b1) / det, (a00 * b1 - a01 * b0) / det),
                 (np.maximum(b0 / a00, 0.0) + 0 * b1, 0 * b1),
                 (0 * b1, np.maximum(b1 / a11, 0.0))]
    best_gain = np.zeros(b1.shape)
    best_kd, best_ks = np.zeros(b1.shape), np.zeros(b1.shape)
    for kd, ks in cands:
        ok = np.isfinite(kd) & np.isfinite(ks) & (kd >= 0) & (ks >= 0)
        kd, ks = np.where(ok, kd, 0.0), np.where(ok, ks, 0.0)
        gain = 2 * (b0 * kd + b1 * ks) - (a00 * kd * kd + 2 * a01 * kd * ks + a11 * ks * ks)
        better = ok & (gain > best_gain)
        best_gain = np.where(better, gain, best_gain)
        best_kd, best_ks = np.where(better, kd, best_kd), np.where(better, ks, best_ks)
    k = _closest_in_log(rho, mask, level, d, best_kd, best_ks)
    lobe = np.concatenate([[LOBE_ALPHAS[k]], best_kd[k], best_ks[k]])
    lobe = np.minimum(lobe, float(np.finfo(np.float16).max))
    return tuple(float(v) for v in lobe.astype(np.float16))


def _closest_in_log(rho: np.ndarray, mask: np.ndarray, level: float, d: np.ndarray,
                    kd: np.ndarray, ks: np.ndarray) -> int:
    """The index of the alpha (rows of ``d``, (A, n1); ``kd``, ``ks`` (A, 3)) whose lobe
    has the least sum over the valid bins of (x - o)^2, x = ln(rho W + 1), o = ln(b W +
    1), W = K / L: o is constant along a theta_h row, so the sum is, per channel and
    row, S2 - 2 o S1 + n o^2 with the row's sums S1 of x and S2 of x^2 over its n valid
    bins, computed once."""
    n1 = rho.shape[1]
    w = np.float32(LOBE_KNEE / level)
    x = np.log1p(np.where(mask, np.maximum(rho, np.float32(0)), np.float32(0)) * w)
    x = x.reshape(3, n1, -1)  # 0 on the invalid bins: they add nothing to S1 and S2
    s1 = x.sum(axis=2).astype(np.float64)  # (3, n1); float32 sums: a choice, not a value
    s2 = np.einsum("cij,cij->ci", x, x).astype(np.float64)
    n = mask.reshape(n1, -1).sum(axis=1).astype(np.float64)  # (n1,)
    o = np.log1p((kd[:, :, None] + ks[:, :, None] * d[:, None, :]) * float(w))  # (A, 3, n1)
    err = (s2[None] - 2.0 * o * s1[None] + n * o * o).sum(axis=(1, 2))
    return int(np.argmin(err))


def check_lobe(name: str, lobe) -> tuple[float, ...] | None:
    """``lobe`` as 7 floats if transform ``name`` can have it: finite, float16-exact,
    alpha > 0, kd and ks >= 0 for a lobe transform; None (and ``lobe`` None) for the
    others. A ValueError otherwise."""
    if not has_lobe(name):
        if lobe is not None:
            raise ValueError(f"transform {name!r} has no base lobe, got {lobe!r}")
        return None
    if lobe is None:
        raise ValueError(f"transform {name!r} needs the material's base lobe")
    v = np.asarray(lobe, np.float64).reshape(-1)
    if v.size != LOBE_SIZE or not np.all(np.isfinite(v)) or not v[0] > 0 or np.any(v < 0):
        raise ValueError(f"transform {name!r}: a base lobe is {LOBE_SIZE} finite numbers, "
                         f"alpha > 0, kd and ks >= 0; got {lobe!r}")
    if not np.array_equal(v.astype(np.float16).astype(np.float64), v):
        raise ValueError(f"transform {name!r}: the base lobe's numbers must be float16 "
                         f"values, got {lobe!r}")
    return tuple(float(x) for x in v)


def material_lobe(name: str, rho: np.ndarray, valid: np.ndarray | None = None
                  ) -> tuple[float, ...] | None:
    """The base lobe transform ``name`` gives the material ``rho`` (:func:`fit_base_lobe`),
    None for the transforms without one."""
    return fit_base_lobe(rho, valid) if has_lobe(name) else None


def _lobe_offset(w, b) -> np.ndarray:
    """o = ln(b W + 1), float32, of the weight ``w`` and the lobe ``b`` (broadcast)."""
    return np.log1p(np.asarray(b, np.float32) * np.asarray(w, np.float32))


def to_lobe(x, w, b) -> np.ndarray:
    """A lobe transform's coded value t = m (x - o) from x = ln(rho W + 1), with o =
    ln(b W + 1) and m = ((b W + 1) / K)^G: ``w`` the weight W, ``b`` the base lobe at the
    same bins (broadcast together). float32, as the coded values are."""
    o = _lobe_offset(w, b)
    t = np.subtract(np.asarray(x, np.float32), o)
    o -= np.float32(np.log(LOBE_KNEE))
    o *= np.float32(LOBE_POWER)
    t *= np.exp(o, out=o)
    return t


def from_lobe(t, w, b) -> np.ndarray:
    """Inverse of :func:`to_lobe`: x = t (K / (b W + 1))^G + ln(b W + 1), the value the
    inverse transform then maps to rho = (exp(x) - 1) / W; float32, as the kernels
    compute it (``mitsuba_plugin.kernels.lobe_x``)."""
    o = _lobe_offset(w, b)
    x = np.exp(np.float32(LOBE_POWER) * (np.float32(np.log(LOBE_KNEE)) - o))
    x = np.multiply(np.asarray(t, np.float32), x)  # the shape of t and the lobe's
    x += o
    return x


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
            gain: float | None = None, lobe=None) -> np.ndarray:
    """Transform linear BRDF values into the domain the dictionaries code.

    Parameters
    ----------
    rho : numpy.ndarray
        Linear BRDF values (1/sr), channel-first: shape (..., n_h, n_d, n_p); (3, n_h,
        n_d, n_p), one material's R, G, B, for the lobe transforms.
    name : str
        One of :data:`TRANSFORMS` (the module's docstring gives each formula).
    valid : numpy.ndarray, optional
        Bool (n_h, n_d, n_p), broadcast over the leading axes: invalid bins are set to
        rho = 0 first (and to t = 0 by the lobe transforms). None: every bin as given.
    gain : float, optional
        The material's gain 1/L for the level and lobe transforms; None: ``rho``'s own
        (:func:`material_gain`, ``rho`` then being one material's R, G, B).
    lobe : sequence of 7 floats, optional
        The material's base lobe for the lobe transforms; None: ``rho``'s own
        (:func:`fit_base_lobe`).

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
    t = np.log1p(t, out=t)  # float32: rho and the weight are
    if not has_lobe(name):
        return t
    if lobe is None:
        lobe = fit_base_lobe(rho, valid)
    b = lobe_rows(check_lobe(name, lobe), rho.shape[-3:])[:, :, None, None]
    t = to_lobe(t, w, b).astype(np.float32)
    if valid is not None:
        t[:, ~np.asarray(valid, bool)] = 0.0  # an invalid bin codes the lobe itself
    return t


def inverse(t: np.ndarray, name: str, gain: float = 1.0, lobe=None,
            floor: float = 0.0) -> np.ndarray:
    """Inverse of :func:`forward`: transformed values back to linear BRDF values.

    Parameters
    ----------
    t : numpy.ndarray
        Transformed values, channel-first: shape (..., n_h, n_d, n_p); (3, n_h, n_d,
        n_p) for the lobe transforms.
    name : str
        The transform they are in, one of :data:`TRANSFORMS`.
    gain : float
        The material's gain 1/L (sr) for the level and lobe transforms; 1 for the others.
    lobe : sequence of 7 floats, optional
        The material's base lobe for the lobe transforms (:func:`check_lobe`).
    floor : float
        The material's floor f for the floor transforms (:func:`check_floor`): values
        below f L decode as 0; 0 for the others.

    Returns
    -------
    numpy.ndarray
        Linear BRDF values (1/sr), the shape of ``t``, clamped to >= 0.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`TRANSFORMS`, or a lobe transform's lobe is
        missing.
    """
    t = np.asarray(t)
    w = weight(name, t.shape[-3:], gain)
    lobe, floor = check_lobe(name, lobe), check_floor(name, floor)
    if lobe is not None:
        t = from_lobe(t, w, lobe_rows(lobe, t.shape[-3:])[:, :, None, None])
    return apply_floor(_inverse(t, w), floor, gain)


def inverse_at_bins(
    t: np.ndarray, name: str, bins: tuple[np.ndarray, ...], shape: tuple[int, int, int],
    gain: float = 1.0, lobe=None, floor: float = 0.0,
) -> np.ndarray:
    """Inverse transform of values ``t`` (..., N) that belong to the bins ``(i, j, k)``
    (index arrays of shape (N,)), for a material of gain ``gain``, base lobe ``lobe``
    and floor ``floor`` (:func:`inverse`); the lobe transforms take one material's R, G,
    B, ``t`` (3, N)."""
    w = weight(name, shape, gain)
    w = w[bins] if isinstance(w, np.ndarray) else w
    t = np.asarray(t)
    lobe, floor = check_lobe(name, lobe), check_floor(name, floor)
    if lobe is not None:
        t = from_lobe(t, w, lobe_rows(lobe, shape)[:, bins[0]])
    return apply_floor(_inverse(t, w), floor, gain)


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
