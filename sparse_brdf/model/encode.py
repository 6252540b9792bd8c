"""Encoding a BRDF over an ensemble: projection, sparsification, model selection.

Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model"; ``docs/method.md``,
"Encoding".

For each transform and colour channel, the transformed tensor Y is projected on every
dictionary; the largest |s| are kept until ``n_coeffs`` are kept or the relative residual
(||Y||^2 - sum of kept s^2) / ||Y||^2 falls to ``max_error``. The channel takes the
dictionary needing the fewest coefficients, then the least residual, then the lowest
index. The transform (the same for all channels) is the one whose reconstruction has
the smaller gamma-mapped MSE against the BRDF, unless forced.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..brdf import BRDF
from ..coords import geometric_valid
from ..metrics import cosine_weighted_snr, gamma_mse, mse, rae
from ..transforms import TRANSFORMS, check_transform, forward, inverse
from .ensemble import Ensemble, resolve_ensemble
from .sparse import SparseBRDF
from .tensor import n_threads, parallel_map, phi_major_to_flat, project_phi_major, top_k

DEFAULT_N_COEFFS = 262


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


def _energies(y: np.ndarray) -> np.ndarray:
    """||Y_c||^2 of each channel, accumulated in float64 (a float32 dot product over 1.4 M
    entries is off by about 1e-5 relative, the size of the residuals compared here)."""
    return np.array([float(np.sum(np.square(ch, dtype=np.float64))) for ch in y])


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


#: Cumulative numbers of phi_d slices (rows of U3^T, taken in order of decreasing energy
#: of the tensor along them) projected in the rounds of :func:`project_pruned`; after the
#: last round every surviving dictionary is completed.
PRUNE_ROUNDS = (12, 36, 90)

#: Safety margin of the pruning bounds, relative to ||Y||^2: far above float32 rounding
#: of the energies (about 1e-6), far below the gaps between dictionaries (about 1e-4).
PRUNE_SLACK = 1e-5


@dataclass
class _PruneSearch:
    """The state of :func:`project_pruned`'s search. The dicts are keyed by (channel,
    dictionary) pairs, all of them present from the start (:meth:`start`)."""

    n_dicts: int
    n3: int  # phi_d slices of a tensor
    n: int  # coefficients wanted per channel
    max_error: float | None
    done: dict[tuple[int, int], int] = field(default_factory=dict)  # slices projected
    energy: dict[tuple[int, int], float] = field(default_factory=dict)  # their energy
    #: flat indices and values of the n largest coefficients computed so far
    top: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    alive: dict[tuple[int, int], bool] = field(default_factory=dict)  # may still win

    @classmethod
    def start(cls, n_dicts: int, n3: int, n: int, max_error: float | None) -> _PruneSearch:
        search = cls(n_dicts, n3, n, max_error)
        for p in search.pairs:
            search.done[p], search.energy[p] = 0, 0.0
            search.top[p] = (np.zeros(0, np.int64), np.zeros(0, np.float32))
            search.alive[p] = True
        return search

    @property
    def pairs(self) -> list[tuple[int, int]]:
        return [(c, k) for c in range(3) for k in range(self.n_dicts)]

    def add(self, p: tuple[int, int], hi: int, idx: np.ndarray, val: np.ndarray,
            energy: float) -> None:
        """Merge the coefficients of pair ``p``'s slices up to ``hi`` (their total energy
        ``energy``) into what is known of it."""
        old_idx, old_val = self.top[p]
        idx = np.concatenate([old_idx, idx])
        val = np.concatenate([old_val, val])
        keep = top_k(val * val, self.n)
        self.top[p] = (idx[keep], val[keep])
        self.energy[p] += energy
        self.done[p] = hi


def project_pruned(brdf: BRDF, ens: Ensemble, transform: str, n_coeffs: int,
                   max_error: float | None = None,
                   y: np.ndarray | None = None) -> Projections:
    """:func:`project_all`, skipping dictionaries that provably cannot be selected.

    Gives the selection of the full search (:func:`select` with the same ``n_coeffs`` and
    ``max_error``) at a fraction of its cost. Each channel's tensor is projected slice by
    slice along phi_d, the slices of largest energy first (energies from one Gram matrix
    per channel). After each round, the coefficients computed so far bound every
    dictionary's outcome: the kept energy after m coefficients lies between the m largest
    computed ones (L) and L plus all energy not yet computed. A dictionary whose best case
    needs more coefficients than another's worst case, or at equal count leaves more
    residual, is dropped (with a margin of ``PRUNE_SLACK`` ||Y||^2 against rounding);
    the survivors are completed, so their coefficients are exact.
    """
    if y is None:
        y = forward(brdf.channel_first(), check_transform(transform), brdf.valid)
    n1, n2, n3 = tuple(y.shape[1:])
    n_dicts = ens.n_dicts
    n = int(n_coeffs)
    yt = np.ascontiguousarray(np.moveaxis(y, -1, 1)).reshape(3, n3, n1 * n2)
    norms = _energies(y)
    u1t = [np.ascontiguousarray(ens.u1[k].T) for k in range(n_dicts)]
    u3t = [np.ascontiguousarray(ens.u3[k].T) for k in range(n_dicts)]

    # slice order per (channel, dictionary): energy of Y along each row of U3^T
    grams = list(parallel_map(lambda c: yt[c] @ yt[c].T, range(3)))
    order = [[np.argsort(-np.einsum("ij,ij->j", g @ ens.u3[k], ens.u3[k]), kind="stable")
              for k in range(n_dicts)] for g in grams]

    search = _PruneSearch.start(n_dicts, n3, n, max_error)
    pairs, done, alive = search.pairs, search.done, search.alive

    def chunk(task):
        (c, k), hi = task
        rows = order[c][k][done[(c, k)]:hi]
        t = (u3t[k][rows] @ yt[c]).reshape(rows.size, n1, n2)
        sv = np.matmul(np.matmul(u1t[k], t), ens.u2[k]).ravel()
        e = sv * sv
        loc = top_k(e, n)
        slot, ab = np.divmod(loc, n1 * n2)
        return (c, k), hi, ab * n3 + rows[slot], sv[loc], float(e.sum(dtype=np.float64))

    for hi_round in (*PRUNE_ROUNDS, n3):
        hi = min(hi_round, n3)
        tasks = [(p, hi) for p in pairs if alive[p] and done[p] < hi]
        for p, hi_, idx, val, en in parallel_map(chunk, tasks):
            search.add(p, hi_, idx, val, en)
        for c in range(3):
            _prune(search, c, norms[c])
        if all(done[p] == n3 for p in pairs if alive[p]):
            break

    k_keep = min(n, n1 * n2 * n3)
    residual = np.full((3, n_dicts, k_keep), np.inf)
    idx_out = [[np.zeros(0, np.int64) for _ in range(n_dicts)] for _ in range(3)]
    val_out = [[np.zeros(0, np.float32) for _ in range(n_dicts)] for _ in range(3)]
    for (c, k), ok in alive.items():
        if not ok:
            continue
        idx, val = search.top[(c, k)]
        e = val.astype(np.float32) ** 2
        idx_out[c][k], val_out[c][k] = idx, val
        residual[c, k, :idx.size] = norms[c] - np.cumsum(e, dtype=np.float64)
    return Projections(transform, brdf.shape, ens.id, idx=idx_out, val=val_out,
                       residual=residual, norms=norms, exact_for=(n_coeffs, max_error))


def _prune(search: _PruneSearch, c: int, norm: float) -> None:
    """Drop channel ``c``'s dictionaries that cannot win (see :func:`project_pruned`);
    ``norm``: the channel's ||Y||^2."""
    n, n3 = search.n, search.n3
    ks = [k for k in range(search.n_dicts) if search.alive[(c, k)]]
    if len(ks) <= 1 or norm <= 0:
        return
    lower = np.empty((len(ks), n))  # L(m): kept energy of the m largest computed
    gap = np.empty(len(ks))  # energy not computed yet
    for r, k in enumerate(ks):
        _, val = search.top[(c, k)]
        cum = np.cumsum(val.astype(np.float32) ** 2, dtype=np.float64)
        lower[r, :cum.size] = cum
        lower[r, cum.size:] = cum[-1] if cum.size else 0.0
        gap[r] = 0.0 if search.done[(c, k)] == n3 else max(norm - search.energy[(c, k)], 0.0)
    upper = lower + (gap + PRUNE_SLACK * norm)[:, None]
    if search.max_error is None:
        need_hi = need_lo = np.full(len(ks), n)
    else:
        thr = (1.0 - search.max_error) * norm

        def first(a):
            hit = a >= thr
            return np.where(hit.any(axis=1), hit.argmax(axis=1) + 1, n)

        need_hi, need_lo = first(lower), first(upper)
    n_star = int(need_hi.min())
    best = lower[need_hi == n_star, n_star - 1].max()
    drop = (need_lo > n_star) | ((need_lo == n_star) & (upper[:, n_star - 1] < best))
    for r, k in enumerate(ks):
        if drop[r]:
            search.alive[(c, k)] = False


