"""The training tensors as shards, kept where an executor runs them (``docs/scale-out.md``).

:class:`Shards` splits the tensors into shards of ``SHARD_TENSORS`` consecutive tensors,
each a :class:`~sparse_brdf.training._tensor_store.TensorStore` placed once where the executor
runs it (``parallel.py``: here, or on one Dask worker for the whole run). The trainer runs
each step of an iteration as a function of a shard; the functions here are the steps
that only read and write the store (its fills, Gram matrices and the dictionary update's
partial sums); the coding steps are the trainer's (``train.py``).
"""

from __future__ import annotations

import numpy as np

from ..coding.tensor import mode_grams
from ..parallel import parallel_map
from ._tensor_store import TensorStore

#: Tensors per shard (:class:`Shards`). Fixed, not derived from the number of workers,
#: so that every sum over tensors is summed per shard and then over the shards in the
#: same order wherever the shards run: results are the same bit for bit in-process and
#: on any cluster.
SHARD_TENSORS = 32


def shard_info(sh: TensorStore) -> tuple:
    """The shard's norms as given, valid energies and unmeasured bins (once, at the start)."""
    return sh.raw_norms, sh.energy, sh.extra


def shard_refill(sh: TensorStore, labels, idx, val, u1, u2, u3) -> None:
    """Masked: set every tensor's free bins from its code (on resuming, to restore the
    filled tensors the checkpointed iteration ended with)."""
    if not sh.masked:
        return

    def one(i):
        j = labels[i]
        return sh.reconstruct_free(i, idx[i], val[i], (u1[j], u2[j], u3[j]))[0]

    for i, fill in enumerate(parallel_map(one, range(len(sh)))):
        sh.set_fill(i, fill)


def _code_atoms(idx: np.ndarray, shape) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per mode, the distinct atoms a code uses and each coefficient's place among them:
    [(atoms, inverse)] for modes 1, 2, 3 of the flat indices ``idx`` into ``shape``."""
    return [np.unique(m, return_inverse=True) for m in np.unravel_index(idx, shape)]


def shard_partials(sh: TensorStore, labels, codes_idx, codes_val, mode, n_dicts,
                   u1, u2, u3) -> list:
    """The shard's part of each cluster's Procrustes product Z for ``mode`` (0, 1, 2):
    a float64 (n, n) sum over the cluster's tensors in the shard, None for none.

    Z for mode 1 is sum_t s_t W1[:, b_t, c_t] e_(a_t)^T, W1 = X x2 U2^T x3 U3^T, over the
    code's coefficients s_t at (a_t, b_t, c_t) (likewise for modes 2 and 3): only the
    columns of W at the code's own atoms are needed. So each tensor is contracted with
    the mode matrices' columns of the distinct atoms its code uses in the other modes
    (K_a x K_b x K_c, e.g. 20 x 15 x 8 of 90 x 90 x 180 at tau 256), not with the whole
    matrices: about n1 n2 n3 (K_c + K_a) multiply-adds per tensor over the three modes
    instead of 3.5 n1 n2 n3 (n1 + n2 + n3) / 3 (16 times fewer at tau 256).
    """
    n1, n2, n3 = shape = sh.shape

    def onehot(pos, val, n):
        m = np.zeros((len(pos), n), np.float32)
        np.add.at(m, (np.arange(len(pos)), pos), val)
        return m

    def contrib(i):
        j = labels[i]
        s = codes_val[i]
        a, b, c = np.unravel_index(codes_idx[i], shape)
        (ka, ia), (kb, ib), (kc, ic) = _code_atoms(codes_idx[i], shape)
        x = sh[i]
        if mode < 2:  # X x3 U3[:, K_c]^T: (n1, n2, K_c)
            am = (x.reshape(n1 * n2, n3) @ u3[j][:, kc]).reshape(n1, n2, kc.size)
        if mode == 0:  # W1[:, K_b, K_c]; Z1[:, a_t] += s_t W1[:, b_t, c_t]
            w = np.matmul(am.transpose(0, 2, 1), u2[j][:, kb])  # (n1, K_c, K_b)
            return w[:, ic, ib] @ onehot(a, s, n1)
        if mode == 1:  # W2[K_a, :, K_c]; Z2[:, b_t] += s_t W2[a_t, :, c_t]
            w = (u1[j][:, ka].T @ am.reshape(n1, n2 * kc.size)).reshape(ka.size, n2, kc.size)
            return w[ia, :, ic].T @ onehot(b, s, n2)
        # W3[K_a, K_b, :]; Z3[:, c_t] += s_t W3[a_t, b_t, :]
        t = (u1[j][:, ka].T @ x.reshape(n1, n2 * n3)).reshape(ka.size, n2, n3)
        w = np.matmul(u2[j][:, kb].T, t)  # (K_a, K_b, n3)
        return w[ia, ib, :].T @ onehot(c, s, n3)

    z: list = [None] * n_dicts
    order = np.argsort(labels, kind="stable")  # by cluster, then by tensor
    for i, part in zip(order, parallel_map(contrib, order), strict=True):
        j = labels[i]  # each cluster's sum in the order of its members, wherever it runs
        z[j] = part.astype(np.float64) if z[j] is None else z[j] + part
    return z


def shard_grams(sh: TensorStore) -> None:
    """Keep the mode Gram matrices of the shard's tensors (for the initialisation)."""
    sh.grams = list(parallel_map(lambda i: mode_grams(sh[i]), range(len(sh))))


