"""The ``tabulated_brdf`` BSDF: a measured BRDF's whole table, looked up by bin (the
reference the other BSDFs are compared with). Registered for a variant by
:func:`~mitsuba_plugin.registration.register`.
"""

from __future__ import annotations

from sparse_brdf.decoders.layouts import LOBES, PLUGIN_DEFAULTS
from sparse_brdf.decoders.lobe import table_profile

from .glossy import GlossyBSDF
from .kernels import Shape, angle_coords, linear_bins, nearest_bins
from .loading import REQUIRED, bool_prop, choice_prop, load_table, read_props, resolve_file


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
        p = read_props(props, self.plugin, {"filename": REQUIRED,
                                             "sampling": PLUGIN_DEFAULTS["sampling"],
                                             "interpolate": False, "ensemble": None})
        self.sampling = choice_prop(p["sampling"], LOBES, self.plugin, "sampling")
        self.interpolate = bool_prop(p["interpolate"], self.plugin, "interpolate")
        self.filename = resolve_file(str(p["filename"]))
        brdf = load_table(self.filename, p["ensemble"], self.plugin)
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
