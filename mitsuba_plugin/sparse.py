"""The ``sparse_brdf`` BSDF: the sparse model evaluated from its coefficients at render
time, by the grouped or the strict decoder (:mod:`~mitsuba_plugin.decoders`), in the
scalar variants by the numpy lookups of :mod:`sparse_brdf.decoders.lookups`; its
coefficient values are differentiable. A loaded one exposes ``decoder``, ``layout``,
``n_terms``, ``distinct_atoms`` and ``basis`` (the file's colour basis: "rgb", or
"opponent", whose coded channels the kernel mixes back to R, G, B). Registered for a
variant by :func:`~mitsuba_plugin.registration.register`.
"""

from __future__ import annotations

import dataclasses
import threading

import drjit as dr

from sparse_brdf.decoders.buffers import colour_mix, float_buffer
from sparse_brdf.decoders.layouts import (
    DECODERS,
    LAYOUTS,
    LOBES,
    PLUGIN_DEFAULTS,
    channel_terms,
    grouped_channels,
    grouped_layout,
    grouped_plan,
    model_digest,
    strict_channel,
    strict_layout,
    strict_orders,
    term_values,
)
from sparse_brdf.decoders.lobe import sparse_profile
from sparse_brdf.decoders.lookups import GroupedLookup, StrictLookup
from sparse_brdf.decoders.scene import (
    MEMORY_BUDGET_MIB,
    distinct_atoms,
    material_cost,
    strict_shared_layout,
)
from sparse_brdf.errors import PluginError
from sparse_brdf.transforms import scale as transform_scale
from sparse_brdf.transforms import uses_cosine

from .budget import default_budget, enroll, resolve
from .decoders import grouped_x, shared_rows, strict_x, upload_grouped, upload_strict
from .glossy import GlossyBSDF
from .kernels import (
    angle_coords,
    bin_weight,
    bin_weight_from_cos,
    cos_terms,
    interp_weight,
    linear_bins,
    mix_colour,
    nearest_bins,
    point_rho_from_cos,
    rho_from_x,
    shared_shape,
)
from .loading import REQUIRED, bool_prop, choice_prop, load_model, read_props, resolve_file

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


