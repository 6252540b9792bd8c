"""Training a dictionary ensemble on a corpus of materials.

- ``train``: the training algorithm (:func:`train_ensemble`, :func:`train_dictionaries`),
  resumable from checkpoints.
- Private to the trainer: ``_tensor_store`` (the training tensors and their free-bin
  fills), ``_shards`` (the tensors as shards placed where an executor runs them) and
  ``_checkpoint`` (``TrainState``, fingerprints, resuming).
"""

from .train import train_dictionaries, train_ensemble

__all__ = ["train_dictionaries", "train_ensemble"]
