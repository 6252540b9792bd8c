"""The ``sparse_library`` BSDF: many sparse materials served by one BSDF, each shape
picking its material by a shape attribute (``sbrdf_index``), by the pair decoder
(:func:`~mitsuba_plugin.decoders.pair_x`; data from
:mod:`sparse_brdf.decoders.library`).

Mitsuba traces every BSDF instance of a scene on every render; a library is one
instance, however many materials it holds, so a scene of a thousand materials traces
one BSDF. Registered for a variant by :func:`~mitsuba_plugin.registration.register`;
``sparse-brdf render`` and :func:`sparse_brdf.evaluation.render.render_scene` write a
scene's many ``sparse_brdf`` materials as one library (docs/rendering.md).
"""

from __future__ import annotations

import drjit as dr

from sparse_brdf.decoders.layouts import LOBES, PACKET, PLUGIN_DEFAULTS, grouped_plan
from sparse_brdf.decoders.library import (
    HEADER_F,
    HEADER_U,
    PairLookup,
    grouped_blocks,
    pair_buffers,
    pair_counts,
    pair_header,
)
from sparse_brdf.decoders.lobe import fit_lobe, sparse_profile
from sparse_brdf.decoders.scene import MEMORY_BUDGET_MIB, MaterialCost, plan_decoders
from sparse_brdf.errors import PluginError

from .decoders import grouped_x, lane_grouped, pair_x, shared_rows, upload_pairs
from .glossy import GlossyBSDF
from .kernels import (
    angle_coords,
    bin_weight,
    cos_terms,
    interp_weight,
    linear_bins,
    lobe_d_at,
    lobe_x,
    nearest_bins,
    point_rho_from_cos,
    point_rho_lobe,
    rho_from_x,
    shared_shape,
)
from .loading import (
    REQUIRED,
    bool_prop,
    choice_prop,
    load_models,
    read_props,
    resolve_file,
    split_names,
)

#: The shape attribute that names a shape's material in its library (a ``uniform``
#: texture holding the material's index, 0 for the first file).
ATTRIBUTE = "sbrdf_index"


def _read_props(props, plugin: str) -> dict:
    p = read_props(props, plugin, {
        "filenames": REQUIRED, "ensemble": None, "sampling": PLUGIN_DEFAULTS["sampling"],
        "interpolate": False, "attribute": ATTRIBUTE, "memory_budget": None})
    if p["memory_budget"] is not None and p["memory_budget"] not in MEMORY_BUDGET_MIB:
        raise PluginError(f"{plugin}: memory_budget={p['memory_budget']!r}: "
                          f"expected MiB, {MEMORY_BUDGET_MIB.describe()}")
    p["sampling"] = choice_prop(p["sampling"], LOBES, plugin, "sampling")
    p["interpolate"] = bool_prop(p["interpolate"], plugin, "interpolate")
    if not str(p["attribute"]).strip():
        raise PluginError(f"{plugin}: attribute={p['attribute']!r} is empty")
    return p


