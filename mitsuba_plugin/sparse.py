"""The ``sparse_brdf`` BSDF: the sparse model evaluated from its coefficients at render
time, by the grouped or the strict decoder (:mod:`~mitsuba_plugin.decoders`; the
material's decoder data, built now or once its scene's budget decides, in
:mod:`~mitsuba_plugin.sparse_buffers`), in the scalar variants by the numpy lookups of
:mod:`sparse_brdf.decoders.lookups` (:class:`ScalarRho`); its coefficient values are
differentiable. A loaded one exposes ``decoder``, ``layout``, ``n_terms``,
``distinct_atoms`` and ``basis`` (the file's colour basis: "rgb", or "opponent", whose
coded channels the kernel mixes back to R, G, B). Registered for a variant by
:func:`~mitsuba_plugin.registration.register`.
"""

from __future__ import annotations

import dataclasses

import drjit as dr

from sparse_brdf.decoders.buffers import colour_mix, float_buffer
from sparse_brdf.decoders.layouts import DECODERS, LAYOUTS, LOBES, PLUGIN_DEFAULTS, term_values
from sparse_brdf.decoders.lobe import sparse_profile
from sparse_brdf.decoders.scene import MEMORY_BUDGET_MIB
from sparse_brdf.errors import PluginError
from sparse_brdf.transforms import material_scale, uses_cosine

from .budget import default_budget, resolve
from .decoders import grouped_x, strict_x
from .glossy import GlossyBSDF
from .kernels import (
    angle_coords,
    bin_weight,
    bin_weight_from_cos,
    cos_terms,
    interp_weight,
    linear_bins,
    lobe_d_at,
    lobe_inputs,
    lobe_x,
    mix_colour,
    nearest_bins,
    point_rho_from_cos,
    point_rho_lobe,
    rho_from_x,
    shared_shape,
)
from .loading import REQUIRED, bool_prop, choice_prop, load_model, read_props, resolve_file
from .sparse_buffers import SparseBuffers


def _read_props(props, plugin: str) -> dict:
    """The plugin's properties, each checked against its declaration."""
    p = read_props(props, plugin, {
        "filename": REQUIRED, "ensemble": None, "decoder": "auto",
        "sampling": PLUGIN_DEFAULTS["sampling"], "interpolate": False,
        "layout": "auto", "memory_budget": None})
    if p["memory_budget"] is not None and p["memory_budget"] not in MEMORY_BUDGET_MIB:
        raise PluginError(f"{plugin}: memory_budget={p['memory_budget']!r}: "
                          f"expected MiB, {MEMORY_BUDGET_MIB.describe()}")
    p["sampling"] = choice_prop(p["sampling"], LOBES, plugin, "sampling")
    p["interpolate"] = bool_prop(p["interpolate"], plugin, "interpolate")
    p["decoder"] = choice_prop(p["decoder"], DECODERS, plugin, "decoder")
    p["layout"] = choice_prop(p["layout"], LAYOUTS, plugin, "layout")
    return p


