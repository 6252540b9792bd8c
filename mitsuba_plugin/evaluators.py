"""Dr.Jit evaluators of the baseline models, each from its own stored numbers.

One evaluator per model kind of :mod:`sparse_brdf.compared.baselines` (the ``params`` of its
:class:`~sparse_brdf.compared.baselines.Compact`), never from a dense reconstruction, so that
what it costs to evaluate is the model's own cost:

============  =================================================================
``naive``     rho_c = kd_c + ks_c a_c[i] b_c[j] c_c[k]  (Bagher et al. 2016)
``cpd``       X_c = sum_r w_cr a_c[i, r] b_c[j, r] c_c[k, r], rho_c = exp(X_c) - 1
``tucker``    X_c = sum_pqs G_c[p, q, s] a_c[i, p] b_c[j, q] c_c[k, s],
              rho_c = exp(X_c) - 1
``pca``       m = mean[e] + sum_r coef_r basis[r, e] at the entry e of (bin, c),
              rho_c = (exp(m) (median[e] + eps) - eps) / clip(cos_i cos_o, 0.01, 1);
              0 outside the PCA mask  (Nielsen et al. 2015)
``nbrdf``     the 6 -> 21 -> 21 -> 3 network of :mod:`sparse_brdf.mlp` at the pair's
              half and difference vectors, rho = max(exp(z) - 1, 0)
              (Sztrajman et al. 2021)
============  =================================================================

For the kinds stored on the grid, (i, j, k) is the bin of the direction pair, found with
the plugins' own lookup (:func:`~mitsuba_plugin.kernels.angle_coords`,
:func:`~mitsuba_plugin.kernels.nearest_bins`), so the evaluators, ``tabulated_brdf`` and
``sparse_brdf`` index bins identically. As in the plugins, a bin below the horizon at its
angles (docs/method.md, "Grid, lookup convention, validity"), or a direction below the
horizon, gives 0, and values are clamped to >= 0 (as every model's ``reconstruct``
does). ``nbrdf`` is a continuous function: it is evaluated at the pair itself, 0 only
where a direction is below the horizon. Values are linear RGB BRDF values (1/sr),
without the cosine factor that ``BSDF.eval`` includes.

Per-material numbers live in Dr.Jit arrays and opaque scalars, as in the plugins: one
compiled kernel serves every material of a kind (and ranks / coefficient counts are
loop counts, not literals). Import this module lazily: it needs Dr.Jit and Mitsuba.

Example::

    import mitsuba as mi
    from mitsuba_plugin.evaluators import evaluator_for

    mi.set_variant("llvm_ad_rgb")
    ev = evaluator_for(NaiveModel().fit(brdf))
    rgb = ev.eval(mi.Vector3f(wi), mi.Vector3f(wo))   # mi.Color3f, one value per pair
"""

from __future__ import annotations

import importlib

import drjit as dr
import numpy as np

from sparse_brdf.decoders.layouts import PACKET

from .kernels import (
    Ops,
    Shape,
    VariantNamespace,
    angle_coords,
    bin_weight,
    expm1,
    mlp_forward,
    mlp_weights,
    nbrdf_rho,
    nearest_bins,
)

KINDS = ("naive", "cpd", "tucker", "pca", "nbrdf")


def _variant_module(variant: str | None) -> tuple[VariantNamespace, str]:
    import mitsuba as mi  # lazy: importing this module does not load Mitsuba

    name = variant or mi.variant()
    if name is None:
        raise RuntimeError("no Mitsuba variant is set: call mi.set_variant(...) first")
    return VariantNamespace(importlib.import_module(f"mitsuba.{name}")), name


def _require(kind: str, params: dict, keys, ndims) -> list[np.ndarray]:
    """The arrays ``params[key]``, checked for presence and number of axes."""
    if params is None:
        raise ValueError(f"{kind} evaluator: params is None (the model stored no params)")
    out = []
    for key, nd in zip(keys, ndims, strict=True):
        if key not in params:
            raise ValueError(f"{kind} evaluator: params lacks {key!r} (has "
                             f"{', '.join(sorted(params))})")
        a = np.asarray(params[key])
        if a.ndim != nd:
            raise ValueError(f"{kind} evaluator: params[{key!r}] must have {nd} axes, "
                             f"got shape {a.shape}")
        out.append(a)
    return out


