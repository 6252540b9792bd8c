"""Dr.Jit building blocks shared by the two BSDFs, written once for every variant.

Each function takes an :class:`Ops` bound to one Mitsuba variant module. In JIT variants
(``llvm_*``) buffers are ``Float``/``UInt32`` arrays and gathers are ``dr.gather``; in
scalar variants buffers are numpy arrays indexed with Python ints, so the same code
serves both. Everything here is traced once into a kernel: no Python ``if`` on arrays,
and per-material numbers only as buffers or ``dr.opaque`` scalars (see :meth:`Ops.u`,
:meth:`Ops.f`), never as Python constants. The few functions a scalar variant runs once
per BSDF call on plain Python floats use the scalar helpers :func:`point_weight` and
:func:`point_rho` (:func:`rho_from_x` branches to the latter), fused for one bin in
:func:`point_rho_from_cos`.
"""

from __future__ import annotations

import math
import struct
import threading

import drjit as dr

from sparse_brdf.coords import grid_coords
from sparse_brdf.decoders.buffers import (
    angle_tables,
    float_buffer,
    read_rgb2spec_table,
    uint_buffer,
)
from sparse_brdf.transforms import COS_CLIP, LOBE_KNEE, LOBE_POWER, floor_value

_W_LO, _W_HI = COS_CLIP
_LOG_KNEE = math.log(LOBE_KNEE)
_F32 = struct.Struct("<f")  # a double rounded to float32, as the kernels hold it


class VariantNamespace:
    """Attribute access to one variant module, falling back to variant-independent names
    (``BSDFFlags``, ``BSDFContext``, ...), which live in ``mitsuba.mitsuba_ext``."""

    def __init__(self, module) -> None:
        from mitsuba import mitsuba_ext  # lazy: `import mitsuba_plugin` does not load Mitsuba

        self._module = module
        self._ext = mitsuba_ext
        self.name = module.__name__.rsplit(".", 1)[-1]

    def __getattr__(self, name: str):
        try:
            value = getattr(self._module, name)
        except AttributeError:
            value = getattr(self._ext, name)
        # kept: the next lookup is a plain attribute read (a scalar variant's BSDF looks
        # up e.g. Color3f on every call; through this method it took 0.7 us)
        setattr(self, name, value)
        return value


class Ops:
    """Storage and gathers for one variant module ``m`` (e.g. ``mitsuba.llvm_ad_rgb``)."""

    def __init__(self, m) -> None:
        self.m = m
        self.jit = bool(dr.is_jit_v(m.Float))

    # buffers and opaque scalars ------------------------------------------------------
    def floats(self, a):
        """A numpy array as a Float buffer (aligned, see
        :func:`sparse_brdf.decoders.layouts.float_buffer`)."""
        a = float_buffer(a)
        return self.m.Float(a) if self.jit else a

    def uints(self, a):
        """A numpy array as a UInt32 buffer."""
        a = uint_buffer(a)
        return self.m.UInt32(a) if self.jit else a

    def u(self, v: int):
        """A per-material unsigned integer that is a kernel input, not a literal."""
        return dr.opaque(self.m.UInt32, int(v)) if self.jit else int(v)

    def f(self, v: float):
        """A per-material float that is a kernel input, not a literal."""
        return dr.opaque(self.m.Float, float(v)) if self.jit else float(v)

    def nbytes(self, buf) -> int:
        return int(dr.width(buf) * 4) if self.jit else int(buf.nbytes)

    # gathers -------------------------------------------------------------------------
    def gather(self, buf, idx, active=True):
        if self.jit:
            return dr.gather(self.m.Float, buf, idx, active)
        return float(buf[int(idx)]) if active else 0.0

    def gather_u(self, buf, idx, active=True):
        if self.jit:
            return dr.gather(self.m.UInt32, buf, idx, active)
        return int(buf[int(idx)]) if active else 0

    def gather3(self, buf, idx, active=True):
        """Three consecutive floats buf[3 idx + (0, 1, 2)] as a Color3f."""
        if self.jit:
            return dr.gather(self.m.Color3f, buf, idx, active)
        if not active:
            return self.m.Color3f(0.0)
        i = 3 * int(idx)
        return self.m.Color3f(float(buf[i]), float(buf[i + 1]), float(buf[i + 2]))

    def gather_packet(self, buf, row, width: int, active=True):
        """The ``width`` contiguous floats buf[row * width + (0 .. width - 1)], as a
        sequence of ``width`` Floats (a packet load in JIT variants)."""
        if self.jit:
            return dr.gather(self.m.ArrayXf, buf, row, active,
                             shape=(width, dr.width(row)))
        if not active:
            return [0.0] * width
        r = int(row) * width
        return [float(v) for v in buf[r:r + width]]

    def to_u(self, x):
        """Non-negative float -> UInt32 (truncation)."""
        return self.m.UInt32(x) if self.jit else int(x)

    def where(self, cond, a, b):
        """``dr.select`` in JIT variants, a Python conditional in scalar ones."""
        if self.jit:
            return dr.select(cond, a, b)
        return a if cond else b

    def loop(self, n, body, init, sum_style: bool = False):
        """acc = init; for g in range(n): acc = body(g, acc) -- a Dr.Jit loop over an
        opaque count, so one kernel serves any n. ``sum_style``: the body only adds to
        ``acc`` terms that do not depend on it, which lets Dr.Jit differentiate the loop
        in reverse mode without storing its trajectory (set only when differentiating,
        so undifferentiated kernels are unchanged). In JIT variants the loop is symbolic
        by request, which is what the default ("auto") gives, but then Dr.Jit's
        differentiation of it no longer logs a warning per traced loop, which flooded
        stderr during ``render_backward``."""
        m = self.m
        extra = {"max_iterations": -1} if sum_style else {}
        if self.jit:
            extra.update(mode="symbolic", label="sparse_brdf")
        _, acc = dr.while_loop(
            state=(m.UInt32(0), init),
            cond=lambda g, acc: g < n,
            body=lambda g, acc: (g + 1, body(g, acc)),
            **extra,
        )
        return acc


