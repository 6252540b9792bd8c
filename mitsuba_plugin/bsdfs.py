"""The three Python BSDFs, ``tabulated_brdf``, ``sparse_brdf`` and ``neural_brdf``, and
their registration.

Laid out like Mitsuba 3's own Python plugins: helpers, the sparse decoders' lookup
kernels (:func:`grouped_x`, :func:`strict_x`), the BSDF classes with their parameters in
their docstrings, and registration at the end (:func:`register`). One difference: a
Python BSDF must derive from the *variant's* ``mi.BSDF``, which exists only once a
variant is set, and nanobind allows a Python class one base only. So
:class:`GlossyBSDF` (shared sampling, pdf, cosine and the variants' colours),
:class:`TabulatedBRDF`, :class:`SparseBSDF` and :class:`NeuralBRDF` are written against
no base, and :func:`make_classes` copies their
bodies onto subclasses of one variant's ``mi.BSDF`` (cached per variant by
:func:`classes`). The variant reaches the methods as class attributes (``_m``, the
variant's names; ``_ops``, its :class:`~mitsuba_plugin.kernels.Ops`; a few constants).

The per-material data the kernels read is built with numpy by
:mod:`sparse_brdf.model.layouts`; :mod:`sparse_brdf.model.lookups` holds numpy twins of
both kernels, which ``sparse_brdf`` itself evaluates with in the scalar variants
(:meth:`SparseBSDF._rho_point`).
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import drjit as dr

from sparse_brdf.coords import MERL_SHAPE
from sparse_brdf.errors import PluginError
from sparse_brdf.mlp import tabulate
from sparse_brdf.model.ensemble import resolve_ensemble
from sparse_brdf.model.layouts import (
    DECODERS,
    END_B,
    END_C,
    LAYOUTS,
    PACK_BITS,
    PACKET,
    PLUGIN_DEFAULTS,
    SAMPLING,
    SLOT,
    UNION_ATOMS,
    channel_terms,
    choose_decoder,
    colour_mix,
    fit_lobe,
    float_buffer,
    grouped_channels,
    grouped_layout,
    model_digest,
    sparse_profile,
    strict_channel,
    strict_layout,
    strict_orders,
    table_profile,
    term_values,
)
from sparse_brdf.model.lookups import GroupedLookup, StrictLookup
from sparse_brdf.model.sbrdf import decode_file, load_sbrdf
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.nbrdf import read_nbrdf_weights
from sparse_brdf.transforms import scale as transform_scale
from sparse_brdf.transforms import uses_cosine

from .kernels import (
    Ops,
    Shape,
    SpectralUpsampling,
    VariantNamespace,
    angle_coords,
    bin_weight,
    bin_weight_from_cos,
    interp_weight,
    linear_bins,
    lobe_pdf,
    mix_colour,
    mlp_weights,
    nbrdf_rho,
    nearest_bins,
    power_cosine_sample,
    rho_from_x,
)

_ENSEMBLES: dict = {}
_ENSEMBLE_LOCK = threading.Lock()
# The last grouped build, keyed by its model's support, values, ensemble, layout and
# variant: the several scenes of an image fit (one per view) hold one model whose values
# change together, and each rebuilds its buffers on ``params.update()``; the second and
# later scenes of a step reuse the first one's (read-only) buffers.
_LAST_GROUPED: list = [None, None]
_GROUPED_LOCK = threading.Lock()


def _grouped_key(model, ens, layout, ops) -> tuple:
    # ``ops`` itself (one per variant, kept for the process) names the variant: the
    # variant modules all report ``__name__ == "mitsuba"``
    return (model_digest(model), id(ens), layout, ops)


def load_ensemble(path: str | None, for_id: str | None = None):
    """The ensemble at ``path`` (None: the shipped one with id ``for_id``, or the shipped
    default), cached by path, size and mtime."""
    if path is None:
        key = ("<shipped>", for_id)
    else:
        st = os.stat(path)
        key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    with _ENSEMBLE_LOCK:
        ens = _ENSEMBLES.get(key)
        if ens is None:
            ens = resolve_ensemble(path, for_id=for_id)
            _ENSEMBLES.clear()  # keep one ensemble in memory
            _ENSEMBLES[key] = ens
    return ens


def _resolve(filename: str) -> str:
    """Resolve a scene-relative file name with Mitsuba's file resolver."""
    if filename.startswith("mitsuba:"):
        return filename
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    try:
        return str(mi.file_resolver().resolve(filename))
    except Exception:  # noqa: BLE001 - fall back to the name as given
        return filename


def _read_props(props, plugin: str, spec: dict) -> dict:
    """Read every known property (Mitsuba rejects unread ones) with its default."""
    out = {}
    for name, default in spec.items():
        if name in props:
            out[name] = props.get(name)
        elif default is _REQUIRED:
            raise PluginError(f"{plugin}: the parameter {name!r} is required")
        else:
            out[name] = default
    return out


_REQUIRED = object()


def _as_bool(v, plugin: str, name: str) -> bool:
    if isinstance(v, bool):
        return v
    s = str(v).strip().lower()
    if s in ("true", "1", "yes", "on"):
        return True
    if s in ("false", "0", "no", "off"):
        return False
    raise PluginError(f"{plugin}: {name}={v!r} is not a boolean")


def _choice(v, allowed, plugin: str, name: str) -> str:
    s = str(v)
    if s not in allowed:
        raise PluginError(f"{plugin}: {name}={s!r}: expected one of {', '.join(allowed)}")
    return s


def _load_table(filename: str, ensemble, plugin: str):
    try:
        if ensemble is not None and Path(filename).suffix.lower() == ".sbrdf":
            return decode_file(filename, load_ensemble(_resolve(str(ensemble))))
        return load_brdf(filename)
    except Exception as exc:  # noqa: BLE001 - re-raised with the plugin and file named
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc


