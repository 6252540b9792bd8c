"""Encoding a BRDF over an ensemble: projection, sparsification, model selection (SPEC 5).

For each transform and colour channel, the transformed tensor Y is projected on every
dictionary; the largest |s| are kept until ``n_coeffs`` are kept or the relative residual
(||Y||^2 - sum of kept s^2) / ||Y||^2 falls to ``max_error``. The channel takes the
dictionary needing the fewest coefficients, then the least residual, then the lowest
index. The transform (the same for all channels) is the one whose reconstruction has
the smaller gamma-mapped MSE against the BRDF, unless forced.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .brdf import BRDF
from .coords import geometric_valid
from .ensemble import Ensemble
from .metrics import gamma_mse, mse, rae
from .sparse import SparseBRDF
from .tensor import n_threads, parallel_map, phi_major_to_flat, project_phi_major, top_k
from .transforms import TRANSFORMS, check_transform, forward, inverse

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


def project_all(brdf: BRDF, ens: Ensemble, transform: str, max_coeffs: int,
                y: np.ndarray | None = None) -> Projections:
    """Transform ``brdf`` and project each channel on every dictionary (3 K projections).

    ``y``: the transformed tensor (3, n1, n2, n3) to project instead of ``brdf``'s own.
    """
    if y is None:
        y = forward(brdf.channel_first(), check_transform(transform), brdf.valid)
    norms = np.array([float(np.dot(ch.ravel(), ch.ravel())) for ch in y])
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


def select(p: Projections, n_coeffs: int, max_error: float | None = None,
           name: str = "brdf") -> SparseBRDF:
    """Per channel, the dictionary needing fewest coefficients, then least residual, then
    lowest index; coefficients kept up to ``n_coeffs`` or a relative residual ``max_error``."""
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
    """The transform rule (SPEC section 5): the smaller gamma-mapped MSE."""
    return min(stats, key=lambda t: stats[t]["gamma_mse"])


def error_curve(brdf: BRDF, ens: Ensemble, counts: list[int]) -> dict:
    """Errors against the coefficient count, per transform, and the transform chosen.

    Returns ``{"counts": counts, "<transform>": {"rae": [...], "cos_snr": [...],
    "gamma_mse": [...], "mse": [...]}, "chosen": [...]}`` (one projection per transform).
    """
    from .metrics import cosine_weighted_snr

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
    from concurrent.futures import ThreadPoolExecutor

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
    n_coeffs : at most this many coefficients per channel (default 262, the paper's).
    max_error : optional relative squared residual in the transformed domain at which a
        channel stops adding coefficients (e.g. 1e-4); None keeps ``n_coeffs``.
    transform : "auto" (gamma-mapped MSE picks), "log-plus" or "log-plus-cosine".
    fill_iters : for BRDFs with unmeasured bins above the horizon (negative entries in a
        MERL file), that many rounds of filling them from the model and re-encoding, so
        that holes are not fitted as zeros (0 disables; the paper fits them as zeros).

    ``result.stats`` holds, per transform tried: gamma-mapped MSE, plain MSE, RAE and the
    relative residual per channel.
    """
    ens = Ensemble.default() if ensemble is None else ensemble
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
    model = select(project_all(brdf, ens, transform, n_coeffs, y=y), n_coeffs, max_error,
                   brdf.name)
    missing = geometric_valid(brdf.shape) & ~brdf.valid
    if not missing.any():
        return model
    # Bins above the horizon without a measurement would act as zeros in the projection;
    # replace them by the current reconstruction and re-encode (expectation-maximisation).
    for _ in range(fill_iters):
        y[:, missing] = model.transformed(ens)[:, missing]
        model = select(project_all(brdf, ens, transform, n_coeffs, y=y), n_coeffs, max_error,
                       brdf.name)
    return model
