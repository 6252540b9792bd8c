"""A scene's memory budget: which decoder each ``auto`` material of a scene gets.

A ``sparse_brdf`` whose ``decoder`` is ``auto`` builds nothing when it loads: it joins
the pool of materials waiting for a decision (:func:`enroll`). The first time any of them
is used (a render traces it, or an attribute such as ``decoder`` is read), the whole pool
is decided at once (:func:`resolve`): every material on the compact (strict) decoder, then
the fast (grouped) tables for the largest speed gain per byte first while the pool's
per-material data stays within its budget
(:func:`sparse_brdf.decoders.scene.plan_decoders`). The pool's budget is the smallest its
members state (their ``memory_budget`` property, else the default in force when each was
loaded: :func:`memory_budget`, which ``sparse-brdf render --memory-budget`` sets). The
choice is logged through Mitsuba's log (Info) and kept on each material
(``decoder``, ``memory_bytes``).
"""

from __future__ import annotations

import contextlib
import threading
import weakref

from sparse_brdf.decoders.scene import DEFAULT_MEMORY_BUDGET, plan_decoders

_POOL: list = []  # weak references to the materials waiting for a decision
_LOCK = threading.RLock()
_DEFAULT = [DEFAULT_MEMORY_BUDGET]
#: The last decision: (number of materials, how many got the fast decoder, bytes, budget).
LAST_PLAN: list = [None]


def default_budget() -> int:
    """The budget a material loaded now takes when its scene states none, in bytes."""
    return _DEFAULT[0]


@contextlib.contextmanager
def memory_budget(nbytes: int | None):
    """Within the block, materials loaded without a ``memory_budget`` property take
    ``nbytes`` (None: the default, :data:`~sparse_brdf.decoders.scene.DEFAULT_MEMORY_BUDGET`)."""
    with _LOCK:
        old = _DEFAULT[0]
        _DEFAULT[0] = DEFAULT_MEMORY_BUDGET if nbytes is None else int(nbytes)
    try:
        yield
    finally:
        with _LOCK:
            _DEFAULT[0] = old


def enroll(material) -> None:
    """Add ``material`` (the :class:`~mitsuba_plugin.sparse_buffers.SparseBuffers` of a
    ``sparse_brdf`` with ``decoder="auto"``) to the waiting pool."""
    with _LOCK:
        _POOL.append(weakref.ref(material))


def resolve(bsdf=None) -> None:
    """Decide and build the decoders of the pool that ``bsdf`` (a ``sparse_brdf``, or its
    :class:`~mitsuba_plugin.sparse_buffers.SparseBuffers`) waits in (nothing if it is
    already built; None: the pool, if any material waits). Each member's ``cost()``
    gives its :class:`~sparse_brdf.decoders.scene.MaterialCost`; ``build(decoder)``
    builds it. A scene loader calls it once the scene is loaded, so that the buffers
    are built there rather than inside the first render."""
    material = getattr(bsdf, "buffers", bsdf)
    with _LOCK:
        if material is not None and not getattr(material, "pending", False):
            return
        members = [m for m in (r() for r in _POOL) if m is not None and m.pending]
        if material is not None and not any(m is material for m in members):
            members.append(material)
        _POOL.clear()
        if not members:
            return
        costs = [m.cost() for m in members]
        budget = min(m.budget for m in members)
        choice = plan_decoders(costs, budget)
        for m, dec in zip(members, choice, strict=True):
            m.build(dec)
        held = sum(m.memory_bytes for m in members)
        n_fast = choice.count("grouped")
        LAST_PLAN[0] = (len(members), n_fast, held, budget)
    _log(f"sparse_brdf: {len(members)} auto material(s) under a memory budget of "
         f"{budget / 2**20:.1f} MiB: {n_fast} on the grouped decoder, "
         f"{len(members) - n_fast} on the strict decoder, {held / 2**20:.2f} MiB of "
         f"per-material data")


def _log(message: str) -> None:
    import mitsuba as mi  # lazy: `import mitsuba_plugin` does not load Mitsuba

    mi.Log(mi.LogLevel.Info, message)