def expm1(x):
    """exp(x) - 1 without cancellation for small x.

    |x| < 0.1: a degree-6 Taylor polynomial (relative error below 3e-10); otherwise
    exp(x) - 1 (relative error below 2e-6 there). Cheaper than Kahan's log-based trick:
    one exp and six fused multiply-adds, no log or division.
    """
    p = 1.0 / 720.0
    for c in (1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0):
        p = dr.fma(p, x, c)
    return dr.select(dr.abs(x) < 0.1, p * x, dr.exp(x) - 1.0)


def point_rho(x0: float, x1: float, x2: float, scale: float, floor: float = 0.0) -> tuple:
    """The inverse transform of one point in a scalar variant: ``max(expm1(X) scale, 0)``
    per channel for ``scale = valid / w > 0`` (Python floats, 1/sr), 0 below ``floor``
    (a floor transform's value, :func:`sparse_brdf.transforms.floor_value`; 0: none).
    ``math.expm1`` in double precision; where it would overflow a double, X is capped at
    700 (the value is then inf once stored as float32, as the kernel's is past 88.7)."""
    try:  # unrolled: this runs once per BSDF call
        r0, r1, r2 = math.expm1(x0) * scale, math.expm1(x1) * scale, math.expm1(x2) * scale
    except OverflowError:
        r0, r1, r2 = (math.expm1(min(x, 700.0)) * scale for x in (x0, x1, x2))
    if floor > 0.0:  # the kernels compare float32 values: so does this
        f32 = _F32.pack
        return tuple(r if _F32.unpack(f32(r))[0] >= floor else 0.0 for r in (r0, r1, r2))
    return (r0 if r0 > 0.0 else 0.0, r1 if r1 > 0.0 else 0.0, r2 if r2 > 0.0 else 0.0)


def point_weight(c: float) -> float:
    """The transform weight clip(c, 0.01, 1) of a bin's ``c = cos_i cos_o`` (a Python
    float; scalar variants)."""
    return (c if c > _W_LO else _W_LO) if c < _W_HI else _W_HI