def _load_model(filename: str, ens_path: str | None, plugin: str):
    try:
        model = load_sbrdf(filename)
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc
    try:
        ens = load_ensemble(ens_path, model.ensemble_id)
    except Exception as exc:  # noqa: BLE001
        what = "the shipped ensemble" if ens_path is None else repr(ens_path)
        raise PluginError(f"{plugin}: cannot load {what} for {filename!r}: {exc}") from exc
    try:
        model.check_ensemble(ens)
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc
    if tuple(model.shape) != tuple(ens.shape):
        raise PluginError(f"{plugin}: {filename!r} has grid {model.shape}, its ensemble "
                          f"{ens.shape}")
    return model, ens


# ---------------------------------------------------------------- grouped decoder kernel


@dataclass
class GroupedBuffers:
    """The grouped decoder's per-material data as the kernel reads it (from a
    :class:`sparse_brdf.model.layouts.GroupedLayout`); numbers are opaque Dr.Jit scalars."""

    tables: object  # Float: per bin pair (ip, iq), ``chunks`` chunks of table floats
    values: object  # Float: per bin of mode g, ``chunks`` chunks of atom values
    chunks: dict  # {"slots": n, "union": n}: the material's layout has n > 0, the other 0
    sel: list  # for modes (p, q, g): three 0/1 UInt32 that pick that mode's bin index
    fsel: list  # the same as Floats, to pick that mode's interpolation weight
    n_q: object  # UInt32: the size of mode q (the table's row stride in bin pairs)


def upload_grouped(ops: Ops, lay, ch) -> GroupedBuffers:
    """:class:`GroupedBuffers` of layout ``lay``, whose channels' modes are those of
    ``ch`` (a :class:`~sparse_brdf.model.layouts.GroupedChannel`)."""
    tables = ops.floats(lay.tables)
    values = ops.floats(lay.values)
    # one kernel for both layouts: a loop for each, the other runs 0 times
    chunks = {k: ops.u(lay.chunks if k == lay.kind else 0) for k in ("slots", "union")}
    modes = (ch.mode_p, ch.mode_q, ch.mode_g)
    sel = [[ops.u(int(mode == s)) for mode in range(3)] for s in modes]
    fsel = [[ops.f(float(mode == s)) for mode in range(3)] for s in modes]
    return GroupedBuffers(tables, values, chunks, sel, fsel, ops.u(ch.n_q))


def _pick(idx, sel):
    """``idx[mode]`` for the mode whose entry of ``sel`` (three 0/1 values) is 1: no
    Python branch on per-material data, so one kernel serves every grouped mode."""
    return idx[0] * sel[0] + idx[1] * sel[1] + idx[2] * sel[2]


def _grouped_rows(buf: GroupedBuffers, bins, lin):
    """([(bin pair, weight)], [(bin of mode g, weight)]) a lookup reads: one of each with
    weight None at the nearest bin (``bins``), or the 4 bin pairs and 2 bins of mode g
    around the point with their interpolation weights (``lin``, bins is None)."""
    nq = buf.n_q
    sel_p, sel_q, sel_g = buf.sel
    if lin is None:
        return ([(_pick(bins, sel_p) * nq + _pick(bins, sel_q), None)],
                [(_pick(bins, sel_g), None)])
    i0s = tuple(x[0] for x in lin)
    i1s = tuple(x[1] for x in lin)
    ts = tuple(x[2] for x in lin)
    fp, fq, fg = buf.fsel
    tp, tq, tg = _pick(ts, fp), _pick(ts, fq), _pick(ts, fg)
    pairs = [(ep * nq + eq, wp * wq)
             for ep, wp in ((_pick(i0s, sel_p), 1.0 - tp), (_pick(i1s, sel_p), tp))
             for eq, wq in ((_pick(i0s, sel_q), 1.0 - tq), (_pick(i1s, sel_q), tq))]
    gs = [(_pick(i0s, sel_g), 1.0 - tg), (_pick(i1s, sel_g), tg)]
    return pairs, gs


def _blend(ops: Ops, buf, rows, stride, h, active):
    """Packet h of each of ``rows`` [(row index, weight)] of ``buf`` (a row is
    ``stride`` packets), summed with the weights; a weight of None: that row alone."""
    out = None
    for row, wt in rows:
        pk = ops.gather_packet(buf, row * stride + h, PACKET, active)
        if wt is None:
            return list(pk)
        pk = [wt * x for x in pk]
        out = pk if out is None else [a + b for a, b in zip(out, pk, strict=True)]
    return out


def _fma(ops: Ops, a, b, c):
    return dr.fma(a, b, c) if ops.jit else a * b + c


def _union_chunk(ops: Ops, tv, vv, acc):
    """Add one union chunk: table floats ``tv`` (3 a + c: channel c at atom a < 5; 15:
    the weight) times atom values ``vv`` (a: atom a; 5: the weight) to the four sums."""
    out = list(acc)
    for a in range(UNION_ATOMS):
        for c in range(3):
            out[c] = _fma(ops, tv[3 * a + c], vv[a], out[c])
    out[3] = _fma(ops, tv[3 * UNION_ATOMS], vv[UNION_ATOMS], out[3])
    return tuple(out)