def _check_factors(kind: str, factors, ranks) -> tuple[int, int, int]:
    """Grid shape from (3, n_m, r_m) factor arrays, checked against the ranks."""
    shape = []
    for key, f, r in zip("abc", factors, ranks, strict=True):
        if f.shape[0] != 3 or f.shape[2] != r:
            raise ValueError(f"{kind} evaluator: params[{key!r}] must have shape "
                             f"(3, n, {r}), got {f.shape}")
        shape.append(int(f.shape[1]))
    return tuple(shape)


def _interleave(f: np.ndarray) -> np.ndarray:
    """(3, n, r) per-channel factor -> (n, r, 3): RGB of (row, rank) contiguous."""
    return np.ascontiguousarray(np.moveaxis(np.asarray(f, np.float32), 0, -1))


class Evaluator:
    """Base of the evaluators: bin lookup, validity and clamping.

    Subclasses set ``kind`` and implement :meth:`_value`. Attributes: ``shape`` (the
    grid), ``memory_bytes`` (bytes of the arrays the evaluator holds, shared state
    included), ``material_bytes`` (of those, the per-material ones).
    """

    kind = "?"

    def __init__(self, params: dict, variant: str | None = None) -> None:
        self.m, self.variant = _variant_module(variant)
        self.ops = Ops(self.m)

    def _setup_shape(self, shape) -> None:
        self.shape = tuple(int(n) for n in shape)
        self._shape = Shape(self.ops, self.shape)

    def _value(self, bins, w, active):  # pragma: no cover - abstract
        """Unclamped RGB (Color3f) at the bins; ``w`` = clip(cos_i cos_o, 0.01, 1)."""
        raise NotImplementedError

    def eval(self, wi, wo, active=True):
        """Linear RGB BRDF values at the direction pairs (local shading frame).

        Parameters
        ----------
        wi, wo : Vector3f
            Unit directions of the variant (Dr.Jit arrays of n pairs in JIT variants).
        active : Bool
            Lanes to evaluate; the others give 0.

        Returns
        -------
        Color3f
            rho >= 0 per channel (1/sr), cosine not included; 0 where either direction
            or the pair's bin is below the horizon.
        """
        m, ops, sh = self.m, self.ops, self._shape
        ok = active & (wi.z > 0.0) & (wo.z > 0.0)
        bins = nearest_bins(ops, sh, angle_coords(ops, sh, wi, wo))
        w, valid = bin_weight(ops, sh, *bins, 1.0)
        ok = ok & valid
        rgb = self._value(bins, w, ok)
        return dr.select(ok, dr.maximum(rgb, 0.0), m.Color3f(0.0))

    def eval_numpy(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """:meth:`eval` of numpy direction pairs, shape (n, 3) each -> (n, 3) float32
        (JIT variants only)."""
        if not self.ops.jit:
            raise RuntimeError(f"eval_numpy needs a JIT variant, not {self.variant}")
        m = self.m
        wi = np.asarray(wi, np.float32).reshape(-1, 3)
        wo = np.asarray(wo, np.float32).reshape(-1, 3)
        out = self.eval(m.Vector3f(wi.T.copy()), m.Vector3f(wo.T.copy()))
        return np.asarray(out, np.float32).reshape(3, -1).T.copy()

    def _rgb(self, values) -> object:
        """A per-material Color3f of opaque scalars (kernel inputs, not literals)."""
        return self.m.Color3f(*(self.ops.f(float(v)) for v in values))

    def __repr__(self) -> str:
        return (f"{type(self).__name__}[shape={self.shape}, variant={self.variant}, "
                f"memory_bytes={self.memory_bytes}]")


class NaiveEvaluator(Evaluator):
    """Bagher et al.'s naive model: rho_c = kd_c + ks_c a_c[i] b_c[j] c_c[k].

    params: ``kd`` (3,), ``ks`` (3,), ``a`` (3, n1), ``b`` (3, n2), ``c`` (3, n3).
    """

    kind = "naive"

    def __init__(self, params: dict, variant: str | None = None) -> None:
        super().__init__(params, variant)
        kd, ks, a, b, c = _require(self.kind, params, ("kd", "ks", "a", "b", "c"),
                                   (1, 1, 2, 2, 2))
        for key, v in (("kd", kd), ("ks", ks)):
            if v.shape != (3,):
                raise ValueError(f"naive evaluator: params[{key!r}] must have shape (3,), "
                                 f"got {v.shape}")
        shape = _check_factors(self.kind, [f[..., None] for f in (a, b, c)], (1, 1, 1))
        self._setup_shape(shape)
        ops = self.ops
        self._kd, self._ks = self._rgb(kd), self._rgb(ks)
        self._f = [ops.floats(_interleave(f[..., None])) for f in (a, b, c)]
        self.memory_bytes = self.material_bytes = sum(ops.nbytes(f) for f in self._f) + 24

    def _value(self, bins, w, active):
        g = self.ops.gather3
        fa, fb, fc = self._f
        i, j, k = bins
        return self._kd + self._ks * g(fa, i, active) * g(fb, j, active) * g(fc, k, active)


class CPDEvaluator(Evaluator):
    """Rank-R CP decomposition of the log-plus tensor, per channel.

    params: ``weights`` (3, R), ``a`` (3, n1, R), ``b`` (3, n2, R), ``c`` (3, n3, R).
    A Dr.Jit loop over the R terms (an opaque count: one kernel for every rank).
    """

    kind = "cpd"

    def __init__(self, params: dict, variant: str | None = None) -> None:
        super().__init__(params, variant)
        wts, a, b, c = _require(self.kind, params, ("weights", "a", "b", "c"), (2, 3, 3, 3))
        if wts.shape[0] != 3:
            raise ValueError(f"cpd evaluator: params['weights'] must have shape (3, R), "
                             f"got {wts.shape}")
        rank = int(wts.shape[1])
        self._setup_shape(_check_factors(self.kind, (a, b, c), (rank,) * 3))
        ops = self.ops
        self.rank = rank
        self._r = ops.u(rank)
        self._w = ops.floats(np.asarray(wts, np.float32).T)  # (R, 3)
        self._f = [ops.floats(_interleave(f)) for f in (a, b, c)]  # (n, R, 3)
        self.memory_bytes = self.material_bytes = (
            ops.nbytes(self._w) + sum(ops.nbytes(f) for f in self._f))

    def _value(self, bins, w, active):
        m, ops = self.m, self.ops
        g = ops.gather3
        fa, fb, fc = self._f
        i, j, k = bins
        rank = self._r

        def body(r, acc):
            return acc + (g(self._w, r, active) * g(fa, i * rank + r, active)
                          * g(fb, j * rank + r, active) * g(fc, k * rank + r, active))

        x = ops.loop(rank, body, m.Color3f(0.0))
        return m.Color3f(*(expm1(x[c]) for c in range(3)))


class TuckerEvaluator(Evaluator):
    """Tucker decomposition (ranks r1 x r2 x r3) of the log-plus tensor, per channel.

    params: ``core`` (3, r1, r2, r3), ``a`` (3, n1, r1), ``b`` (3, n2, r2),
    ``c`` (3, n3, r3). A Dr.Jit loop over the r1 r2 r3 core entries, whose (p, q, s)
    come from a small index buffer.
    """

    kind = "tucker"

    def __init__(self, params: dict, variant: str | None = None) -> None:
        super().__init__(params, variant)
        core, a, b, c = _require(self.kind, params, ("core", "a", "b", "c"), (4, 3, 3, 3))
        if core.shape[0] != 3:
            raise ValueError(f"tucker evaluator: params['core'] must have shape "
                             f"(3, r1, r2, r3), got {core.shape}")
        ranks = tuple(int(r) for r in core.shape[1:])
        self._setup_shape(_check_factors(self.kind, (a, b, c), ranks))
        ops = self.ops
        self.ranks = ranks
        self._n = ops.u(int(np.prod(ranks)))
        self._ranks = tuple(ops.u(r) for r in ranks)
        self._g = ops.floats(np.moveaxis(np.asarray(core, np.float32), 0, -1))  # (T, 3)
        pqs = np.stack(np.unravel_index(np.arange(int(np.prod(ranks))), ranks), -1)
        self._pqs = ops.uints(pqs)  # (T, 3): (p, q, s) of core entry t
        self._f = [ops.floats(_interleave(f)) for f in (a, b, c)]  # (n, r, 3)
        self.material_bytes = ops.nbytes(self._g) + sum(ops.nbytes(f) for f in self._f)
        self.memory_bytes = self.material_bytes + ops.nbytes(self._pqs)

    def _value(self, bins, w, active):
        m, ops = self.m, self.ops
        g, gu = ops.gather3, ops.gather_u
        fa, fb, fc = self._f
        i, j, k = bins
        r1, r2, r3 = self._ranks

        def body(t, acc):
            p = gu(self._pqs, 3 * t, active)
            q = gu(self._pqs, 3 * t + 1, active)
            s = gu(self._pqs, 3 * t + 2, active)
            return acc + (g(self._g, t, active) * g(fa, i * r1 + p, active)
                          * g(fb, j * r2 + q, active) * g(fc, k * r3 + s, active))

        x = ops.loop(self._n, body, m.Color3f(0.0))
        return m.Color3f(*(expm1(x[c]) for c in range(3)))


class PCAEvaluator(Evaluator):
    """Nielsen et al.'s PCA in the log-relative mapping.

    params: ``coef`` (k,) per material; shared: ``shared_basis`` (k, M),
    ``shared_mean`` (M,) over the M masked entries of ``shared_mask`` (n1, n2, n3, 3) in C
    order, ``shared_median`` (n1, n2, n3, 3), ``shared_eps`` (scalar).

    Layout: one row per masked (bin, channel) entry e, ``[mean[e], median[e] + eps,
    basis[0, e], ..., basis[k-1, e]]`` padded to whole packets of ``PACKET`` floats, plus
    a zero row for the entries outside the mask; a UInt32 table maps (bin, channel) to
    its row. The coefficients are stored as ``[0, 0, coef..., 0...]`` aligned with the
    rows, so a lookup reads three rows (one per channel) packet by packet in a Dr.Jit
    loop (an opaque packet count: one kernel for every k) and takes the mean and median
    from the cache line of the row's first packet. The shared rows are the bulk of the
    memory (about (k + 2) x 4.4 M floats on the MERL grid).
    """

    kind = "pca"
    _HEAD = 2  # mean, median + eps

    def __init__(self, params: dict, variant: str | None = None) -> None:
        super().__init__(params, variant)
        coef, basis, mean, median, mask = _require(
            self.kind, params, ("coef", "shared_basis", "shared_mean", "shared_median",
                                "shared_mask"), (1, 2, 1, 4, 4))
        eps = float(params.get("shared_eps", 1e-3))
        mask = mask.astype(bool)
        n_masked = int(mask.sum())
        k = int(coef.size)
        if mask.shape[-1] != 3 or median.shape != mask.shape:
            raise ValueError(f"pca evaluator: shared_mask and shared_median must have one "
                             f"shape (n1, n2, n3, 3), got {mask.shape} and {median.shape}")
        if basis.shape != (k, n_masked) or mean.shape != (n_masked,):
            raise ValueError(f"pca evaluator: with {k} coefficients and {n_masked} masked "
                             f"entries, shared_basis must be ({k}, {n_masked}) and "
                             f"shared_mean ({n_masked},), got {basis.shape}, {mean.shape}")
        self._setup_shape(mask.shape[:3])
        ops = self.ops
        self.n_coeffs = k
        head = self._HEAD
        chunks = -(-(k + head) // PACKET)
        width = chunks * PACKET
        rows = np.zeros((n_masked + 1, width), np.float32)
        rows[:n_masked, 0] = mean
        rows[:n_masked, 1] = np.asarray(median, np.float32)[mask] + np.float32(eps)
        rows[:n_masked, head:head + k] = np.asarray(basis, np.float32).T
        row_of = np.full(mask.size, n_masked, np.uint32)
        row_of[mask.ravel()] = np.arange(n_masked, dtype=np.uint32)
        coefs = np.zeros(width, np.float32)
        coefs[head:head + k] = coef
        self._rows = ops.floats(rows)
        del rows
        self._row_of = ops.uints(row_of)
        self._coef = ops.floats(coefs)
        self._chunks = ops.u(chunks)
        self._width = ops.u(width)
        self._n_masked = ops.u(n_masked)
        self._eps = ops.f(eps)
        self.material_bytes = ops.nbytes(self._coef)
        self.memory_bytes = sum(ops.nbytes(b) for b in (self._rows, self._row_of, self._coef))

    def _value(self, bins, w, active):
        m, ops = self.m, self.ops
        i, j, k = bins
        n1, n2, n3 = self._shape.n
        flat = ((i * n2 + j) * n3 + k) * 3
        rows = [ops.gather_u(self._row_of, flat + c, active) for c in range(3)]
        oks = [active & (r < self._n_masked) for r in rows]
        chunks = self._chunks
        rows_buf, coef_buf = self._rows, self._coef

        def fma(a, b, c):
            return dr.fma(a, b, c) if ops.jit else a * b + c

        def body(h, acc):
            cp = ops.gather_packet(coef_buf, h, PACKET, active)
            out = []
            for c in range(3):
                bp = ops.gather_packet(rows_buf, rows[c] * chunks + h, PACKET, oks[c])
                x = acc[c]
                for lane in range(PACKET):
                    x = fma(bp[lane], cp[lane], x)
                out.append(x)
            return tuple(out)

        zero = m.Float(0.0) if ops.jit else 0.0
        dots = ops.loop(chunks, body, (zero,) * 3)
        inv_w = dr.rcp(w)
        out = []
        for c in range(3):
            base = rows[c] * self._width
            mean = ops.gather(rows_buf, base, oks[c])
            med = ops.gather(rows_buf, base + 1, oks[c])
            rho = (dr.exp(mean + dots[c]) * med - self._eps) * inv_w
            out.append(dr.select(oks[c], rho, 0.0))
        return m.Color3f(*out)


class NBRDFEvaluator(Evaluator):
    """Neural-BRDF (Sztrajman et al. 2021): the network of :mod:`sparse_brdf.mlp`.

    params: ``w1`` (6, 21), ``b1`` (21,), ``w2`` (21, 21), ``b2`` (21,), ``w3`` (21, 3),
    ``b3`` (3,) (any hidden widths). Evaluated at the pair itself, not at a bin: the
    input is the half vector with phi_h = 0, (sin th, 0, cos th), and the difference
    vector (:func:`~mitsuba_plugin.kernels.half_diff`), phi_d folded into [0, pi) by
    reciprocity (d -> (-dx, -dy, dz) where dy < 0). The layers are unrolled fused
    multiply-adds over the weights, which are opaque scalars (kernel inputs: one kernel
    for every network of these widths); hy = 0 drops a row of w1. 0 where either
    direction is below the horizon.
    """

    kind = "nbrdf"

    def __init__(self, params: dict, variant: str | None = None) -> None:
        super().__init__(params, variant)
        arrays = _require(self.kind, params, ("w1", "b1", "w2", "b2", "w3", "b3"),
                          (2, 1, 2, 1, 2, 1))
        layers = list(zip(arrays[::2], arrays[1::2], strict=True))
        width = 6
        for i, (k, b) in enumerate(layers, 1):
            if k.shape[0] != width or b.shape != (k.shape[1],):
                raise ValueError(f"nbrdf evaluator: params w{i} {k.shape} and b{i} {b.shape}"
                                 f" do not continue a layer of width {width}")
            width = k.shape[1]
        if width != 3:
            raise ValueError(f"nbrdf evaluator: the last layer must give 3 values, not {width}")
        self.shape = tuple(k.shape[1] for k, _ in layers)  # the layers' widths
        self._layers = mlp_weights(self.ops, [(np.asarray(k, np.float32),
                                               np.asarray(b, np.float32)) for k, b in layers])
        self.memory_bytes = self.material_bytes = 4 * sum(k.size + b.size for k, b in layers)

    def network(self, inputs):
        """The network's output z (before exp(z) - 1) at six input Floats (hy may be
        None: 0); returns a list of three Floats (:func:`~mitsuba_plugin.kernels.
        mlp_forward`)."""
        return mlp_forward(self.ops, self._layers, inputs)

    def eval(self, wi, wo, active=True):
        """As :meth:`Evaluator.eval`, at the pairs' own half and difference vectors
        (:func:`~mitsuba_plugin.kernels.nbrdf_rho`, shared with the ``neural_brdf``
        BSDF)."""
        m = self.m
        ok = active & (wi.z > 0.0) & (wo.z > 0.0)
        return dr.select(ok, nbrdf_rho(self.ops, self._layers, wi, wo), m.Color3f(0.0))


EVALUATORS: dict[str, type[Evaluator]] = {
    "naive": NaiveEvaluator, "cpd": CPDEvaluator, "tucker": TuckerEvaluator,
    "pca": PCAEvaluator, "nbrdf": NBRDFEvaluator,
}


def make_evaluator(kind: str, params: dict, variant: str | None = None) -> Evaluator:
    """The evaluator of model ``kind`` (one of :data:`KINDS`) from its ``params``, for
    ``variant`` (default: the current Mitsuba variant)."""
    if kind not in EVALUATORS:
        raise ValueError(f"no evaluator for model kind {kind!r}: expected one of "
                         f"{', '.join(KINDS)}")
    return EVALUATORS[kind](params, variant)


def evaluator_for(compact, variant: str | None = None) -> Evaluator:
    """The evaluator of a fitted :class:`~sparse_brdf.compared.baselines.Compact` (its ``kind``
    and ``params``)."""
    kind = compact.model.split("-", 1)[0]
    if compact.params is None:
        raise ValueError(f"{compact.model}: the compact model has no params to evaluate")
    return make_evaluator(kind, compact.params, variant)


__all__ = ["KINDS", "EVALUATORS", "Evaluator", "NaiveEvaluator", "CPDEvaluator",
           "TuckerEvaluator", "PCAEvaluator", "NBRDFEvaluator", "make_evaluator",
           "evaluator_for"]
