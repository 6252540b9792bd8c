"""Evaluation speed of BRDF models: evaluations per second at random direction pairs.

Every model is timed with its own evaluator, never through a dense table:

- ``sparse`` (a :class:`~sparse_brdf.coding.coefficients.SparseBRDF`, or the ``Compact`` of
  :class:`~sparse_brdf.compared.sparse_model.SparseModel`): the ``sparse_brdf`` Mitsuba plugin's
  ``eval``, with the ``grouped`` or ``strict`` decoder;
- ``tabulated`` (a :class:`~sparse_brdf.brdf.BRDF`, or the ``Compact`` of
  :class:`~sparse_brdf.compared.baselines.TabulatedModel`): the ``tabulated_brdf``
  plugin's ``eval``;
- ``naive``, ``cpd``, ``tucker``, ``pca``, ``nbrdf`` (their ``Compact``): the Dr.Jit
  evaluators of :mod:`mitsuba_plugin.evaluators`, computed from the model's stored
  ``params`` (for ``nbrdf``, the network itself at each pair).

The plugins' ``eval`` includes the cosine factor and the evaluators do not; that one
multiplication is part of the cost. Mitsuba is imported only when a function is called.

>>> from sparse_brdf.compared.baselines import NaiveModel
>>> rate = evals_per_second(NaiveModel().compress(brdf))     # doctest: +SKIP
>>> f"{rate / 1e6:.0f} M evaluations/s"                 # doctest: +SKIP
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coding.coefficients import SparseBRDF
from ..coding.fileformat import save_sbrdf
from ..compared.compact import Compact
from ..coords import geometric_valid
from ..decoders.layouts import DECODERS
from ..evaluation.render import SHARED_PATHS
from ..mitsuba_env import variant as use_variant
from ..params import check_choice
from ..sources.merl import write_merl

#: Model kinds :func:`evals_per_second` times (the part of ``Compact.model`` before ``-``).
KINDS = ("tabulated", "sparse", "naive", "cpd", "tucker", "pca", "nbrdf")


def random_directions(n: int, rng: np.random.Generator):
    """``n`` random direction pairs, uniform on the upper hemisphere (local frame).

    Returns ``(si, wo)``: a ``mi.SurfaceInteraction3f`` of width ``n`` whose ``wi`` holds
    the incident directions (and ``sh_frame`` the identity frame), and a ``mi.Vector3f``
    of the ``n`` outgoing directions. Needs a JIT Mitsuba variant to be set.
    """
    import drjit as dr  # lazy: Dr.Jit and Mitsuba are slow to import (see the module doc)
    import mitsuba as mi

    v = rng.standard_normal((2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(v[0].T.astype(np.float32))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    return si, mi.Vector3f(v[1].T.astype(np.float32))


#: How far one noisy timing may move a median rate: each neighbour of the median (in
#: sorted order) lies within this fraction of it before timing stops.
SETTLE = 0.10
#: Most timed calls of one measurement (it stops earlier once settled).
MAX_REPEATS = 41


@dataclass(frozen=True)
class Rate:
    """Evaluations per second of one measurement: the ``median`` of the timed calls' rates,
    their ``min`` and ``max``, the calls timed (``repeats``), the pairs per call (``n``)
    and whether the median ``settled`` (:func:`settled`) before :data:`MAX_REPEATS`."""

    median: float
    min: float
    max: float
    repeats: int
    n: int
    settled: bool

    def spread(self) -> dict:
        """``min``, ``max``, ``repeats``, ``n`` and ``settled``, as results record them."""
        return {"min": self.min, "max": self.max, "repeats": self.repeats, "n": self.n,
                "settled": self.settled}


def settled(rates, tolerance: float = SETTLE) -> bool:
    """Whether no single timing can move the median of ``rates`` (an odd count) by more
    than ``tolerance``: whatever one value becomes, the median becomes one of its
    neighbours in sorted order, so both must lie within ``tolerance`` of it."""
    r = np.sort(np.asarray(rates, float))
    if len(r) < 3 or len(r) % 2 == 0:
        return False
    k = len(r) // 2
    return bool(r[k + 1] - r[k] <= tolerance * r[k] and r[k] - r[k - 1] <= tolerance * r[k])


def timed_rate(call: Callable[[], Callable[[], object]], n: int, repeats: int = 5,
               clock: Callable[[], float] = time.perf_counter,
               max_repeats: int = MAX_REPEATS) -> Rate:
    """Time ``call`` until its median rate has settled (see :func:`settled`).

    ``call()`` prepares one call (untimed) and returns the work to time; the first one
    warms up (compiles) and is not timed. At least ``repeats`` calls are timed, then more
    until their count is odd and the median settled, at most ``max_repeats``.
    ``clock`` is the timer (seconds), to be replaced in tests. Rates are ``n`` over each
    call's seconds.
    """
    call()()  # warm-up: the first call compiles
    rates: list[float] = []
    while len(rates) < max_repeats:
        work = call()
        t0 = clock()
        work()
        rates.append(n / max(clock() - t0, 1e-12))
        if len(rates) >= repeats and settled(rates):
            break
    return Rate(float(np.median(rates)), min(rates), max(rates), len(rates), n,
                settled(rates))


def time_evaluations(evaluate: Callable, n: int = 1 << 20, repeats: int = 5,
                     seed: int = 0) -> Rate:
    """Evaluations per second of ``evaluate(si, wo)`` (which returns Dr.Jit arrays).

    Each call gets ``n`` fresh random pairs from :func:`random_directions` (so Dr.Jit
    cannot reuse an earlier result), made and evaluated before the clock starts. A call
    is timed from the Python call (tracing included) until its kernel has run
    (``dr.eval`` then ``dr.sync_thread``). The first call compiles and is not timed; at
    least ``repeats`` are, and more until one noisy call could not move the median by
    more than :data:`SETTLE` (:func:`timed_rate`).
    """
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)

    n, repeats = _check_counts(n, repeats)
    rng = np.random.default_rng(seed)

    def call():
        si, wo = random_directions(n, rng)
        dr.eval(si, wo)
        dr.sync_thread()

        def work():
            dr.eval(evaluate(si, wo))
            dr.sync_thread()

        return work

    return timed_rate(call, n, repeats)


def eval_rate(bsdf, n: int = 1 << 20, repeats: int = 5, seed: int = 0) -> float:
    """``bsdf.eval`` calls per second (a loaded Mitsuba BSDF) at ``n`` random
    upper-hemisphere pairs: :func:`time_evaluations` of ``bsdf.eval(ctx, si, wo)``."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    ctx = mi.BSDFContext()
    return time_evaluations(lambda si, wo: bsdf.eval(ctx, si, wo), n, repeats, seed).median


