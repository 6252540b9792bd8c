"""The ``neural_brdf`` BSDF: a Neural-BRDF network evaluated at the direction pair itself.
Registered for a variant by :func:`~mitsuba_plugin.registration.register`.
"""

from __future__ import annotations

from pathlib import Path

from sparse_brdf.coords import MERL_SHAPE
from sparse_brdf.decoders.layouts import LOBES, PLUGIN_DEFAULTS
from sparse_brdf.decoders.lobe import table_profile
from sparse_brdf.errors import PluginError
from sparse_brdf.mlp import tabulate
from sparse_brdf.sources.nbrdf import read_nbrdf_weights

from .glossy import GlossyBSDF
from .kernels import mlp_weights, nbrdf_rho
from .loading import REQUIRED, choice_prop, read_props, resolve_file


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
        p = read_props(props, self.plugin, {"filename": REQUIRED,
                                             "sampling": PLUGIN_DEFAULTS["sampling"]})
        self.sampling = choice_prop(p["sampling"], LOBES, self.plugin, "sampling")
        self.filename = resolve_file(str(p["filename"]))
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