def grouped_x(ops: Ops, buf: GroupedBuffers, bins, lin, active):
    """X of the three channels and the bins' cos_i cos_o from the shared rows (see
    :func:`sparse_brdf.model.layouts.grouped_layout`; its numpy twin is
    :func:`~sparse_brdf.model.lookups.layout_eval`). Two loops, one per layout; a
    material's data has one of them, and the other's count is 0.

    slots: a chunk is one packet of table row and one of atom values, float 4 s + c of
    both belonging to channel c (c = 3: the weight): one multiply-add sum per float.
    union: a chunk is two packets of table row and one of atom values
    (:func:`_union_chunk`)."""
    n_s, n_u = buf.chunks["slots"], buf.chunks["union"]
    pairs, gs = _grouped_rows(buf, bins, lin)
    t_buf, v_buf = buf.tables, buf.values

    def body_slots(h, acc):
        tv = _blend(ops, t_buf, pairs, n_s, h, active)
        vv = _blend(ops, v_buf, gs, n_s, h, active)
        return tuple(_fma(ops, a, b, c) for a, b, c in zip(tv, vv, acc, strict=True))

    def body_union(h, acc):
        tv = (_blend(ops, t_buf, pairs, 2 * n_u, 2 * h, active)
              + _blend(ops, t_buf, pairs, 2 * n_u, 2 * h + 1, active))
        return _union_chunk(ops, tv, _blend(ops, v_buf, gs, n_u, h, active), acc)

    zero = ops.m.Float(0.0) if ops.jit else 0.0
    acc_s = ops.loop(n_s, body_slots, (zero,) * PACKET)
    acc_u = ops.loop(n_u, body_union, (zero,) * SLOT)
    sums = [sum(acc_s[c::SLOT], acc_u[c]) for c in range(SLOT)]
    return sums[:3], sums[3]


# ----------------------------------------------------------------- strict decoder kernel


@dataclass
class StrictBuffers:
    """The strict decoder's per-material data as the kernel reads it (from a
    :class:`sparse_brdf.model.layouts.StrictLayout`); numbers are opaque Dr.Jit scalars."""

    values: object  # Float: the coefficients s of every channel's terms
    packed: object  # UInt32: their packed atom indices and group-end flags
    rows: object  # Float: the distinct atom rows, per channel and mode
    channels: list  # per channel {"t": terms, "soff": first term, "roff": [row offset]}


def upload_strict(ops: Ops, lay) -> StrictBuffers:
    """:class:`StrictBuffers` of layout ``lay``."""
    # a buffer is never empty (a material without coefficients): Dr.Jit refuses to trace
    # a gather from an empty array, even one a zero-trip loop never runs
    values = ops.floats(lay.values if len(lay.values) else [0.0])
    packed = ops.uints(lay.packed if len(lay.packed) else [0])
    rows = ops.floats(lay.rows if len(lay.rows) else [0.0])
    per = [{"t": ops.u(t), "soff": ops.u(soff), "roff": [ops.u(r) for r in roff]}
           for t, soff, roff in zip(lay.n_terms, lay.term_offsets, lay.row_offsets,
                                    strict=True)]
    return StrictBuffers(values, packed, rows, per)


def strict_x(ops: Ops, buf: StrictBuffers, shape: Shape, c: int, bins, lin, active,
             grad=None):
    """X of channel ``c``: one loop over its terms, sorted by (c, b, a), evaluating
    ``sum_c U3[k, c] sum_b U2[j, b] sum_a s U1[i, a]``; the partial sums are closed at
    the flagged ends of each b-group and c-group, so U2 and U3 are read once per group
    (numpy twin: :func:`~sparse_brdf.model.lookups.strict_eval`). At the nearest bin
    (``bins``) or interpolated (``lin``, bins is None).

    ``grad`` = (values, order): instead, the derivative carrier
    ``sum_t (s_t - detach(s_t)) U1[i, a_t] U2[j, b_t] U3[k, c_t]``, zero in value, with
    ``s_t = values[order[t]]`` read from the differentiable values themselves (a
    sum-style loop, which Dr.Jit differentiates in both modes)."""
    sp = buf.channels[c]
    n = shape.n
    s_buf, p_buf, r_buf = buf.values, buf.packed, buf.rows
    soff, roff = sp["soff"], sp["roff"]
    mask = (1 << PACK_BITS) - 1
    zero = ops.m.Float(0.0)

    if lin is None:
        def row(mode, a, active_):
            return ops.gather(r_buf, roff[mode] + a * n[mode] + bins[mode], active_)
    else:
        def row(mode, a, active_):
            i0, i1, w = lin[mode]
            base = roff[mode] + a * n[mode]
            return ((1.0 - w) * ops.gather(r_buf, base + i0, active_)
                    + w * ops.gather(r_buf, base + i1, active_))

    def body(t, state):
        acc, acc_c, acc_b = state
        p = ops.gather_u(p_buf, soff + t, active)
        s = ops.gather(s_buf, soff + t, active)
        end_b = (p & END_B) != 0
        end_c = (p & END_C) != 0
        acc_b = acc_b + s * row(0, p & mask, active)
        # close the (c, b) group: multiply by U2[j, b] (read only at group ends)
        u2 = row(1, (p >> PACK_BITS) & mask, active & end_b)
        acc_c = dr.select(end_b, acc_c + acc_b * u2, acc_c)
        acc_b = dr.select(end_b, zero, acc_b)
        # close the c group: multiply by U3[k, c]
        u3 = row(2, (p >> (2 * PACK_BITS)) & mask, active & end_c)
        acc = dr.select(end_c, acc + acc_c * u3, acc)
        acc_c = dr.select(end_c, zero, acc_c)
        return acc, acc_c, acc_b

    def body_grad(t, state):
        values, order = grad
        p = ops.gather_u(p_buf, soff + t, active)
        s = ops.gather(values, ops.gather_u(order, t, active), active)
        term = ((s - dr.detach(s)) * row(0, p & mask, active)
                * row(1, (p >> PACK_BITS) & mask, active)
                * row(2, (p >> (2 * PACK_BITS)) & mask, active))
        return (state[0] + term,)

    if grad is not None:
        return ops.loop(sp["t"], body_grad, (zero,), sum_style=True)[0]
    return ops.loop(sp["t"], body, (zero, zero, zero))[0]


# ---------------------------------------------------------------------------- the BSDFs