def evals_per_second(model, n: int = 1 << 20, repeats: int = 5, ensemble=None, *,
                     decoder: str = "grouped", variant: str = "llvm_ad_rgb",
                     seed: int = 0) -> float:
    """Evaluations per second of ``model`` with its own evaluator (see the module doc):
    the median of :func:`measure_speed`."""
    return measure_speed(model, n, repeats, ensemble, decoder=decoder, variant=variant,
                         seed=seed).median


def measure_speed(model, n: int = 1 << 20, repeats: int = 5, ensemble=None, *,
                  decoder: str = "grouped", variant: str = "llvm_ad_rgb",
                  seed: int = 0) -> Rate:
    """Evaluations per second of ``model`` with its own evaluator, with their spread.

    Parameters
    ----------
    model : Compact, SparseBRDF, BRDF or CompressedBRDF
        A fitted :class:`~sparse_brdf.compared.compact.Compact` of any baseline kind (naive,
        cpd, tucker, pca, nbrdf, tabulated, sparse), a sparse model, a tabulated BRDF, or
        any compressed material with a ``drjit_evaluator()``
        (:mod:`sparse_brdf.compared.protocol`).
    n : int, default 2**20
        Random upper-hemisphere direction pairs per timed call.
    repeats : int, default 5
        Fewest timed calls (after one untimed call that compiles the kernel); more are
        timed until one noisy call could not move the median by more than
        :data:`SETTLE`, at most :data:`MAX_REPEATS`.
    ensemble : Ensemble, optional
        Sparse models only: the ensemble the model was encoded with (default: the
        shipped one).
    decoder : {"grouped", "strict", "auto"}, default "grouped"
        Sparse models only: the ``sparse_brdf`` plugin's decoder.
    variant : str, default "llvm_ad_rgb"
        The (JIT) Mitsuba variant to time in; the previous variant is restored after.
    seed : int, default 0
        Seed of the random directions.

    Returns
    -------
    Rate
        Evaluations (one RGB value of one direction pair) per second of wall time, on
        every core Dr.Jit uses: the median over the timed calls, their min and max.
    """
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)

    n, repeats = _check_counts(n, repeats)
    check_choice("decoder", decoder, DECODERS)
    if not variant.startswith(("llvm", "cuda")):
        raise ValueError(f"variant={variant!r}: timing needs a JIT variant (llvm_* or cuda_*)")
    with use_variant(variant):
        evaluate = _evaluator(model, ensemble, decoder)
        rate = time_evaluations(evaluate, n, repeats, seed)
        del evaluate
        dr.sync_thread()
    return rate