def point_rho_from_cos(x0: float, x1: float, x2: float, c: float, use_cos: bool,
                       s: float) -> tuple:
    """One bin's RGB in a scalar variant from its transformed R, G, B and its ``c =
    cos_i cos_o``: :func:`bin_weight_from_cos` and :func:`rho_from_x` in one call (the
    scalar variants' default lookup runs it once per BSDF call). ``s``: the transform's
    scale (the weight is ``s w``). 0 where the bin is invalid (c <= 0)."""
    if not c > 0.0:
        return (0.0, 0.0, 0.0)
    return point_rho(x0, x1, x2, 1.0 / ((point_weight(c) if use_cos else 1.0) * s))


def point_rho_lobe(ops: Ops, shape: Shape, xs, c: float, use_cos: bool, s: float, lobe,
                   i: int, floor: float = 0.0) -> tuple:
    """:func:`point_rho_from_cos` for a lobe transform's material in a scalar variant:
    the bin's weight, the lobe's x (:func:`lobe_x`, the lobe at theta_h row ``i``), the
    inverse transform (0 below ``floor``, as :func:`point_rho`); 0 where the bin is
    invalid (c <= 0)."""
    if not c > 0.0:
        return (0.0, 0.0, 0.0)
    w = (point_weight(c) if use_cos else 1.0) * s
    xs = lobe_x(ops, xs, w, lobe_d(ops, shape, i, lobe[0]), lobe)
    return point_rho(xs[0], xs[1], xs[2], 1.0 / w, floor)


def rho_from_x(ops: Ops, xs, valid, w, floor=None) -> list | tuple:
    """The inverse transform of the transformed values ``xs`` (R, G, B: its first three
    items) at a bin (or point) of validity ``valid`` (1 or 0, or interpolated) and weight
    ``w``: ``max((exp(X) - 1) valid / w, 0)`` per channel (1/sr), 0 where ``valid / w``
    is 0, and 0 below ``floor`` (a floor transform's value,
    :func:`sparse_brdf.transforms.floor_value`, a Float or a Python float; None: none).
    Returns three values (Floats, or Python floats in scalar variants, from
    :func:`point_rho`).

    A select, not only the product: an invalid bin gives 0 even where the model's X
    there is large enough for exp to overflow (inf * 0 = nan).
    """
    if not ops.jit:
        scale = valid / w
        if not scale > 0.0:
            return (0.0, 0.0, 0.0)
        return point_rho(xs[0], xs[1], xs[2], scale, 0.0 if floor is None else float(floor))
    scale = valid * dr.rcp(w)
    rho = [dr.select(scale > 0.0, dr.maximum(expm1(x) * scale, 0.0), 0.0) for x in xs[:3]]
    if floor is None:  # a Python branch: materials without a floor trace no select
        return rho
    return [dr.select(r < floor, 0.0, r) for r in rho]


def lobe_inputs(ops: Ops, model) -> tuple:
    """A sparse model's (base lobe, floor) as kernel inputs: a lobe transform's 7
    numbers and a floor transform's value f L (1/sr, :func:`sparse_brdf.transforms.
    floor_value`) as opaque scalars (Python floats in scalar variants); None for a model
    without them (or with floor 0), so that its kernels trace neither."""
    lobe = None if model.lobe is None else tuple(ops.f(v) for v in model.lobe)
    floor = ops.f(floor_value(model.floor, model.gain)) if model.floor > 0.0 else None
    return lobe, floor


def lobe_d(ops: Ops, shape: Shape, i, alpha):
    """The base lobe's GGX D(theta_h; alpha) at the lower edge of theta_h row ``i``:
    alpha^2 / (pi (alpha^2 cos^2 + sin^2)^2) from the angle tables (the sine keeps it
    exact near the peak, where a float32 cosine rounds to 1), as
    :func:`sparse_brdf.transforms.ggx`."""
    c, s = ops.gather(shape.trig[0], i), ops.gather(shape.trig[1], i)
    a2 = alpha * alpha
    den = a2 * c * c + s * s
    return a2 / (math.pi * den * den)


def lobe_d_at(ops: Ops, shape: Shape, bins, lin, alpha):
    """:func:`lobe_d` at the nearest bin (``bins``) or, interpolating (``lin``), its
    linear blend between the two theta_h rows around the point."""
    if lin is None:
        return lobe_d(ops, shape, bins[0], alpha)
    i0, i1, ti = lin[0]
    return (1.0 - ti) * lobe_d(ops, shape, i0, alpha) + ti * lobe_d(ops, shape, i1, alpha)


