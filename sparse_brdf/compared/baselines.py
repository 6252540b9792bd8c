"""The baseline BRDF models the paper's model is compared with.

Each is a :class:`~sparse_brdf.compared.compact.BRDFModel` (``fit(brdfs)`` learns and
returns the model, ``compress(brdf)`` gives a :class:`~sparse_brdf.compared.compact.Compact`
with ``reconstruct()`` (linear RGB values of the BRDF's grid shape, (n1, n2, n3, 3)),
``nbytes`` (exact storage of what the model keeps per material, float32 numbers; shared
bases such as a PCA basis are not counted, as in the paper) and ``params`` (those stored
numbers themselves, which :mod:`mitsuba_plugin.evaluators` evaluates at direction pairs
without a dense reconstruction). PCA learns from training BRDFs; compressing with it
unfitted raises. The paper's own model is :class:`~sparse_brdf.compared.sparse_model.SparseModel`.

- :class:`NaiveModel`    Bagher et al. 2016: kd + ks a(theta_h) b(theta_d) c(phi_d) per
  channel (362 numbers), non-negative alternating weighted least squares
  (:func:`fit_separable`) with solid-angle and cosine weights
- :class:`CPDModel`      rank-L CPD of the log-plus tensor per channel (360 L numbers),
  via tensorly
- :class:`TuckerModel`   Tucker of the log-plus tensor per channel, via tensorly
- :class:`PCAModel`      Nielsen et al. 2015: PCA basis of the training set in the
  log-relative mapping ln((rho c + 0.001) / (median + 0.001))
- :class:`TabulatedModel` the full table (the upper bound)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..brdf import BRDF
from ..coords import MERL_SHAPE, bin_solid_angle, cosine_product
from ..errors import UsageError
from ..parallel import blas_single_thread, parallel_map
from ..params import Interval, check
from ..transforms import cosine_weight, forward, inverse
from .compact import BRDFModel, Compact, require_fitted

_F32 = 4


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def _naive_params(per_channel) -> dict[str, np.ndarray]:
    """The naive model's stored numbers from per-channel fits (kd, a, b, c), or (kd, ks,
    a, b, c): kd (3,), ks (3,), a (3, n1), b (3, n2), c (3, n3), float32, with a, b, c
    of unit norm and their scale in ks, so that rho = kd + ks a[i] b[j] c[k] per channel
    (2 + n1 + n2 + n3 numbers per channel, as the model's ``nbytes`` counts)."""
    out: dict[str, list] = {"kd": [], "ks": [], "a": [], "b": [], "c": []}
    for fit in per_channel:
        kd, ks, *factors = fit if len(fit) == 5 else (fit[0], 1.0, *fit[1:])
        norms = [float(np.linalg.norm(f)) for f in factors]
        out["kd"].append(kd)
        out["ks"].append(ks * float(np.prod(norms)))
        for key, f, nrm in zip("abc", factors, norms, strict=True):
            out[key].append(np.asarray(f, np.float64) / nrm if nrm > 0 else np.zeros(len(f)))
    return {k: _f32(v) for k, v in out.items()}


class TabulatedModel(BRDFModel):
    """The full tabulated BRDF (float32), the upper bound of every comparison."""

    name = "tabulated"

    def compress(self, brdf: BRDF) -> Compact:
        v = brdf.values.copy()
        return Compact(self.name, v.nbytes, lambda: v, params={"table": v})


def _axis_sums(t: np.ndarray, x: np.ndarray, y: np.ndarray, axis: int) -> np.ndarray:
    """sum over the two axes other than ``axis`` of t * x[., m] * y[., m], for each column
    m of x (length of the first other axis) and y (the second): (t.shape[axis], m)."""
    n1, n2, n3 = t.shape
    if axis == 2:
        u = (x.T @ t.reshape(n1, n2 * n3)).reshape(-1, n2, n3)
        return np.einsum("mjk,jm->km", u, y)
    u = (t.reshape(n1 * n2, n3) @ y).reshape(n1, n2, -1)
    return np.einsum("ijm,jm->im" if axis == 0 else "ijm,im->jm", u, x)


def _kd_and_factor(n, cross, d, m, s, steps: int = 80):
    """Exact block update of (kd, f) for sum w (z - kd - f[i] g)^2 with kd, f >= 0, where
    n_i = sum w z g, cross_i = sum w g, d_i = sum w g^2 (over bins of row i), m = sum w z,
    s = sum w. Given kd, f_i = max((n_i - cross_i kd) / d_i, 0); the reduced objective is
    convex in kd with derivative s kd - m + sum_i cross_i f_i(kd) (nondecreasing), whose
    root on kd >= 0 is found by bisection."""
    def slope(kd):
        return s * kd - m + np.sum(cross * np.maximum(n - cross * kd, 0.0) / d)

    kd = 0.0
    if slope(0.0) < 0.0:
        pos = cross > 0
        lo, hi = 0.0, max(m / s, float(np.max(n[pos] / cross[pos])) if pos.any() else 0.0)
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if slope(mid) < 0.0 else (lo, mid)
        kd = 0.5 * (lo + hi)
    return kd, np.maximum((n - cross * kd) / d, 0.0)


def fit_separable(rho: np.ndarray, w: np.ndarray, n_iter: int = 100, tol: float = 1e-6):
    """Weighted non-negative fit of one channel: rho[i, j, k] ~ kd + a[i] b[j] c[k].

    Minimises E = sum w (rho - kd - a[i] b[j] c[k])^2 subject to kd >= 0, a, b, c >= 0,
    by alternating weighted least squares: each step solves one block (kd together with
    one factor) exactly, so E never increases; it starts from a = b = c = 1 and stops
    when E falls by less than ``tol`` (relative) in a sweep, or after ``n_iter`` sweeps.

    Parameters
    ----------
    rho : ndarray of shape (n1, n2, n3)
        Values (finite wherever ``w > 0``).
    w : ndarray of shape (n1, n2, n3)
        Non-negative weights; bins of weight 0 are ignored.

    Returns
    -------
    kd, (a, b, c), E, sweeps : float, three 1-D arrays, float, int
    """
    rho = np.where(w > 0, rho, 0.0)
    wz = w * rho
    s, m, mzz = float(w.sum()), float(wz.sum()), float((wz * rho).sum())
    if s <= 0:
        return 0.0, tuple(np.zeros(n) for n in rho.shape), 0.0, 0
    f = [np.ones(n) for n in rho.shape]
    kd, prev, err, sweeps = 0.0, np.inf, mzz, 0
    while sweeps < n_iter:
        sweeps += 1
        for ax in range(3):
            x, y = (f[k] for k in range(3) if k != ax)
            if not (x.any() and y.any()):
                continue  # a zero factor: the block is undetermined, keep it
            n = _axis_sums(wz, x[:, None], y[:, None], ax)[:, 0]
            cd = _axis_sums(w, np.stack([x, x * x], 1), np.stack([y, y * y], 1), ax)
            cross, d = cd[:, 0], np.maximum(cd[:, 1], 1e-300)
            kd, f[ax] = _kd_and_factor(n, cross, d, m, s)
            # E from this block's sums (no extra pass over the grid)
            err = (mzz + kd * kd * s - 2 * kd * m + float(np.sum(f[ax] ** 2 * d))
                   - 2 * float(np.sum(f[ax] * n)) + 2 * kd * float(np.sum(f[ax] * cross)))
        norms = [float(np.linalg.norm(v)) for v in f]
        if min(norms) > 0:  # balance the factors' scales (the product is unchanged)
            scale = float(np.prod(norms)) ** (1 / 3)
            f = [v * (scale / nv) for v, nv in zip(f, norms, strict=True)]
        if sweeps > 1 and prev - err <= tol * prev:
            break
        prev = err
    return kd, tuple(f), max(err, 0.0), sweeps


class NaiveModel(BRDFModel):
    """Bagher et al. 2016 "naive" model: per channel rho ~ kd + ks a(th) b(td) c(pd).

    M. M. Bagher, J. Snyder, D. Nowrouzezahrai, "A Non-Parametric Factor Microfacet Model
    for Isotropic BRDFs", ACM TOG 35(5), 2016, in the form the paper compares against: per
    colour channel a diffuse constant kd plus one separable product of tabulated factors on
    the grid, a(theta_h) (n1 numbers), b(theta_d) (n2), c(phi_d) (n3), scaled by ks;
    2 + n1 + n2 + n3 numbers per channel (362 on the MERL grid), linear BRDF units (1/sr).

    Objective, per channel (``fit_separable``; AWLS, alternating weighted least squares)::

        min  sum_bins  w (rho - kd - a[i] b[j] c[k])^2     s.t. kd >= 0, a, b, c >= 0
        w  = valid * Omega^solid_angle_power * (cos_i cos_o)^cos_power
                   * (rho + eps)^(2 q - 2)

    - valid: only measured, above-horizon bins count (``brdf.valid``).
    - Omega (:func:`bin_solid_angle`, sr^2): the bin's measure in (wi, wo) space. A
      renderer integrates the BRDF over directions, so a bin matters in proportion to the
      directions it covers; without it the tiny first theta_h bins of the MERL grid
      (square-root spacing) dominate the fit. The power 1.25 (the sharpest bins weigh a
      little less than their measure; lights and pixels have extent, so an image sees a
      lobe's core averaged) measured better than 1 in the paper's scene at 16 and 512 spp.
    - (cos_i cos_o)^1.5 (unclipped cosines at the bin's angles): under direct lighting a
      light sample's error is Delta rho cos_i, squared, and a sphere's pixels per unit
      solid angle of view grow with cos_o; cos_i^2 cos_o, symmetrised by reciprocity.
    - (rho + eps)^(2q - 2): the compressive weighting of Bagher et al. (weights falling
      with the measured value, so that the residual approximates the error of the
      compressed value rho^q; q = 0 is relative error, q = 1 plain least squares). Off by
      default (q = 1): every q < 1 tried lowered the paper scene's SNR.

    Fit (:func:`fit_separable`): from a = b = c = 1, sweeps of exact block solves of
    (kd, a), (kd, b), (kd, c), each a non-negative weighted least-squares problem, until
    the objective falls by less than ``tol``; vectorised over the grid (no loop over
    bins), about 1 s per MERL material (polyethylene, slow to converge: 10 s).

    Measured with ``benchmarks/naive_fit.py`` (paper scene, 14 unseen MERL materials,
    res 96, same-seed SNR): whole-image mean 39.4 dB (object-only 22.9) at 16 spp and
    46.0 (25.5) at 512 spp, against 32.7 (16.2) and 34.3 (13.8) for the former fit
    (weights clip(cos_i cos_o, 0.01, 1), kd >= 0 only); studio scene 20.3 / 23.1 dB
    against 13.7 / 14.4.

    Parameters
    ----------
    n_iter : int, default 100
        Maximum number of sweeps (each updates kd with a, then b, then c).
    tol : float, default 1e-6
        Stop when a sweep lowers the objective by less than this fraction.
    cos_power, solid_angle_power : float, default 1.5 and 1.25
        Exponents of the cosine and solid-angle factors of the weights.
    q : float in [0, 1], default 1.0
        Compression exponent of the compressive weighting (1: none).
    eps : float, default 1e-3
        Offset of the compressive weighting (1/sr); used only when q < 1.
    """

    name = "naive"
    #: The options' ranges.
    PARAMETERS = {"n_iter": Interval(int, 1), "tol": Interval(float, 0.0),
                  "cos_power": Interval(float, 0.0), "solid_angle_power": Interval(float, 0.0),
                  "q": Interval(float, 0.0, 1.0), "eps": Interval(float, 0.0, closed="right")}

    def __init__(self, n_iter: int = 100, tol: float = 1e-6, cos_power: float = 1.5,
                 solid_angle_power: float = 1.25, q: float = 1.0, eps: float = 1e-3):
        for key, value in (("n_iter", n_iter), ("tol", tol), ("cos_power", cos_power),
                           ("solid_angle_power", solid_angle_power), ("q", q), ("eps", eps)):
            check(f"NaiveModel: {key}", value, self.PARAMETERS[key])
        self.n_iter, self.tol = int(n_iter), float(tol)
        self.cos_power, self.solid_angle_power = float(cos_power), float(solid_angle_power)
        self.q, self.eps = float(q), float(eps)

    def weights(self, brdf: BRDF) -> np.ndarray:
        """The objective's weights w, float64 of shape (n1, n2, n3, 3); 0 on invalid bins."""
        w = (brdf.valid * bin_solid_angle(brdf.shape) ** self.solid_angle_power
             * np.clip(cosine_product(brdf.shape), 0.0, None) ** self.cos_power)
        w = np.repeat(w[..., None], 3, axis=-1)
        if self.q != 1.0:
            rho = np.where(brdf.valid[..., None], brdf.values, 0.0).astype(np.float64)
            w *= (np.maximum(rho, 0.0) + self.eps) ** (2.0 * self.q - 2.0)
        return w

    def objective(self, brdf: BRDF, per_channel) -> np.ndarray:
        """The objective of per-channel parameters (kd, a, b, c), per channel: (3,)."""
        w = self.weights(brdf)
        rho = np.where(brdf.valid[..., None], brdf.values, 0.0).astype(np.float64)
        return np.array([np.sum(w[..., ch] * (rho[..., ch] - kd - np.einsum(
            "i,j,k->ijk", a, b, c)) ** 2) for ch, (kd, a, b, c) in enumerate(per_channel)])

    def compress(self, brdf: BRDF) -> Compact:
        w = self.weights(brdf)
        out = []
        params = []
        for c in range(3):
            rho = brdf.values[..., c].astype(np.float64)
            kd, (a, b, cc), _, _ = fit_separable(rho, w[..., c], self.n_iter, self.tol)
            params.append((kd, a, b, cc))
            out.append(kd + np.einsum("i,j,k->ijk", a, b, cc))
        n = sum(1 + 1 + a.size + b.size + cc.size for _, a, b, cc in params)
        rec = np.maximum(np.stack(out, -1), 0).astype(np.float32)
        return Compact(self.name, n * _F32, lambda: rec, params=_naive_params(params))


def _log_plus_channels(brdf: BRDF) -> np.ndarray:
    return forward(brdf.channel_first(), "log-plus", brdf.valid).astype(np.float64)


class CPDModel(BRDFModel):
    """Rank-``rank`` CP decomposition of the log-plus tensor of each channel (tensorly).

    Invalid bins are masked out (tensorly's EM imputation), not fitted as zeros.
    """

    #: The rank: at least 1, at most the MERL grid's entries (per channel).
    PARAMETERS = {"rank": Interval(int, 1, int(np.prod(MERL_SHAPE)))}

    def __init__(self, rank: int = 1, n_iter: int = 30, seed: int = 0):
        check("cpd rank", rank, self.PARAMETERS["rank"])
        self.rank, self.n_iter, self.seed = rank, n_iter, seed
        self.name = f"cpd-{rank}"

    def compress(self, brdf: BRDF) -> Compact:
        # lazy: tensorly takes ~0.7 s to import and only these two baselines use it
        import tensorly as tl
        from tensorly.decomposition import parafac

        y = _log_plus_channels(brdf)
        rec = np.empty_like(y)
        mask = np.broadcast_to(brdf.valid, y.shape[1:])
        kept = []
        for c in range(3):
            cp = parafac(tl.tensor(y[c]), self.rank, n_iter_max=self.n_iter,
                         init="random", mask=mask.astype(float), random_state=self.seed)
            rec[c] = tl.cp_to_tensor(cp)
            kept.append((tl.to_numpy(cp.weights), *map(tl.to_numpy, cp.factors)))
        n = 3 * self.rank * (sum(brdf.shape) + 1)
        out = np.moveaxis(inverse(rec, "log-plus"), 0, -1)
        # X[i, j, k] = sum_r weights[r] a[i, r] b[j, r] c[k, r], rho = exp(X) - 1
        params = {key: _f32([ch[m] for ch in kept])
                  for m, key in enumerate(("weights", "a", "b", "c"))}
        return Compact(self.name, n * _F32, lambda: out, params=params)


class TuckerModel(BRDFModel):
    """Tucker decomposition with ``ranks`` of the log-plus tensor of each channel."""

    #: Each mode's rank: at least 1, at most the MERL grid's side of that mode.
    PARAMETERS = {"ranks": tuple(Interval(int, 1, n) for n in MERL_SHAPE)}

    def __init__(self, ranks: tuple[int, int, int] = (1, 1, 1), seed: int = 0):
        ranks = tuple(ranks)
        if len(ranks) != 3:
            raise UsageError(f"tucker ranks must be three integers, got {ranks!r}")
        for r, c in zip(ranks, self.PARAMETERS["ranks"], strict=True):
            check("tucker rank", r, c)
        self.ranks, self.seed = ranks, seed
        self.name = "tucker-" + "x".join(map(str, self.ranks))

    def compress(self, brdf: BRDF) -> Compact:
        # lazy: tensorly takes ~0.7 s to import and only these two baselines use it
        import tensorly as tl
        from tensorly.decomposition import tucker

        y = _log_plus_channels(brdf)
        rec = np.empty_like(y)
        mask = np.broadcast_to(brdf.valid, y.shape[1:])
        kept = []
        for c in range(3):
            core, factors = tucker(tl.tensor(y[c]), rank=list(self.ranks), n_iter_max=30,
                                   init="random",
                                   mask=mask.astype(float), random_state=self.seed)
            rec[c] = tl.tucker_to_tensor((core, factors))
            kept.append((tl.to_numpy(core), *map(tl.to_numpy, factors)))
        r1, r2, r3 = self.ranks
        n1, n2, n3 = brdf.shape
        n = 3 * (r1 * r2 * r3 + n1 * r1 + n2 * r2 + n3 * r3)
        out = np.moveaxis(inverse(rec, "log-plus"), 0, -1)
        # X[i, j, k] = sum_pqs core[p, q, s] a[i, p] b[j, q] c[k, s], rho = exp(X) - 1
        params = {key: _f32([ch[m] for ch in kept])
                  for m, key in enumerate(("core", "a", "b", "c"))}
        return Compact(self.name, n * _F32, lambda: out, params=params)


#: The offset of the log-relative mapping (1/sr).
LOG_RELATIVE_EPS = 1e-3


def log_relative(rho: np.ndarray, c, median) -> np.ndarray:
    """Nielsen et al.'s log-relative mapping ln((rho c + eps) / (median + eps)) of linear
    values ``rho`` with cosine weights ``c`` (broadcast) and a median of rho c (same
    units), eps = :data:`LOG_RELATIVE_EPS`."""
    return np.log((rho * c + LOG_RELATIVE_EPS) / (median + LOG_RELATIVE_EPS))


def from_log_relative(m: np.ndarray, c, median) -> np.ndarray:
    """Inverse of :func:`log_relative`: linear values from mapped ones (not clamped)."""
    with np.errstate(over="ignore"):
        return (np.exp(m) * (median + LOG_RELATIVE_EPS) - LOG_RELATIVE_EPS) / c


def _median(brdfs: Sequence[BRDF]) -> np.ndarray:
    """The median of rho c (c the cosine weights) per bin and channel over ``brdfs``,
    columns in chunks on the thread pool."""
    shape = brdfs[0].shape
    c = cosine_weight(shape)[..., None]
    stack = np.stack([b.values * c for b in brdfs]).reshape(len(brdfs), -1)
    out = np.empty(stack.shape[1], stack.dtype)
    step = 1 << 16

    def one(s: int) -> None:
        out[s : s + step] = np.median(stack[:, s : s + step], axis=0)

    for _ in parallel_map(one, range(0, out.size, step)):
        pass
    return out.reshape((*shape, 3))


class PCAModel(BRDFModel):
    """Nielsen et al. 2015: a PCA basis of the training set in the log-relative mapping.

    Mapping: m = ln((rho c + eps) / (median + eps)), eps = 0.001, c = clip(cos_i cos_o,
    0.01, 1), median per bin and channel over the training set. A BRDF is the mean plus
    its projection on the first ``n_coeffs`` principal components (at most N - 1 for N
    training BRDFs).
    """

    EPS = LOG_RELATIVE_EPS
    learns = True
    #: Components kept: at least 1 (and at most the training BRDFs less one, by itself).
    PARAMETERS = {"n_coeffs": Interval(int, 1, int(np.prod(MERL_SHAPE)))}

    def __init__(self, n_coeffs: int = 40):
        check("pca n_coeffs", n_coeffs, self.PARAMETERS["n_coeffs"])
        self.n_coeffs = n_coeffs
        self.name = f"pca-{n_coeffs}"
        self.basis_: np.ndarray | None = None

    def _map(self, brdf: BRDF) -> np.ndarray:
        c = cosine_weight(brdf.shape)[..., None]
        return log_relative(brdf.values, c, self.median_)[self.mask_]

    def fit(self, brdfs: Sequence[BRDF]) -> PCAModel:
        """Learn the median, mean and principal components of ``brdfs`` (at least 2, on
        one grid); returns ``self``."""
        if len(brdfs) < 2:
            raise UsageError(f"{self.name}: PCA needs at least 2 training BRDFs, "
                             f"got {len(brdfs)}")
        shape = brdfs[0].shape
        for b in brdfs:
            if b.shape != shape:
                first = brdfs[0].source or brdfs[0].name
                raise UsageError(f"{self.name}: training BRDFs on different grids: "
                                 f"{b.source or b.name} {b.shape}, {first} {shape}")
        self.mask_ = np.broadcast_to(brdfs[0].valid[..., None], (*shape, 3))
        for b in brdfs:
            self.mask_ = self.mask_ & b.valid[..., None]
        self.median_ = _median(brdfs)
        # in place where it can: each new GB of pages costs seconds in a VM
        centred = np.empty((len(brdfs), int(self.mask_.sum())))
        for row, b in zip(centred, brdfs, strict=True):
            row[:] = self._map(b)
        self.mean_ = centred.mean(0)
        centred -= self.mean_
        # thin products (N x bins): BLAS's own threads made them 10x slower on 2 cores
        with blas_single_thread():
            gram = centred @ centred.T
            w, v = np.linalg.eigh(gram)
            order = np.argsort(w)[::-1]
            w, v = w[order], v[:, order]
            keep = w > w[0] * 1e-12
            basis = v[:, keep].T @ centred  # (components, bins), no transposed copy
        basis /= np.sqrt(w[keep])[:, None]
        self.basis_ = basis.astype(np.float32)
        return self

    def compress(self, brdf: BRDF) -> Compact:
        require_fitted(self, self.basis_ is not None)
        if brdf.shape != self.mask_.shape[:3]:
            raise UsageError(f"{brdf.source or brdf.name}: BRDF grid {brdf.shape} does not "
                             f"match the {self.mask_.shape[:3]} grid {self.name} was fitted on")
        k = min(self.n_coeffs, self.basis_.shape[0])
        basis = self.basis_[:k]
        coef = basis @ (self._map(brdf) - self.mean_)
        m = np.zeros((*brdf.shape, 3))
        m[self.mask_] = self.mean_ + coef @ basis
        c = cosine_weight(brdf.shape)[..., None]
        rho = from_log_relative(m, c, self.median_)
        rho = np.where(self.mask_, np.maximum(rho, 0), 0).astype(np.float32)
        # per material only coef; the rest are references to the trained, shared state:
        # basis (k, M) and mean (M,) over the M masked (bin, channel) entries in C order
        # of mask (n1, n2, n3, 3); median (n1, n2, n3, 3); eps
        params = {"coef": _f32(coef), "shared_basis": basis, "shared_mean": self.mean_,
                  "shared_median": self.median_, "shared_mask": self.mask_,
                  "shared_eps": np.array(self.EPS, np.float32)}
        return Compact(self.name, k * _F32, lambda: rho, {"n_coeffs": k}, params)

    def __repr__(self) -> str:
        fitted = "unfitted" if self.basis_ is None else f"{self.basis_.shape[0]} components"
        return f"PCAModel({self.name!r}, {fitted})"