class SparseLibrary(GlossyBSDF):
    """A library of sparse materials (``sparse_library``): the model of ``sparse_brdf``
    for each of its files, the file picked per shape.

    A shape that uses the library holds a ``uniform`` texture ``sbrdf_index`` (or the
    name ``attribute`` gives): the index of its material in ``filenames`` (0, 1, ...).
    Every material's data lives in buffers of the library: per (b, c) pair of atoms of
    each channel, the mode-1 contraction of its terms (n1 floats, about 45 kB a
    material), with U2 and U3 read from the ensemble's rows that strict-decoded
    ``sparse_brdf`` materials also share. A shape without the attribute gets material
    0; an index outside the list renders black (``render_scene`` checks the indices:
    :func:`check_scene`). Mitsuba merges the meshes that share a BSDF when a scene loads
    with ``optimize=True`` (the default), dropping their attributes: load a scene whose
    meshes share a library with ``optimize=False`` (``render_scene`` does).

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - filenames
         - string
         - The ``.sbrdf`` files, separated by commas: material 0, 1, ... All of one
           ensemble and one grid.
       * - ensemble
         - string
         - Optional ensemble ``.npz`` the files were encoded with (default: the shipped
           one the first file names).
       * - sampling
         - string
         - ``lobe`` (default: each material's own lobe) or ``cosine``, as for
           ``sparse_brdf``.
       * - interpolate
         - boolean
         - Trilinear interpolation, as for ``sparse_brdf`` (default: false).
       * - attribute
         - string
         - The shape attribute holding the index (default: ``sbrdf_index``).
       * - memory_budget
         - float
         - MiB of decoder data the library may hold: within it, the grouped decoder's
           tables (faster per lookup, 1.0-1.6 MB a material) go to the materials with the
           largest speed gain per byte first, the others keep their pairs (default:
           none, pairs for all; ``n_grouped`` says how many).

    Example::

        <bsdf type="sparse_library" id="lib">
            <string name="filenames" value="gold.sbrdf,blue-acrylic.sbrdf"/>
        </bsdf>
        <shape type="sphere">
            <ref id="lib"/>
            <texture name="sbrdf_index" type="uniform"><float name="value" value="1"/>
            </texture>
        </shape>
    """

    plugin = "sparse_library"
    per_lane = True

    def __init__(self, props) -> None:
        GlossyBSDF.__init__(self, props)
        ops = self._ops
        p = _read_props(props, self.plugin)
        self.interpolate, self.attribute = p["interpolate"], str(p["attribute"]).strip()
        self.filenames = [resolve_file(f) for f in split_names(p["filenames"])]
        ens_path = None if p["ensemble"] is None else resolve_file(str(p["ensemble"]))
        models, ens = load_models(self.filenames, ens_path, self.plugin)
        self.n_materials = len(models)
        self._shape = shared_shape(ops, models[0].shape)
        shared, rows = shared_rows(ops, ens)
        budget = p["memory_budget"]
        self._build(models, ens, shared, rows, p["sampling"] == "lobe",
                    None if budget is None else int(float(budget) * 2**20))
        # each material's lobe is in the header (_lobe); none of the library's own
        self._setup_sampling("cosine", None, models[0].shape)
        self.sampling = p["sampling"]
        # Python branches at trace time: a library of "rgb" materials traces no mix, one
        # of the paper's transforms (scale 1) no multiply
        self._mixed = any(m.basis != "rgb" for m in models)
        self._n_f = ops.f(float(self.n_materials))
        # JIT variants: each shape's index by its registry id, once check_scene has read
        # them (no virtual call over the scene's shapes per lookup); until then the
        # attribute itself
        self._ids, self._known = None, {}
        self.shared_bytes = shared.nbytes

    def _build(self, models, ens, shared, rows, lobe: bool, budget: int | None) -> None:
        """The library's buffers: each material's pairs, or its grouped tables where
        ``budget`` (bytes of the library's decoder data; None: pairs for all) gives them
        (:func:`_grouped_choice`), and the headers."""
        ops, n1 = self._ops, models[0].shape[0]
        lobes = [fit_lobe(sparse_profile(m, ens), m.shape) for m in models] if lobe else None
        chosen, plans = _grouped_choice(models, ens, budget)
        blocks, self._grouped = None, None
        if any(chosen):
            g_tables, g_values, blocks = grouped_blocks(models, ens, plans, chosen)
            self._grouped = (ops.floats(g_tables), ops.floats(g_values))
        header = pair_header(models, shared, lobes, blocks)
        try:
            tables, packed = pair_buffers(models, ens, shared, header.n_pairs, blocks)
        except ValueError as exc:
            raise PluginError(f"{self.plugin}: {exc}") from None
        self._buf = upload_pairs(ops, tables, packed, header, rows, n1)
        del tables, packed  # (the scalar variants keep them as their buffers)
        self._scaled = bool((header.f[:, 1] != 1.0).any())
        self._lobed = bool((header.f[:, 13] > 0.5).any())  # a lobe transform's material
        self._floored = bool((header.f[:, 21] > 0.0).any())  # a floor transform's material
        self.n_grouped = sum(chosen)
        self.memory_bytes = (header.n_pairs * (4 * n1 + 4) + header.nbytes + (
            0 if blocks is None else sum(ops.nbytes(b) for b in self._grouped)))
        if not ops.jit:  # scalar variants: one numpy lookup per call
            self._header = header
            self._lookup = PairLookup(self._buf.tables, self._buf.packed, header,
                                      shared.rows, models[0].shape, blocks)

    # per-lane materials (GlossyBSDF.per_lane) ----------------------------------------
    def _material(self, si, active):
        """(index, in range) of each lane's material: its shape's attribute, read from
        the table of shape ids once :func:`check_scene` has made it (-1, out of range,
        for a shape it did not see)."""
        if self._ids is not None:
            ids, n_ids = self._ids
            sid = dr.reinterpret_array(self._m.UInt32, si.shape)
            seen = active & (sid < n_ids)
            x = dr.select(seen, self._ops.gather(ids, sid, seen), -1.0)
        else:
            x = si.shape.eval_attribute_1(self.attribute, si, active)
        if not self._ops.jit:
            idx = int(x + 0.5) if x > -0.5 else -1
            return idx, 0 <= idx < self.n_materials
        ok = (x > -0.5) & (x < self._n_f - 0.5)
        return self._ops.to_u(dr.maximum(x + 0.5, 0.0)), ok

    def _lobe(self, mat):
        idx, ok = mat
        if not self._ops.jit:
            return tuple(float(v) for v in self._header.f[idx if ok else 0, 11:13])
        hf = self._buf.header_f
        return (dr.select(ok, self._ops.gather(hf, idx * HEADER_F + 11, ok), 1.0),
                self._ops.gather(hf, idx * HEADER_F + 12, ok))

    def _rho_at(self, mat, wi, wo, active):
        idx, ok = mat
        if not self._ops.jit:
            return _point_rho(self, idx, wi, wo, active and ok)
        ops, sh, hf = self._ops, self._shape, self._buf.header_f
        active = active & ok
        coords = angle_coords(ops, sh, wi, wo)
        use_cos = ops.gather(hf, idx * HEADER_F, active)
        if self.interpolate:
            lin, bins = linear_bins(ops, sh, coords), None
            w, valid = interp_weight(ops, sh, lin, use_cos)
        else:
            lin, bins = None, nearest_bins(ops, sh, coords)
            w, in_bin = bin_weight(ops, sh, *bins, use_cos)
            active = active & in_bin  # invalid bins hold no measurement: 0
            valid = dr.select(in_bin, 1.0, 0.0)
        xs = pair_x(ops, self._buf, sh, idx, bins, lin, active)
        if self._grouped is not None:  # the materials on the grouped decoder (0 elsewhere)
            gbuf = lane_grouped(ops, *self._grouped, self._buf.header_u, idx, active)
            xs = [a + b for a, b in zip(xs, grouped_x(ops, gbuf, bins, lin, active)[0],
                                        strict=True)]
        if self._mixed:  # the lane's material's M^T (the identity for "rgb")
            mt = [ops.gather(hf, idx * HEADER_F + 2 + r, active) for r in range(9)]
            xs = [dr.fma(mt[3 * r], xs[0], dr.fma(mt[3 * r + 1], xs[1], mt[3 * r + 2] * xs[2]))
                  for r in range(3)]
        if self._scaled:  # (1 where inactive: valid / w stays finite)
            w = w * dr.select(active, ops.gather(hf, idx * HEADER_F + 1, active), 1.0)
        if self._lobed:  # the lane's material's base lobe, where it has one
            lobe = [ops.gather(hf, idx * HEADER_F + 14 + r, active) for r in range(7)]
            lx = lobe_x(ops, xs, w, lobe_d_at(ops, sh, bins, lin, lobe[0]), lobe)
            on = ops.gather(hf, idx * HEADER_F + 13, active) > 0.5
            xs = [dr.select(on, a, b) for a, b in zip(lx, xs, strict=True)]
        floor = ops.gather(hf, idx * HEADER_F + 21, active) if self._floored else None
        return self._m.Color3f(*rho_from_x(ops, xs, valid, w, floor))

    def bind(self, indices: dict) -> None:
        """Read the materials of the shapes ``indices`` ({shape registry id: index},
        checked) from a table instead of their attribute (JIT variants; each call adds
        to the shapes known)."""
        if not self._ops.jit or not indices:
            return
        self._known.update(indices)
        table = [-1.0] * (max(self._known) + 1)
        for sid, x in self._known.items():
            table[sid] = x
        self._ids = (self._ops.floats(table), self._ops.u(len(table)))

    def to_string(self):
        return (f"{type(self).__name__}[materials={self.n_materials}, "
                f"first={self.filenames[0]!r}, sampling={self.sampling}, "
                f"interpolate={self.interpolate}, attribute={self.attribute!r}, "
                f"memory_bytes={self.memory_bytes}]")


