"""The encoder's search: every dictionary's largest coefficients of a tensor, the selection
of a dictionary per channel, and the re-coding of channels on chosen dictionaries.

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model"; ``docs/method.md``,
"Encoding". :func:`~sparse_brdf.coding.encode.encode` runs these; the fill solver
(:mod:`sparse_brdf.coding.fill`) re-codes through them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..brdf import BRDF
from ..parallel import parallel_map
from ..transforms import (
    check_transform,
    forward,
    has_lobe,
    material_gain,
    material_lobe,
    to_basis,
)
from .coefficients import SparseBRDF
from .ensemble import Ensemble
from .pruning import PrunedSearch, slice_order
from .tensor import (
    phi_major_to_flat,
    project,
    project_phi_major,
    reconstruct_sparse,
    top_k,
)


@dataclass
class Projections:
    """The largest coefficients of each channel on each dictionary, for one transform.

    ``idx[c][k]``/``val[c][k]``: flat indices and values of the ``max_coeffs`` largest |s|
    of channel c on dictionary k, largest first; ``residual[c, k, m]``: squared residual
    after keeping the first m + 1 of them; ``norms[c]``: ||Y_c||^2.
    """

    transform: str
    shape: tuple[int, int, int]
    ensemble_id: str
    idx: list[list[np.ndarray]]
    val: list[list[np.ndarray]]
    residual: np.ndarray
    norms: np.ndarray
    #: (n_coeffs, max_error) if dictionaries that cannot win that selection were pruned
    #: (their residuals are inf); None if every dictionary was projected in full.
    exact_for: tuple[int, float | None] | None = None


def _energy(x: np.ndarray) -> float:
    """||x||^2, accumulated in float64 (a float32 dot product over 1.4 M entries is off by
    about 1e-5 relative, the size of the residuals compared here)."""
    return float(np.sum(np.square(x, dtype=np.float64)))


def _energies(y: np.ndarray) -> np.ndarray:
    """||Y_c||^2 of each channel (:func:`_energy`)."""
    return np.array([_energy(ch) for ch in y])


def energies_many(ys: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """:func:`_energies` of each entry's channels, side by side on the thread pool."""
    tasks = [(t, c) for t in ys for c in range(3)]
    e = list(parallel_map(lambda tc: _energy(ys[tc[0]][tc[1]]), tasks))
    return {t: np.array(e[3 * i: 3 * i + 3]) for i, t in enumerate(ys)}


def coded_many(models: list[SparseBRDF], ens: Ensemble) -> list[np.ndarray]:
    """``m.coded(ens)`` of each model, the 3 x len(models) channels side by side on the
    thread pool."""
    tasks = [(m, c) for m in models for c in range(3)]
    out = list(parallel_map(lambda mc: reconstruct_sparse(
        mc[0].locations[mc[1]], mc[0].values[mc[1]], mc[0].shape,
        *ens.dictionary(int(mc[0].dict_index[mc[1]]))), tasks))
    return [np.stack(out[3 * i: 3 * i + 3]) for i in range(len(models))]


def project_all(brdf: BRDF, ens: Ensemble, transform: str, max_coeffs: int,
                y: np.ndarray | None = None) -> Projections:
    """Transform ``brdf`` and project each channel on every dictionary (3 K projections).

    ``y``: the transformed tensor (3, n1, n2, n3) to project instead of ``brdf``'s own.
    """
    if y is None:
        y = forward(brdf.channel_first(), check_transform(transform), brdf.valid)
    norms = _energies(y)
    tasks = [(c, k) for c in range(3) for k in range(ens.n_dicts)]
    # every channel meets every dictionary: store the channels phi_d-major once
    yt = np.ascontiguousarray(np.moveaxis(y, -1, 1))  # (3, n3, n1, n2)
    shape = tuple(y.shape[1:])

    def one(task):
        c, k = task
        u1, u2, u3 = ens.dictionary(k)
        s = project_phi_major(yt[c], np.ascontiguousarray(u1.T), u2,
                              np.ascontiguousarray(u3.T)).ravel()
        e = s * s
        idx = top_k(e, max_coeffs)
        return (phi_major_to_flat(idx, shape), s[idx],
                norms[c] - np.cumsum(e[idx], dtype=np.float64))

    res = list(parallel_map(one, tasks))
    k = ens.n_dicts
    return Projections(
        transform, brdf.shape, ens.id,
        idx=[[res[c * k + j][0] for j in range(k)] for c in range(3)],
        val=[[res[c * k + j][1] for j in range(k)] for c in range(3)],
        residual=np.array([[res[c * k + j][2] for j in range(k)] for c in range(3)]),
        norms=norms)