def lobe_x(ops: Ops, xs, w, d, lobe) -> list:
    """A lobe transform's coded R, G, B back to x = ln(rho w + 1), the value
    :func:`rho_from_x` inverts: ``x_c = X_c (K / (b_c w + 1))^G + ln(b_c w + 1)`` with
    ``b_c = kd_c + ks_c d`` (:func:`sparse_brdf.transforms.from_lobe`). ``w``: the full
    weight (scale included); ``d``: :func:`lobe_d_at`; ``lobe``: alpha, kd (R, G, B), ks
    (R, G, B), opaque scalars (Python floats in scalar variants). ln(1 + u) as
    ln(v) u / (v - 1), v = 1 + u, exact for small u without a log1p."""
    out = []
    for c in range(3):
        u = (lobe[1 + c] + lobe[4 + c] * d) * w
        if ops.jit:
            v = 1.0 + u
            o = dr.select(v == 1.0, u, dr.log(v) * u / (v - 1.0))
            out.append(dr.fma(xs[c], dr.exp(LOBE_POWER * (_LOG_KNEE - o)), o))
        else:
            o = math.log1p(u)
            out.append(xs[c] * math.exp(LOBE_POWER * (_LOG_KNEE - o)) + o)
    return out


def mix_colour(xs, mt):
    """Transformed R, G, B from the three coded values ``xs``: ``M^T @ xs`` for the
    constant matrix ``mt`` (M^T as nested Python floats, from
    :func:`sparse_brdf.decoders.layouts.colour_mix`): at most 9 multiply-adds, its zero
    entries skipped. Kernel constants, not opaque scalars: one colour basis, one matrix.
    The caller skips this for the "rgb" basis (``mt`` None), so rgb kernels are unchanged.
    """
    out = []
    for row in mt:
        acc = None
        for v, x in zip(row, xs, strict=True):
            if v != 0.0:
                acc = v * x if acc is None else dr.fma(v, x, acc)
        out.append(0.0 * xs[0] if acc is None else acc)
    return out


class Shape:
    """A material's grid shape as opaque scalars (plus its Python values), and the
    cosines and sines of its bins' lower-edge angles as small buffers."""

    def __init__(self, ops: Ops, shape) -> None:
        self.py = tuple(int(n) for n in shape)
        self.n = tuple(ops.u(n) for n in self.py)
        self.nf = tuple(ops.f(n) for n in self.py)
        self.trig = tuple(ops.floats(a) for a in angle_tables(self.py))


_SHAPES: dict = {}
_SHAPES_LOCK = threading.Lock()


def shared_shape(ops: Ops, shape) -> Shape:
    """The :class:`Shape` of grid ``shape`` in variant ``ops``, made once and shared by
    every material on that grid (its angle tables are the grid's, not the material's)."""
    key = (ops, tuple(int(n) for n in shape))
    with _SHAPES_LOCK:
        if key not in _SHAPES:
            _SHAPES[key] = Shape(ops, key[1])
        return _SHAPES[key]


def half_diff(wi, wo):
    """The half vector's angle and the difference vector of a direction pair, phi_h = 0.

    Returns ``(st, ct, dx, dy, dz)``: sin and cos of theta_h, and the difference vector
    d = R_y(-theta_h) R_z(-phi_h) wi (docs/method.md, "Grid"), so that the half vector
    with phi_h = 0 is (st, 0, ct). Only arithmetic and square roots (no trigonometry).
    """
    h = dr.normalize(wi + wo)
    st = dr.sqrt(dr.maximum(h.x * h.x + h.y * h.y, 0.0))
    ct = h.z
    has = st > 0.0
    inv = dr.rcp(dr.maximum(st, 1e-30))
    cp = dr.select(has, h.x * inv, 1.0)
    sp = dr.select(has, h.y * inv, 0.0)
    x = cp * wi.x + sp * wi.y
    y = cp * wi.y - sp * wi.x
    z = wi.z
    return st, ct, ct * x - st * z, y, st * x + ct * z


