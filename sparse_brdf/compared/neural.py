"""Neural-BRDF (Sztrajman et al. 2021) as a compared model: a small network fitted per material.

Sztrajman, Rainer, Ritschel, Weyrich, "Neural BRDF Representation and Importance
Sampling", Computer Graphics Forum 40(6), 2021. The network (:mod:`sparse_brdf.mlp`):
6 -> 21 -> 21 -> 3, ReLU, output exp(x) - 1; 675 float32 numbers (2700 bytes) per
material. :func:`train_nbrdf` fits it to a tabulated BRDF with the published recipe, in
numpy (hand-written backpropagation, float32, vectorised per batch):

- training set: ``n_samples`` (800,000) direction pairs drawn uniformly in (theta_h,
  theta_d, phi_d) over [0, pi/2) x [0, pi/2) x [0, pi), keeping only pairs whose two
  directions are above the horizon (drawn until there are ``n_samples`` of them);
- target at a drawn angle: the table's trilinear interpolation between the grid's samples
  (the bins' lower-edge angles, :func:`sparse_brdf.coords.linear_neighbours`; phi_d
  wraps, theta clamps), over the neighbours whose bin is valid, renormalised (a pair none
  of whose eight neighbours is valid is not drawn). Interpolation rather than the nearest
  bin: a table sampled at lower edges is a smooth function's samples, and the nearest
  sample of a continuous angle is up to one bin away (far in the specular peak); refits
  of two glossy demo networks rendered about 7 dB closer to the originals with it
  (``docs/benchmarks.md``, "Neural-BRDF");
- loss: mean over the batch and the three channels of
  |ln(1 + rho cos_i) - ln(1 + rho_hat cos_i)|, rho_hat = exp(z) - 1 unclipped;
- Adam (Keras' form and defaults: beta1 0.9, beta2 0.999, epsilon 1e-7) with learning
  rate 5e-4, batches of 512 in a fresh random order each epoch (the last one partial),
  100 epochs;
- initial weights: Keras' defaults, Glorot uniform kernels (U(-l, l), l = sqrt(6 /
  (n_in + n_out))) and zero biases.

Everything random comes from one ``numpy.random.Generator`` seeded by ``seed`` (the
training set, the initial weights, the batch orders), and BLAS runs on one thread, so a
seed gives the same weights bit for bit. ``time_budget`` stops training early (the
network as it then is); the result says so. Measured times are in ``docs/benchmarks.md``.

:class:`NBRDFModel` is the bench's ``nbrdf`` model (:mod:`sparse_brdf.compared.specs`).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coords import HALF_PI, cos_io, linear_neighbours
from ..mlp import (
    LAYER_SIZES,
    N_WEIGHTS,
    Layers,
    forward,
    network_inputs,
    params_from_layers,
    save_keras,
    tabulate,
)
from ..parallel import blas_single_thread
from ..params import SEED, Interval, check
from .compact import BRDFModel, Compact

#: The published recipe, the defaults of :func:`train_nbrdf` and :class:`NBRDFModel`.
RECIPE = {"epochs": 100, "batch_size": 512, "learning_rate": 5e-4, "n_samples": 800_000}
#: Every training option's range (``time_budget`` in seconds; None: no budget).
PARAMETERS = {"epochs": Interval(int, 1, 100_000), "batch_size": Interval(int, 1, 1 << 20),
              "learning_rate": Interval(float, 0.0, 1.0, closed="right"),
              "n_samples": Interval(int, 1, 1 << 26),
              "time_budget": Interval(float, 0.0, closed="neither"), "seed": SEED}
#: Adam's constants (Keras' defaults).
ADAM_BETAS, ADAM_EPSILON = (0.9, 0.999), 1e-7
#: Training samples on which the per-epoch loss is reported.
MONITOR = 1 << 14


@dataclass(repr=False)
class NeuralFit:
    """A trained Neural-BRDF network and how its training went.

    Attributes
    ----------
    layers : list of (kernel, bias)
        The network, float32: (6, 21) (21,), (21, 21) (21,), (21, 3) (3,).
    loss : list of float
        The loss after each finished epoch, on the first ``MONITOR`` training samples.
    epochs : int
        Epochs run (fewer than asked when the time budget stopped training).
    steps : int
        Adam steps taken.
    seconds : float
        Wall time of training, the training set's construction included.
    stopped_early : bool
        Whether ``time_budget`` stopped training before its last epoch.
    """

    layers: Layers
    loss: list[float] = field(default_factory=list)
    epochs: int = 0
    steps: int = 0
    seconds: float = 0.0
    stopped_early: bool = False

    def params(self) -> dict[str, np.ndarray]:
        """The network's stored numbers.

        Returns
        -------
        dict of str to ndarray
            ``w1`` (6, 21), ``b1`` (21,), ``w2`` (21, 21), ``b2`` (21,), ``w3`` (21, 3),
            ``b3`` (3,): float32 copies, 675 numbers in all.
        """
        return params_from_layers(self.layers)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the network as a Neural-BRDF ``.h5`` file, the published Keras layout
        (:func:`sparse_brdf.mlp.save_keras`, atomic), which ``load_brdf`` tabulates and
        the ``neural_brdf`` Mitsuba plugin renders; the weights read back bit for bit.

        Parameters
        ----------
        path : str or PathLike
            The file to write (replaced if it exists).

        Returns
        -------
        Path
            ``path``.

        Examples
        --------
        >>> train_nbrdf(brdf, time_budget=60).save("gold.h5")  # doctest: +SKIP
        """
        return save_keras(path, self.layers)

    def __repr__(self) -> str:
        last = f"{self.loss[-1]:.4g}" if self.loss else "n/a"
        return (f"NeuralFit({'x'.join(map(str, LAYER_SIZES))}, epochs={self.epochs}, "
                f"steps={self.steps}, loss={last}, seconds={self.seconds:.1f}"
                f"{', stopped early' if self.stopped_early else ''})")