def project_pruned(brdf: BRDF, ens: Ensemble, transform: str, n_coeffs: int,
                   max_error: float | None = None,
                   y: np.ndarray | None = None) -> Projections:
    """:func:`project_all`, skipping dictionaries that provably cannot be selected.

    Gives the selection of the full search (:func:`select` with the same ``n_coeffs`` and
    ``max_error``) at a fraction of its cost: each channel's tensor is projected slice by
    slice along phi_d, the slices of largest energy first, and a dictionary is dropped
    once the coefficients computed so far prove it cannot be selected (the pruned
    projection, :mod:`~sparse_brdf.coding.pruning`); the survivors are completed, so their
    coefficients are exact.
    """
    if y is None:
        y = forward(brdf.channel_first(), check_transform(transform), brdf.valid)
    return project_pruned_many(brdf, ens, {transform: y}, n_coeffs, max_error)[transform]


def project_pruned_many(brdf: BRDF, ens: Ensemble, ys: dict[str, np.ndarray],
                        n_coeffs: int, max_error: float | None = None
                        ) -> dict[str, Projections]:
    """:func:`project_pruned` of several transformed tensors ``ys`` (transform name:
    channels (3, n1, n2, n3)) in one search: each tensor's channels are pruned on their
    own, as by separate calls, with the same result, but every round's slices of all of
    them share the thread pool, so that a round's few long tasks of one tensor overlap
    those of another."""
    names = list(ys)
    n1, n2, n3 = tuple(ys[names[0]].shape[1:])
    n_dicts = ens.n_dicts
    n = int(n_coeffs)
    channels = [(t, c) for t in names for c in range(3)]
    # each channel phi_d-major (n3, n1 n2), the copies side by side on the pool
    phi_major = dict(zip(channels, parallel_map(lambda tc: np.ascontiguousarray(
        np.moveaxis(ys[tc[0]][tc[1]], -1, 0)).reshape(n3, n1 * n2), channels,
        limit_blas=False), strict=True))
    yt = {t: [phi_major[(t, c)] for c in range(3)] for t in names}
    norms = dict(zip(channels, parallel_map(
        lambda tc: _energy(ys[tc[0]][tc[1]]), channels), strict=True))
    u1t = [np.ascontiguousarray(ens.u1[k].T) for k in range(n_dicts)]
    u3t = [np.ascontiguousarray(ens.u3[k].T) for k in range(n_dicts)]

    # slice order per (channel, dictionary): energy of Y along each row of U3^T
    def slice_orders(tc):  # on the workers: small products on threaded BLAS stall under load
        x = yt[tc[0]][tc[1]]
        g = x @ x.T
        return [slice_order(g, ens.u3[k]) for k in range(n_dicts)]

    order = dict(zip(channels, parallel_map(slice_orders, channels), strict=True))

    def chunk(key, lo, hi):
        t, c, k = key
        rows = order[(t, c)][k][lo:hi]
        m = (u3t[k][rows] @ yt[t][c]).reshape(rows.size, n1, n2)
        sv = np.matmul(np.matmul(u1t[k], m), ens.u2[k]).ravel()
        e = sv * sv
        loc = top_k(e, n)
        slot, ab = np.divmod(loc, n1 * n2)
        return ab * n3 + rows[slot], sv[loc], float(e.sum(dtype=np.float64))

    keys = [(t, c, k) for t, c in channels for k in range(n_dicts)]
    groups = [([(t, c, k) for k in range(n_dicts)], norms[(t, c)], np.inf)
              for t, c in channels]
    pruned = PrunedSearch.start(keys, n3, n, max_error).run(groups, chunk,
                                                            mapper=parallel_map)
    k_keep = min(n, n1 * n2 * n3)
    out = {}
    for t in names:
        norm = np.array([norms[(t, c)] for c in range(3)])
        residual = np.full((3, n_dicts, k_keep), np.inf)
        idx_out = [[np.zeros(0, np.int64) for _ in range(n_dicts)] for _ in range(3)]
        val_out = [[np.zeros(0, np.float32) for _ in range(n_dicts)] for _ in range(3)]
        for tt, c, k in pruned.survivors():
            if tt != t:
                continue
            idx, val = pruned.top[(t, c, k)]
            e = val.astype(np.float32) ** 2
            idx_out[c][k], val_out[c][k] = idx, val
            residual[c, k, :idx.size] = norm[c] - np.cumsum(e, dtype=np.float64)
        out[t] = Projections(t, brdf.shape, ens.id, idx=idx_out, val=val_out,
                             residual=residual, norms=norm, exact_for=(n_coeffs, max_error))
    return out


