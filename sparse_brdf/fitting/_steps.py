"""The steps of a fit to images: the views' loss and gradient by differentiable rendering,
an Adam or L-BFGS step, the prior toward the starting coefficients, and the monitor of
the fit's SNR, and the fit's checkpoints (``docs/fit-images.md``).

Mitsuba, Dr.Jit and SciPy are slow to import: they are imported inside the functions that
use them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UsageError
from ..fileio import atomic_path

#: Keys under which the plugin exposes the coded channels' values (``mi.traverse``).
VALUE_KEYS = ("values_0", "values_1", "values_2")


@dataclass
class FitScene:
    scene: object
    params: object
    keys: list
    reference: object  # mi.TensorXf
    norm: float
    seed: int


def write_checkpoint(path: Path, it: int, opt, snr: list[float], fp: str,
                      extra: Mapping[str, np.ndarray] | None = None) -> None:
    arrays = {"iteration": np.array(it), "snr_db": np.array(snr, np.float64),
              "fingerprint": np.array(fp), **(extra or {})}
    for c, key in enumerate(VALUE_KEYS):
        value, _, _, extra = opt.state[key]
        arrays[f"u{c}"] = np.array(value, np.float32)
        arrays[f"t{c}"] = np.array(extra[0], np.uint32).reshape(-1)[:1]  # a UInt, width 1
        arrays[f"m{c}"] = np.array(extra[1], np.float32)
        arrays[f"v{c}"] = np.array(extra[2], np.float32)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def read_checkpoint(path: Path, opt, fp: str):
    """(iteration, snr history, every array of the file) restored into ``opt``; a
    checkpoint of another fit is refused in one line."""
    import mitsuba as mi  # lazy: Mitsuba is slow to import (see the module doc)

    try:
        with np.load(path) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: unreadable checkpoint ({exc}): delete it to start over") from exc
    if str(data.get("fingerprint")) != fp:
        raise UsageError(f"{path}: a checkpoint of another fit (other scene, views, start "
                         "file or settings): delete it or use another --checkpoint-dir")
    for c, key in enumerate(VALUE_KEYS):
        opt[key] = mi.Float(data[f"u{c}"])
        value, promoted, lr, extra = opt.state[key]
        extra = (mi.UInt32(data[f"t{c}"]), mi.Float(data[f"m{c}"]), mi.Float(data[f"v{c}"]),
                 *extra[3:])
        opt.state[key] = (value, promoted, lr, extra)
    return int(data["iteration"]), [float(x) for x in data["snr_db"]], data


class _BudgetSpent(Exception):
    """Raised inside the L-BFGS objective once the evaluation budget is spent."""


def _evaluate(views: list[FitScene], values: Sequence[np.ndarray], seed: int, grad_seed: int,
              spp: int, log_loss: bool = False) -> tuple[float, list]:
    """The loss at ``values`` (the three channels' values, host arrays) and its gradient
    (three Dr.Jit Floats): the mean over the views of the relative squared error, or with
    ``log_loss`` the mean of its natural logarithm (then every view weighs by its own
    error, as the mean of the views' SNRs in dB does; :func:`_snr_of`).

    Per view: a primal render (the view's seed, ``seed`` unless it has its own), the
    loss's image gradient
    ``2 (img - ref) / sum ref^2``, and the integrator's ``render_backward`` with seed
    ``grad_seed`` (the primal's for the shared-path gradient, the exact gradient of the
    very estimate the loss compares), which accumulates d loss / d values on the
    plugin's parameters. The values reach every view as the same host arrays: each
    view's plugin rebuilds its buffers from them (the later views reuse the first one's
    build)."""
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)
    import mitsuba as mi

    losses = []
    grads = [dr.zeros(mi.Float, len(v)) for v in values]
    for i, v in enumerate(views):
        for key, host in zip(v.keys, values, strict=True):
            val = mi.Float(np.asarray(host, np.float32))
            dr.enable_grad(val)
            v.params[key] = val
        v.params.update()
        with dr.suspend_grad():
            img = mi.render(v.scene, spp=spp, seed=v.seed)
            diff = img - v.reference
            loss = float(np.asarray(dr.sum(dr.square(diff), axis=None)).ravel()[0]) / v.norm
        g_img = diff * (2.0 / (v.norm * len(views) * (max(loss, 1e-30) if log_loss
                                                       else 1.0)))
        v.scene.integrator().render_backward(v.scene, v.params, g_img,
                                             seed=grad_seed + i if grad_seed != seed
                                             else v.seed, spp=spp)
        for c, key in enumerate(v.keys):
            grads[c] = grads[c] + dr.grad(v.params[key])
            dr.disable_grad(v.params[key])
        losses.append(loss)
    if log_loss:
        return float(np.mean(np.log(np.maximum(losses, 1e-30)))), grads
    return float(np.mean(losses)), grads


def _primal_loss(views: list[FitScene], values: Sequence[np.ndarray], spp: int,
                 log_loss: bool = False) -> float:
    """The views' mean relative squared error ``sum (img - ref)^2 / sum ref^2`` at
    ``values``, or (``log_loss``) the mean of its natural logarithm, as in
    :func:`_evaluate` (primal renders only, each at its view's seed)."""
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)
    import mitsuba as mi

    losses = []
    for v in views:
        for key, host in zip(v.keys, values, strict=True):
            v.params[key] = mi.Float(np.asarray(host, np.float32))
        v.params.update()
        with dr.suspend_grad():
            img = mi.render(v.scene, spp=spp, seed=v.seed)
            err = dr.sum(dr.square(img - v.reference), axis=None)
        losses.append(float(np.asarray(err).ravel()[0]) / v.norm)
    if log_loss:
        return float(np.mean(np.log(np.maximum(losses, 1e-30))))
    return float(np.mean(losses))


class Monitor:
    """Every ``every`` evaluations: ``callback(evaluations, values)`` (three float32
    arrays) and the SNR (dB, in the form of the fit's loss, :func:`_snr_of`: of
    the views' mean relative squared error) of the validation ``views`` at the iterate;
    keeps the iterate they like best (early stopping on views the fit never sees)."""

    def __init__(self, views: list[FitScene], callback, every: int, spp: int,
                 log_loss: bool = False) -> None:
        self.views, self.callback, self.every, self.spp = views, callback, every, spp
        self.log_loss = log_loss
        self.record: list[tuple[int, float]] = []
        self.best: tuple[float, int, list[np.ndarray]] | None = None
        self.last: int | None = None

    def __call__(self, n: int, values: Sequence[np.ndarray], force: bool = False) -> None:
        if (n % self.every and not force) or n == self.last:
            return
        self.last = n
        values = [np.array(v, np.float32) for v in values]
        if self.callback is not None:
            self.callback(n, [v.copy() for v in values])
        if self.views:
            snr = _snr_of(_primal_loss(self.views, values, self.spp, self.log_loss),
                          self.log_loss)
            self.record.append((n, snr))
            if self.best is None or snr > self.best[0]:
                self.best = (snr, n, values)

    def state(self) -> dict[str, np.ndarray]:
        """Its record and best iterate as checkpoint arrays (none without views)."""
        if not self.views or self.best is None:
            return {}
        return {"val_n": np.array([n for n, _ in self.record], np.int64),
                "val_snr": np.array([x for _, x in self.record], np.float64),
                "val_best": np.array(self.best[:2], np.float64),
                **{f"val_best{c}": v for c, v in enumerate(self.best[2])}}

    def restore(self, data: Mapping[str, np.ndarray], done: int) -> None:
        """Its record and best iterate from a checkpoint's arrays (:meth:`state`)."""
        self.last = done
        if not self.views or "val_best" not in data:
            return
        self.record = [(int(n), float(x)) for n, x in zip(data["val_n"], data["val_snr"],
                                                          strict=True)]
        snr, n = (float(x) for x in data["val_best"])
        self.best = (snr, int(n), [np.array(data[f"val_best{c}"], np.float32)
                                   for c in range(len(VALUE_KEYS))])


def _prior(u: np.ndarray, u0: np.ndarray | None, weight: float) -> tuple[float, np.ndarray]:
    """The penalty ``weight * mean((u - u0)^2)`` on the relative values ``u`` (``u0`` at
    the start: 1, or less for a value below its channel's scale floor) and its
    gradient."""
    d = np.asarray(u, np.float64) - (1.0 if u0 is None else u0)
    return float(weight * np.mean(np.square(d))), (2.0 * weight / max(d.size, 1)) * d


def _snr_of(objective: float, log_loss: bool = False) -> float:
    """The SNR (dB) an objective of :func:`_evaluate` stands for: of the views' mean
    relative error, or (``log_loss``) the mean of the views' SNRs."""
    if log_loss:
        return float(-10.0 * objective / np.log(10.0))
    return float(-10.0 * np.log10(max(objective, 1e-30)))


def take_step(views: list[FitScene], opt, scales, seed: int, grad_seed: int, spp: int,
          log_loss: bool = False, prior_weight: float = 0.0,
          u0: np.ndarray | None = None) -> float:
    """One Adam step over all views (:func:`_evaluate`, then the chain rule through
    ``scale * u``, plus the gradient of :func:`_prior`); returns their mean whole-image
    SNR (dB) before it (of the views' loss, without the prior)."""
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)
    import mitsuba as mi

    # the values, evaluated once per step for all views
    values = [np.array(dr.detach(opt[name]) * s, np.float32)
              for name, s in zip(VALUE_KEYS, scales, strict=True)]
    loss, grads = _evaluate(views, values, seed, grad_seed, spp, log_loss)
    us = [np.array(dr.detach(opt[name]), np.float64) for name in VALUE_KEYS]
    _, pg = _prior(np.concatenate(us), u0, prior_weight)
    pgs = np.split(pg, np.cumsum([len(u) for u in us])[:-1])
    for name, g, s, p in zip(VALUE_KEYS, grads, scales, pgs, strict=True):
        dr.set_grad(opt[name], g * s + mi.Float(p.astype(np.float32)))
    opt.step()
    return _snr_of(loss, log_loss)


def _lbfgs(views: list[FitScene], u0: np.ndarray, scales: np.ndarray, sizes: list[int],
           evaluations: int, seed: int, spp: int, on_eval,
           log_loss: bool = False, prior_weight: float = 0.0,
           centre: np.ndarray | None = None) -> np.ndarray:
    """Minimise the loss over ``u`` (values = ``scales * u``, the three channels
    concatenated) with SciPy's L-BFGS-B, at most ``evaluations`` loss-and-gradient
    evaluations (each renders every view once, forward and backward: an Adam iteration's
    cost). The shared-path loss is a smooth deterministic function of the values, which
    is what a quasi-Newton method needs; the objective adds :func:`_prior` (about
    ``centre``, the start's ``u``) to the loss.
    ``on_eval(u, loss, objective)`` sees every evaluation. Returns the ``u`` of the best
    objective evaluated."""
    from scipy.optimize import minimize  # lazy: SciPy is slow to import

    cuts = np.cumsum(sizes)[:-1]
    best = {"loss": np.inf, "u": u0.copy(), "n": 0}

    def fun(u):
        if best["n"] >= evaluations:  # the budget is spent: stop the line search here
            raise _BudgetSpent
        values = np.split((u * scales).astype(np.float32), cuts)
        loss, grads = _evaluate(views, values, seed, seed, spp, log_loss)
        g = np.concatenate([np.asarray(x, np.float64) for x in grads]) * scales
        penalty, pg = _prior(u, centre, prior_weight)
        objective, g = loss + penalty, g + pg
        best["n"] += 1
        if objective < best["loss"]:
            best["loss"], best["u"] = objective, u.copy()
        on_eval(u, loss, objective)
        return objective, g

    while best["n"] < evaluations:  # restarted from the best point if a line search fails
        before = (best["n"], best["loss"])
        try:
            minimize(fun, best["u"].astype(np.float64), jac=True, method="L-BFGS-B",
                     options={"maxfun": evaluations + 1, "maxiter": evaluations,
                              "maxcor": 20, "ftol": 0.0, "gtol": 0.0})
        except _BudgetSpent:
            break
        if best["loss"] >= before[1] or best["n"] == before[0]:
            break  # no progress from a fresh start: converged to rounding
    return best["u"]


def run_lbfgs(scenes, opt, scales, done, iterations, snr, seed, spp, bar, ckpt, every,
               fp, log_loss, prior_weight, u0, monitor) -> None:
    """The L-BFGS fit from ``opt``'s values (``u``), writing the best ``u`` back into
    ``opt`` and, every ``every`` evaluations, into the checkpoint (Adam's moments are
    written as zeros: an L-BFGS checkpoint only ever resumes an L-BFGS fit); ``monitor``
    sees the best ``u`` so far at its own cadence."""
    import drjit as dr  # lazy: Dr.Jit is slow to import (see the module doc)
    import mitsuba as mi

    us = [np.array(dr.detach(opt[k]), np.float64) for k in VALUE_KEYS]
    sizes = [len(u) for u in us]
    sc = np.concatenate([np.array(s, np.float64) for s in scales])
    cuts = np.cumsum(sizes)[:-1]
    state = {"n": done, "best": np.inf, "u": np.concatenate(us)}

    def put(u):
        for k, part in zip(VALUE_KEYS, np.split(u, cuts), strict=True):
            opt[k] = mi.Float(part.astype(np.float32))

    def on_eval(u, loss, objective):
        snr.append(_snr_of(loss, log_loss))
        state["n"] += 1
        if objective < state["best"]:
            state["best"], state["u"] = objective, u.copy()
        monitor(state["n"], np.split(state["u"] * sc, cuts))
        bar.set_postfix(snr_db=f"{snr[-1]:.2f}")
        bar.update(1)
        if ckpt is not None and (state["n"] % every == 0 or state["n"] == iterations):
            put(state["u"])
            write_checkpoint(ckpt, state["n"], opt, snr, fp, monitor.state())

    u = _lbfgs(scenes, state["u"], sc, sizes, iterations - done, seed, spp, on_eval,
               log_loss, prior_weight, u0)
    monitor(state["n"], np.split(u * sc, cuts), force=True)  # the returned iterate
    put(u)
    if ckpt is not None and state["n"] > done:  # finished (or converged): a rerun is done
        write_checkpoint(ckpt, iterations, opt, snr, fp, monitor.state())
