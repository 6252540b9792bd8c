"""The pruned projection: a tensor's largest coefficients on the dictionaries that may win.

Shared by the encoder (:func:`~sparse_brdf.coding.projection.project_pruned`: each colour
channel against every dictionary) and the trainer (clustering: each tensor against every
dictionary). Choosing a dictionary means finding the one whose ``n`` largest
coefficients keep the most energy (or reach a relative residual ``max_error`` with the
fewest); the others need not be projected in full (``docs/benchmarks.md``).

How: the coefficients of a dictionary are computed one phi_d slice (mode-3 atom, a row
of U3^T) at a time, the slices along which the tensor has most energy first
(:func:`slice_order`, from one n3 x n3 Gram matrix), in the cumulative rounds
``PRUNE_ROUNDS``. After each round the kept energy after m coefficients of each
dictionary lies between the m largest computed (L) and L plus all the energy not yet
computed; a dictionary whose best case needs more coefficients than another's worst case,
or at equal count keeps less energy, or cannot beat a given ``floor`` on the error, is
dropped (with a margin of ``PRUNE_SLACK`` ||X||^2 against rounding). The survivors are
completed, so their coefficients are exact. How a slice's coefficients are computed is
the caller's (each stores its tensors in its own layout): :meth:`PrunedSearch.run` takes
it as a function.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from .tensor import top_k

#: Cumulative numbers of phi_d slices computed per dictionary in the rounds of a pruned
#: search; after the last round every surviving dictionary is completed.
PRUNE_ROUNDS = (12, 36, 90)
#: Safety margin of the pruning bounds, relative to ||X||^2: far above float32 rounding
#: of the energies (about 1e-6), far below the gaps between dictionaries (about 1e-4).
PRUNE_SLACK = 1e-5

#: A slice kernel: ``chunk(key, lo, hi)`` computes the coefficients of the slices
#: ``order[lo:hi]`` of ``key`` and returns the flat indices and values of the ``n``
#: largest of them and the float64 energy of all of them.
Chunk = Callable[[Hashable, int, int], tuple[np.ndarray, np.ndarray, float]]


def slice_order(gram: np.ndarray, u3: np.ndarray) -> np.ndarray:
    """The phi_d slices of dictionary mode matrix ``u3`` (n3, n3) in order of decreasing
    energy of the tensor along them, from the tensor's mode-3 Gram matrix ``gram``."""
    return np.argsort(-np.einsum("ij,ij->j", gram @ u3, u3), kind="stable")


def search_rounds(n3: int, upto: int | None = None) -> tuple[int, ...]:
    """The cumulative slice counts of each round; ``upto``: one round of that many."""
    if upto:
        return (min(upto, n3),)
    return (*[r for r in PRUNE_ROUNDS if r < n3], n3)


@dataclass
class PrunedSearch:
    """The state of a pruned search over ``keys`` (a (channel, dictionary) pair, or a
    dictionary): ``n`` coefficients wanted per key, ``n3`` slices per tensor, and an
    optional ``max_error`` (relative residual at which fewer coefficients do)."""

    n3: int
    n: int
    max_error: float | None = None
    done: dict = field(default_factory=dict)  # slices computed per key
    energy: dict = field(default_factory=dict)  # their energy (float64)
    #: flat indices and values of the n largest coefficients computed so far
    top: dict = field(default_factory=dict)
    alive: dict = field(default_factory=dict)  # may still win
    slices: int = 0  # slices computed, over all keys

    @classmethod
    def start(cls, keys: Iterable[Hashable], n3: int, n: int,
              max_error: float | None = None) -> PrunedSearch:
        search = cls(n3, n, max_error)
        for key in keys:
            search.done[key], search.energy[key] = 0, 0.0
            search.top[key] = (np.zeros(0, np.int64), np.zeros(0, np.float32))
            search.alive[key] = True
        return search

    def add(self, key: Hashable, hi: int, idx: np.ndarray, val: np.ndarray,
            energy: float) -> None:
        """Merge the coefficients of ``key``'s slices up to ``hi`` (their flat indices,
        values and total energy) into what is known of it."""
        old_idx, old_val = self.top[key]
        idx = np.concatenate([old_idx, idx])
        val = np.concatenate([old_val, val])
        keep = top_k(val * val, self.n)
        self.top[key] = (idx[keep], val[keep])
        self.energy[key] += energy
        self.slices += hi - self.done[key]
        self.done[key] = hi

    def survivors(self) -> list:
        """The keys still alive, in the order they were given."""
        return [k for k, ok in self.alive.items() if ok]

    def prune(self, keys: Sequence[Hashable], norm: float, floor: float = np.inf) -> None:
        """Drop those of ``keys`` (the candidates for one tensor of energy ``norm``) that
        cannot win, or cannot reach an error below ``floor`` (module doc)."""
        ks = [k for k in keys if self.alive[k]]
        if norm <= 0 or not ks or (len(ks) <= 1 and not np.isfinite(floor)):
            return
        n = self.n
        lower = np.empty((len(ks), n))  # L(m): kept energy of the m largest computed
        gap = np.empty(len(ks))  # energy not computed yet
        for r, k in enumerate(ks):
            cum = np.cumsum(self.top[k][1].astype(np.float32) ** 2, dtype=np.float64)
            lower[r, :cum.size] = cum
            lower[r, cum.size:] = cum[-1] if cum.size else 0.0
            gap[r] = 0.0 if self.done[k] == self.n3 else max(norm - self.energy[k], 0.0)
        upper = lower + (gap + PRUNE_SLACK * norm)[:, None]
        if self.max_error is None:
            need_hi = need_lo = np.full(len(ks), n)
        else:
            thr = (1.0 - self.max_error) * norm

            def first(a):
                hit = a >= thr
                return np.where(hit.any(axis=1), hit.argmax(axis=1) + 1, n)

            need_hi, need_lo = first(lower), first(upper)
        n_star = int(need_hi.min())
        best = lower[need_hi == n_star, n_star - 1].max()
        if np.isfinite(floor):  # the kept energy a winner must reach
            best = max(best, norm - floor)
        drop = (need_lo > n_star) | ((need_lo == n_star) & (upper[:, n_star - 1] < best))
        for r, k in enumerate(ks):
            if drop[r]:
                self.alive[k] = False

    def run(self, groups: Sequence[tuple[Sequence[Hashable], float, float]], chunk: Chunk,
            upto: int | None = None,
            mapper: Callable[[Callable, list], Iterator] = map) -> PrunedSearch:
        """Run the rounds: compute every live key's next slices (``chunk``, mapped over
        the keys with ``mapper``), then prune each group ``(keys, norm, floor)`` (the
        candidates of one tensor). ``upto``: stop after that many slices of every key,
        without pruning (the coefficients are then the largest of those slices)."""
        for hi in search_rounds(self.n3, upto):
            tasks = [(k, self.done[k], hi) for k, ok in self.alive.items()
                     if ok and self.done[k] < hi]
            for (k, _, hi_), (idx, val, energy) in zip(
                    tasks, mapper(lambda t: chunk(*t), tasks), strict=True):
                self.add(k, hi_, idx, val, energy)
            if upto:
                break
            for keys, norm, floor in groups:
                self.prune(keys, norm, floor)
            if all(self.done[k] == self.n3 for k in self.survivors()):
                break
        return self