def _point_rho(lib, idx: int, wi, wo, active: bool):
    """:meth:`SparseLibrary._rho_at` in a scalar variant: one direction pair, numpy
    lookups (:class:`~sparse_brdf.decoders.library.PairLookup`) of ``lib``'s material
    ``idx``."""
    if not active:
        return lib._zero3
    ops, sh = lib._ops, lib._shape
    use_cos, scale, floor = (float(v) for v in lib._header.f[idx, (0, 1, 21)])
    lobe = ([float(v) for v in lib._header.f[idx, 14:21]]
            if lib._header.f[idx, 13] > 0.5 else None)
    coords = angle_coords(ops, sh, wi, wo)
    if lib.interpolate:
        lin = linear_bins(ops, sh, coords)
        w, valid = interp_weight(ops, sh, lin, use_cos)
        xs, w = lib._lookup.point_linear(idx, lin), w * scale
        if lobe is not None:
            xs = lobe_x(ops, xs, w, lobe_d_at(ops, sh, None, lin, lobe[0]), lobe)
        return lib._m.Color3f(*rho_from_x(ops, xs, valid, w, floor))
    bins = nearest_bins(ops, sh, coords)
    xs = lib._lookup.point(idx, *bins)
    c = cos_terms(ops, sh, *bins)
    if lobe is not None:
        return lib._m.Color3f(*point_rho_lobe(ops, sh, xs, c, use_cos > 0.5, scale, lobe,
                                              bins[0], floor))
    return lib._m.Color3f(*point_rho_from_cos(*xs, c, use_cos > 0.5, scale))


