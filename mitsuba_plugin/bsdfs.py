"""The two Python BSDFs, built once per Mitsuba variant by :func:`make_classes`.

See :mod:`mitsuba_plugin` for the plugins' parameters; this module holds the code.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import drjit as dr
import numpy as np

from . import data as D
from .kernels import (
    Ops,
    Shape,
    VariantNamespace,
    angle_coords,
    bin_weight,
    bin_weight_from_cos,
    expm1,
    interp_weight,
    linear_bins,
    lobe_pdf,
    nearest_bins,
    power_cosine_sample,
)

SAMPLING = ("cosine", "lobe")
DECODERS = ("grouped", "strict", "auto")
LAYOUTS = ("auto", "union", "slots")

_ENSEMBLES: dict = {}
_ENSEMBLE_LOCK = threading.Lock()


class PluginError(ValueError):
    """A BSDF parameter or file is unusable; the message names the plugin and the file."""


def load_ensemble(path: str | None):
    """The ensemble at ``path`` (None: the shipped one), cached by path, size and mtime."""
    from sparse_brdf.model.ensemble import Ensemble

    if path is None:
        key = ("<default>",)
    else:
        st = os.stat(path)
        key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    with _ENSEMBLE_LOCK:
        ens = _ENSEMBLES.get(key)
        if ens is None:
            ens = Ensemble.default() if path is None else Ensemble.load(path)
            _ENSEMBLES.clear()  # keep one ensemble in memory
            _ENSEMBLES[key] = ens
    return ens


def _resolve(filename: str) -> str:
    """Resolve a scene-relative file name with Mitsuba's file resolver."""
    if filename.startswith("mitsuba:"):
        return filename
    import mitsuba as mi

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