def mlp_weights(ops: Ops, layers) -> list:
    """A Neural-BRDF network's (kernel, bias) pairs (float32 arrays, kernel (n_in, n_out))
    as nested lists of opaque scalars (kernel inputs: one kernel for every network of
    these widths)."""
    return [([[ops.f(v) for v in row] for row in k.tolist()], [ops.f(v) for v in b.tolist()])
            for k, b in layers]


def mlp_forward(ops: Ops, weights, inputs) -> list:
    """The network's output z (before exp(z) - 1) at its input Floats (an input may be
    None: 0, its row of the first kernel skipped); dense layers unrolled into fused
    multiply-adds, ReLU after all but the last (the Dr.Jit twin of
    :func:`sparse_brdf.mlp.forward`). Returns a list of the last layer's Floats."""
    h = inputs
    for n, (rows, bias) in enumerate(weights):
        out = []
        for j, acc in enumerate(bias):
            for x, row in zip(h, rows, strict=True):
                if x is not None:
                    acc = dr.fma(x, row[j], acc) if ops.jit else x * row[j] + acc
            out.append(dr.maximum(acc, 0.0) if n < len(weights) - 1 else acc)
        h = out
    return h


def nbrdf_rho(ops: Ops, weights, wi, wo):
    """A Neural-BRDF network's value at direction pairs: max(exp(z) - 1, 0) per channel
    (linear RGB, 1/sr; a Color3f), z the network at the pair's own half vector with
    phi_h = 0, (sin th, 0, cos th), and difference vector (:func:`half_diff`), phi_d
    folded into [0, pi) by reciprocity (d -> (-dx, -dy, dz) where dy < 0); hy = 0 drops a
    row of the first kernel. Directions below the horizon are the caller's to mask."""
    st, ct, dx, dy, dz = half_diff(wi, wo)
    flip = dy < 0.0
    dx, dy = dr.select(flip, -dx, dx), dr.select(flip, -dy, dy)
    z = mlp_forward(ops, weights, [st, None, ct, dx, dy, dz])
    return ops.m.Color3f(*(dr.maximum(expm1(c), 0.0) for c in z))


def angle_coords(ops: Ops, shape: Shape, wi, wo):
    """Continuous grid coordinates (x_h, x_d, x_p) of a direction pair (docs/method.md,
    "Grid, lookup convention, validity").

    The angles' :func:`sparse_brdf.coords.grid_coords`, phi_d folded into [0, pi):
    floor(x) is the bin, x itself the position between the bins' lower-edge samples (for
    interpolation). Angles use atan2 rather than acos so that small theta_h keeps its
    precision in float32.
    """
    st, ct, dx, y, dz = half_diff(wi, wo)
    theta_h = dr.atan2(st, ct)
    theta_d = dr.atan2(dr.sqrt(dx * dx + y * y), dz)
    phi_d = dr.atan2(y, dx)
    phi_d = dr.select(phi_d < 0.0, phi_d + math.pi, phi_d)
    return grid_coords(dr.maximum(theta_h, 0.0), theta_d, phi_d, shape.nf, sqrt=dr.sqrt)


def nearest_bins(ops: Ops, shape: Shape, coords):
    """Integer bins (i, j, k), clamped to the grid."""
    out = []
    for x, nf in zip(coords, shape.nf, strict=True):
        out.append(ops.to_u(dr.clip(dr.floor(x), 0.0, nf - 1.0)))
    return tuple(out)


def linear_bins(ops: Ops, shape: Shape, coords):
    """Per mode (i0, i1, t): the two neighbouring lower-edge samples and the weight of i1.

    theta_h and theta_d clamp at the grid's ends; phi_d wraps around (period pi).
    """
    out = []
    for mode, (x, nf, n) in enumerate(zip(coords, shape.nf, shape.n, strict=True)):
        if mode < 2:
            xc = dr.clip(x, 0.0, nf - 1.0)
            f0 = dr.minimum(dr.floor(xc), dr.maximum(nf - 2.0, 0.0))
            t = dr.clip(xc - f0, 0.0, 1.0)
            i0 = ops.to_u(f0)
            i1 = dr.minimum(i0 + 1, n - 1)
        else:
            xc = dr.clip(x, 0.0, nf)
            f0 = dr.floor(xc)
            t = xc - f0
            i0 = ops.to_u(dr.minimum(f0, nf - 1.0))
            i1 = i0 + 1
            i1 = dr.select(i1 >= n, i1 - n, i1)
            t = dr.select(f0 >= nf, 1.0, t)  # x = n3 is the sample at 0
        out.append((i0, i1, t))
    return tuple(out)


