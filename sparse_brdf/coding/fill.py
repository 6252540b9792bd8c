"""The fill solver: encoding with every invalid bin a free value (``fill="invalid"``,
``docs/method.md``, "Encoding"): hard thresholding pursuit whose least-squares fits on the
chosen dictionaries' supports are conjugate gradients on the valid bins only.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..brdf import BRDF
from ..parallel import parallel_map
from .coefficients import SparseBRDF
from .ensemble import Ensemble
from .projection import (
    CodingOptions,
    budget_stats,
    code_many,
    coded_channels,
    coded_many,
    energies_many,
    materials_of,
    search_many,
)


class SizeControl(Protocol):
    """What :func:`~sparse_brdf.coding.counted.encode_at` asks while the fill runs, of
    one transform's model (its support and fitted values)."""

    def recount(self, model: SparseBRDF) -> int:
        """The coefficient count (per channel, as ``n_coeffs``) of the next support."""

    def trim(self, model: SparseBRDF) -> SparseBRDF:
        """The model's final support: the model itself, or some of its coefficients."""


def fill_invalid(brdf: BRDF, ens: Ensemble, transforms: tuple[str, ...],
                 o: CodingOptions, size: SizeControl | None = None) -> dict[str, SparseBRDF]:
    """Encode with every invalid bin a free value (``docs/method.md``, "Encoding"), one
    model per transform.

    Minimises the residual on valid bins only, ||P_V (Y - U S)||^2 over sparse S, by hard
    thresholding pursuit on the dictionaries the search chose
    (:func:`~sparse_brdf.coding.projection.search_many`, run once on the zero-filled
    channels): the values of the current support are the least squares fit to the valid
    bins (:func:`_fit_supports`, conjugate gradients); the invalid bins of Y are then set
    to that reconstruction, the channels re-projected on their dictionaries and the
    largest |s| kept (:func:`~sparse_brdf.coding.projection.code_many`) as the next
    support.
    Stops when the support repeats or after ``o.fill_iters`` fits. The mask is the same
    for the three channels, so filling the coded channels is filling the transformed
    R, G, B (the basis is a per-bin 3 x 3 mix), and the channels' least squares
    problems are independent: the fits of every transform and channel run side by side.
    ``size`` (:func:`~sparse_brdf.coding.counted.encode_at`) revises each transform's
    count between fits (a revised support is never taken as settled) and trims the last
    fit's support.
    """
    invalid = ~brdf.valid
    mats = materials_of(brdf, transforms)
    ys = dict(zip(transforms, parallel_map(  # invalid bins are 0
        lambda t: coded_channels(brdf, t, o.basis, mats[t]), transforms), strict=True))
    valid_energies = energies_many(ys)  # before any filling
    models = search_many(brdf, ens, ys, o, mats)
    if not invalid.any() or o.fill_iters == 0:
        return models
    searched = {t: m.stats for t, m in models.items()}
    history: dict[str, list[float]] = {t: [] for t in transforms}
    residual: dict[str, np.ndarray] = {}
    active = list(transforms)
    counts = {t: o.n for t in transforms}
    recounts: dict[str, list[int]] = {t: [] for t in transforms}
    for fit in range(o.fill_iters):
        fitted = _fit_supports([(ys[t], models[t]) for t in active], invalid, ens)
        for t, (m, r) in zip(active, fitted, strict=True):
            models[t], residual[t] = m, r
            history[t].append(float(r.sum()))
        if fit == o.fill_iters - 1:
            break
        for t, coded in zip(active, coded_many([models[t] for t in active], ens),
                            strict=True):
            np.copyto(ys[t], coded, where=invalid)  # fill the invalid bins
        revised = set()
        if size is not None:
            for t in active:
                n = max(int(size.recount(models[t])), 1)
                recounts[t].append(n)
                if n != counts[t]:
                    counts[t] = n
                    revised.add(t)
        recoded = code_many([(ys[t], models[t], None) for t in active], ens, o,
                             [counts[t] for t in active])
        for t, new in zip(list(active), recoded, strict=True):
            if t not in revised and all(np.array_equal(np.sort(a), np.sort(b))
                   for a, b in zip(models[t].locations, new.locations, strict=True)):
                active.remove(t)  # the support has settled: its fit is done
            else:
                models[t] = new
        if not active:
            break
    if size is not None:  # the final support: trimmed to size, its values fitted again
        trimmed = dict(zip(transforms, parallel_map(  # LZMA releases the GIL
            lambda t: size.trim(models[t]), transforms, limit_blas=False), strict=True))
        cut = [t for t in transforms
               if int(trimmed[t].n_coeffs.sum()) < int(models[t].n_coeffs.sum())]
        for t, (m, r) in zip(cut, _fit_supports([(ys[t], trimmed[t]) for t in cut],
                                                invalid, ens), strict=True):
            models[t], residual[t] = m, r
            history[t].append(float(r.sum()))
    filled_energies = energies_many(ys)
    for t, m in models.items():
        valid_energy = valid_energies[t]
        m.stats = {
            "relative_residual": [float(r / n) if n > 0 else 0.0
                                  for r, n in zip(residual[t], valid_energy, strict=True)],
            "budget": budget_stats(m, filled_energies[t]),
            "projections_completed": searched[t]["projections_completed"],
            "fill": {"fits": len(history[t]), "valid_residual": history[t],
                     "valid_residual_unfilled": float(np.sum(
                         np.asarray(searched[t]["relative_residual"]) * valid_energy))},
        }
        if size is not None:
            m.stats["recount"] = recounts[t]
    return models