class GlossyBSDF:
    """What the BSDFs share: a single-sided glossy reflector (``GlossyReflection |
    FrontSide``) with cosine or lobe sampling, whose ``eval`` is ``BRDF * cos(theta_o)``.

    Subclasses set ``plugin``, read their properties and call :meth:`_setup_sampling` in
    ``__init__``, and define ``_rho(wi, wo, active)``, the BRDF's RGB value. Written
    against no base class: see the module docstring and :func:`make_classes`.
    """

    plugin = "?"

    def __init__(self, props) -> None:
        self._m.BSDF.__init__(self, props)
        self.m_flags = self._flags
        self.m_components = [self._flags]
        if self._kind == "spectral":
            self._upsampling()  # a missing or corrupt table fails at load, not in a render

    def _setup_sampling(self, sampling: str, profile, shape) -> None:
        self.sampling = sampling
        n, p = fit_lobe(profile, shape) if sampling == "lobe" else (1.0, 0.0)
        self.lobe_exponent, self.lobe_prob = float(n), float(p)
        self._exp = self._ops.f(n)
        self._prob = self._ops.f(p)

    def _rho(self, wi, wo, active):  # pragma: no cover - abstract
        raise NotImplementedError

    def _colour(self, rgb, si):
        """The variant's value of the linear-RGB BRDF value ``rgb`` (a Color3f): itself
        in rgb variants, its luminance (``mi.luminance``) in mono ones, its spectrum at
        ``si.wavelengths`` in spectral ones (:class:`~mitsuba_plugin.kernels.
        SpectralUpsampling`). A Python branch at trace time: rgb kernels are unchanged."""
        if self._kind == "rgb":
            return rgb
        if self._kind == "mono":
            return self._m.UnpolarizedSpectrum(self._m.luminance(rgb))
        return self._upsampling().spectrum(rgb, si.wavelengths)

    def _out(self, value):
        """``value`` (an UnpolarizedSpectrum) as the variant's Spectrum: in polarized
        variants a depolarizing Mueller matrix (``mi.depolarizer``), which needs no
        rotation between the local and world frames."""
        return self._m.depolarizer(value) if self._polarized else value

    def _pdf(self, wi, wo):
        m = self._m
        ci = m.Frame3f.cos_theta(wi)
        co = m.Frame3f.cos_theta(wo)
        p = m.warp.square_to_cosine_hemisphere_pdf(wo)
        if self.sampling == "lobe":
            p = (1.0 - self._prob) * p + self._prob * lobe_pdf(self._ops, wi, wo, self._exp)
        return dr.select((ci > 0.0) & (co > 0.0), p, 0.0)

    # Mitsuba interface ---------------------------------------------------------------
    def sample(self, ctx, si, sample1, sample2, active=True):
        m, zero = self._m, self._zero_s
        bs = dr.zeros(m.BSDFSample3f)
        if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
            return bs, self._out(zero)
        wi = si.wi
        wo = m.warp.square_to_cosine_hemisphere(sample2)
        if self.sampling == "lobe":
            h = power_cosine_sample(self._ops, sample2, self._exp)
            wo_lobe = 2.0 * dr.dot(wi, h) * h - wi
            wo = dr.select(sample1 < self._prob, wo_lobe, wo)
        pdf = self._pdf(wi, wo)
        bs.wo = wo
        bs.pdf = pdf
        bs.eta = 1.0
        bs.sampled_type = m.UInt32(self._glossy)
        bs.sampled_component = m.UInt32(0)
        co = m.Frame3f.cos_theta(wo)
        ok = active & (m.Frame3f.cos_theta(wi) > 0.0) & (co > 0.0) & (pdf > 0.0)
        f = self._colour(self._rho(wi, wo, ok), si)
        weight = f * (co / dr.maximum(pdf, 1e-30))
        return bs, self._out(dr.select(ok, weight, zero))

    def eval(self, ctx, si, wo, active=True):
        m, zero = self._m, self._zero_s
        if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
            return self._out(zero)
        co = m.Frame3f.cos_theta(wo)
        ok = active & (m.Frame3f.cos_theta(si.wi) > 0.0) & (co > 0.0)
        f = self._colour(self._rho(si.wi, wo, ok), si)
        return self._out(dr.select(ok, f * co, zero))

    def pdf(self, ctx, si, wo, active=True):
        if not ctx.is_enabled(self._m.BSDFFlags.GlossyReflection):
            return self._m.Float(0.0)
        return dr.select(active, self._pdf(si.wi, wo), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def traverse(self, callback):
        # the material is read-only: nothing to expose for differentiation
        pass

    def parameters_changed(self, keys=None):
        pass


class TabulatedBRDF(GlossyBSDF):
    """Tabulated measured BRDF (``tabulated_brdf``): the reference BSDF.

    Holds the whole (n1, n2, n3, 3) table (16.7 MiB for the MERL grid) in one Dr.Jit Float
    array and gathers one RGB triple by flat bin index, with the project's bin convention
    (docs/method.md, "Grid, lookup convention, validity"), shared with ``sparse_brdf``.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - filename
         - string
         - Anything :func:`sparse_brdf.sources.load.load_brdf` reads: a MERL/DTU ``.binary``, a
           Neural-BRDF ``.h5``, a ``.sbrdf`` (fully decoded) or ``mitsuba:<name>``.
       * - ensemble
         - string
         - Optional ensemble ``.npz`` used to decode a ``.sbrdf`` file (default: the
           shipped ensemble).
       * - sampling
         - string
         - ``lobe`` (default: cosine mixed with a power-cosine half-vector lobe fitted to
           the BRDF at load time; lower noise on glossy materials) or ``cosine``
           (cosine-weighted hemisphere, independent of the BRDF, so a reference and a
           model rendered with one seed and spp share their sample paths: set it for
           comparisons of renders).
       * - interpolate
         - boolean
         - Trilinear interpolation between the bins' lower-edge samples (default: false,
           nearest-lower bin as in the MERL convention).

    Example::

        {"type": "tabulated_brdf", "filename": "gold-metallic-paint.binary",
         "sampling": "lobe"}
    """

    plugin = "tabulated_brdf"

    def __init__(self, props) -> None:
        GlossyBSDF.__init__(self, props)
        ops = self._ops
        p = _read_props(props, self.plugin, {"filename": _REQUIRED,
                                             "sampling": PLUGIN_DEFAULTS["sampling"],
                                             "interpolate": False, "ensemble": None})
        self.sampling = _choice(p["sampling"], SAMPLING, self.plugin, "sampling")
        self.interpolate = _as_bool(p["interpolate"], self.plugin, "interpolate")
        self.filename = _resolve(str(p["filename"]))
        brdf = _load_table(self.filename, p["ensemble"], self.plugin)
        self.name = brdf.name
        self.shape = brdf.shape
        self._shape = Shape(ops, brdf.shape)
        self._table = ops.floats(brdf.values)  # (n1 n2 n3 3), RGB interleaved
        self.memory_bytes = ops.nbytes(self._table)
        self._setup_sampling(self.sampling, table_profile(brdf.values), brdf.shape)

    def _rho(self, wi, wo, active):
        ops, sh = self._ops, self._shape
        n1, n2, n3 = sh.n
        coords = angle_coords(ops, sh, wi, wo)
        if not self.interpolate:
            i, j, k = nearest_bins(ops, sh, coords)
            return ops.gather3(self._table, (i * n2 + j) * n3 + k, active)
        (i0, i1, ti), (j0, j1, tj), (k0, k1, tk) = linear_bins(ops, sh, coords)
        acc = self._m.Color3f(self._zero3)
        for ei, wi_ in ((i0, 1.0 - ti), (i1, ti)):
            for ej, wj in ((j0, 1.0 - tj), (j1, tj)):
                for ek, wk in ((k0, 1.0 - tk), (k1, tk)):
                    v = ops.gather3(self._table, (ei * n2 + ej) * n3 + ek, active)
                    acc = acc + v * (wi_ * wj * wk)
        return acc

    def to_string(self):
        return (f"{type(self).__name__}[filename={self.filename!r}, shape={self.shape}, "
                f"sampling={self.sampling}, interpolate={self.interpolate}, "
                f"memory_bytes={self.memory_bytes}]")


class SparseBSDF(GlossyBSDF):
    """Sparse non-parametric BRDF (``sparse_brdf``): the model of Tongbuasirilai et al.,
    "A Sparse Non-parametric BRDF Model" (see docs/method.md).

    Evaluates ``X = sum_t s_t U1[i, a_t] U2[j, b_t] U3[k, c_t]`` per coded channel at the
    bin of (wi, wo), mixes the three back to the transformed R, G, B if the file's colour
    basis is "opponent" (:func:`~mitsuba_plugin.kernels.mix_colour`; "rgb" materials trace
    no mix, so their kernel is unchanged), then ``rho = max((exp(X) - 1) / w, 0)``, without
    ever building the full tensor (:func:`grouped_x`, :func:`strict_x`; data from
    :mod:`sparse_brdf.model.layouts`).
    Per-material data lives in Dr.Jit arrays and opaque scalars, so every material shares
    one compiled kernel. ``memory_bytes`` reports the bytes of the arrays the BSDF holds.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - filename
         - string
         - The ``.sbrdf`` coefficient file.
       * - ensemble
         - string
         - Optional ensemble ``.npz`` the file was encoded with (default: the shipped one).
       * - decoder
         - string
         - ``grouped`` (terms grouped by the atom of one mode, the other two modes
           contracted at load time into an (n_p n_q) x K table: fastest), ``strict`` (loops
           over the nonzero terms: least memory) or ``auto`` (default: grouped unless its
           tables exceed ``sparse_brdf.model.layouts.AUTO_GROUPED_MAX_BYTES``, 32 MiB).
       * - layout
         - string
         - How the grouped decoder lays out its rows (see
           :func:`sparse_brdf.model.layouts.grouped_layout`): ``union`` (each atom the
           three channels use stored once), ``slots`` (every channel its own columns) or
           ``auto`` (default: the one that reads fewer packets per lookup). Both run in
           the same kernel.
       * - sampling
         - string
         - ``lobe`` (default) or ``cosine``, as for ``tabulated_brdf``.
       * - interpolate
         - boolean
         - Trilinear interpolation of the transformed value X (separable: each mode's atoms
           are interpolated linearly) and of the weight w (default: false).

    Example::

        {"type": "sparse_brdf", "filename": "gold-metallic-paint.sbrdf",
         "decoder": "grouped", "sampling": "cosine"}
    """

    plugin = "sparse_brdf"

    def __init__(self, props) -> None:
        GlossyBSDF.__init__(self, props)
        ops = self._ops
        p = _read_props(props, self.plugin, {
            "filename": _REQUIRED, "ensemble": None, "decoder": "auto",
            "sampling": PLUGIN_DEFAULTS["sampling"], "interpolate": False,
            "layout": "auto"})
        self.sampling = _choice(p["sampling"], SAMPLING, self.plugin, "sampling")
        self.interpolate = _as_bool(p["interpolate"], self.plugin, "interpolate")
        decoder = _choice(p["decoder"], DECODERS, self.plugin, "decoder")
        layout = _choice(p["layout"], LAYOUTS, self.plugin, "layout")
        self.filename = _resolve(str(p["filename"]))
        ens_path = None if p["ensemble"] is None else _resolve(str(p["ensemble"]))
        model, ens = _load_model(self.filename, ens_path, self.plugin)
        self.name = model.name
        self.shape = model.shape
        self.transform = model.transform
        self.basis = model.basis
        # M^T of the colour basis, traced as constants; None ("rgb"): no mix is traced
        self._mix = colour_mix(model.basis)
        self.n_terms = tuple(int(n) for n in model.n_coeffs)
        self.decoder = choose_decoder(decoder, model, ens)
        self._shape = Shape(ops, model.shape)
        self._use_cos = ops.f(1.0 if uses_cosine(model.transform) else 0.0)
        # the relative transforms' constant factor s of the weight (a Python float: the
        # paper's transforms, s = 1, trace no multiply)
        self._scale = transform_scale(model.transform)
        self.layout = None
        self._model, self._ens, self._grad, self._ad = model, ens, False, None
        if self.decoder == "grouped":
            self._build_grouped(model, ens, layout)
        else:
            self._build_strict(model, ens)
        # the coded channels' values, as mi.traverse exposes them (``values_0`` ...)
        self._values = [self._value_array(v) for v in model.values]
        self._setup_sampling(self.sampling, sparse_profile(model, ens), model.shape)
        if not ops.jit:  # scalar variants: each call goes straight to the numpy lookups
            self._rho = self._rho_point

    # data ----------------------------------------------------------------------------
    def _build_grouped(self, model, ens, layout: str) -> None:
        key = _grouped_key(model, ens, layout, self._ops)
        with _GROUPED_LOCK:
            if _LAST_GROUPED[0] == key:
                chans, lay, grouped, _ = _LAST_GROUPED[1]
            else:
                chans = grouped_channels(model, ens)
                lay = grouped_layout(chans, model.shape,
                                     None if layout in ("auto", None) else layout)
                grouped = upload_grouped(self._ops, lay, chans[0])
                _LAST_GROUPED[:] = [key, (chans, lay, grouped, ens)]  # kept: its id stays unique
        self.channels = chans
        self.layout = lay.kind
        self._grouped = grouped
        self.memory_bytes = (self._ops.nbytes(self._grouped.tables)
                             + self._ops.nbytes(self._grouped.values))
        self.distinct_atoms = tuple(c.k for c in chans)
        self.packets = lay.packets
        self.grouped_modes = tuple(c.mode_g + 1 for c in chans)
        if not self._ops.jit:  # the scalar variants' lookup reads the same table buffer
            self._lookup = GroupedLookup(lay, chans[0], self._mix, self._grouped.tables)

    def _build_strict(self, model, ens) -> None:
        chans = [strict_channel(*channel_terms(model, ens, c)) for c in range(3)]
        self.channels = chans
        self._strict = upload_strict(self._ops, strict_layout(chans))
        self.memory_bytes = sum(self._ops.nbytes(b) for b in (
            self._strict.values, self._strict.packed, self._strict.rows))
        self.distinct_atoms = tuple(tuple(r.shape[0] for r in ch.rows) for ch in chans)
        if not self._ops.jit:
            self._lookup = StrictLookup(chans, self._mix)

    # differentiable values -----------------------------------------------------------
    # Both decoders' buffers are linear in the values, but a buffer derived from a
    # parameter outside a render (as the grouped decoder's contracted tables would be)
    # breaks Mitsuba's forward mode: a render may only differentiate through variables it
    # reads itself. So after ``params.update()`` the buffers are rebuilt exactly as from a
    # file holding the new values (detached), and when a channel's values carry
    # gradients the kernel adds, per channel, the derivative carrier
    # ``sum_t (s_t - detach(s_t)) U1[i, a_t] U2[j, b_t] U3[k, c_t]``: zero in value, with
    # the model's exact derivative, ``s_t`` gathered inside the kernel from the values
    # that ``mi.traverse`` holds (see :func:`strict_x`).
    def _value_array(self, v):
        v = float_buffer(v)
        return self._m.Float(v) if self._ops.jit else self._m.TensorXf(v)

    def traverse(self, callback):
        """Expose the coded channels' coefficient values as ``values_0``, ``values_1``,
        ``values_2`` (Float arrays in the file's term order, one per channel),
        differentiable. The support (which atoms) is fixed; only the values change."""
        for c, v in enumerate(self._values):
            callback.put(f"values_{c}", v, self._m.ParamFlags.Differentiable)

    def parameters_changed(self, keys=None):
        """Re-derive the decoder's buffers from the (possibly updated) values: exactly as
        from a file holding those values, plus, when a channel's values carry gradients,
        a zero-valued Dr.Jit term through which they flow (see the comment above)."""
        if keys and not any(str(k).startswith("values_") for k in keys):
            return
        try:
            vals = term_values([dr.detach(v) if self._ops.jit else v for v in self._values],
                               self.n_terms)
        except ValueError as exc:
            raise PluginError(f"{self.plugin}: {self.filename!r}: {exc}") from None
        model = dataclasses.replace(self._model, values=vals)
        self._model = model
        if self.decoder == "grouped":
            self._build_grouped(model, self._ens, self.layout)
        else:
            self._build_strict(model, self._ens)
        if self.sampling == "lobe":  # the lobe follows the values, as from a file
            self._setup_sampling(self.sampling, sparse_profile(model, self._ens), model.shape)
        self._grad = self._ops.jit and any(dr.grad_enabled(v) for v in self._values)
        if self._grad:
            self._attach_gradients()

    def _attach_gradients(self) -> None:
        """Build the derivative carrier's data once (it depends on the support only): the
        strict decoder's atom rows and packed indices, and per channel the file's term
        index of each of its terms (:func:`sparse_brdf.model.layouts.strict_orders`).
        The decoders' own buffers stay detached, so the kernel's derivative flows only
        through the values, read inside the kernel like any Mitsuba parameter."""
        if self._ad is None:
            chans = [strict_channel(*channel_terms(self._model, self._ens, c))
                     for c in range(3)]
            orders = [self._ops.uints(o if o.size else [0])
                      for o in strict_orders(self._model, self._ens)]
            self._ad = (upload_strict(self._ops, strict_layout(chans)), orders)

    # lookups -------------------------------------------------------------------------
    def _x_grouped(self, bins, lin, active):
        return grouped_x(self._ops, self._grouped, bins, lin, active)

    def _x_strict(self, c, bins, lin, active):
        return strict_x(self._ops, self._strict, self._shape, c, bins, lin, active)

    def _x_grad(self, c, bins, lin, active):
        """The derivative carrier of channel c (zero in value), see :func:`strict_x`."""
        buf, orders = self._ad
        return strict_x(self._ops, buf, self._shape, c, bins, lin, active,
                        grad=(self._values[c], orders[c]))

    def _rho(self, wi, wo, active):
        if not self._ops.jit:  # (an instance binds _rho_point itself, see __init__)
            return self._rho_point(wi, wo, active)
        ops, sh = self._ops, self._shape
        coords = angle_coords(ops, sh, wi, wo)
        grouped = self.decoder == "grouped"
        if self.interpolate:
            lin = linear_bins(ops, sh, coords)
            bins = None
            w, valid = interp_weight(ops, sh, lin, self._use_cos)
            if grouped:
                xs, _ = self._x_grouped(bins, lin, active)
        else:
            lin = None
            bins = nearest_bins(ops, sh, coords)
            if grouped:
                # the grouped rows carry the bins' cos_i cos_o as a fourth channel
                xs, cc = self._x_grouped(bins, lin, active)
                w, ok = bin_weight_from_cos(cc, self._use_cos)
            else:
                w, ok = bin_weight(ops, sh, *bins, self._use_cos)
                # invalid bins (below the horizon at their angles) hold no
                # measurement: 0, as in the tabulated reference and SparseBRDF.decode
                active = active & ok
            valid = dr.select(ok, 1.0, 0.0)
        if not grouped:
            xs = [self._x_strict(c, bins, lin, active) for c in range(3)]
        if self._grad:  # a Python branch: only differentiated renders trace the carrier
            xs = [x + self._x_grad(c, bins, lin, active) for c, x in enumerate(xs)]
        if self._mix is not None:  # a Python branch: rgb materials trace no mix
            xs = mix_colour(xs, self._mix)
        if self._scale != 1.0:
            w = w * self._scale
        return self._m.Color3f(*rho_from_x(ops, xs, valid, w))

    def _rho_point(self, wi, wo, active):
        """:meth:`_rho` in the scalar variants, one direction pair per call: the same
        bins, weights and inverse transform, with X (already mixed to the transformed R,
        G, B) from the numpy lookups of :mod:`sparse_brdf.model.lookups`, which read the
        same decoder data in a few numpy calls instead of the kernels' per-float Python
        loops."""
        ops, sh = self._ops, self._shape
        coords = angle_coords(ops, sh, wi, wo)
        if self.interpolate:
            lin = linear_bins(ops, sh, coords)
            w, valid = interp_weight(ops, sh, lin, self._use_cos)
            if not active:
                return self._zero3
            xs = self._lookup.point_linear(lin)
        else:
            bins = nearest_bins(ops, sh, coords)
            if not active:
                return self._zero3
            xs = self._lookup.point(*bins)
            if self.decoder == "grouped":  # the rows carry the bins' cos_i cos_o
                w, ok = bin_weight_from_cos(xs[3], self._use_cos)
            else:
                w, ok = bin_weight(ops, sh, *bins, self._use_cos)
            valid = 1.0 if ok else 0.0
        if self._scale != 1.0:
            w = w * self._scale
        return self._m.Color3f(*rho_from_x(ops, xs, valid, w))

    def to_string(self):
        return (f"{type(self).__name__}[filename={self.filename!r}, transform={self.transform}, "
                f"basis={self.basis}, terms={self.n_terms}, decoder={self.decoder}, "
                f"layout={self.layout}, sampling={self.sampling}, "
                f"interpolate={self.interpolate}, memory_bytes={self.memory_bytes}]")


class NeuralBRDF(GlossyBSDF):
    """Neural-BRDF (``neural_brdf``): the 6 -> 21 -> 21 -> 3 network of Sztrajman et al.,
    "Neural BRDF Representation and Importance Sampling" (2021), evaluated at the
    direction pair itself (no grid) by :func:`~mitsuba_plugin.kernels.nbrdf_rho`, the
    same kernel as the ``nbrdf`` evaluator: 675 weights (2700 bytes) per material, as
    opaque scalars, so every network of these widths shares one compiled kernel.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - filename
         - string
         - A Neural-BRDF network in the published Keras HDF5 layout (``.h5``: the demo
           materials, or a network trained with :func:`sparse_brdf.train_nbrdf` and saved
           with ``NeuralFit.save``).
       * - sampling
         - string
         - ``lobe`` (default) or ``cosine``, as for ``tabulated_brdf``; the lobe is fitted
           to the network's table on the MERL grid at load time, so it equals the lobe of
           ``tabulated_brdf`` reading the same file.

    Example::

        {"type": "neural_brdf", "filename": "blue-fabric.h5", "sampling": "cosine"}
    """

    plugin = "neural_brdf"

    def __init__(self, props) -> None:
        GlossyBSDF.__init__(self, props)
        p = _read_props(props, self.plugin, {"filename": _REQUIRED,
                                             "sampling": PLUGIN_DEFAULTS["sampling"]})
        self.sampling = _choice(p["sampling"], SAMPLING, self.plugin, "sampling")
        self.filename = _resolve(str(p["filename"]))
        try:
            layers = read_nbrdf_weights(self.filename)
        except Exception as exc:  # noqa: BLE001 - re-raised with the plugin and file named
            raise PluginError(f"{self.plugin}: cannot load {self.filename!r}: {exc}") from exc
        self.name = Path(self.filename).stem
        self.widths = tuple(k.shape[1] for k, _ in layers)
        self._weights = mlp_weights(self._ops, layers)
        self.memory_bytes = 4 * sum(k.size + b.size for k, b in layers)
        # the lobe of the table tabulated_brdf reads from the same file (symmetrised)
        profile = (table_profile(tabulate(layers, symmetric=True)[0])
                   if self.sampling == "lobe" else None)
        self._setup_sampling(self.sampling, profile, MERL_SHAPE)

    def _rho(self, wi, wo, active):
        return nbrdf_rho(self._ops, self._weights, wi, wo)

    def to_string(self):
        return (f"{type(self).__name__}[filename={self.filename!r}, widths={self.widths}, "
                f"sampling={self.sampling}, memory_bytes={self.memory_bytes}]")


# ------------------------------------------------------------------------- registration


def _derive(blueprint: type, base: type, **attrs) -> type:
    """A subclass of ``base`` with the body (methods, docstring) of ``blueprint``."""
    body = {k: v for k, v in vars(blueprint).items() if k not in ("__dict__", "__weakref__")}
    return type(blueprint.__name__, (base,), {**body, **attrs})


#: What each kind of variant returns from ``eval``: its colour representation.
VARIANT_KINDS = ("rgb", "mono", "spectral")


def variant_kind(name: str) -> tuple[str, bool]:
    """(colour kind, polarized) of the Mitsuba variant ``name``, e.g.
    ``("spectral", True)`` for ``llvm_ad_spectral_polarized``; a :class:`PluginError`
    naming the variant if the plugin cannot render in it."""
    parts = name.split("_")
    kinds = [k for k in VARIANT_KINDS if k in parts]
    if len(kinds) != 1 or (parts[0] not in ("scalar", "llvm", "cuda")):
        raise PluginError(f"mitsuba_plugin: the Mitsuba variant {name!r} is not supported "
                          f"(expected a scalar, llvm or cuda variant of "
                          f"{', '.join(VARIANT_KINDS)} colours)")
    return kinds[0], "polarized" in parts


def srgb_coeff_path() -> Path:
    """Mitsuba's RGB-to-spectrum table, ``data/srgb.coeff`` (Mitsuba's file resolver,
    else the installed package's folder)."""
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    try:
        p = Path(str(mi.file_resolver().resolve("data/srgb.coeff")))
        if p.is_file():
            return p
    except Exception:  # noqa: BLE001 - fall back to the package folder
        pass
    return Path(mi.__file__).parent / "data" / "srgb.coeff"


def _upsampling_loader(name: str, ops: Ops):
    """A function returning the variant's :class:`SpectralUpsampling`, read once."""
    box: list = []
    lock = threading.Lock()

    def get(_self=None):
        with lock:
            if not box:
                path = srgb_coeff_path()
                try:
                    box.append(SpectralUpsampling(ops, path))
                except (OSError, ValueError) as exc:
                    raise PluginError(f"mitsuba_plugin: variant {name}: cannot read "
                                      f"Mitsuba's spectral upsampling table {path}: "
                                      f"{exc}") from exc
        return box[0]

    return get


def make_classes(module, name: str | None = None) -> tuple[type, type, type]:
    """(TabulatedBRDF, SparseBSDF, NeuralBRDF) of variant module ``module`` (e.g.
    ``mitsuba.llvm_ad_rgb``, whose variant is ``name``, default: the module's own name):
    the classes above on that variant's ``mi.BSDF``."""
    m = VariantNamespace(module)
    name = name or m.name
    kind, polarized = variant_kind(name)
    ops = Ops(m)
    flags = m.BSDFFlags.GlossyReflection | m.BSDFFlags.FrontSide
    base = _derive(GlossyBSDF, m.BSDF, _m=m, _ops=ops, _flags=flags,
                   _glossy=int(+m.BSDFFlags.GlossyReflection), _zero3=m.Color3f(0.0),
                   _zero_s=m.UnpolarizedSpectrum(0.0), _kind=kind, _polarized=polarized,
                   _upsampling=_upsampling_loader(name, ops))
    return _derive(TabulatedBRDF, base), _derive(SparseBSDF, base), _derive(NeuralBRDF, base)


_CLASSES: dict[str, tuple[type, type, type]] = {}
_REGISTERED: set[str] = set()


def _current_variant(variant: str | None = None) -> str:
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    name = variant or mi.variant()
    if name is None:
        raise PluginError("mitsuba_plugin: no Mitsuba variant is set: call "
                          "mi.set_variant(...) first")
    return name


def classes(variant: str | None = None) -> tuple[type, type, type]:
    """(TabulatedBRDF, SparseBSDF, NeuralBRDF) classes of ``variant`` (default: the current one)."""
    name = _current_variant(variant)
    if name not in _CLASSES:
        variant_kind(name)  # an unsupported variant: one line naming it
        try:
            module = importlib.import_module(f"mitsuba.{name}")
        except ImportError as exc:
            raise PluginError(f"mitsuba_plugin: the Mitsuba variant {name!r} is not "
                              f"available in this installation: {exc}") from exc
        _CLASSES[name] = make_classes(module, name)
    return _CLASSES[name]


def register() -> str:
    """Register ``sparse_brdf``, ``tabulated_brdf`` and ``neural_brdf`` for the current
    variant.

    Idempotent per variant; returns the variant's name. Call after ``mi.set_variant``
    and before loading a scene that uses the plugins.
    """
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    name = _current_variant()
    if name in _REGISTERED:
        return name
    tabulated, sparse, neural = classes(name)
    mi.register_bsdf("tabulated_brdf", lambda props: tabulated(props))
    mi.register_bsdf("sparse_brdf", lambda props: sparse(props))
    mi.register_bsdf("neural_brdf", lambda props: neural(props))
    _REGISTERED.add(name)
    return name