def make_classes(m):
    """Define the BSDF classes of variant module ``m``; returns (TabulatedBRDF, SparseBSDF)."""
    m = VariantNamespace(m)
    ops = Ops(m)
    flags = m.BSDFFlags.GlossyReflection | m.BSDFFlags.FrontSide
    glossy = int(+m.BSDFFlags.GlossyReflection)
    zero3 = m.Color3f(0.0)

    class _Base(m.BSDF):
        """Shared sampling, pdf and cosine handling; subclasses define ``_rho``."""

        plugin = "?"

        def __init__(self, props) -> None:
            m.BSDF.__init__(self, props)
            self.m_flags = flags
            self.m_components = [flags]

        # set by subclasses ------------------------------------------------------------
        def _setup_sampling(self, sampling: str, profile: np.ndarray, shape) -> None:
            self.sampling = sampling
            n, p = D.fit_lobe(profile, shape) if sampling == "lobe" else (1.0, 0.0)
            self.lobe_exponent, self.lobe_prob = float(n), float(p)
            self._exp = ops.f(n)
            self._prob = ops.f(p)

        def _rho(self, wi, wo, active):  # pragma: no cover - abstract
            raise NotImplementedError

        # Mitsuba interface -------------------------------------------------------------
        def _pdf(self, wi, wo):
            ci = m.Frame3f.cos_theta(wi)
            co = m.Frame3f.cos_theta(wo)
            p = m.warp.square_to_cosine_hemisphere_pdf(wo)
            if self.sampling == "lobe":
                p = (1.0 - self._prob) * p + self._prob * lobe_pdf(ops, wi, wo, self._exp)
            return dr.select((ci > 0.0) & (co > 0.0), p, 0.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = dr.zeros(m.BSDFSample3f)
            if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
                return bs, m.Color3f(zero3)
            wi = si.wi
            wo = m.warp.square_to_cosine_hemisphere(sample2)
            if self.sampling == "lobe":
                h = power_cosine_sample(ops, sample2, self._exp)
                wo_lobe = 2.0 * dr.dot(wi, h) * h - wi
                wo = dr.select(sample1 < self._prob, wo_lobe, wo)
            pdf = self._pdf(wi, wo)
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_type = m.UInt32(glossy)
            bs.sampled_component = m.UInt32(0)
            co = m.Frame3f.cos_theta(wo)
            ok = active & (m.Frame3f.cos_theta(wi) > 0.0) & (co > 0.0) & (pdf > 0.0)
            f = self._rho(wi, wo, ok)
            weight = f * (co / dr.maximum(pdf, 1e-30))
            return bs, dr.select(ok, weight, zero3)

        def eval(self, ctx, si, wo, active=True):
            if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
                return m.Color3f(zero3)
            co = m.Frame3f.cos_theta(wo)
            ok = active & (m.Frame3f.cos_theta(si.wi) > 0.0) & (co > 0.0)
            return dr.select(ok, self._rho(si.wi, wo, ok) * co, zero3)

        def pdf(self, ctx, si, wo, active=True):
            if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
                return m.Float(0.0)
            return dr.select(active, self._pdf(si.wi, wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            # the material is read-only: nothing to expose for differentiation
            pass

        def parameters_changed(self, keys=None):
            pass

    class TabulatedBRDF(_Base):
        __doc__ = _TABULATED_DOC
        plugin = "tabulated_brdf"

        def __init__(self, props) -> None:
            _Base.__init__(self, props)
            p = _read_props(props, self.plugin, {"filename": _REQUIRED, "sampling": "cosine",
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
            self._setup_sampling(self.sampling, D.table_profile(brdf.values), brdf.shape)

        def _rho(self, wi, wo, active):
            sh = self._shape
            n1, n2, n3 = sh.n
            coords = angle_coords(ops, sh, wi, wo)
            if not self.interpolate:
                i, j, k = nearest_bins(ops, sh, coords)
                return ops.gather3(self._table, (i * n2 + j) * n3 + k, active)
            (i0, i1, ti), (j0, j1, tj), (k0, k1, tk) = linear_bins(ops, sh, coords)
            acc = m.Color3f(zero3)
            for ei, wi_ in ((i0, 1.0 - ti), (i1, ti)):
                for ej, wj in ((j0, 1.0 - tj), (j1, tj)):
                    for ek, wk in ((k0, 1.0 - tk), (k1, tk)):
                        v = ops.gather3(self._table, (ei * n2 + ej) * n3 + ek, active)
                        acc = acc + v * (wi_ * wj * wk)
            return acc

        def to_string(self):
            return (f"TabulatedBRDF[filename={self.filename!r}, shape={self.shape}, "
                    f"sampling={self.sampling}, interpolate={self.interpolate}, "
                    f"memory_bytes={self.memory_bytes}]")

    class SparseBSDF(_Base):
        __doc__ = _SPARSE_DOC
        plugin = "sparse_brdf"

        def __init__(self, props) -> None:
            _Base.__init__(self, props)
            p = _read_props(props, self.plugin, {
                "filename": _REQUIRED, "ensemble": None, "decoder": "auto",
                "sampling": "cosine", "interpolate": False, "layout": "auto"})
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
            self.n_terms = tuple(int(n) for n in model.n_coeffs)
            self.decoder = D.choose_decoder(decoder, model, ens)
            self._shape = Shape(ops, model.shape)
            self._use_cos = ops.f(1.0 if model.transform == "log-plus-cosine" else 0.0)
            self.layout = None
            if self.decoder == "grouped":
                self._build_grouped(model, ens, layout)
            else:
                self._build_strict(model, ens)
            self._setup_sampling(self.sampling, D.sparse_profile(model, ens), model.shape)

        # data --------------------------------------------------------------------------
        def _build_grouped(self, model, ens, layout: str) -> None:
            chans = D.grouped_channels(model, ens)
            self.channels = chans
            lay = D.grouped_layout(chans, model.shape, None if layout == "auto" else layout)
            self.layout = lay.kind
            self._t = ops.floats(lay.tables)
            self._v = ops.floats(lay.values)
            # one kernel for both layouts: a loop for each, the other runs 0 times
            self._chunks = {k: ops.u(lay.chunks if k == lay.kind else 0)
                            for k in ("slots", "union")}
            ch = chans[0]
            self._sel = [[ops.u(int(mode == sel)) for mode in range(3)]
                         for sel in (ch.mode_p, ch.mode_q, ch.mode_g)]
            self._fsel = [[ops.f(float(mode == sel)) for mode in range(3)]
                          for sel in (ch.mode_p, ch.mode_q, ch.mode_g)]
            self._nq = ops.u(ch.n_q)
            self.memory_bytes = ops.nbytes(self._t) + ops.nbytes(self._v)
            self.distinct_atoms = tuple(c.k for c in chans)
            self.packets = lay.packets
            self.grouped_modes = tuple(c.mode_g + 1 for c in chans)

        def _build_strict(self, model, ens) -> None:
            chans = [D.strict_channel(*D.channel_terms(model, ens, c)) for c in range(3)]
            self.channels = chans
            soff = np.cumsum([0] + [ch.n_terms for ch in chans])
            rows = [r for ch in chans for r in ch.rows]
            roff = np.cumsum([0] + [r.size for r in rows])
            self._s = ops.floats(np.concatenate([ch.values for ch in chans]))
            self._p = ops.uints(np.concatenate([ch.packed for ch in chans]))
            self._r = ops.floats(np.concatenate([r.ravel() for r in rows]))
            self._sp = [{"t": ops.u(ch.n_terms), "soff": ops.u(soff[c]),
                         "roff": [ops.u(roff[3 * c + mode]) for mode in range(3)]}
                        for c, ch in enumerate(chans)]
            self.memory_bytes = sum(ops.nbytes(b) for b in (self._s, self._p, self._r))
            self.distinct_atoms = tuple(tuple(r.shape[0] for r in ch.rows) for ch in chans)

        # lookups -----------------------------------------------------------------------
        def _x_grouped(self, bins, lin, active):
            """X of the three channels and the bins' cos_i cos_o from the shared rows
            (see data.grouped_layout). Two loops, one per layout; a material's data
            has one of them, and the other's count is 0.

            slots: a chunk is one packet of table row and one of atom values, float
            4 s + c of both belonging to channel c (c = 3: the weight): one
            multiply-add sum per float. union: a chunk is two packets of table row
            (float 3 a + c: channel c at atom a < 5, float 15: the weight) and one
            of atom values (float a: atom a, float 5: the weight)."""
            w = D.PACKET
            n_s, n_u = self._chunks["slots"], self._chunks["union"]
            nq = self._nq
            sel_p, sel_q, sel_g = self._sel
            t_buf, v_buf = self._t, self._v

            def pick(idx, sel):
                return idx[0] * sel[0] + idx[1] * sel[1] + idx[2] * sel[2]

            # [(bin pair, weight)], [(bin of mode g, weight)]
            if lin is None:
                pairs = [(pick(bins, sel_p) * nq + pick(bins, sel_q), None)]
                gs = [(pick(bins, sel_g), None)]
            else:
                i0s = tuple(x[0] for x in lin)
                i1s = tuple(x[1] for x in lin)
                ts = tuple(x[2] for x in lin)
                fp, fq, fg = self._fsel
                tp, tq, tg = pick(ts, fp), pick(ts, fq), pick(ts, fg)
                pairs = [(ep * nq + eq, wp * wq)
                         for ep, wp in ((pick(i0s, sel_p), 1.0 - tp), (pick(i1s, sel_p), tp))
                         for eq, wq in ((pick(i0s, sel_q), 1.0 - tq), (pick(i1s, sel_q), tq))]
                gs = [(pick(i0s, sel_g), 1.0 - tg), (pick(i1s, sel_g), tg)]

            def blend(buf, rows_, stride, h):
                """Packet h of the rows (row index * stride packets), blended."""
                out = None
                for row, wt in rows_:
                    pk = ops.gather_packet(buf, row * stride + h, w, active)
                    if wt is None:
                        return list(pk)
                    pk = [wt * x for x in pk]
                    out = pk if out is None else [a + b for a, b in zip(out, pk, strict=True)]
                return out

            def fma(a, b, c):
                return dr.fma(a, b, c) if ops.jit else a * b + c

            def body_slots(h, acc):
                tv, vv = blend(t_buf, pairs, n_s, h), blend(v_buf, gs, n_s, h)
                return tuple(fma(a, b, c) for a, b, c in zip(tv, vv, acc, strict=True))

            def body_union(h, acc):
                tv = blend(t_buf, pairs, 2 * n_u, 2 * h) + blend(t_buf, pairs, 2 * n_u, 2 * h + 1)
                vv = blend(v_buf, gs, n_u, h)
                out = list(acc)
                for a in range(D.UNION_ATOMS):
                    for c in range(3):
                        out[c] = fma(tv[3 * a + c], vv[a], out[c])
                out[3] = fma(tv[3 * D.UNION_ATOMS], vv[D.UNION_ATOMS], out[3])
                return tuple(out)

            zero = m.Float(0.0) if ops.jit else 0.0
            acc_s = ops.loop(n_s, body_slots, (zero,) * w)
            acc_u = ops.loop(n_u, body_union, (zero,) * D.SLOT)
            sums = [sum(acc_s[c::D.SLOT], acc_u[c]) for c in range(D.SLOT)]
            return sums[:3], sums[3]

        def _x_strict(self, c, bins, lin, active):
            sp = self._sp[c]
            n = self._shape.n
            s_buf, p_buf, r_buf = self._s, self._p, self._r
            soff, roff = sp["soff"], sp["roff"]
            mask = (1 << D.PACK_BITS) - 1
            zero = m.Float(0.0)

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
                end_b = (p & D.END_B) != 0
                end_c = (p & D.END_C) != 0
                acc_b = acc_b + s * row(0, p & mask, active)
                # close the (c, b) group: multiply by U2[j, b] (read only at group ends)
                u2 = row(1, (p >> D.PACK_BITS) & mask, active & end_b)
                acc_c = dr.select(end_b, acc_c + acc_b * u2, acc_c)
                acc_b = dr.select(end_b, zero, acc_b)
                # close the c group: multiply by U3[k, c]
                u3 = row(2, (p >> (2 * D.PACK_BITS)) & mask, active & end_c)
                acc = dr.select(end_c, acc + acc_c * u3, acc)
                acc_c = dr.select(end_c, zero, acc_c)
                return acc, acc_c, acc_b

            return ops.loop(sp["t"], body, (zero, zero, zero))[0]

        def _rho(self, wi, wo, active):
            sh = self._shape
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
            scale = valid * dr.rcp(w)
            # a select, not only the product: an invalid bin gives 0 even where the
            # model's X there is large enough for expm1 to overflow (inf * 0 = nan)
            out = [dr.select(scale > 0.0, dr.maximum(expm1(x) * scale, 0.0), 0.0)
                   for x in xs]
            return m.Color3f(*out)

        def to_string(self):
            return (f"SparseBRDF[filename={self.filename!r}, transform={self.transform}, "
                    f"terms={self.n_terms}, decoder={self.decoder}, layout={self.layout}, "
                    f"sampling={self.sampling}, "
                    f"interpolate={self.interpolate}, memory_bytes={self.memory_bytes}]")

    return TabulatedBRDF, SparseBSDF


def _load_table(filename: str, ensemble, plugin: str):
    from sparse_brdf.sources.load import load_brdf

    try:
        if ensemble is not None and Path(filename).suffix.lower() == ".sbrdf":
            from sparse_brdf.model.sbrdf import decode_file

            return decode_file(filename, load_ensemble(_resolve(str(ensemble))))
        return load_brdf(filename)
    except Exception as exc:  # noqa: BLE001 - re-raised with the plugin and file named
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc


def _load_model(filename: str, ens_path: str | None, plugin: str):
    from sparse_brdf.model.sbrdf import load_sbrdf

    try:
        ens = load_ensemble(ens_path)
    except Exception as exc:  # noqa: BLE001
        what = "the shipped ensemble" if ens_path is None else repr(ens_path)
        raise PluginError(f"{plugin}: cannot load {what} for {filename!r}: {exc}") from exc
    try:
        model = load_sbrdf(filename, ens)
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{plugin}: cannot load {filename!r}: {exc}") from exc
    if tuple(model.shape) != tuple(ens.shape):
        raise PluginError(f"{plugin}: {filename!r} has grid {model.shape}, its ensemble "
                          f"{ens.shape}")
    return model, ens


_TABULATED_DOC = """Tabulated measured BRDF (``tabulated_brdf``): the reference BSDF.

Holds the whole (n1, n2, n3, 3) table (16.7 MiB for the MERL grid) in one Dr.Jit Float
array and gathers one RGB triple by flat bin index, with the project's bin convention
(SPEC section 1), shared with ``sparse_brdf``.

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
     - ``cosine`` (default: cosine-weighted hemisphere, independent of the BRDF, so a
       reference and a model render share their sample paths) or ``lobe`` (cosine mixed
       with a power-cosine half-vector lobe fitted to the BRDF at load time).
   * - interpolate
     - boolean
     - Trilinear interpolation between the bins' lower-edge samples (default: false,
       nearest-lower bin as in the MERL convention).

Example::

    {"type": "tabulated_brdf", "filename": "gold-metallic-paint.binary",
     "sampling": "cosine"}
"""

_SPARSE_DOC = """Sparse non-parametric BRDF (``sparse_brdf``): the model of SPEC section 3.

Evaluates ``X = sum_t s_t U1[i, a_t] U2[j, b_t] U3[k, c_t]`` per channel at the bin of
(wi, wo), then ``rho = max((exp(X) - 1) / w, 0)``, without ever building the full tensor
(see :mod:`mitsuba_plugin.data`). Per-material data lives in Dr.Jit arrays and opaque
scalars, so every material shares one compiled kernel. ``memory_bytes`` reports the
bytes of the arrays the BSDF holds.

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
       tables exceed ``mitsuba_plugin.data.AUTO_GROUPED_MAX_BYTES``, 32 MiB).
   * - layout
     - string
     - How the grouped decoder lays out its rows (see :func:`mitsuba_plugin.data.
       grouped_layout`): ``union`` (each atom the three channels use stored once),
       ``slots`` (every channel its own columns) or ``auto`` (default: the one that
       reads fewer packets per lookup). Both run in the same kernel.
   * - sampling
     - string
     - ``cosine`` (default) or ``lobe``, as for ``tabulated_brdf``.
   * - interpolate
     - boolean
     - Trilinear interpolation of the transformed value X (separable: each mode's atoms
       are interpolated linearly) and of the weight w (default: false).

Example::

    {"type": "sparse_brdf", "filename": "gold-metallic-paint.sbrdf",
     "decoder": "grouped", "sampling": "cosine"}
"""