def shard_gram(sh: TensorStore, i: int) -> tuple:
    return sh.grams[i]


def shard_gram_sums(sh: TensorStore, labels, n_dicts) -> list:
    """Per cluster, the sums of the Gram matrices of its tensors in the shard (float64);
    then forget the Gram matrices."""
    n1, n2, n3 = sh.shape
    sums = [[np.zeros((m, m)) for m in (n1, n2, n3)] for _ in range(n_dicts)]
    for i, g in enumerate(sh.grams):
        for m in range(3):
            sums[labels[i]][m] += g[m]
    sh.grams = None
    return sums


def shard_set_fill(sh: TensorStore, i: int, fill) -> None:
    sh.set_fill(i, fill)


class Shards:
    """The training tensors as shards of ``shard_tensors`` (default ``SHARD_TENSORS``; 0:
    one shard of all) consecutive tensors, each a
    :class:`TensorStore` kept where the executor runs it (``parallel.py``: here, or on one
    worker for the whole run, so the tensors and their free-bin values travel once).

    Each step of an iteration runs a shard function on every shard, with the shard's
    slice of the labels and codes and the dictionaries it needs (scattered once per
    step to each worker, not sent per tensor or per shard), and returns the per-tensor
    results in order; sums over tensors come back as one partial sum per shard, added
    here in shard order.
    """

    def __init__(self, x: np.ndarray, masked: bool, missing: dict | None, ex,
                 progress: bool, shard_tensors: int = SHARD_TENSORS):
        self.ex, self.masked, self.progress = ex, masked, progress
        self.shape = tuple(int(n) for n in x.shape[1:])
        self.n = n = len(x)
        # 0: one shard of every tensor (the summation order of the trainer before shards)
        self.size = size = int(shard_tensors) or max(n, 1)
        self.bounds = [(lo, min(lo + size, n)) for lo in range(0, n, size)]
        args = []
        for lo, hi in self.bounds:
            part = np.ascontiguousarray(x[lo:hi]) if ex.distributed else x[lo:hi]
            local = {int(i) - lo: m for i, m in (missing or {}).items() if lo <= int(i) < hi}
            args.append((part, masked, local))
        self.handles = ex.place(TensorStore, args)
        info = self.run(shard_info, None)
        self.raw_norms = np.concatenate([r[0] for r in info])
        self.energy = np.concatenate([r[1] for r in info])
        self.extra = {lo + i: e for (lo, _), r in zip(self.bounds, info, strict=True)
                      for i, e in r[2].items()}

    def __len__(self) -> int:
        return self.n

    def slices(self, *arrays) -> list[tuple]:
        """Each shard's slice of per-tensor ``arrays``."""
        return [tuple(a[lo:hi] for a in arrays) for lo, hi in self.bounds]

    def run(self, fn, arg_lists, *shared, desc: str | None = None) -> list:
        """``fn(shard, *args, *shared)`` on every shard (:meth:`InProcess.run_on`)."""
        from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

        bar = tqdm(total=self.n, desc=desc, unit="tensor", leave=False,
                   disable=not (self.progress and desc))
        out = self.ex.run_on(self.handles, fn, arg_lists, *shared,
                             tick=lambda k: bar.update(self.bounds[k][1] - self.bounds[k][0]))
        bar.close()
        return out

    def run_one(self, i: int, fn, *args):
        """``fn(shard, local index of tensor i, *args)`` on the shard holding tensor i."""
        k = i // self.size
        return self.ex.run_on([self.handles[k]], fn, [(i - self.bounds[k][0], *args)])[0]

    def scatter(self, *arrays) -> list:
        return [self.ex.scatter(a) for a in arrays]

    def release(self, handles) -> None:
        self.ex.release([h for h in handles if h is not None])

    def __enter__(self) -> Shards:
        return self

    def __exit__(self, *exc) -> None:
        self.ex.release(self.handles)


def cat(parts: list, k: int) -> np.ndarray:
    return np.concatenate([p[k] for p in parts])