def select(p: Projections, n_coeffs: int, max_error: float | None = None,
           name: str = "brdf", gain: float = 1.0, lobe=None) -> SparseBRDF:
    """Per channel, the dictionary needing fewest coefficients, then least residual, then
    lowest index; coefficients kept up to ``n_coeffs`` or a relative residual ``max_error``.
    ``gain`` and ``lobe``: the material's, for the transforms that hold them
    (:func:`materials_of`)."""
    if p.exact_for is not None and p.exact_for != (n_coeffs, max_error):
        raise ValueError(f"these projections were pruned for n_coeffs, max_error = "
                         f"{p.exact_for}; project again to select with "
                         f"{(n_coeffs, max_error)}")
    n_coeffs = min(n_coeffs, p.residual.shape[2])
    dicts, locs, vals, rel = [], [], [], []
    for c in range(3):
        norm = p.norms[c]
        best = None
        for k in range(p.residual.shape[1]):
            res = p.residual[c, k, :n_coeffs]
            need = n_coeffs
            if norm == 0:
                need = 0
            elif max_error is not None:
                ok = np.flatnonzero(res <= max_error * norm)
                if ok.size:
                    need = int(ok[0]) + 1
            r = max(float(res[need - 1]), 0.0) if need else float(norm)
            if best is None or (need, r, k) < best:
                best = (need, r, k)
        need, r, k = best
        dicts.append(k)
        locs.append(p.idx[c][k][:need])
        vals.append(p.val[c][k][:need])
        rel.append(r / norm if norm > 0 else 0.0)
    model = SparseBRDF(p.transform, p.shape, p.ensemble_id, dicts, locs, vals, name=name,
                       gain=gain, lobe=lobe)
    model.stats = {"relative_residual": rel}
    return model


@dataclass(frozen=True)
class CodingOptions:
    """The coding options of one :func:`encode` call."""

    n: int
    max_error: float | None
    fill: str
    fill_iters: int
    basis: str
    joint: bool


def coded_channels(brdf: BRDF, transform: str, basis: str,
                   material: tuple | None = None) -> np.ndarray:
    """The channels to code: ``to_basis`` of the transformed R, G, B, a fresh array.
    ``material``: the (gain, lobe) of :func:`materials_of`; None: computed here."""
    gain, lobe = material if material is not None else (None, None)
    return to_basis(forward(brdf.channel_first(), transform, brdf.valid, gain, lobe), basis)


def materials_of(brdf: BRDF, transforms) -> dict[str, tuple[float, tuple | None]]:
    """Per transform, the gain and base lobe it gives ``brdf`` (1 and None for the
    transforms without them), as :func:`~sparse_brdf.transforms.forward` computes them;
    the lobe, which depends on the material only, fitted once."""
    rho, valid = brdf.channel_first(), brdf.valid
    lobe = next((material_lobe(t, rho, valid) for t in transforms if has_lobe(t)), None)
    return {t: (material_gain(t, rho, valid), lobe if has_lobe(t) else None)
            for t in transforms}


def search_many(brdf: BRDF, ens: Ensemble, ys: dict[str, np.ndarray],
                 o: CodingOptions, materials: dict | None = None) -> dict[str, SparseBRDF]:
    """Each coded channel's dictionary by the (pruned) search over the ensemble, and its
    coefficients (the selection's own, or with a joint budget re-coded on the chosen
    dictionaries, :func:`code_many`), for the channels of several transforms (name:
    channels), their projections side by side on the thread pool; ``materials``:
    :func:`materials_of` the transforms (None: computed here)."""
    ps = project_pruned_many(brdf, ens, ys, o.n, o.max_error)
    if materials is None:
        materials = materials_of(brdf, tuple(ys))
    models = {}
    for t, p in ps.items():
        models[t] = select(p, o.n, o.max_error, brdf.name, *materials[t])
        models[t].basis = o.basis
    if o.joint:
        coded = code_many([(ys[t], models[t], ps[t].norms) for t in ys], ens, o)
        models = dict(zip(ys, coded, strict=True))
    else:
        for t, m in models.items():
            m.stats["budget"] = budget_stats(m, ps[t].norms)
    for t, m in models.items():
        # (channel, dictionary) projections completed; the others were pruned
        m.stats["projections_completed"] = int(np.isfinite(ps[t].residual[:, :, 0]).sum())
    return models