def select(p: Projections, n_coeffs: int, max_error: float | None = None,
           name: str = "brdf") -> SparseBRDF:
    """Per channel, the dictionary needing fewest coefficients, then least residual, then
    lowest index; coefficients kept up to ``n_coeffs`` or a relative residual ``max_error``."""
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
    model = SparseBRDF(p.transform, p.shape, p.ensemble_id, dicts, locs, vals, name=name)
    model.stats = {"relative_residual": rel}
    return model


def pick_transform(stats: dict[str, dict]) -> str:
    """The transform rule (``docs/method.md``, "Encoding"): the smaller gamma-mapped MSE."""
    return min(stats, key=lambda t: stats[t]["gamma_mse"])


def error_curve(brdf: BRDF, ens: Ensemble, counts: list[int]) -> dict:
    """Errors against the coefficient count, per transform, and the transform chosen.

    Returns ``{"counts": counts, "<transform>": {"rae": [...], "cos_snr": [...],
    "gamma_mse": [...], "mse": [...]}, "chosen": [...]}`` (one projection per transform).
    """
    proj = {t: project_all(brdf, ens, t, max(counts)) for t in TRANSFORMS}
    out: dict = {"counts": list(counts), "chosen": []}
    out.update({t: {"rae": [], "cos_snr": [], "gamma_mse": [], "mse": []} for t in TRANSFORMS})
    for n in counts:
        stats = {}
        for t in TRANSFORMS:
            rec = select(proj[t], n, name=brdf.name).decode(ens, valid=brdf.valid).values
            ref, flat = brdf.values[brdf.valid], rec[brdf.valid]
            stats[t] = {"rae": rae(ref, flat), "gamma_mse": gamma_mse(ref, flat),
                        "mse": mse(ref, flat),
                        "cos_snr": cosine_weighted_snr(brdf.values, rec, brdf.valid)}
            for k, v in stats[t].items():
                out[t][k].append(v)
        out["chosen"].append(pick_transform(stats))
    return out


