"""The decoder data of one ``sparse_brdf`` material: which decoder it uses, its buffers
as uploaded, and what the scene's memory budget weighs (:mod:`~mitsuba_plugin.budget`).

A :class:`SparseBuffers` is made when the material loads. Given a decoder ("grouped" or
"strict") it builds at once; left to the budget ("auto") it waits in the budget's pool
until the pool is decided (:func:`~mitsuba_plugin.budget.resolve`), then builds. The
grouped decoder's plan (its mode, layout and bytes,
:func:`sparse_brdf.decoders.layouts.grouped_plan`) is made once, when first needed, and
kept: it depends on the support only, which an update of the values keeps.
"""

from __future__ import annotations

import threading

from sparse_brdf.decoders.layouts import (
    channel_terms,
    grouped_channels,
    grouped_layout,
    grouped_plan,
    model_digest,
    strict_channel,
    strict_layout,
    strict_orders,
)
from sparse_brdf.decoders.lookups import GroupedLookup, StrictLookup
from sparse_brdf.decoders.scene import distinct_atoms, material_cost, strict_shared_layout

from .budget import enroll
from .decoders import shared_rows, upload_grouped, upload_strict

# The last grouped build, keyed by its model's support, values, ensemble, layout and
# variant: the several scenes of an image fit (one per view) hold one model whose values
# change together, and each rebuilds its buffers on ``params.update()``; the second and
# later scenes of a step reuse the first one's (read-only) buffers.
LAST_GROUPED: list = [None, None]
_GROUPED_LOCK = threading.Lock()


def _grouped_key(model, ens, layout, ops) -> tuple:
    # ``ops`` itself (one per variant, kept for the process) names the variant: the
    # variant modules all report ``__name__ == "mitsuba"``
    return (model_digest(model), id(ens), layout, ops)


class SparseBuffers:
    """The decoder data of one material (see the module docstring).

    Parameters
    ----------
    ops : object
        The variant's array operations (:mod:`~mitsuba_plugin.kernels`).
    model, ens : SparseBRDF, Ensemble
        The material and its ensemble, checked against each other.
    mix : nested floats or None
        The colour basis's M^T (None: "rgb", no mix).
    layout : str
        The grouped layout asked for: "auto", "union" or "slots".
    budget : int
        The scene's budget of per-material decoder data this material states, in bytes.
    decoder : str
        "grouped" or "strict" (built now), or "auto" (left to the budget).

    Attributes
    ----------
    decoder, layout, channels, memory_bytes, distinct_atoms, packets, grouped_modes,
    shared_bytes
        What the built decoder holds (:class:`~mitsuba_plugin.sparse.SparseBSDF`
        exposes them); ``layout`` is None on the strict decoder.
    pending : bool
        Whether the decoder still waits for its scene's budget.
    """

    #: What a material whose decoder waits for its scene's budget does not hold yet:
    #: reading one through the BSDF decides the pool.
    LAZY = frozenset({"decoder", "channels", "memory_bytes", "distinct_atoms", "packets",
                      "grouped_modes", "shared_bytes"})

    def __init__(self, ops, model, ens, mix, layout: str, budget: int, decoder: str) -> None:
        self._ops, self.model, self.ens, self._mix = ops, model, ens, mix
        self._layout_asked, self.budget = layout, budget
        self.layout = None
        self._plan = None  # the grouped decoder's plan, made once when first needed
        self._ad = None  # the derivative carrier's data, made once when first needed
        self.pending = decoder == "auto"
        if self.pending:  # decided with the scene's other auto materials (budget.py)
            enroll(self)
        else:  # "grouped" or "strict", checked by the plugin
            self.build(decoder)

    def plan(self):
        """The material's :class:`~sparse_brdf.decoders.layouts.GroupedPlan`, made once."""
        if self._plan is None:
            self._plan = grouped_plan(self.model, self.ens)
        return self._plan

    def cost(self):
        """The :class:`~sparse_brdf.decoders.scene.MaterialCost` the budget weighs."""
        return material_cost(self.model, self.ens, self.plan())

    def build(self, decoder: str, model=None) -> None:
        """Build the buffers of ``decoder`` ("grouped" or "strict"), of ``model`` if given
        (the same support, new values). The material stops pending only once they are
        built: the scalar variants render on many threads, and one that saw it no longer
        pending would read a lookup not yet made."""
        if model is not None:
            self.model = model
        self.decoder = decoder
        self.shared_bytes = 0
        if decoder == "grouped":
            self._build_grouped()
        else:
            self._build_strict()
        self.pending = False

    def _build_grouped(self) -> None:
        model, ens, ops, layout = self.model, self.ens, self._ops, self._layout_asked
        key = _grouped_key(model, ens, layout, ops)
        with _GROUPED_LOCK:
            if LAST_GROUPED[0] == key:
                chans, lay, grouped, _ = LAST_GROUPED[1]
            else:
                plan = self.plan()
                chans = grouped_channels(model, ens, plan.mode)
                lay = grouped_layout(chans, model.shape,
                                     plan.kind if layout in ("auto", None) else layout)
                grouped = upload_grouped(ops, lay, chans[0])
                LAST_GROUPED[:] = [key, (chans, lay, grouped, ens)]  # kept: its id stays unique
        self.channels = chans
        self.layout = lay.kind
        self.grouped = grouped
        self.memory_bytes = ops.nbytes(grouped.tables) + ops.nbytes(grouped.values)
        self.distinct_atoms = tuple(c.k for c in chans)
        self.packets = lay.packets
        self.grouped_modes = tuple(c.mode_g + 1 for c in chans)
        if not ops.jit:  # the scalar variants' lookup reads the same table buffer
            self.lookup = GroupedLookup(lay, chans[0], self._mix, grouped.tables)

    def _build_strict(self) -> None:
        model, ens, ops = self.model, self.ens, self._ops
        self.distinct_atoms = distinct_atoms(model, ens)
        if not ops.jit:  # numpy lookups of the material's own atom rows
            chans = [strict_channel(*channel_terms(model, ens, c)) for c in range(3)]
            self.channels = chans
            self.strict = upload_strict(ops, strict_layout(chans))
            self.memory_bytes = sum(ops.nbytes(b) for b in (
                self.strict.values, self.strict.packed, self.strict.rows))
            self.lookup = StrictLookup(chans, self._mix)
            return
        # the atom rows are the ensemble's, uploaded once for every material
        shared, rows = shared_rows(ops, ens)
        self.channels = None
        self.strict = upload_strict(ops, strict_shared_layout(model, ens, shared), rows)
        self.memory_bytes = sum(ops.nbytes(b) for b in (self.strict.values,
                                                         self.strict.packed))
        self.shared_bytes = shared.nbytes

    def carrier(self):
        """The derivative carrier's data, built once (it depends on the support only):
        the strict decoder's atom rows and packed indices, and per channel the file's term
        index of each of its terms (:func:`sparse_brdf.decoders.layouts.strict_orders`)."""
        if self._ad is None:
            chans = [strict_channel(*channel_terms(self.model, self.ens, c))
                     for c in range(3)]
            orders = [self._ops.uints(o if o.size else [0])
                      for o in strict_orders(self.model, self.ens)]
            self._ad = (upload_strict(self._ops, strict_layout(chans)), orders)
        return self._ad
