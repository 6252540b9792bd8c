"""Many materials in one scene: what every material of an ensemble shares, and which
decoder each material gets under a scene's memory budget.

- **Shared rows** (:func:`ensemble_rows`): the atoms of every dictionary of an ensemble,
  one row per atom (``U_m[d][:, a]``, contiguous over the mode's bins), uploaded once per
  ensemble and read by every strict-decoded material of a scene. A strict material then
  holds only its terms: the coefficients and their packed atom indices
  (:func:`strict_shared_layout`, 8 bytes per term), where it held its own copy of its
  distinct atom rows before. The terms are in the same order, with the same group-end
  flags and the same row values, so a render is bit-identical.
- **The budget** (:func:`plan_decoders`): a scene's materials whose decoder is ``auto``
  share one budget of bytes for their per-material data. Every material starts on the
  compact (strict) decoder; the fast (grouped) tables are then given to the materials
  with the largest speed gain per byte first (:func:`lookup_cost`), while they fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..params import Interval
from .layouts import (
    AUTO_GROUPED_MAX_BYTES,
    PACK_BITS,
    GroupedPlan,
    StrictLayout,
    channel_terms,
    grouped_plan,
    strict_channel,
)

#: The default scene budget of ``auto`` materials' per-material decoder data, in bytes
#: (the plugin's ``memory_budget``, ``sparse-brdf render --memory-budget``). 64 MiB
#: holds the fast tables of 40-60 materials (1.0-1.6 MB each at 262 coefficients per
#: channel), and keeps a scene of 1,000 materials near 100 kB per material above the
#: shared ensemble: it fits a laptop beside Mitsuba's own memory.
DEFAULT_MEMORY_BUDGET = 64 * 1024 * 1024

#: The range of a memory budget as a user states it, in MiB (the plugin's
#: ``memory_budget`` property, ``render --memory-budget``).
MEMORY_BUDGET_MIB = Interval(float, 0.0, 2.0 ** 30)


@dataclass(frozen=True)
class SharedRows:
    """Every atom of an ensemble as one flat float32 array.

    Attributes
    ----------
    rows : np.ndarray
        Flat float32: for dictionary d, mode m (in that order), the n_m atoms of
        ``U_m[d]``, each as n_m contiguous floats (its values at the mode's bins).
    offsets : np.ndarray
        (K, 3) int64: the first float of dictionary d, mode m in ``rows``.
    """

    rows: np.ndarray
    offsets: np.ndarray

    @property
    def nbytes(self) -> int:
        return int(self.rows.nbytes)


def ensemble_rows(ensemble) -> SharedRows:
    """The :class:`SharedRows` of ``ensemble`` (K dictionaries of shapes (n1, n1),
    (n2, n2), (n3, n3): 4 K (n1^2 + n2^2 + n3^2) bytes, 6.2 MB for the shipped MERL-grid
    ensemble)."""
    parts, offsets, at = [], np.zeros((ensemble.n_dicts, 3), np.int64), 0
    for d in range(ensemble.n_dicts):
        for m, u in enumerate(ensemble.dictionary(d)):
            offsets[d, m] = at
            parts.append(np.ascontiguousarray(u.T, np.float32).ravel())  # row a = atom a
            at += u.size
    return SharedRows(np.concatenate(parts), offsets)


def strict_shared_layout(model, ensemble, shared: SharedRows) -> StrictLayout:
    """The strict decoder's data of ``model`` reading its atom rows from ``shared``.

    The terms, their order and group-end flags are those of
    :func:`~sparse_brdf.decoders.layouts.strict_channel`; their packed indices name the
    atoms themselves (their column in the dictionary) instead of their rank among the
    channel's distinct atoms, and each channel's row offsets are its dictionary's in
    ``shared``. ``rows`` is empty: the kernel reads ``shared.rows``.

    Raises
    ------
    ValueError
        A mode has more than ``2**PACK_BITS - 1`` atoms (the packed index's field).
    """
    mask = (1 << PACK_BITS) - 1
    values, packed, n_terms, row_offsets = [], [], [], []
    for c in range(3):
        s, modes, us = channel_terms(model, ensemble, c)
        ch = strict_channel(s, modes, us)
        p = ch.packed.astype(np.int64)
        raw = 0
        for m in range(3):
            if us[m].shape[1] > mask:
                raise ValueError(f"mode {m + 1} has {us[m].shape[1]} atoms; the shared "
                                 f"strict decoder packs at most {mask}")
            atoms = np.unique(modes[m])  # sorted: rank r is atoms[r]
            rank = (p >> (m * PACK_BITS)) & mask
            raw = raw | ((atoms[rank] if atoms.size else rank) << (m * PACK_BITS))
        flags = p & ~((1 << (3 * PACK_BITS)) - 1)
        values.append(ch.values)
        packed.append((raw | flags).astype(np.uint32))
        n_terms.append(ch.n_terms)
        row_offsets.append(tuple(int(o) for o in shared.offsets[int(model.dict_index[c])]))
    starts = np.cumsum([0] + n_terms)
    return StrictLayout(np.concatenate(values), np.concatenate(packed),
                        np.zeros(0, np.float32), tuple(n_terms),
                        tuple(int(v) for v in starts[:3]), tuple(row_offsets))


def distinct_atoms(model, ensemble) -> tuple[tuple[int, int, int], ...]:
    """Per channel of ``model``, its number of distinct atoms of each mode."""
    return tuple(tuple(int(np.unique(m).size) for m in channel_terms(model, ensemble, c)[1])
                 for c in range(3))


def strict_shared_bytes(model) -> int:
    """Bytes of the per-material part of :func:`strict_shared_layout`: 8 per term."""
    return 8 * int(np.sum(model.n_coeffs))


def lookup_cost(model, ensemble, plan: GroupedPlan | None = None) -> tuple[float, float]:
    """Estimated reads of one lookup: (strict decoder, grouped decoder).

    The strict decoder reads a coefficient, a packed index and an atom value per term,
    and two atom values per group end (counted as one per term); the grouped decoder
    reads ``plan.packets`` packets of 8 floats (``plan``: the model's
    :func:`~sparse_brdf.decoders.layouts.grouped_plan`, made here if None).
    Units: loads, a packet counted as one.
    """
    strict = 4.0 * float(np.sum(model.n_coeffs))
    if plan is None:
        plan = grouped_plan(model, ensemble)
    return strict, float(plan.packets)


@dataclass(frozen=True)
class MaterialCost:
    """What the budget weighs for one material: bytes of its fast (grouped) and compact
    (strict, shared rows) data, and the reads one lookup saves on the fast decoder."""

    fast_bytes: int
    compact_bytes: int
    gain: float


def material_cost(model, ensemble, plan: GroupedPlan | None = None) -> MaterialCost:
    """The :class:`MaterialCost` of ``model`` (no table is built; ``plan``: its
    :func:`~sparse_brdf.decoders.layouts.grouped_plan`, made here if None)."""
    if plan is None:
        plan = grouped_plan(model, ensemble)
    strict, grouped = lookup_cost(model, ensemble, plan)
    return MaterialCost(plan.nbytes, strict_shared_bytes(model), strict - grouped)


def plan_decoders(costs, budget: int,
                  max_fast_bytes: int = AUTO_GROUPED_MAX_BYTES) -> list[str]:
    """The decoder of each material of a scene under a memory budget.

    Every material starts on "strict"; then, in decreasing order of gain per extra byte
    (``gain / (fast_bytes - compact_bytes)``; ties: the earlier material), a material
    moves to "grouped" if its fast tables are at most ``max_fast_bytes`` (as
    ``decoder="auto"`` alone decides) and the scene's total stays within ``budget``.

    Parameters
    ----------
    costs : sequence of MaterialCost
        One per material, in the scene's order.
    budget : int
        Bytes of per-material decoder data the scene may hold (>= 0).
    max_fast_bytes : int, optional
        The largest fast tables one material may hold.

    Returns
    -------
    list of str
        "grouped" or "strict", one per material.
    """
    out = ["strict"] * len(costs)
    total = sum(c.compact_bytes for c in costs)
    extra = [max(c.fast_bytes - c.compact_bytes, 1) for c in costs]
    order = sorted(range(len(costs)), key=lambda i: (-costs[i].gain / extra[i], i))
    for i in order:
        c = costs[i]
        if c.fast_bytes <= max_fast_bytes and total + extra[i] <= budget:
            out[i] = "grouped"
            total += extra[i]
    return out