def cos_terms(ops: Ops, shape: Shape, i, j, k):
    """cos(theta_i) cos(theta_o) at the lower-edge angles of bin (i, j, k), from the
    angle tables (five table reads instead of five trigonometric functions)."""
    cos_h, sin_h, cos_d, sin_d, cos_p = shape.trig
    ch, sh = ops.gather(cos_h, i), ops.gather(sin_h, i)
    cd, sd = ops.gather(cos_d, j), ops.gather(sin_d, j)
    cp = ops.gather(cos_p, k)
    a = cd * ch
    b = sd * cp * sh
    return (a - b) * (a + b)


def bin_weight_from_cos(c, use_cos):
    """(w, valid) of a bin from its ``c = cos_i cos_o``: the transform weight clip(c,
    0.01, 1) (or 1 for log-plus) and whether both directions are above the horizon at
    the bin's angles (a bin is invalid otherwise, docs/method.md; since cos_i + cos_o
    >= 0 on the grid, c > 0 means both are positive). The scalar variants' default
    lookup takes the same weight from :func:`point_weight` instead (no select)."""
    return dr.select(use_cos > 0.5, dr.clip(c, _W_LO, _W_HI), 1.0), c > 0.0


def bin_weight(ops: Ops, shape: Shape, i, j, k, use_cos):
    """(w, valid) of bin (i, j, k), see :func:`bin_weight_from_cos`."""
    return bin_weight_from_cos(cos_terms(ops, shape, i, j, k), use_cos)


def interp_weight(ops: Ops, shape: Shape, lin, use_cos):
    """Trilinear interpolation of the bins' weights w and of their validity (0 or 1)."""
    (i0, i1, ti), (j0, j1, tj), (k0, k1, tk) = lin
    acc = 0.0
    vacc = 0.0
    for ei, wi in ((i0, 1.0 - ti), (i1, ti)):
        for ej, wj in ((j0, 1.0 - tj), (j1, tj)):
            for ek, wk in ((k0, 1.0 - tk), (k1, tk)):
                c = cos_terms(ops, shape, ei, ej, ek)
                wt = wi * wj * wk
                acc = acc + wt * dr.clip(c, _W_LO, _W_HI)
                vacc = vacc + dr.select(c > 0.0, wt, 0.0)
    return dr.select(use_cos > 0.5, acc, 1.0), vacc


# ------------------------------------------------------------------------- sampling


def power_cosine_sample(ops: Ops, u, exponent):
    """A unit vector around +z with density (n + 1) / (2 pi) cos^n(theta)."""
    m = ops.m
    cos_t = dr.power(dr.maximum(u.x, 1e-30), dr.rcp(exponent + 1.0))
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    s, c = dr.sincos(2.0 * math.pi * u.y)
    return m.Vector3f(c * sin_t, s * sin_t, cos_t)


def power_cosine_pdf(cos_t, exponent):
    return (exponent + 1.0) * (0.5 / math.pi) * dr.power(dr.maximum(cos_t, 0.0), exponent)


def lobe_pdf(ops: Ops, wi, wo, exponent):
    """Density (solid angle of wo) of the half-vector power-cosine lobe."""
    h = dr.normalize(wi + wo)
    d = dr.abs(dr.dot(wo, h))
    p = power_cosine_pdf(h.z, exponent) * dr.rcp(4.0 * dr.maximum(d, 1e-12))
    return dr.select((d > 0.0) & (h.z > 0.0), p, 0.0)


# ------------------------------------------------------------- spectral upsampling


