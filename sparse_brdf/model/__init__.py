"""The sparse model and its baselines.

- ``tensor``: projections on a dictionary and reconstruction (the numeric kernels).
- ``ensemble``: the :class:`Ensemble` container and the shipped default; ``train``: the
  trainer that learns one.
- ``encode``: projection, sparsification and model selection; ``sparse``: the
  :class:`SparseBRDF` result; ``sbrdf``: its file format and :func:`decode_file`.
- ``interpolate``: blending two coded materials; ``layouts``: the flat buffers a renderer
  reads, with numpy reference decoders.
- The models compared in the bench: ``compact`` (the interface: ``fit(brdfs)`` learns,
  ``compress(brdf)`` gives a ``Compact``), ``sparse_model`` (the paper's model),
  ``baselines`` (the others) and ``specs`` (the grammar of their bench specs).
"""
