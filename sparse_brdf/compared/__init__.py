"""The models the bench compares, the paper's sparse model among them.

- ``protocol``: what a compared model follows (:class:`ComparedModel`,
  :class:`CompressedBRDF`); ``compact``: the built-in models' interface (``fit(brdfs)``
  learns, ``compress(brdf)`` gives a ``Compact``).
- ``sparse_model``: the paper's model; ``baselines``: naive, CPD, Tucker, PCA,
  tabulated; ``neural``: Neural-BRDF (the trainer and its model).
- ``specs``: the bench's model-spec grammar; ``_outside``: models from outside the
  package (``module:Class`` specs).
"""

from .compact import BRDFModel, Compact
from .neural import NeuralFit, train_nbrdf
from .protocol import ComparedModel, CompressedBRDF
from .specs import make_model, parse_spec

__all__ = ["BRDFModel", "Compact", "ComparedModel", "CompressedBRDF", "NeuralFit",
           "make_model", "parse_spec", "train_nbrdf"]
