"""Interpolating two encoded BRDFs in coefficient space.

As in the TOG version of Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model".

Per channel, B's coefficients are brought into A's dictionary mode by mode,
R_n = U_nA^T U_nB and S_B' = S_B x1 R1 x2 R2 x3 R3 (exact, the bases being orthonormal),
then blended, S(alpha) = (1 - alpha) S_A + alpha S_B', and re-sparsified to the budget
by keeping the largest |s|. The result uses A's dictionaries and transform.
"""

from __future__ import annotations

from .ensemble import Ensemble, resolve_ensemble
from .sparse import SparseBRDF
from .tensor import reconstruct, sparse_to_dense, top_k


def interpolate(
    a: SparseBRDF,
    b: SparseBRDF,
    alpha: float,
    ensemble: Ensemble | None = None,
    n_coeffs: int | None = None,
) -> SparseBRDF:
    """Blend ``a`` and ``b`` (same ensemble and transform) at ``alpha`` in [0, 1].

    ``n_coeffs``: coefficients per channel of the result (default: the larger of the two
    inputs' counts for that channel).
    """
    ens = resolve_ensemble(ensemble)
    a.check_ensemble(ens)
    b.check_ensemble(ens)
    if a.transform != b.transform:
        raise ValueError(f"cannot blend {a.name} ({a.transform}) with {b.name} "
                         f"({b.transform}): encode both with the same --transform")
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    locs, vals = [], []
    for c in range(3):
        ka, kb = int(a.dict_index[c]), int(b.dict_index[c])
        sa = sparse_to_dense(a.locations[c], a.values[c], a.shape)
        sb = sparse_to_dense(b.locations[c], b.values[c], b.shape)
        if ka != kb:
            ua, ub = ens.dictionary(ka), ens.dictionary(kb)
            rot = [x.T @ y for x, y in zip(ua, ub, strict=True)]
            sb = reconstruct(sb, *rot)
        s = ((1.0 - alpha) * sa + alpha * sb).ravel()
        budget = n_coeffs or max(a.n_coeffs[c], b.n_coeffs[c])
        idx = top_k(s * s, int(budget))
        locs.append(idx)
        vals.append(s[idx])
    name = f"{a.name}+{b.name}@{alpha:g}"
    return SparseBRDF(a.transform, a.shape, a.ensemble_id, a.dict_index.copy(), locs, vals,
                      name=name[:255])
