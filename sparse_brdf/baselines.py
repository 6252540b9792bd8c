"""Baseline BRDF models behind one interface: fit a BRDF -> compact model -> reconstruct.

Every model is a :class:`BRDFModel`: ``fit(brdf)`` returns a :class:`Compact` with
``reconstruct()`` (linear RGB values of the BRDF's grid shape, (n1, n2, n3, 3)) and
``nbytes`` (exact storage of what the model keeps per material, float32 numbers; shared
bases such as a PCA basis or an ensemble are not counted, as in the paper) and ``params``
(those stored numbers themselves, which :mod:`mitsuba_plugin.evaluators` evaluates at
direction pairs without a dense reconstruction). Models that learn from a training set
(PCA) have ``train(brdfs)``; using them untrained raises.

- :class:`SparseModel`   the paper's model over an ensemble (8 bytes per coefficient)
- :class:`NaiveModel`    Bagher et al. 2016: kd + ks a(theta_h) b(theta_d) c(phi_d) per
  channel (362 numbers), alternating weighted least squares
- :class:`CPDModel`      rank-L CPD of the log-plus tensor per channel (360 L numbers),
  via tensorly
- :class:`TuckerModel`   Tucker of the log-plus tensor per channel, via tensorly
- :class:`PCAModel`      Nielsen et al. 2015: PCA basis of the training set in the
  log-relative mapping ln((rho c + 0.001) / (median + 0.001))
- :class:`TabulatedModel` the full table (the upper bound)
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .brdf import BRDF
from .transforms import cosine_weight, forward, inverse

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


@dataclass
class Compact:
    """A fitted compact model of one BRDF.

    Attributes
    ----------
    model : str
        The model's name (``"naive"``, ``"cpd-1"``, ``"tucker-1x1x1"``, ``"pca-40"``,
        ``"tabulated"``, ``"sparse-262"``, ...); the part before the first ``-`` is its kind.
    nbytes : int
        Storage of the numbers kept per material (float32): the bytes of the arrays in
        ``params`` whose keys do not start with ``shared_``.
    reconstruct : callable
        Returns the dense linear RGB tensor, shape (n1, n2, n3, 3).
    info : dict or None
        Extra results (e.g. the sparse model itself under ``"model"``).
    params : dict of str to ndarray, or None
        Exactly the numbers the model stores per material, as float32 arrays (see each
        model's ``fit``); shared state the model needs to evaluate (e.g. a PCA basis) is
        referenced under keys prefixed ``shared_`` and not counted in ``nbytes``. What
        :mod:`mitsuba_plugin.evaluators` evaluates from. None for the sparse model (its
        :class:`~sparse_brdf.sparse.SparseBRDF` is ``info["model"]``).
    """

    model: str
    nbytes: int
    reconstruct: Callable[[], np.ndarray]
    info: dict | None = None
    params: dict[str, np.ndarray] | None = None

    @property
    def kind(self) -> str:
        """The model family: ``naive``, ``cpd``, ``tucker``, ``pca``, ``tabulated``,
        ``sparse`` (the name up to its first ``-``)."""
        return self.model.split("-", 1)[0]

    def param_nbytes(self) -> int:
        """Bytes of the per-material arrays in ``params`` (keys not prefixed ``shared_``)."""
        if self.params is None:
            raise ValueError(f"{self.model}: this compact model has no params")
        return sum(int(v.nbytes) for k, v in self.params.items()
                   if not k.startswith("shared_"))


class BRDFModel(ABC):
    """Fit a BRDF -> compact model -> reconstruct the tensor."""

    name: str = "model"

    def train(self, brdfs: Sequence[BRDF]) -> BRDFModel:  # noqa: B027 - optional hook
        """Learn shared state from training BRDFs (no-op for per-material models)."""
        return self

    @abstractmethod
    def fit(self, brdf: BRDF) -> Compact:
        """Fit ``brdf``; return its compact model."""


class TabulatedModel(BRDFModel):
    """The full tabulated BRDF (float32), the upper bound of every comparison."""

    name = "tabulated"

    def fit(self, brdf: BRDF) -> Compact:
        v = brdf.values.copy()
        return Compact(self.name, v.nbytes, lambda: v, params={"table": v})


class SparseModel(BRDFModel):
    """The sparse ensemble model at ``n_coeffs`` per channel (see :func:`encode`)."""

    def __init__(self, ensemble=None, n_coeffs: int = 262, transform: str = "auto"):
        from .ensemble import Ensemble

        self.ensemble = Ensemble.default() if ensemble is None else ensemble
        self.n_coeffs = n_coeffs
        self.transform = transform
        self.name = f"sparse-{n_coeffs}" + ("" if transform == "auto" else f"-{transform}")

    def fit(self, brdf: BRDF) -> Compact:
        from .encode import encode
        from .sbrdf import RECORD_BYTES

        m = encode(brdf, self.ensemble, self.n_coeffs, transform=self.transform)
        return Compact(self.name, RECORD_BYTES * int(m.n_coeffs.sum()),
                       lambda: m.decode(self.ensemble, valid=brdf.valid).values,
                       {"transform": m.transform, "model": m})


class NaiveModel(BRDFModel):
    """Bagher et al. 2016 "naive" model, per channel rho ~ kd + ks a(th) b(td) c(pd).

    Fitted by alternating weighted least squares (weights: valid bins times
    clip(cos_i cos_o, 0.01, 1), so that what the renderer integrates dominates).
    kd is kept >= 0; ks is folded into the unit-norm factors' scale.
    """

    name = "naive"

    def __init__(self, n_iter: int = 30):
        self.n_iter = n_iter

    def fit(self, brdf: BRDF) -> Compact:
        w = brdf.valid * cosine_weight(brdf.shape)
        out = []
        params = []
        for c in range(3):
            rho = brdf.values[..., c].astype(np.float64)
            kd, a, b, cc = self._fit_channel(rho, w)
            params.append((kd, a, b, cc))
            out.append(kd + np.einsum("i,j,k->ijk", a, b, cc))
        n = sum(1 + 1 + a.size + b.size + cc.size for _, a, b, cc in params)
        rec = np.maximum(np.stack(out, -1), 0).astype(np.float32)
        return Compact(self.name, n * _F32, lambda: rec, params=_naive_params(params))

    def _fit_channel(self, rho, w):
        n1, n2, n3 = rho.shape
        kd = float(np.percentile(rho[w > 0], 5)) if np.any(w > 0) else 0.0
        a, b, c = np.ones(n1), np.ones(n2), np.ones(n3)
        for _ in range(self.n_iter):
            r = rho - kd
            a = np.einsum("ijk,ijk,j,k->i", w, r, b, c) / np.maximum(
                np.einsum("ijk,j,k->i", w, b * b, c * c), 1e-30)
            b = np.einsum("ijk,ijk,i,k->j", w, r, a, c) / np.maximum(
                np.einsum("ijk,i,k->j", w, a * a, c * c), 1e-30)
            c = np.einsum("ijk,ijk,i,j->k", w, r, a, b) / np.maximum(
                np.einsum("ijk,i,j->k", w, a * a, b * b), 1e-30)
            prod = np.einsum("i,j,k->ijk", a, b, c)
            kd = max(float(np.sum(w * (rho - prod)) / max(np.sum(w), 1e-30)), 0.0)
        return kd, a, b, c


def _log_plus_channels(brdf: BRDF) -> np.ndarray:
    return forward(brdf.channel_first(), "log-plus", brdf.valid).astype(np.float64)


class CPDModel(BRDFModel):
    """Rank-``rank`` CP decomposition of the log-plus tensor of each channel (tensorly).

    Invalid bins are masked out (tensorly's EM imputation), not fitted as zeros.
    """

    def __init__(self, rank: int = 1, n_iter: int = 30, seed: int = 0):
        self.rank, self.n_iter, self.seed = rank, n_iter, seed
        self.name = f"cpd-{rank}"

    def fit(self, brdf: BRDF) -> Compact:
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

    def __init__(self, ranks: tuple[int, int, int] = (1, 1, 1), seed: int = 0):
        self.ranks, self.seed = tuple(ranks), seed
        self.name = "tucker-" + "x".join(map(str, self.ranks))

    def fit(self, brdf: BRDF) -> Compact:
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


class PCAModel(BRDFModel):
    """Nielsen et al. 2015: a PCA basis of the training set in the log-relative mapping.

    Mapping: m = ln((rho c + eps) / (median + eps)), eps = 0.001, c = clip(cos_i cos_o,
    0.01, 1), median per bin and channel over the training set. A BRDF is the mean plus
    its projection on the first ``n_coeffs`` principal components (at most N - 1 for N
    training BRDFs).
    """

    EPS = 1e-3

    def __init__(self, n_coeffs: int = 40):
        self.n_coeffs = n_coeffs
        self.name = f"pca-{n_coeffs}"
        self.basis_: np.ndarray | None = None

    def _map(self, brdf: BRDF) -> np.ndarray:
        c = cosine_weight(brdf.shape)[..., None]
        return np.log((brdf.values * c + self.EPS) / (self.median_ + self.EPS))[self.mask_]

    def train(self, brdfs: Sequence[BRDF]) -> PCAModel:
        if len(brdfs) < 2:
            raise ValueError("PCA needs at least 2 training BRDFs")
        shape = brdfs[0].shape
        self.mask_ = np.broadcast_to(brdfs[0].valid[..., None], (*shape, 3))
        for b in brdfs:
            self.mask_ = self.mask_ & b.valid[..., None]
        c = cosine_weight(shape)[..., None]
        self.median_ = np.median(np.stack([b.values * c for b in brdfs]), axis=0)
        data = np.stack([self._map(b) for b in brdfs]).astype(np.float64)
        self.mean_ = data.mean(0)
        centred = data - self.mean_
        gram = centred @ centred.T
        w, v = np.linalg.eigh(gram)
        order = np.argsort(w)[::-1]
        w, v = w[order], v[:, order]
        keep = w > w[0] * 1e-12
        self.basis_ = ((centred.T @ v[:, keep]) / np.sqrt(w[keep])).T.astype(np.float32)
        return self

    def fit(self, brdf: BRDF) -> Compact:
        if self.basis_ is None:
            raise RuntimeError(f"{self.name}: call train() with training BRDFs first")
        k = min(self.n_coeffs, self.basis_.shape[0])
        basis = self.basis_[:k]
        coef = basis @ (self._map(brdf) - self.mean_)
        m = np.zeros((*brdf.shape, 3))
        m[self.mask_] = self.mean_ + coef @ basis
        c = cosine_weight(brdf.shape)[..., None]
        rho = ((np.exp(m) * (self.median_ + self.EPS)) - self.EPS) / c
        rho = np.where(self.mask_, np.maximum(rho, 0), 0).astype(np.float32)
        # per material only coef; the rest are references to the trained, shared state:
        # basis (k, M) and mean (M,) over the M masked (bin, channel) entries in C order
        # of mask (n1, n2, n3, 3); median (n1, n2, n3, 3); eps
        params = {"coef": _f32(coef), "shared_basis": basis, "shared_mean": self.mean_,
                  "shared_median": self.median_, "shared_mask": self.mask_,
                  "shared_eps": np.array(self.EPS, np.float32)}
        return Compact(self.name, k * _F32, lambda: rho, {"n_coeffs": k}, params)