def _grouped_choice(models, ens, budget: int | None):
    """(per material, whether it gets the grouped decoder; their grouped plans): within
    ``budget`` bytes of the library's decoder data, the largest speed gain per byte first
    (:func:`~sparse_brdf.decoders.scene.plan_decoders`, a material's pairs its compact
    data); None: every material on pairs (no plan made)."""
    if budget is None:
        return [False] * len(models), None
    plans = [grouped_plan(m, ens) for m in models]
    n1 = models[0].shape[0]
    costs = []
    for model, plan in zip(models, plans, strict=True):
        pairs = sum(pair_counts(model))
        costs.append(MaterialCost(plan.nbytes, 4 * (n1 + 1) * pairs, 4.0 * pairs - plan.packets))
    # the headers, and each grouped block's padding to whole packets, count too
    room = budget - len(models) * (4 * (HEADER_U + HEADER_F) + 2 * 4 * PACKET)
    return [d == "grouped" for d in plan_decoders(costs, max(room, 0))], plans


def check_scene(scene) -> int:
    """Check that every shape of ``scene`` that uses a ``sparse_library`` names one of
    its materials: its attribute holds an integer in range; then each library reads its
    shapes' materials by their ids (:meth:`SparseLibrary.bind`). Returns the number of
    such shapes; a :class:`PluginError` naming the first shape that does not. (A scene
    with instances keeps reading the attribute: their shapes are not listed.)"""
    count, bound = 0, {}
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if not getattr(bsdf, "per_lane", False):
            continue
        count += 1
        if not shape.has_attribute(bsdf.attribute):
            raise PluginError(f"{bsdf.plugin}: shape {shape.id()!r} uses the library but "
                              f"has no attribute {bsdf.attribute!r} (meshes that share a "
                              f"BSDF are merged, attributes dropped, unless the scene "
                              f"loads with optimize=False)")
        x = _attribute_value(shape, bsdf.attribute)
        if x != round(x) or not 0 <= x < bsdf.n_materials:
            raise PluginError(f"{bsdf.plugin}: shape {shape.id()!r}: {bsdf.attribute}={x:g}"
                              f" is not a material of the library (0 to "
                              f"{bsdf.n_materials - 1})")
        if bsdf._ops.jit:
            sid = dr.reinterpret_array(bsdf._m.UInt32, bsdf._m.ShapePtr(shape))
            bound.setdefault(id(bsdf), (bsdf, {}))[1][int(sid[0])] = x
    # a shape inside an instance is not among the scene's shapes: with instances the
    # libraries keep reading the attribute itself
    if not any(shape.class_name() == "Instance" for shape in scene.shapes()):
        for bsdf, indices in bound.values():
            bsdf.bind(indices)
    return count


def _attribute_value(shape, name: str) -> float:
    """The value of a shape's uniform attribute (read at one point)."""
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    v = shape.eval_attribute_1(name, dr.zeros(mi.SurfaceInteraction3f))
    return float(v if isinstance(v, float) else v[0])
