"""The training tensors as the trainer sees them: a store of tensors whose free bins hold
values of the model (``docs/method.md``, "Training")."""

from __future__ import annotations

import numpy as np

from ..coding.tensor import reconstruct_sparse
from ..coords import geometric_valid
from ..parallel import parallel_map


def sq_norms(x: np.ndarray) -> np.ndarray:
    """||X_i||^2 of each tensor (float32 dot products, as the checkpoint fingerprint)."""
    return np.array([float(np.dot(t.ravel(), t.ravel())) for t in x])


def sq64(v: np.ndarray) -> float:
    """Squared norm accumulated in float64."""
    return float(np.sum(np.square(v, dtype=np.float64)))


class TensorStore:
    """The training tensors as the trainer sees them (``docs/method.md``, Training).

    Unmasked: the tensors as given. Masked: each tensor's free bins -- below the horizon
    (one index set shared by every tensor) plus, rarely, its material's unmeasured bins --
    hold the reconstruction from the tensor's latest code (zero before the first).
    Only those values are stored (N x 24 % of the grid, float32); ``x`` is never
    written, so the caller's array is unchanged and a read-only memory map works.
    ``norms[i]`` is ||X~_i||^2 of the filled tensor, ``energy[i]`` its valid part.
    """

    def __init__(self, x: np.ndarray, masked: bool, missing: dict | None = None):
        self.x, self.masked = x, masked
        self.shape = tuple(int(n) for n in x.shape[1:])
        self.grams: list | None = None  # mode Gram matrices, during the initialisation
        self.raw_norms = sq_norms(x)  # of x as given (the checkpoint fingerprint)
        self.extra: dict[int, np.ndarray] = {}
        if not masked:
            self.free = np.zeros(0, np.int64)
            self.energy = self.raw_norms
            self.norms = self.raw_norms
            return
        geo = geometric_valid(self.shape).reshape(-1)
        self.free = np.flatnonzero(~geo)
        by_mask: dict[int, np.ndarray] = {}  # a material's channels share one mask object
        for i, m in (missing or {}).items():
            if id(m) not in by_mask:
                mask = np.asarray(m, bool)
                if mask.shape != self.shape:
                    raise ValueError(f"missing-bin mask of tensor {i} has shape {mask.shape}, "
                                     f"expected {self.shape}")
                by_mask[id(m)] = np.flatnonzero(mask.reshape(-1) & geo)
            if by_mask[id(m)].size:
                self.extra[int(i)] = by_mask[id(m)]
        self.fill = np.zeros((len(x), self.free.size), np.float32)
        self.fill_extra = {i: np.zeros(e.size, np.float32) for i, e in self.extra.items()}

        def valid_energy(i):  # independent of what x holds in free bins
            flat = np.asarray(x[i], np.float32).reshape(-1)
            if i not in self.extra:
                return sq64(flat[geo])
            keep = geo.copy()
            keep[self.extra[i]] = False
            return sq64(flat[keep])

        self.energy = np.array(list(parallel_map(valid_energy, range(len(x)))))
        self.norms = self.energy.copy()

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> np.ndarray:
        """X~_i: tensor i with its free bins filled (a copy when masked)."""
        if not self.masked:
            return self.x[i]
        y = np.array(self.x[i], np.float32)
        flat = y.reshape(-1)
        flat[self.free] = self.fill[i]
        if i in self.extra:
            flat[self.extra[i]] = self.fill_extra[i]
        return y

    def reconstruct_free(self, i, idx, val, u) -> tuple[tuple, float]:
        """The free-bin values of the reconstruction of tensor i from the code (idx, val)
        in dictionary u, and their squared distance to the values held now."""
        rec = reconstruct_sparse(idx, val, self.shape, *u).reshape(-1)
        new = rec[self.free]
        change = sq64(new - self.fill[i])
        new_extra = None
        if i in self.extra:
            new_extra = rec[self.extra[i]]
            change += sq64(new_extra - self.fill_extra[i])
        return (new, new_extra), change

    def set_fill(self, i: int, fill: tuple) -> None:
        new, new_extra = fill
        self.fill[i] = new
        self.norms[i] = self.energy[i] + sq64(new)
        if new_extra is not None:
            self.fill_extra[i] = new_extra
            self.norms[i] += sq64(new_extra)