#: Conjugate-gradient iterations of each least-squares fit of :func:`_fit_supports`, at
#: most; a fit stops early once a step lowers the residual by less than FIT_CG_RTOL of it.
FIT_CG_ITERS = 10
FIT_CG_RTOL = 1e-3


def _fit_supports(jobs: list[tuple[np.ndarray, SparseBRDF]], invalid: np.ndarray,
                  ens: Ensemble) -> list[tuple[SparseBRDF, np.ndarray]]:
    """For each (channels y, model m): the values on m's support (its coefficient
    locations and dictionaries) that fit y on the valid bins in least squares,
    ``FIT_CG_ITERS`` conjugate-gradient steps on the normal equations from m's values.
    Returns, per job, the model (sorted by decreasing |value|) and each channel's
    residual on valid bins (3,). The 3 x len(jobs) channels run on the thread pool."""
    keep = (~invalid).astype(np.float32)  # masks by a product: cheaper than fancy indexing

    def one(task):
        y, m, c = task
        if m.locations[c].size == 0:  # nothing to fit (a joint budget spent elsewhere)
            res = y[c] * keep
            return m.locations[c], m.values[c], float(np.sum(np.square(res, dtype=np.float64)))
        sup = _Support(m.locations[c], m.shape, ens.dictionary(int(m.dict_index[c])))
        s = m.values[c].astype(np.float32)  # a copy, updated in place
        res = y[c] - sup.expand(s)
        res *= keep
        energy = float(np.dot(res.ravel(), res.ravel()))  # ||res||^2, tracked below
        r = sup.gather(res)
        p, rr = r.copy(), float(r @ r)
        for _ in range(FIT_CG_ITERS):
            q = sup.expand(p)
            q *= keep
            qq = float(np.dot(q.ravel(), q.ravel()))  # float32 BLAS dot: enough for steps
            if rr <= 0.0 or qq <= 0.0:
                break
            alpha = rr / qq
            s += np.float32(alpha) * p
            q *= np.float32(alpha)
            res -= q
            energy -= alpha * rr  # the step lowers ||res||^2 by exactly alpha rr
            if alpha * rr <= FIT_CG_RTOL * energy:
                break
            r = sup.gather(res)
            rr_new = float(r @ r)
            p = r + np.float32(rr_new / rr) * p
            rr = rr_new
        order = np.argsort(-np.abs(s), kind="stable")
        return m.locations[c][order], s[order], float(np.sum(np.square(res, dtype=np.float64)))

    # the largest supports first, so that the pool's last tasks are short
    tasks = sorted(((y, m, c) for y, m in jobs for c in range(3)),
                   key=lambda t: -t[1].locations[t[2]].size)
    done = {(id(m), c): out for (y, m, c), out in zip(tasks, parallel_map(one, tasks),
                                                      strict=True)}
    out = []
    for _, m in jobs:
        res = [done[(id(m), c)] for c in range(3)]
        fitted = SparseBRDF(m.transform, m.shape, m.ensemble_id, m.dict_index,
                            [a for a, _, _ in res], [v for _, v, _ in res], name=m.name,
                            basis=m.basis, gain=m.gain, lobe=m.lobe)
        out.append((fitted, np.array([e for _, _, e in res])))
    return out


class _Support:
    """The atoms of a set of coefficient locations on one dictionary: ``expand`` maps
    their values to the tensor (as :func:`tensor.reconstruct_sparse`), ``gather`` is its
    adjoint (the projection of a tensor on those atoms only), each about n1 n2 n3 K3
    multiply-adds for K3 distinct mode-3 atoms (a full projection: n1 n2 n3 (n1+n2+n3))."""

    def __init__(self, flat: np.ndarray, shape: tuple[int, int, int], u) -> None:
        self.shape = shape
        a, b, c = np.unravel_index(np.asarray(flat, np.int64), shape)
        (ka, self.ia), (kb, self.ib), (kc, self.ic) = (
            np.unique(x, return_inverse=True) for x in (a, b, c))
        self.u1 = np.ascontiguousarray(u[0][:, ka])
        self.u2 = np.ascontiguousarray(u[1][:, kb])
        self.u3 = np.ascontiguousarray(u[2][:, kc])
        self.core = (ka.size, kb.size, kc.size)

    def expand(self, v: np.ndarray) -> np.ndarray:
        n1, n2, n3 = self.shape
        ka, kb, kc = self.core
        core = np.zeros(self.core, np.float32)
        core[self.ia, self.ib, self.ic] = v  # the locations are distinct
        t = (self.u1 @ core.reshape(ka, -1)).reshape(n1, kb, kc)
        t = np.matmul(self.u2, t)  # (n1, n2, Kc)
        return (t.reshape(n1 * n2, kc) @ self.u3.T).reshape(n1, n2, n3)

    def gather(self, x: np.ndarray) -> np.ndarray:
        n1, n2, n3 = self.shape
        ka, kb, kc = self.core
        t = (x.reshape(n1 * n2, n3) @ self.u3).reshape(n1, n2 * kc)
        t = (self.u1.T @ t).reshape(ka, n2, kc)
        t = np.matmul(self.u2.T, t)  # (Ka, Kb, Kc)
        return t[self.ia, self.ib, self.ic]
