"""Where BRDFs come from: every loader returns a :class:`sparse_brdf.BRDF` on the grid.

- ``merl``: MERL/DTU ``.binary`` files (read and write).
- ``nbrdf``: Neural-BRDF ``.h5`` networks, tabulated on the grid.
- ``analytic``: Mitsuba 3 BSDFs tabulated through ``mi.BSDF.eval``; ``catalog``: the
  built-in list of them.
- ``fits``: the published ABC and SGD analytic fits of the MERL materials, tabulated.
- ``load``: :func:`load_brdf`, one entry point for all of the above and ``.sbrdf`` files.
- ``cache``: the on-disk cache of tabulations; ``corpora``: named corpora and their
  train/test split; ``dataset``: the training tensors of a list of materials.
"""

__all__ = ["analytic", "cache", "catalog", "corpora", "dataset", "fits", "load", "merl",
           "nbrdf"]