class SparseBSDF(GlossyBSDF):
    """Sparse non-parametric BRDF (``sparse_brdf``): the model of Tongbuasirilai et al.,
    "A Sparse Non-parametric BRDF Model" (see docs/method.md).

    Evaluates ``X = sum_t s_t U1[i, a_t] U2[j, b_t] U3[k, c_t]`` per coded channel at the
    bin of (wi, wo), mixes the three back to the transformed R, G, B if the file's colour
    basis is "opponent" (:func:`~mitsuba_plugin.kernels.mix_colour`; "rgb" materials trace
    no mix), maps a lobe transform's by its base lobe (:func:`~mitsuba_plugin.kernels.lobe_x`),
    then ``rho = max((exp(X) - 1) / w, 0)``, never building the full tensor (decoders:
    :mod:`~mitsuba_plugin.decoders`; data from :mod:`sparse_brdf.decoders.layouts`).
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
        p = _read_props(props, self.plugin)
        self.sampling, self.interpolate = p["sampling"], p["interpolate"]
        self.filename = resolve_file(str(p["filename"]))
        ens_path = None if p["ensemble"] is None else resolve_file(str(p["ensemble"]))
        model, ens = load_model(self.filename, ens_path, self.plugin)
        self.name, self.shape = model.name, model.shape
        self.transform, self.basis = model.transform, model.basis
        # M^T of the colour basis, traced as constants; None ("rgb"): no mix is traced
        self._mix = colour_mix(model.basis)
        self.n_terms = tuple(int(n) for n in model.n_coeffs)
        self._shape = shared_shape(ops, model.shape)
        self._cos_on = uses_cosine(model.transform)
        self._use_cos = ops.f(1.0 if self._cos_on else 0.0)
        # the weight's constant factor s (a Python float: s = 1 traces no multiply)
        self._scale = material_scale(model.transform, model.gain)
        self._lobe, self._floor = lobe_inputs(ops, model)  # None, None: kernels unchanged
        self._grad = False
        budget = p["memory_budget"]
        #: The decoder data (built now, or once the scene's budget decides: budget.py).
        self.buffers = SparseBuffers(
            ops, model, ens, self._mix, p["layout"],
            default_budget() if budget is None else int(float(budget) * 2**20), p["decoder"])
        # the coded channels' values, as mi.traverse exposes them (``values_0`` ...)
        self._values = [self._value_array(v) for v in model.values]
        # the lobe's theta_h profile only where the lobe samples (cosine: none to fit)
        self._setup_sampling(self.sampling, sparse_profile(model, ens)
                             if self.sampling == "lobe" else None, model.shape)
        if not ops.jit:  # scalar variants: each call goes straight to the numpy lookups
            self._rho = ScalarRho(self)

    def __getattr__(self, name):
        """The decoder's attributes (:attr:`SparseBuffers.LAZY`, and ``layout``), read
        from :attr:`buffers`; reading one of a material that waits for its scene's
        budget decides the pool (:func:`~mitsuba_plugin.budget.resolve`)."""
        buf = self.__dict__.get("buffers")
        if buf is not None and name == "layout":
            return buf.layout
        if buf is not None and name in SparseBuffers.LAZY:
            if buf.pending:
                resolve(buf)
            return getattr(buf, name)
        raise AttributeError(name)

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
        buf = self.buffers
        if buf.pending:
            resolve(buf)
        try:
            vals = term_values([dr.detach(v) if self._ops.jit else v for v in self._values],
                               self.n_terms)
        except ValueError as exc:
            raise PluginError(f"{self.plugin}: {self.filename!r}: {exc}") from None
        model = dataclasses.replace(buf.model, values=vals)
        buf.build(buf.decoder, model)
        if self.sampling == "lobe":  # the lobe follows the values, as from a file
            self._setup_sampling(self.sampling, sparse_profile(model, buf.ens), model.shape)
        self._grad = self._ops.jit and any(dr.grad_enabled(v) for v in self._values)
        if self._grad:  # its data (SparseBuffers.carrier) stays detached: the derivative
            buf.carrier()  # flows only through the values, read inside the kernel

    # lookups -------------------------------------------------------------------------
    def _rho(self, wi, wo, active):
        buf = self.buffers
        if buf.pending:
            resolve(buf)
        if not self._ops.jit:  # (an instance binds its ScalarRho itself, see __init__)
            return self.__dict__["_rho"](wi, wo, active)
        ops, sh = self._ops, self._shape
        coords = angle_coords(ops, sh, wi, wo)
        grouped = buf.decoder == "grouped"
        if self.interpolate:
            lin = linear_bins(ops, sh, coords)
            bins = None
            w, valid = interp_weight(ops, sh, lin, self._use_cos)
            if grouped:
                xs, _ = grouped_x(ops, buf.grouped, bins, lin, active)
        else:
            lin = None
            bins = nearest_bins(ops, sh, coords)
            if grouped:
                # the grouped rows carry the bins' cos_i cos_o as a fourth channel
                xs, cc = grouped_x(ops, buf.grouped, bins, lin, active)
                w, ok = bin_weight_from_cos(cc, self._use_cos)
            else:
                w, ok = bin_weight(ops, sh, *bins, self._use_cos)
                # invalid bins (below the horizon at their angles) hold no
                # measurement: 0, as in the tabulated reference and SparseBRDF.decode
                active = active & ok
            valid = dr.select(ok, 1.0, 0.0)
        if not grouped:
            xs = [strict_x(ops, buf.strict, sh, c, bins, lin, active) for c in range(3)]
        if self._grad:  # a Python branch: only differentiated renders trace the carrier
            ad, orders = buf.carrier()  # (strict_x: zero in value, the values' derivative)
            xs = [x + strict_x(ops, ad, sh, c, bins, lin, active,
                               grad=(self._values[c], orders[c])) for c, x in enumerate(xs)]
        if self._mix is not None:  # a Python branch: rgb materials trace no mix
            xs = mix_colour(xs, self._mix)
        if self._scale != 1.0:
            w = w * self._scale
        if self._lobe is not None:  # a Python branch: only lobe materials trace it
            xs = lobe_x(ops, xs, w, lobe_d_at(ops, sh, bins, lin, self._lobe[0]), self._lobe)
        return self._m.Color3f(*rho_from_x(ops, xs, valid, w, self._floor))

    def to_string(self):
        return (f"{type(self).__name__}[filename={self.filename!r}, transform={self.transform}, "
                f"basis={self.basis}, terms={self.n_terms}, decoder={self.decoder}, "
                f"layout={self.layout}, sampling={self.sampling}, "
                f"interpolate={self.interpolate}, memory_bytes={self.memory_bytes}]")


class ScalarRho:
    """:meth:`SparseBSDF._rho` in the scalar variants, one direction pair per call: the
    same bins, weights and inverse transform, with X (already mixed to the transformed R,
    G, B) from the numpy lookups of :mod:`sparse_brdf.decoders.lookups`, which read the
    same decoder data in a few numpy calls instead of the kernels' per-float Python
    loops. The default (grouped, nearest bin) is one lookup and one
    :func:`~mitsuba_plugin.kernels.point_rho_from_cos`: every Python call here costs a
    measurable share of the render, so the material's constants are copied here once.

    Parameters
    ----------
    bsdf : SparseBSDF
        The material, loaded in a scalar variant.
    """

    def __init__(self, bsdf) -> None:
        self.buffers, self.interpolate = bsdf.buffers, bsdf.interpolate
        self._ops, self._shape, self._m, self._zero3 = bsdf._ops, bsdf._shape, bsdf._m, bsdf._zero3
        self._use_cos, self._cos_on, self._scale = bsdf._use_cos, bsdf._cos_on, bsdf._scale
        self._lobe, self._floor = bsdf._lobe, bsdf._floor

    def __call__(self, wi, wo, active):
        """The material's value at (wi, wo): a Color3f."""
        buf = self.buffers
        if buf.pending:
            resolve(buf)
        ops, sh = self._ops, self._shape
        coords = angle_coords(ops, sh, wi, wo)
        if self.interpolate:
            lin = linear_bins(ops, sh, coords)
            w, valid = interp_weight(ops, sh, lin, self._use_cos)
            if not active:
                return self._zero3
            xs = buf.lookup.point_linear(lin)
            w = w * self._scale
            if self._lobe is not None:
                xs = lobe_x(ops, xs, w, lobe_d_at(ops, sh, None, lin, self._lobe[0]),
                            self._lobe)
            return self._m.Color3f(*rho_from_x(ops, xs, valid, w, self._floor))
        bins = nearest_bins(ops, sh, coords)
        if not active:
            return self._zero3
        if buf.decoder == "grouped":  # the rows carry the bins' cos_i cos_o
            x0, x1, x2, c = buf.lookup.point(*bins)
        else:
            (x0, x1, x2), c = buf.lookup.point(*bins), cos_terms(ops, sh, *bins)
        if self._lobe is not None:
            return self._m.Color3f(*point_rho_lobe(ops, sh, (x0, x1, x2), c, self._cos_on,
                                                   self._scale, self._lobe, bins[0],
                                                   self._floor or 0.0))
        return self._m.Color3f(*point_rho_from_cos(x0, x1, x2, c, self._cos_on,
                                                   self._scale))
