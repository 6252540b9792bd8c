"""What a renderer reads: the flat buffers of a coded material and their numpy twins.

- ``layouts``: the decoders' buffers (``DECODERS``, ``LAYOUTS``), the importance-sampling
  lobes (``LOBES``) and the plugins' defaults.
- ``lobe``: the glossy sampling lobe fitted at load time.
- ``lookups``: numpy lookups of the uploaded data: the kernels' twins and the scalar
  variants' one-point lookups.
- ``scene``: many materials in one scene: the ensemble's atom rows that every
  strict-decoded material shares, and the choice of decoder per material under a
  scene's memory budget.
"""

from .layouts import DECODERS, LAYOUTS, LOBES, PLUGIN_DEFAULTS

__all__ = ["DECODERS", "LAYOUTS", "LOBES", "PLUGIN_DEFAULTS"]