class SparseBSDF(GlossyBSDF):
    """Sparse non-parametric BRDF (``sparse_brdf``): the model of Tongbuasirilai et al.,
    "A Sparse Non-parametric BRDF Model" (see docs/method.md).

    Evaluates ``X = sum_t s_t U1[i, a_t] U2[j, b_t] U3[k, c_t]`` per coded channel at the
    bin of (wi, wo), mixes the three back to the transformed R, G, B if the file's colour
    basis is "opponent" (:func:`~mitsuba_plugin.kernels.mix_colour`; "rgb" materials trace
    no mix, so their kernel is unchanged), then ``rho = max((exp(X) - 1) / w, 0)``, without
    ever building the full tensor (:func:`~mitsuba_plugin.decoders.grouped_x`,
    :func:`~mitsuba_plugin.decoders.strict_x`; data from :mod:`sparse_brdf.decoders.layouts`).
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
           over the nonzero terms, reading the atom rows the ensemble's materials share:
           least memory) or ``auto`` (default: decided with the scene's other ``auto``
           materials under its memory budget, :mod:`~mitsuba_plugin.budget`: grouped for
           the largest speed gain per byte first while the tables fit, and never past
           ``sparse_brdf.decoders.layouts.AUTO_GROUPED_MAX_BYTES``, 32 MiB).
       * - memory_budget
         - float
         - The scene's budget of per-material decoder data for its ``auto`` materials,
           in MiB (default: 64, or what ``mitsuba_plugin.memory_budget`` sets; a scene's
           budget is the smallest its materials state).
       * - layout
         - string
         - How the grouped decoder lays out its rows (see
           :func:`sparse_brdf.decoders.layouts.grouped_layout`): ``union`` (each atom the
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
        p = read_props(props, self.plugin, {
            "filename": REQUIRED, "ensemble": None, "decoder": "auto",
            "sampling": PLUGIN_DEFAULTS["sampling"], "interpolate": False,
            "layout": "auto", "memory_budget": None})
        if p["memory_budget"] is not None and p["memory_budget"] not in MEMORY_BUDGET_MIB:
            raise PluginError(f"{self.plugin}: memory_budget={p['memory_budget']!r}: "
                              f"expected MiB, {MEMORY_BUDGET_MIB.describe()}")
        self.sampling = choice_prop(p["sampling"], LOBES, self.plugin, "sampling")
        self.interpolate = bool_prop(p["interpolate"], self.plugin, "interpolate")
        decoder = choice_prop(p["decoder"], DECODERS, self.plugin, "decoder")
        layout = choice_prop(p["layout"], LAYOUTS, self.plugin, "layout")
        self.filename = resolve_file(str(p["filename"]))
        ens_path = None if p["ensemble"] is None else resolve_file(str(p["ensemble"]))
        model, ens = load_model(self.filename, ens_path, self.plugin)
        self.name = model.name
        self.shape = model.shape
        self.transform = model.transform
        self.basis = model.basis
        # M^T of the colour basis, traced as constants; None ("rgb"): no mix is traced
        self._mix = colour_mix(model.basis)
        self.n_terms = tuple(int(n) for n in model.n_coeffs)
        self._shape = shared_shape(ops, model.shape)
        self._cos_on = uses_cosine(model.transform)
        self._use_cos = ops.f(1.0 if self._cos_on else 0.0)
        # the relative transforms' constant factor s of the weight (a Python float: the
        # paper's transforms, s = 1, trace no multiply)
        self._scale = transform_scale(model.transform)
        self.layout = None
        self._model, self._ens, self._grad, self._ad = model, ens, False, None
        self._plan = None  # the grouped decoder's plan, made once when first needed
        self._layout_asked = layout
        budget = p["memory_budget"]
        self._budget = (default_budget() if budget is None
                        else int(float(budget) * 2**20))
        self._pending = decoder == "auto"
        if self._pending:  # decided with the scene's other auto materials (budget.py)
            enroll(self)
        else:  # "grouped" or "strict", checked above
            self._build(decoder)
        # the coded channels' values, as mi.traverse exposes them (``values_0`` ...)
        self._values = [self._value_array(v) for v in model.values]
        # the lobe's theta_h profile only where the lobe samples (cosine: none to fit)
        self._setup_sampling(self.sampling, sparse_profile(model, ens)
                             if self.sampling == "lobe" else None, model.shape)
        if not ops.jit:  # scalar variants: each call goes straight to the numpy lookups
            self._rho = self._rho_point

    # data ----------------------------------------------------------------------------
    #: What a material whose decoder waits for its scene's budget does not hold yet:
    #: reading one decides the pool (:func:`~mitsuba_plugin.budget.resolve`).
    _LAZY = frozenset({"decoder", "channels", "memory_bytes", "distinct_atoms", "packets",
                       "grouped_modes", "shared_bytes"})

    def __getattr__(self, name):
        if name in SparseBSDF._LAZY and self.__dict__.get("_pending"):
            resolve(self)
            return self.__dict__[name]
        raise AttributeError(name)

    def _grouped_plan(self):
        """The material's :class:`~sparse_brdf.decoders.layouts.GroupedPlan` (the
        grouped mode, layout and bytes), made once: it depends on the support only, which
        an update of the values keeps."""
        if self._plan is None:
            self._plan = grouped_plan(self._model, self._ens)
        return self._plan

    def _cost(self):
        """The :class:`~sparse_brdf.decoders.scene.MaterialCost` the budget weighs."""
        return material_cost(self._model, self._ens, self._grouped_plan())

    def _build(self, decoder: str) -> None:
        """Build the buffers of ``decoder`` ("grouped" or "strict"). The material stops
        pending only once they are built: the scalar variants render on many threads, and
        one that saw it no longer pending would read a lookup not yet made."""
        self.decoder = decoder
        self.shared_bytes = 0
        if decoder == "grouped":
            self._build_grouped(self._model, self._ens, self._layout_asked)
        else:
            self._build_strict(self._model, self._ens)
        self._pending = False

    def _build_grouped(self, model, ens, layout: str) -> None:
        key = _grouped_key(model, ens, layout, self._ops)
        with _GROUPED_LOCK:
            if _LAST_GROUPED[0] == key:
                chans, lay, grouped, _ = _LAST_GROUPED[1]
            else:
                plan = self._grouped_plan()
                chans = grouped_channels(model, ens, plan.mode)
                lay = grouped_layout(chans, model.shape,
                                     plan.kind if layout in ("auto", None) else layout)
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
        self.distinct_atoms = distinct_atoms(model, ens)
        if not self._ops.jit:  # numpy lookups of the material's own atom rows
            chans = [strict_channel(*channel_terms(model, ens, c)) for c in range(3)]
            self.channels = chans
            self._strict = upload_strict(self._ops, strict_layout(chans))
            self.memory_bytes = sum(self._ops.nbytes(b) for b in (
                self._strict.values, self._strict.packed, self._strict.rows))
            self._lookup = StrictLookup(chans, self._mix)
            return
        # the atom rows are the ensemble's, uploaded once for every material
        shared, rows = shared_rows(self._ops, ens)
        self.channels = None
        self._strict = upload_strict(self._ops, strict_shared_layout(model, ens, shared),
                                     rows)
        self.memory_bytes = sum(self._ops.nbytes(b) for b in (
            self._strict.values, self._strict.packed))
        self.shared_bytes = shared.nbytes

    # differentiable values -----------------------------------------------------------
    # Both decoders' buffers are linear in the values, but a buffer derived from a
    # parameter outside a render (as the grouped decoder's contracted tables would be)
    # breaks Mitsuba's forward mode: a render may only differentiate through variables it
    # reads itself. So after ``params.update()`` the buffers are rebuilt exactly as from a
    # file holding the new values (detached), and when a channel's values carry
    # gradients the kernel adds, per channel, the derivative carrier
    # ``sum_t (s_t - detach(s_t)) U1[i, a_t] U2[j, b_t] U3[k, c_t]``: zero in value, with
    # the model's exact derivative, ``s_t`` gathered inside the kernel from the values
    # that ``mi.traverse`` holds (see :func:`~mitsuba_plugin.decoders.strict_x`).
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
        if self._pending:
            resolve(self)
        try:
            vals = term_values([dr.detach(v) if self._ops.jit else v for v in self._values],
                               self.n_terms)
        except ValueError as exc:
            raise PluginError(f"{self.plugin}: {self.filename!r}: {exc}") from None
        model = dataclasses.replace(self._model, values=vals)
        self._model = model
        self._build(self.decoder)
        if self.sampling == "lobe":  # the lobe follows the values, as from a file
            self._setup_sampling(self.sampling, sparse_profile(model, self._ens), model.shape)
        self._grad = self._ops.jit and any(dr.grad_enabled(v) for v in self._values)
        if self._grad:
            self._attach_gradients()

    def _attach_gradients(self) -> None:
        """Build the derivative carrier's data once (it depends on the support only): the
        strict decoder's atom rows and packed indices, and per channel the file's term
        index of each of its terms (:func:`sparse_brdf.decoders.layouts.strict_orders`).
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
        """The derivative carrier of channel c (zero in value), see
        :func:`~mitsuba_plugin.decoders.strict_x`."""
        buf, orders = self._ad
        return strict_x(self._ops, buf, self._shape, c, bins, lin, active,
                        grad=(self._values[c], orders[c]))

    def _rho(self, wi, wo, active):
        if self._pending:
            resolve(self)
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
        G, B) from the numpy lookups of :mod:`sparse_brdf.decoders.lookups`, which read the
        same decoder data in a few numpy calls instead of the kernels' per-float Python
        loops. The default (grouped, nearest bin) is one lookup and one
        :func:`~mitsuba_plugin.kernels.point_rho_from_cos`: every Python call here costs
        a measurable share of the render."""
        if self._pending:
            resolve(self)
        ops, sh = self._ops, self._shape
        coords = angle_coords(ops, sh, wi, wo)
        if self.interpolate:
            lin = linear_bins(ops, sh, coords)
            w, valid = interp_weight(ops, sh, lin, self._use_cos)
            if not active:
                return self._zero3
            xs = self._lookup.point_linear(lin)
            return self._m.Color3f(*rho_from_x(ops, xs, valid, w * self._scale))
        bins = nearest_bins(ops, sh, coords)
        if not active:
            return self._zero3
        if self.decoder == "grouped":  # the rows carry the bins' cos_i cos_o
            x0, x1, x2, c = self._lookup.point(*bins)
        else:
            (x0, x1, x2), c = self._lookup.point(*bins), cos_terms(ops, sh, *bins)
        return self._m.Color3f(*point_rho_from_cos(x0, x1, x2, c, self._cos_on,
                                                   self._scale))

    def to_string(self):
        return (f"{type(self).__name__}[filename={self.filename!r}, transform={self.transform}, "
                f"basis={self.basis}, terms={self.n_terms}, decoder={self.decoder}, "
                f"layout={self.layout}, sampling={self.sampling}, "
                f"interpolate={self.interpolate}, memory_bytes={self.memory_bytes}]")
