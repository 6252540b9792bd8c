"""The sparse model: coding a tabulated BRDF as sparse coefficients over a dictionary
ensemble, and its file.

- ``tensor``: mode products, top-k, HOSVD, Procrustes (the numeric kernels);
  ``pruning``: the pruned projection the encoder and the trainer share.
- ``ensemble``: the :class:`Ensemble` container and the shipped ensembles.
- ``spec``: what an encoding is asked for: the encoder's parameters, their defaults and
  :class:`EncodeSpec`, the request resolved and checked once at each public entry point.
- ``encode``: the encoder's entry point (a count or a byte budget, by default
  ``DEFAULT_N_BYTES``); ``counted``: an encoding at a count and the transform's choice;
  ``projection``: its search (every dictionary's largest coefficients, the selection,
  re-coding); ``fill``: the solver that gives invalid bins free values; ``budget``:
  encoding to a byte budget.
- ``coefficients``: the :class:`SparseBRDF` result; ``fileformat``: the ``.sbrdf`` file.
- ``interpolate``: blending two coded materials.

The functions ``encode`` and ``interpolate`` share their modules' names, so they are not
bound here (``from sparse_brdf.coding import encode`` is the module); the package's top
level has them: ``sparse_brdf.encode``, ``sparse_brdf.interpolate``.
"""

from .budget import encode_to_bytes
from .coefficients import SparseBRDF
from .ensemble import Ensemble, resolve_ensemble
from .fileformat import decode_file, load_sbrdf, save_sbrdf
from .spec import DEFAULT_N_BYTES, DEFAULT_N_COEFFS, ENCODE_OPTIONS, PAPER_OPTIONS, EncodeSpec

__all__ = ["DEFAULT_N_BYTES", "DEFAULT_N_COEFFS", "ENCODE_OPTIONS", "EncodeSpec", "Ensemble",
           "PAPER_OPTIONS", "SparseBRDF", "decode_file", "encode_to_bytes", "load_sbrdf",
           "resolve_ensemble", "save_sbrdf"]
