"""An outside model for ``sparse-brdf bench``: the measured table, quantised.

Every valid bin keeps ln(1 + rho) per channel as a ``bits``-bit integer, on a per-channel
scale from 0 to the channel's largest value, so a material costs ``bits / 8`` bytes per
valid bin and channel plus three float32 scales. It shows what a model must offer the
bench (docs/bench-guide.md): a ``name``, ``learns``, ``fit(brdfs)`` and
``compress(brdf)`` returning an object with ``nbytes`` and ``reconstruct()``. Nothing of
the package is imported: the bench hands it a BRDF (``values``, ``valid``) and reads
plain numpy arrays back.

    sparse-brdf bench ci --model examples.quantised_table:QuantisedLogTable:bits=6 \\
        --model naive --model tabulated
"""

from __future__ import annotations

import numpy as np


class QuantisedLogTable:
    """The table with ln(1 + rho) quantised to ``bits`` bits (1 to 16) per channel."""

    learns = False  # nothing is learnt from training materials: fit() does nothing

    def __init__(self, bits: int = 8):
        if isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 16:
            raise ValueError(f"bits must be an integer from 1 to 16, got {bits!r}")
        self.bits = bits
        self.name = f"quantised-{bits}bit"  # the label in the bench's tables

    def fit(self, brdfs):
        return self

    def compress(self, brdf) -> QuantisedMaterial:
        return QuantisedMaterial(brdf.values, brdf.valid, self.bits)


class QuantisedMaterial:
    """One material: integer codes of the valid bins and a scale per channel."""

    def __init__(self, values: np.ndarray, valid: np.ndarray, bits: int):
        logs = np.log1p(np.maximum(values[valid], 0.0).astype(np.float64))  # (N, 3)
        top = logs.max(axis=0) if len(logs) else np.zeros(3)
        self.scale = np.where(top > 0, top / (2**bits - 1), 1.0).astype(np.float32)
        self.codes = np.rint(logs / self.scale).astype(np.uint16)
        self.valid = valid
        # what a file of this model would hold: the packed codes and the scales
        self.nbytes = int(np.ceil(self.codes.size * bits / 8)) + self.scale.nbytes

    def reconstruct(self) -> np.ndarray:
        """The decoded table, linear RGB, shape (n1, n2, n3, 3)."""
        out = np.zeros((*self.valid.shape, 3), np.float32)
        out[self.valid] = np.expm1(self.codes * self.scale.astype(np.float64))
        return out