# ----------------------------------------------------------------------------- helpers


def _check_counts(n, repeats) -> tuple[int, int]:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be a positive integer (direction pairs), got {n!r}")
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    return int(n), int(repeats)


def _kind(model) -> str:
    if isinstance(model, Compact):
        kind = model.kind
        if kind not in KINDS:
            raise ValueError(f"{model.model}: no evaluator for model kind {kind!r} "
                             f"(expected one of {', '.join(KINDS)})")
        return kind
    if isinstance(model, SparseBRDF):
        return "sparse"
    if isinstance(model, BRDF):
        return "tabulated"
    raise TypeError(f"model must be a Compact, SparseBRDF or BRDF, got {type(model).__name__}")


def _evaluator(model, ensemble, decoder: str) -> Callable:
    """``evaluate(si, wo)`` of ``model`` in the current variant (a plugin's ``eval`` or
    an evaluator's)."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    import mitsuba_plugin  # lazy: imports Mitsuba and Dr.Jit

    if callable(getattr(model, "drjit_evaluator", None)):  # an outside model's own
        own = model.drjit_evaluator()
        return lambda si, wo: own.eval(si.wi, wo)
    kind = _kind(model)
    if kind in ("sparse", "tabulated"):
        mitsuba_plugin.register()
        with tempfile.TemporaryDirectory(prefix="sparse-brdf-speed-") as tmp:
            bsdf = mi.load_dict(_plugin_dict(model, kind, ensemble, decoder, Path(tmp)))
        ctx = mi.BSDFContext()
        return lambda si, wo: bsdf.eval(ctx, si, wo)
    from mitsuba_plugin.evaluators import evaluator_for  # lazy: imports Mitsuba and Dr.Jit

    ev = evaluator_for(model)
    return lambda si, wo: ev.eval(si.wi, wo)


def _plugin_dict(model, kind: str, ensemble, decoder: str, tmp: Path) -> dict:
    """The ``mi.load_dict`` dictionary of a sparse or tabulated model, its files in
    ``tmp`` (the plugins read them at load time)."""
    if kind == "tabulated":
        if isinstance(model, Compact):
            if model.params is None or "table" not in model.params:
                raise ValueError(f"{model.model}: a tabulated Compact needs params['table']")
            table = model.params["table"]
            model = BRDF(table, geometric_valid(tuple(table.shape[:3])), name=model.model)
        return {"type": "tabulated_brdf", "sampling": SHARED_PATHS,
                "filename": str(write_merl(tmp / "table.binary", model))}
    if isinstance(model, Compact):
        if not model.info or "model" not in model.info:
            raise ValueError(f"{model.model}: a sparse Compact needs info['model']")
        model = model.info["model"]
    out = {"type": "sparse_brdf", "decoder": decoder, "sampling": SHARED_PATHS,
           "filename": str(save_sbrdf(tmp / "model.sbrdf", model))}
    if ensemble is not None:
        out["ensemble"] = str(ensemble.save(tmp / "ensemble.npz"))
    return out


def format_rate(rate: float) -> str:
    """Evaluations per second as ``"12.3 M"`` (or ``"n/a"`` if not finite)."""
    return f"{rate / 1e6:.1f} M" if math.isfinite(rate) else "n/a"


__all__ = ["DECODERS", "KINDS", "MAX_REPEATS", "SETTLE", "Rate", "random_directions",
           "settled", "timed_rate", "time_evaluations", "eval_rate", "evals_per_second",
           "measure_speed", "format_rate"]
