"""The sensing operator of encoding from samples, and the sample-domain pieces both
recoveries share (``docs/method.md``, "Encoding from samples").

Per coded channel the model is y(x) = sum_t s_t U1[x_h, a_t] U2[x_d, b_t] U3[x_p, c_t],
the atoms interpolated linearly between the bins' lower-edge samples along each mode
(:func:`sparse_brdf.coords.linear_bins`, the plugins' ``interpolate=true`` lookup). At N
samples this is y = A s with a sensing matrix A of N rows and one column per coefficient
of a dictionary. ``A s`` on a support is a product of gathered atom rows; the adjoint
``A^T r`` scatters the residual onto the grid with the interpolation weights and
projects that tensor on the dictionary (one full projection). Also here: the transforms
at the samples, the folds of the cross-validation, a channel's choice and the joint
budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..coords import linear_bins
from ..transforms import (
    COS_CLIP,
    colour_matrix,
    from_basis,
    material_gain,
    material_scale,
    uses_cosine,
)
from .measurements import Samples

#: Folds of the cross-validation unless told otherwise.
DEFAULT_FOLDS = 4
#: Support sizes of the greedy paths: the first stage, and the growth factor per stage.
FIRST_STAGE, GROWTH = 4, 2.0

# ----------------------------------------------------------------- the sensing operator


@dataclass
class Operator:
    """The sensing operator of N samples on a grid: each sample's 8 neighbouring grid
    samples and their trilinear weights (``flat``, ``w8``: (N, 8)), and per mode the
    interpolation (i0, i1, t) of :func:`~sparse_brdf.coords.linear_bins`."""

    shape: tuple[int, int, int]
    lin: tuple
    flat: np.ndarray
    w8: np.ndarray

    @classmethod
    def of(cls, wi: np.ndarray, wo: np.ndarray, shape: tuple[int, int, int]) -> Operator:
        lin = linear_bins(wi, wo, shape)
        n2, n3 = shape[1], shape[2]
        flat, w8 = [], []
        for ei in (0, 1):
            for ej in (0, 1):
                for ek in (0, 1):
                    (i, ti), (j, tj), (k, tk) = ((m[e], m[2]) for m, e in zip(
                        lin, (ei, ej, ek), strict=True))
                    flat.append((i * n2 + j) * n3 + k)
                    w8.append((ti if ei else 1 - ti) * (tj if ej else 1 - tj)
                              * (tk if ek else 1 - tk))
        return cls(tuple(shape), lin, np.stack(flat, 1), np.stack(w8, 1))

    def rows(self, u: np.ndarray, mode: int, rows=slice(None)) -> np.ndarray:
        """The atoms of mode matrix ``u`` (n, n) interpolated at the samples ``rows``:
        (N, n) float32."""
        i0, i1, t = (a[rows] for a in self.lin[mode])
        t = t[:, None].astype(np.float32)
        return (1 - t) * u[i0] + t * u[i1]

    def scatter(self, r: np.ndarray, rows=slice(None)) -> np.ndarray:
        """The adjoint of the interpolation: sample values ``r`` of ``rows`` spread onto the
        grid with their trilinear weights, float32 (n1, n2, n3)."""
        flat, w = self.flat[rows], self.w8[rows]
        g = np.bincount(flat.ravel(), (w * np.asarray(r, np.float64)[:, None]).ravel(),
                        minlength=math.prod(self.shape))
        return g.astype(np.float32).reshape(self.shape)


def project(g: np.ndarray, u1: np.ndarray, u2: np.ndarray, u3: np.ndarray) -> np.ndarray:
    """g x1 U1^T x2 U2^T x3 U3^T of a tensor g (n1, n2, n3), float32: three large matrix
    products (the coefficients of ``tensor.project``, with mode 2 done as one product on a
    transposed copy rather than n1 small ones)."""
    n1, n2, n3 = g.shape
    t = (g.reshape(n1 * n2, n3) @ u3).reshape(n1, n2 * n3)
    t = (u1.T @ t).reshape(n1, n2, n3).transpose(1, 0, 2).reshape(n2, n1 * n3)
    return (u2.T @ t).reshape(n2, n1, n3).transpose(1, 0, 2)


class Atoms:
    """One dictionary seen through an operator: interpolated atom rows of every sample,
    the columns of the sensing matrix on a support, and the adjoint."""

    def __init__(self, op: Operator, u) -> None:
        self.op, self.u = op, u
        self.r = [op.rows(u[m], m) for m in range(3)]
        self.sq = [np.square(m) for m in u]

    def columns(self, loc: np.ndarray, rows) -> np.ndarray:
        a, b, c = np.unravel_index(loc, self.op.shape)
        return self.r[0][rows][:, a] * self.r[1][rows][:, b] * self.r[2][rows][:, c]

    def correlate(self, res: np.ndarray, rows) -> np.ndarray:
        return project(self.op.scatter(res, rows), *self.u).ravel()

    def norms(self, w: np.ndarray, rows) -> np.ndarray:
        """Approximate column norms: sqrt(sum_s w_s prod_m R_m[s]^2), each squared
        interpolated atom replaced by the interpolated squares (an upper bound, exact at
        the grid's samples)."""
        return np.sqrt(np.maximum(project(self.op.scatter(w, rows), *self.sq).ravel(), 0))


def stage_sizes(t_max: int) -> list[int]:
    """Support sizes of the greedy path up to ``t_max``: FIRST_STAGE, then x GROWTH."""
    sizes, t = [], FIRST_STAGE
    while t < t_max:
        sizes.append(t)
        t = max(t + 1, int(math.ceil(t * GROWTH)))
    return [*sizes, t_max] if t_max > 0 else []


# ------------------------------------------------------- transforms at the samples


def sample_weight(samples: Samples, transform: str) -> np.ndarray:
    """The transform's weight w at each sample, (N,): for the cosine transforms
    clip(cos_i cos_o, 0.01, 1) at the sample's own directions (the value the dictionaries
    code is ln(rho w + 1), smooth between the bins' samples), else 1; times the relative
    transforms' scale, and the level transforms' scale and the samples' gain
    (:func:`samples_gain`), as ``transforms.weight``."""
    s = material_scale(transform, samples_gain(samples, transform))
    if not uses_cosine(transform):
        return np.full(len(samples), s)
    return np.clip(samples.wi[:, 2] * samples.wo[:, 2], *COS_CLIP) * s


def samples_gain(samples: Samples, transform: str) -> float:
    """The gain 1/L of a material measured as ``samples`` under ``transform``
    (``transforms.material_gain`` of the samples' values: every sample counts)."""
    return material_gain(transform, np.asarray(samples.rgb, np.float32).T)


def coded_values(samples: Samples, transform: str, basis: str) -> np.ndarray:
    """The coded channels at the samples, (3, N) float64: the colour basis of the
    transformed R, G, B (``transforms.forward`` at each sample's own weight)."""
    t = np.log1p(samples.rgb * sample_weight(samples, transform)[:, None])
    return colour_matrix(basis) @ t.T


def linear_values(coded: np.ndarray, samples: Samples, transform: str,
                  basis: str) -> np.ndarray:
    """Inverse of :func:`coded_values`: linear RGB (N, 3) from coded channels (3, N),
    clamped >= 0."""
    t = from_basis(coded.astype(np.float32), basis).T.astype(np.float64)
    with np.errstate(over="ignore"):
        rho = np.expm1(t) / sample_weight(samples, transform)[:, None]
    return np.clip(rho, 0.0, np.finfo(np.float32).max)


def cosine_error(samples: Samples, rows: np.ndarray, rgb: np.ndarray) -> float:
    """Weighted squared error of predicted linear RGB ``rgb`` (len(rows), 3) at the samples
    ``rows``, each weighted by (cos_i cos_o)^2 (the cosine-weighted SNR's error,
    ``metrics.cosine_weighted_snr``, at the samples)."""
    c = samples.wi[rows, 2] * samples.wo[rows, 2]
    d = (rgb - samples.rgb[rows]) * c[:, None]
    return float(np.sum(samples.weight[rows][:, None] * d * d))


def fold_of(n: int, folds: int, seed: int) -> np.ndarray:
    """The fold (0 .. folds - 1) of each of ``n`` samples: a seeded balanced shuffle."""
    rng = np.random.default_rng(seed)
    return rng.permutation(np.arange(n) % folds)


@dataclass
class Choice:
    """A channel's cross-validated choice: dictionary, support size, CV error, the CV error
    at every size of the path (``curve`` at ``sizes``, from size 0) and the held-out
    predictions at every size, (N, stages + 1): every sample predicted by the fold that
    held it out."""

    dictionary: int
    size: int
    error: float
    curve: list[float]
    sizes: list[int]
    predicted: np.ndarray


def trim_to_budget(choices: list[Choice], cap: int) -> list[int]:
    """Support sizes per channel within a joint budget of ``cap`` coefficients: while the
    total is over, the channel losing least held-out error per coefficient steps back
    along its path."""
    idx = [ch.sizes.index(ch.size) for ch in choices]
    while sum(ch.sizes[i] for ch, i in zip(choices, idx, strict=True)) > cap:
        cost = [((ch.curve[i - 1] - ch.curve[i]) / (ch.sizes[i] - ch.sizes[i - 1]))
                if i > 0 else np.inf for ch, i in zip(choices, idx, strict=True)]
        idx[int(np.argmin(cost))] -= 1
    return idx