def budget_stats(m: SparseBRDF, norms: np.ndarray) -> dict:
    total = float(np.sum(norms))
    return {"coefficients": m.n_coeffs.tolist(),
            "energy_share": [float(x / total) if total > 0 else 0.0 for x in norms]}


def code_many(jobs: list[tuple[np.ndarray, SparseBRDF, np.ndarray | None]], ens: Ensemble,
               o: CodingOptions, counts: list[int] | None = None) -> list[SparseBRDF]:
    """Re-code each job's channels y (3, n1, n2, n3) on the dictionaries its model m chose
    (a job: y, m, the channels' energies or None): each channel projected on its own
    dictionary, then the largest |s| kept, ``o.n`` per channel, or with a joint budget 3
    ``o.n`` over the channels (largest first across them). With ``o.max_error``,
    coefficients are added until the relative residual (per channel, or of the total for a
    joint budget) is reached. The 3 x len(jobs) projections run side by side on the
    thread pool. ``counts``: per job, its own ``o.n``."""
    opts = [o] * len(jobs) if counts is None else [replace(o, n=int(n)) for n in counts]

    def one(task):
        j, c = task
        y, m, norms = jobs[j]
        s = project(y[c], *ens.dictionary(int(m.dict_index[c]))).ravel()
        idx = top_k(s * s, 3 * opts[j].n if opts[j].joint else opts[j].n)
        return idx, s[idx], _energy(y[c]) if norms is None else float(norms[c])

    tasks = [(j, c) for j in range(len(jobs)) for c in range(3)]
    done = list(parallel_map(one, tasks))
    return [_keep(y, m, done[3 * j: 3 * j + 3], opts[j]) for j, (y, m, _) in enumerate(jobs)]


def _keep(y: np.ndarray, m: SparseBRDF, top: list, o: CodingOptions) -> SparseBRDF:
    """The coefficients :func:`code_many` keeps of each channel's largest (``top``: per
    channel, flat indices, values and the channel's energy)."""
    shape = tuple(y.shape[1:])
    norms = np.array([e for _, _, e in top])
    cap = 3 * o.n if o.joint else o.n
    if o.joint:
        val = np.concatenate([v for _, v, _ in top])
        chan = np.concatenate([np.full(v.size, c) for c, (_, v, _) in enumerate(top)])
        order = np.argsort(-(val * val), kind="stable")[:cap]
        need = _needed(np.cumsum(val[order].astype(np.float64) ** 2), float(norms.sum()),
                       o.max_error)
        keep = [np.sort(order[:need][chan[order[:need]] == c]) for c in range(3)]
        starts = np.cumsum([0] + [v.size for _, v, _ in top])
        locs = [top[c][0][keep[c] - starts[c]] for c in range(3)]
        vals = [top[c][1][keep[c] - starts[c]] for c in range(3)]
    else:
        locs, vals = [], []
        for c, (idx, v, _) in enumerate(top):
            need = _needed(np.cumsum(v.astype(np.float64) ** 2), norms[c], o.max_error)
            locs.append(idx[:need])
            vals.append(v[:need])
    out = SparseBRDF(m.transform, shape, m.ensemble_id, m.dict_index, locs, vals,
                     name=m.name, basis=o.basis, gain=m.gain, lobe=m.lobe)
    kept = np.array([float(np.sum(v.astype(np.float64) ** 2)) for v in vals])
    out.stats = {"relative_residual": [max(float(n - k), 0.0) / n if n > 0 else 0.0
                                       for n, k in zip(norms, kept, strict=True)],
                 "budget": budget_stats(out, norms)}
    return out


def _needed(cum: np.ndarray, norm: float, max_error: float | None) -> int:
    """How many of the coefficients (cumulative kept energies ``cum``, largest first) to
    keep: all, or the fewest whose residual norm - cum is within ``max_error`` norm."""
    if norm <= 0:
        return 0
    if max_error is None:
        return cum.size
    ok = np.flatnonzero(norm - cum <= max_error * norm)
    return int(ok[0]) + 1 if ok.size else cum.size