class SpectralUpsampling:
    """Linear RGB -> spectrum at given wavelengths, as Mitsuba's own textures and emitters
    upsample unbounded RGB in spectral variants: the colour is divided by twice its
    largest component (a reflectance whose largest component is 1/2), its three
    coefficients are looked up in the RGB2Spec table (trilinear, as ``rgb2spec_fetch``:
    greys in closed form), the sigmoid polynomial is evaluated with
    ``mi.srgb_model_eval`` at the wavelengths, and the factor is multiplied back. Unlike
    ``mi.srgb_model_fetch`` (one scalar colour at a time) the lookup runs vectorised in
    the kernel, per BRDF value.
    """

    def __init__(self, ops: Ops, path) -> None:
        res, scale, data = read_rgb2spec_table(path)
        self.ops = ops
        self.res = res
        self.path = str(path)
        self._scale = ops.floats(scale)
        self._data = ops.floats(data)  # flat: 3 floats per grid point
        # binary-search steps over the scale samples (powers of two below res - 1)
        self._steps = [1 << b for b in reversed(range(max(res - 2, 1).bit_length()))]

    def _interval(self, z):
        """The largest k in [0, res - 2] with scale[k] <= z (scale increases)."""
        ops = self.ops
        lo = ops.m.UInt32(0) if ops.jit else 0
        top = self.res - 2
        for step in self._steps:
            cand = lo + step
            ok_c = cand <= top
            c_safe = ops.where(ok_c, cand, top)
            take = ok_c & (ops.gather(self._scale, c_safe) <= z)
            lo = ops.where(take, cand, lo)
        return lo

    def coefficients(self, r, g, b):
        """The three sigmoid-polynomial coefficients of the colour (r, g, b), each
        clamped to [0, 1], as ``rgb2spec_fetch`` computes them."""
        ops = self.ops
        res = self.res
        r, g, b = (dr.clip(x, 0.0, 1.0) for x in (r, g, b))
        # the largest component i (ties: the later one) and the two after it, cyclically
        gi = g >= r
        zrg = ops.where(gi, g, r)
        bi = b >= zrg
        z = ops.where(bi, b, zrg)
        x = ops.where(bi, r, ops.where(gi, b, g))
        y = ops.where(bi, g, ops.where(gi, r, b))
        i = ops.where(bi, 2, ops.where(gi, 1, 0))
        zs = ops.where(z > 0.0, z, 1.0)
        sc = (res - 1) / zs
        xf, yf = x * sc, y * sc
        xi = dr.minimum(ops.to_u(xf), res - 2)
        yi = dr.minimum(ops.to_u(yf), res - 2)
        zi = self._interval(z)
        s0 = ops.gather(self._scale, zi)
        s1 = ops.gather(self._scale, zi + 1)
        x1, y1 = xf - xi, yf - yi
        z1 = (z - s0) / (s1 - s0)
        base = ((i * res + zi) * res + yi) * res + xi
        acc = None
        for dz, wz in ((0, 1.0 - z1), (res * res, z1)):
            for dy, wy in ((0, 1.0 - y1), (res, y1)):
                for dx, wx in ((0, 1.0 - x1), (1, x1)):
                    v = ops.gather3(self._data, base + (dz + dy + dx))
                    w = wz * wy * wx
                    acc = v * w if acc is None else acc + v * w
        # greys in closed form: (0, 0, (v - 1/2) / sqrt(v (1 - v))), black/white -/+ 8192
        grey = (r == g) & (g == b)
        v = dr.clip(r, 1e-30, 1.0 - 1e-7)
        cg = (v - 0.5) * dr.rsqrt(v * (1.0 - v))
        cg = ops.where(r <= 0.0, -8192.0, ops.where(r >= 1.0, 8192.0, cg))
        # (black is a grey, so z > 0 wherever the table is used)
        return [ops.where(grey, 0.0, acc[0]), ops.where(grey, 0.0, acc[1]),
                ops.where(grey, cg, acc[2])]

    def spectrum(self, rgb, wavelengths):
        """The spectrum of unbounded linear RGB ``rgb`` (>= 0) at ``wavelengths`` (nm), an
        ``UnpolarizedSpectrum`` of the variant."""
        m = self.ops.m
        factor = 2.0 * dr.maximum(dr.maximum(rgb[0], rgb[1]), rgb[2])
        inv = dr.rcp(dr.maximum(factor, 1e-8))
        coeff = m.Color3f(*self.coefficients(rgb[0] * inv, rgb[1] * inv, rgb[2] * inv))
        return m.srgb_model_eval(coeff, wavelengths) * factor