def choose_transform(brdf: BRDF, models: dict[str, SparseBRDF], ens: Ensemble) -> SparseBRDF:
    """The model with the smaller gamma-mapped MSE; ``stats`` gets every model's errors."""
    valid = brdf.valid
    ref = brdf.channel_first()[:, valid]  # (3, n_valid): mask once, then flat metrics
    decoded = {name: model.transformed(ens) for name, model in models.items()}

    def errors(name):  # numpy only (no BLAS): the models' metrics run side by side
        rec = inverse(decoded[name], name)[:, valid]
        return name, {
            "gamma_mse": gamma_mse(ref, rec),
            "mse": mse(ref, rec),
            "rae": rae(ref, rec),
            "relative_residual": models[name].stats["relative_residual"],
            "projections_completed": models[name].stats.get("projections_completed"),
        }

    with ThreadPoolExecutor(max(1, min(len(models), n_threads()))) as ex:
        stats = dict(ex.map(errors, list(models)))
    chosen = pick_transform(stats)
    model = models[chosen]
    model.stats = {"transforms": stats, "chosen": chosen}
    return model


def encode(
    brdf: BRDF,
    ensemble: Ensemble | None = None,
    n_coeffs: int = DEFAULT_N_COEFFS,
    max_error: float | None = None,
    transform: str = "auto",
    fill_iters: int = 3,
) -> SparseBRDF:
    """Encode ``brdf`` as a :class:`SparseBRDF` over ``ensemble`` (default: shipped one).

    Parameters
    ----------
    n_coeffs : at most this many coefficients per channel (default DEFAULT_N_COEFFS = 262,
        the paper's).
    max_error : optional relative squared residual in the transformed domain at which a
        channel stops adding coefficients (e.g. 1e-4); None keeps ``n_coeffs``.
    transform : "auto" (gamma-mapped MSE picks), "log-plus" or "log-plus-cosine".
    fill_iters : for BRDFs with unmeasured bins above the horizon (negative entries in a
        MERL file), that many rounds of filling them from the model and re-encoding, so
        that holes are not fitted as zeros (0 disables; the paper fits them as zeros).

    ``result.stats`` holds, per transform tried: gamma-mapped MSE, plain MSE, RAE, the
    relative residual per channel and how many of the 3 K (channel, dictionary)
    projections were completed (the others were pruned, see :func:`project_pruned`).
    """
    ens = resolve_ensemble(ensemble)
    if brdf.shape != ens.shape:
        raise ValueError(f"{brdf.name}: BRDF grid {brdf.shape} does not match the "
                         f"ensemble's {ens.shape}")
    if n_coeffs < 1:
        raise ValueError(f"n_coeffs must be >= 1, got {n_coeffs}")
    if max_error is not None and not (0 <= max_error < 1):
        raise ValueError(f"max_error must be in [0, 1), got {max_error}")
    names = TRANSFORMS if transform == "auto" else (check_transform(transform),)
    models = {t: _encode_one(brdf, ens, t, n_coeffs, max_error, fill_iters) for t in names}
    return choose_transform(brdf, models, ens)


def _encode_one(brdf, ens, transform, n_coeffs, max_error, fill_iters) -> SparseBRDF:
    """Encode with one transform; unmeasured bins are filled from the model (EM)."""
    y = forward(brdf.channel_first(), transform, brdf.valid)

    def one_round():
        p = project_pruned(brdf, ens, transform, n_coeffs, max_error, y=y)
        m = select(p, n_coeffs, max_error, brdf.name)
        # (channel, dictionary) projections completed; the others were pruned
        m.stats["projections_completed"] = int(np.isfinite(p.residual[:, :, 0]).sum())
        return m

    model = one_round()
    missing = geometric_valid(brdf.shape) & ~brdf.valid
    if not missing.any():
        return model
    # Bins above the horizon without a measurement would act as zeros in the projection;
    # replace them by the current reconstruction and re-encode (expectation-maximisation).
    for _ in range(fill_iters):
        y[:, missing] = model.transformed(ens)[:, missing]
        model = one_round()
    return model