def _draw_angles(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    u = rng.random((3, n))
    return u[0] * HALF_PI, u[1] * HALF_PI, u[2] * np.pi


def table_values(brdf: BRDF, theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """The table's trilinear interpolation at angles (1-D arrays of n, radians).

    Returns
    -------
    rho : ndarray of shape (n, 3), float64
        The weighted mean of the valid neighbouring samples (0 where none is valid).
    covered : ndarray of shape (n,), bool
        Where at least one of the eight neighbours is valid.
    """
    (i0, i1, ti), (j0, j1, tj), (k0, k1, tk) = linear_neighbours(theta_h, theta_d, phi_d,
                                                                 brdf.shape)
    acc = np.zeros((len(ti), 3))
    wsum = np.zeros(len(ti))
    for i, wi in ((i0, 1.0 - ti), (i1, ti)):
        for j, wj in ((j0, 1.0 - tj), (j1, tj)):
            for k, wk in ((k0, 1.0 - tk), (k1, tk)):
                w = wi * wj * wk * brdf.valid[i, j, k]
                acc += w[:, None] * brdf.values[i, j, k]
                wsum += w
    covered = wsum > 0.0
    return acc / np.where(covered, wsum, 1.0)[:, None], covered


def training_set(brdf: BRDF, n_samples: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The training samples (see the module doc): ``n_samples`` uniformly drawn angles
    with both directions above the horizon and a valid neighbour in the table.

    Returns
    -------
    x : ndarray of shape (n_samples, 6), float32
        The network's inputs.
    target : ndarray of shape (n_samples, 3), float32
        rho cos_i, the table's value times the cosine of the incident direction.
    cos_i : ndarray of shape (n_samples, 1), float32
    """
    parts: list[tuple[np.ndarray, ...]] = []
    have = 0
    while have < n_samples:
        th, td, pd = _draw_angles(rng, 2 * (n_samples - have) + 64)
        ci, co = cos_io(th, td, pd)
        up = (ci > 0.0) & (co > 0.0)
        th, td, pd, ci = th[up], td[up], pd[up], ci[up]
        rho, covered = table_values(brdf, th, td, pd)
        keep = np.flatnonzero(covered)[: n_samples - have]
        parts.append((th[keep], td[keep], pd[keep], ci[keep], rho[keep]))
        have += len(keep)
    th, td, pd, ci, rho = (np.concatenate(p) for p in zip(*parts, strict=True))
    return (network_inputs(th, td, pd), (rho * ci[:, None]).astype(np.float32),
            ci[:, None].astype(np.float32))


def glorot_layers(rng: np.random.Generator) -> Layers:
    """Keras' default initial weights: Glorot-uniform kernels, zero biases (float32)."""
    out = []
    for n_in, n_out in zip(LAYER_SIZES[:-1], LAYER_SIZES[1:], strict=True):
        lim = math.sqrt(6.0 / (n_in + n_out))
        out.append((rng.uniform(-lim, lim, (n_in, n_out)).astype(np.float32),
                    np.zeros(n_out, np.float32)))
    return out


class _Flat:
    """The network's weights and their gradient as views into two flat float32 vectors,
    so that Adam updates all 675 numbers with a few vector operations."""

    def __init__(self, layers: Layers) -> None:
        self.theta = np.empty(N_WEIGHTS, np.float32)
        self.grad = np.zeros(N_WEIGHTS, np.float32)
        self.layers, self.grads = self._views(self.theta), self._views(self.grad)
        for (k, b), (k0, b0) in zip(self.layers, layers, strict=True):
            k[...], b[...] = k0, b0

    @staticmethod
    def _views(v: np.ndarray) -> Layers:
        out, o = [], 0
        for n_in, n_out in zip(LAYER_SIZES[:-1], LAYER_SIZES[1:], strict=True):
            k = v[o : o + n_in * n_out].reshape(n_in, n_out)
            o += n_in * n_out
            out.append((k, v[o : o + n_out]))
            o += n_out
        return out

    def _ones(self, n: int) -> np.ndarray:
        if getattr(self, "_ones_row", np.empty((1, 0))).shape[1] != n:
            self._ones_row = np.ones((1, n), np.float32)
        return self._ones_row

    def gradient(self, x: np.ndarray, target: np.ndarray, cos_i: np.ndarray) -> None:
        """The loss's gradient on a batch into ``self.grad``.

        With q = rho_hat cos_i, rho_hat = exp(z) - 1: d|ln(1 + q) - ln(1 + q*)| / dz =
        sign(q - q*) cos_i exp(z) / (1 + q) (ln is increasing, so the sign is that of
        q - q*), averaged over the batch's n x 3 terms; then back through the layers.
        """
        acts, z = forward(self.layers, x)
        e = np.exp(z)
        q = e - 1.0
        q *= cos_i
        g = np.sign(q - target)
        g *= cos_i * np.float32(1.0 / z.size)
        g *= e
        q += 1.0
        g /= q
        ones = self._ones(len(x))
        for i in range(len(self.layers) - 1, -1, -1):
            (k, _), (gk, gb) = self.layers[i], self.grads[i]
            np.matmul(acts[i].T, g, out=gk)
            np.matmul(ones, g, out=gb[None])  # the column sums (faster than g.sum(0))
            if i:
                g = g @ k.T
                g *= acts[i] > 0.0  # ReLU's derivative


def loss(layers: Layers, x: np.ndarray, target: np.ndarray, cos_i: np.ndarray) -> float:
    """The training loss of ``layers`` on samples (see :func:`training_set` for the
    arrays): mean |ln(1 + rho cos_i) - ln(1 + rho_hat cos_i)| over samples and channels."""
    _, z = forward(layers, np.asarray(x, np.float32))
    q = np.expm1(z.astype(np.float64)) * cos_i
    return float(np.mean(np.abs(np.log1p(q) - np.log1p(target.astype(np.float64)))))


def loss_gradient(layers: Layers, x: np.ndarray, target: np.ndarray, cos_i: np.ndarray
                  ) -> Layers:
    """The gradient of :func:`loss` with respect to every kernel and bias, as the
    trainer computes it: a list of (d kernel, d bias) float32 pairs."""
    flat = _Flat(layers)
    flat.gradient(np.asarray(x, np.float32), np.asarray(target, np.float32),
                  np.asarray(cos_i, np.float32))
    return [(k.copy(), b.copy()) for k, b in flat.grads]


def _check(options: dict) -> dict:
    for key, value in options.items():
        if value is not None or key != "time_budget":
            options[key] = check(f"nbrdf {key}", value, PARAMETERS[key])
    return options


def train_nbrdf(brdf: BRDF, epochs: int = 100, batch_size: int = 512,
                learning_rate: float = 5e-4, n_samples: int = 800_000, seed: int = 0,
                time_budget: float | None = None, progress: bool = True) -> NeuralFit:
    """Fit a Neural-BRDF network (6 -> 21 -> 21 -> 3) to a tabulated BRDF.

    The published recipe of Sztrajman et al. 2021 (defaults), in numpy: samples drawn
    uniformly in (theta_h, theta_d, phi_d), targets interpolated trilinearly in the
    table, loss mean |ln(1 + rho cos_i) - ln(1 + rho_hat cos_i)|, Adam; see
    :mod:`sparse_brdf.compared.neural` for every detail.

    Parameters
    ----------
    brdf : BRDF
        The material: linear RGB values (1/sr) on any grid, shape (n_h, n_d, n_p, 3).
    epochs : int, default 100
        Passes over the training set.
    batch_size : int, default 512
        Samples per Adam step.
    learning_rate : float, default 5e-4
        Adam's learning rate.
    n_samples : int, default 800000
        Training samples (direction pairs above the horizon).
    seed : int, default 0
        Seeds the training set, the initial weights and the batch orders: the same seed
        gives the same weights.
    time_budget : float, optional
        Seconds of wall time (the training set included); training stops after the step
        that exceeds it, and the result's ``stopped_early`` says so. None: no limit.
    progress : bool, default True
        Show a tqdm progress bar over the epochs (with the loss), and a line when the
        time budget stops training.

    Returns
    -------
    NeuralFit
        The network (``layers``, 675 float32 numbers) and its training record.

    Raises
    ------
    UsageError
        An option outside its range (:data:`PARAMETERS`).

    Examples
    --------
    >>> fit = train_nbrdf(load_brdf("mitsuba:au-ggx-0.25"), time_budget=60)  # doctest: +SKIP
    >>> values, valid = sparse_brdf.mlp.tabulate(fit.layers)                  # doctest: +SKIP
    """
    opts = _check({"epochs": epochs, "batch_size": batch_size, "learning_rate": learning_rate,
                   "n_samples": n_samples, "seed": seed, "time_budget": time_budget})
    t0 = time.perf_counter()
    deadline = math.inf if time_budget is None else t0 + float(opts["time_budget"])
    rng = np.random.default_rng(opts["seed"])
    data = training_set(brdf, opts["n_samples"], rng)
    fit = NeuralFit(glorot_layers(rng))
    with blas_single_thread():
        _adam(fit, data, rng, opts, deadline, progress, brdf.name)
    fit.seconds = time.perf_counter() - t0
    return fit


class _Adam:
    """Adam on the flat weights, in Keras' form: m = b1 m + (1 - b1) g, v = b2 v +
    (1 - b2) g^2, theta -= lr sqrt(1 - b2^t) / (1 - b1^t) m / (sqrt(v) + eps)."""

    def __init__(self, flat: _Flat, learning_rate: float) -> None:
        self.flat, self.lr, self.t = flat, float(learning_rate), 0
        self.m, self.v, self.tmp = (np.zeros(N_WEIGHTS, np.float32) for _ in range(3))
        self.b1, self.b2 = (np.float32(b) for b in ADAM_BETAS)

    def step(self) -> None:
        """One update from ``flat.grad``."""
        g, m, v, tmp = self.flat.grad, self.m, self.v, self.tmp
        self.t += 1
        m *= self.b1
        np.multiply(g, 1.0 - self.b1, out=tmp)
        m += tmp
        v *= self.b2
        np.multiply(g, g, out=tmp)
        tmp *= 1.0 - self.b2
        v += tmp
        np.sqrt(v, out=tmp)
        tmp += np.float32(ADAM_EPSILON)
        np.divide(m, tmp, out=tmp)
        b1, b2 = ADAM_BETAS
        tmp *= np.float32(self.lr * math.sqrt(1.0 - b2 ** self.t) / (1.0 - b1 ** self.t))
        self.flat.theta -= tmp


def _adam(fit: NeuralFit, data, rng: np.random.Generator, opts: dict, deadline: float,
          progress: bool, name: str) -> None:
    """Adam over the epochs, the batches of each in a fresh random order; writes the
    weights and the record into ``fit``."""
    from tqdm.auto import tqdm  # lazy: tqdm.auto adds ~40 ms to `import sparse_brdf`

    x, target, cos_i = data
    flat = _Flat(fit.layers)
    adam = _Adam(flat, opts["learning_rate"])
    bs, n, epochs = opts["batch_size"], len(x), opts["epochs"]
    mon = slice(0, min(n, MONITOR))
    bar = tqdm(total=epochs, desc=f"nbrdf {name}", unit="epoch", disable=not progress,
               leave=False)
    out_of_time = False
    while fit.epochs < epochs and not out_of_time:
        order = rng.permutation(n)
        xs, ts, cs = (np.take(a, order, axis=0) for a in (x, target, cos_i))
        for s in range(0, n, bs):
            flat.gradient(xs[s : s + bs], ts[s : s + bs], cs[s : s + bs])
            adam.step()
            if time.perf_counter() > deadline:
                out_of_time = True
                break
        fit.steps = adam.t
        if s + bs >= n:  # the epoch finished
            fit.epochs += 1
            fit.loss.append(loss(flat.layers, x[mon], target[mon], cos_i[mon]))
            bar.set_postfix(loss=f"{fit.loss[-1]:.4g}")
            bar.update()
    bar.close()
    fit.layers = [(k.copy(), b.copy()) for k, b in flat.layers]
    fit.stopped_early = fit.epochs < epochs
    if fit.stopped_early and progress:
        tqdm.write(f"nbrdf {name}: time budget of {opts['time_budget']:g} s reached after "
                   f"{fit.epochs} of {epochs} epochs ({fit.steps} steps)")


class NBRDFModel(BRDFModel):
    """Neural-BRDF (Sztrajman et al. 2021): a 6-21-21-3 network per material, 675
    float32 numbers (2700 bytes), trained by :func:`train_nbrdf`.

    ``compress(brdf)`` trains a network on the BRDF's table and returns a
    :class:`~sparse_brdf.compared.compact.Compact` whose ``params`` are the network
    (``w1, b1, w2, b2, w3, b3``), whose ``reconstruct()`` is the network on the BRDF's
    grid (at the bins' lower-edge angles, 0 below the horizon) and whose ``info`` holds
    the training record (``epochs``, ``steps``, ``train_s``, ``loss``, ``stopped_early``).
    Float16 storage is not offered.

    Parameters
    ----------
    epochs, batch_size, learning_rate, n_samples, seed, time_budget
        :func:`train_nbrdf`'s options (the published recipe by default; no time budget).
    progress : bool, default True
        Show the trainer's progress bar.
    """

    def __init__(self, epochs: int = 100, batch_size: int = 512, learning_rate: float = 5e-4,
                 n_samples: int = 800_000, seed: int = 0, time_budget: float | None = None,
                 progress: bool = True) -> None:
        self.options = _check({"epochs": epochs, "batch_size": batch_size,
                               "learning_rate": learning_rate, "n_samples": n_samples,
                               "seed": seed, "time_budget": time_budget})
        self.progress = bool(progress)
        self.name = nbrdf_name(self.options)

    def compress(self, brdf: BRDF) -> Compact:
        fit = train_nbrdf(brdf, **self.options, progress=self.progress)
        values, _ = tabulate(fit.layers, brdf.shape)
        info = {"epochs": fit.epochs, "steps": fit.steps, "train_s": fit.seconds,
                "loss": fit.loss[-1] if fit.loss else None,
                "stopped_early": fit.stopped_early}
        params = fit.params()
        return Compact(self.name, sum(int(p.nbytes) for p in params.values()), lambda: values,
                       info, params)


def nbrdf_name(options: dict) -> str:
    """``nbrdf``, then ``-KEY=VALUE`` for each option of :data:`PARAMETERS` not at its
    default (the recipe's, seed 0, no time budget), in that order."""
    defaults = {**RECIPE, "time_budget": None, "seed": 0}
    return "nbrdf" + "".join(f"-{k}={options[k]:g}" for k in PARAMETERS
                             if options.get(k, defaults[k]) != defaults[k])
