"""Encoding a BRDF over an ensemble: projection, sparsification, model selection (SPEC 5).

For each transform and colour channel, the transformed tensor Y is projected on every
dictionary; the largest |s| are kept until ``n_coeffs`` are kept or the relative residual
(||Y||^2 - sum of kept s^2) / ||Y||^2 falls to ``max_error``. The channel takes the
dictionary needing the fewest coefficients, then the least residual, then the lowest
index. The transform (the same for all channels) is the one whose reconstruction has
the smaller gamma-mapped MSE against the BRDF, unless forced.
"""

from __future__ import annotations

import numpy as np

from .brdf import BRDF
from .ensemble import Ensemble
from .metrics import gamma_mse, mse, rae
from .sparse import SparseBRDF
from .tensor import parallel_map, project, top_k
from .transforms import TRANSFORMS, check_transform, forward

DEFAULT_N_COEFFS = 262


def _select(y: np.ndarray, ens: Ensemble, n_coeffs: int, max_error: float | None):
    """Best dictionary and coefficients for each channel of y (3, n1, n2, n3)."""
    norms = [float(np.dot(ch.ravel(), ch.ravel())) for ch in y]
    tasks = [(c, k) for c in range(3) for k in range(ens.n_dicts)]

    def one(task):
        c, k = task
        s = project(y[c], *ens.dictionary(k)).ravel()
        e = s * s
        idx = top_k(e, n_coeffs)
        residual = norms[c] - np.cumsum(e[idx], dtype=np.float64)  # after keeping 1..m
        need = idx.size
        if max_error is not None and norms[c] > 0:
            ok = np.flatnonzero(residual <= max_error * norms[c])
            if ok.size:
                need = int(ok[0]) + 1
        if norms[c] == 0:
            need = 0
        res = float(residual[need - 1]) if need else norms[c]
        return c, k, need, max(res, 0.0), idx[:need], s[idx[:need]]

    best: list = [None, None, None]
    for c, k, need, res, idx, val in parallel_map(one, tasks):
        key = (need, res, k)
        if best[c] is None or key < best[c][0]:
            best[c] = (key, idx, val)
    return best, norms


def encode(
    brdf: BRDF,
    ensemble: Ensemble | None = None,
    n_coeffs: int = DEFAULT_N_COEFFS,
    max_error: float | None = None,
    transform: str = "auto",
) -> SparseBRDF:
    """Encode ``brdf`` as a :class:`SparseBRDF` over ``ensemble`` (default: shipped one).

    Parameters
    ----------
    n_coeffs : at most this many coefficients per channel (default 262, the paper's).
    max_error : optional relative squared residual in the transformed domain at which a
        channel stops adding coefficients (e.g. 1e-4); None keeps ``n_coeffs``.
    transform : "auto" (gamma-mapped MSE picks), "log-plus" or "log-plus-cosine".

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
    rho = brdf.channel_first()
    candidates, stats = {}, {}
    for name in names:
        y = forward(rho, name, brdf.valid)
        best, norms = _select(y, ens, n_coeffs, max_error)
        model = SparseBRDF(
            transform=name, shape=brdf.shape, ensemble_id=ens.id,
            dict_index=[b[0][2] for b in best], locations=[b[1] for b in best],
            values=[b[2] for b in best], name=brdf.name)
        rec = model.decode(ens).values
        stats[name] = {
            "gamma_mse": gamma_mse(brdf.values, rec, brdf.valid),
            "mse": mse(brdf.values, rec, brdf.valid),
            "rae": rae(brdf.values, rec, brdf.valid),
            "relative_residual": [b[0][1] / n if n > 0 else 0.0
                                  for b, n in zip(best, norms, strict=True)],
        }
        candidates[name] = model
    chosen = min(names, key=lambda n: stats[n]["gamma_mse"])
    model = candidates[chosen]
    model.stats = {"transforms": stats, "chosen": chosen}
    return model
