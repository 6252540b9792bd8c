"""The Neural-BRDF network (Sztrajman et al. 2021): its inputs, forward pass and table.

One small multilayer perceptron per material, dense layers 6 -> 21 -> 21 -> 3: ReLU after
the two hidden layers, and an output of exp(x) - 1, evaluated as max(exp(x) - 1, 0) (a
BRDF is not negative). Its input is the Cartesian half vector and difference vector of a
direction pair with phi_h = 0, ``(hx, hy, hz, dx, dy, dz)`` =
``(sin th, 0, cos th, sin td cos pd, sin td sin pd, cos td)``
(:func:`sparse_brdf.coords.half_diff_vectors`), phi_d folded into [0, pi); its output is
the linear RGB BRDF value (1/sr). The network is ``layers``, a list of three ``(kernel,
bias)`` float32 pairs, kernel (n_in, n_out) and bias (n_out,), applied as ``x @ kernel +
bias`` (Keras' convention).

A network is stored in the published Keras HDF5 layout (:data:`KERAS_LAYERS`), written by
:func:`save_keras` and read by :mod:`sparse_brdf.sources.nbrdf` (the shipped networks).
The same formulas serve those networks, the trainer (:mod:`sparse_brdf.compared.neural`,
which backpropagates through :func:`forward`) and the networks' tables
(:func:`tabulate`); the Mitsuba plugin's ``nbrdf`` evaluator and ``neural_brdf`` BSDF are
their Dr.Jit twin (``mitsuba_plugin.kernels.nbrdf_rho``).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from .coords import MERL_SHAPE, geometric_valid, grid_angles, half_diff_vectors
from .fileio import atomic_path
from .parallel import parallel_map

#: The published architecture's widths: input, two hidden layers, output.
LAYER_SIZES: tuple[int, ...] = (6, 21, 21, 3)
#: Its number of weights and biases (675).
N_WEIGHTS: int = sum(a * b + b for a, b in zip(LAYER_SIZES[:-1], LAYER_SIZES[1:], strict=False))

#: The dense layers' names in a Keras HDF5 file of the network: layer ``name``'s kernel
#: and bias are the datasets ``name/name/kernel:0`` and ``name/name/bias:0``.
KERAS_LAYERS: tuple[str, ...] = ("dense_1", "dense_2", "dense_3")

Layers = list[tuple[np.ndarray, np.ndarray]]


def network_inputs(theta_h, theta_d, phi_d) -> np.ndarray:
    """The network's inputs at angles (radians, any matching shapes; phi_d in [0, pi)).

    Returns
    -------
    ndarray of shape (n, 6), float32
        ``(hx, hy, hz, dx, dy, dz)`` per angle triple, flattened in C order.
    """
    h, d = half_diff_vectors(*np.broadcast_arrays(theta_h, theta_d, phi_d))
    return np.concatenate([h, d], axis=-1).reshape(-1, 6).astype(np.float32)


def forward(layers: Layers, x: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """The network's pass on inputs ``x``, keeping what backpropagation needs.

    Parameters
    ----------
    layers : list of (kernel, bias)
        The dense layers, float32.
    x : ndarray of shape (n, 6), float32
        Inputs (:func:`network_inputs`).

    Returns
    -------
    acts : list of ndarray
        The input of each layer: ``[x, h1, h2]``, h1 and h2 (n, width) after their ReLU.
    z : ndarray of shape (n, 3), float32
        The last layer's output before exp(z) - 1.
    """
    acts = [x]
    h = x
    for i, (k, b) in enumerate(layers):
        h = h @ k
        h += b
        if i < len(layers) - 1:
            np.maximum(h, 0.0, out=h)
            acts.append(h)
    return acts, h


def evaluate(layers: Layers, x: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """The BRDF values of the network at inputs ``x`` (n, 6): max(exp(z) - 1, 0), (n, 3)
    float32 linear RGB (1/sr); an overflowing output gives inf. Evaluated ``chunk`` rows
    at a time on the thread pool, BLAS on one thread per chunk
    (:func:`~sparse_brdf.parallel.parallel_map`): its products are too thin for BLAS's
    own threads, which made a table of a network 5x slower (3.2 s against 0.6 s on one
    thread, 2 cores, measured 2026-12-07)."""
    out = np.empty((x.shape[0], 3), np.float32)

    def one(s: int) -> None:
        _, z = forward(layers, np.asarray(x[s : s + chunk], np.float32))
        with np.errstate(over="ignore"):  # inf: refused where a BRDF is built from it
            out[s : s + chunk] = np.maximum(np.expm1(z), 0.0)

    for _ in parallel_map(one, range(0, x.shape[0], chunk)):
        pass
    return out


def tabulate(layers: Layers, shape: tuple[int, int, int] = MERL_SHAPE,
             symmetric: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The network on a grid, at the bins' lower-edge angles (as the grid's samples).

    Parameters
    ----------
    layers : list of (kernel, bias)
        The dense layers, float32.
    shape : tuple of 3 int
        The (theta_h, theta_d, phi_d) grid.
    symmetric : bool
        Average the network over the four sign combinations of the difference vector's x
        and y (:data:`SYMMETRIES`): phi_d, -phi_d, pi - phi_d and pi + phi_d. An isotropic
        BRDF is unchanged by the mirror phi_d -> -phi_d and, by reciprocity, by phi_d ->
        phi_d + pi; a network fitted to noisy data need not be, and the grid folds phi_d
        into [0, pi) by reciprocity. False: the network as it is.

    Returns
    -------
    values : ndarray of shape (*shape, 3), float32
        Linear RGB BRDF values; 0 on bins below the horizon.
    valid : ndarray of ``shape``, bool
        The bins above the horizon (:func:`~sparse_brdf.coords.geometric_valid`).
    """
    valid, x = _grid_inputs(tuple(int(n) for n in shape))
    values = np.zeros((*shape, 3), np.float32)
    if not symmetric:
        values[valid] = evaluate(layers, x)
        return values, valid.copy()
    acc = np.zeros((len(x), 3), np.float64)
    for sx, sy in SYMMETRIES:
        acc += evaluate(layers, x * np.array([1, 1, 1, sx, sy, 1], np.float32))
    values[valid] = (acc / len(SYMMETRIES)).astype(np.float32)
    return values, valid.copy()


@functools.lru_cache(maxsize=2)
def _grid_inputs(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The bins above the horizon of a grid and the network's inputs there (read-only;
    the same for every network: made once per grid, not once per material)."""
    valid = geometric_valid(shape)
    th, td, pd = grid_angles(shape)
    x = network_inputs(th[valid], td[valid], pd[valid])
    for a in (valid, x):
        a.flags.writeable = False
    return valid, x


#: The sign changes (of the difference vector's x and y) under which an isotropic,
#: reciprocal BRDF is unchanged: identity, phi_d -> pi - phi_d, -phi_d, pi + phi_d.
SYMMETRIES: tuple[tuple[int, int], ...] = ((1, 1), (-1, 1), (1, -1), (-1, -1))


def layers_from_params(params: dict[str, np.ndarray]) -> Layers:
    """``[(w1, b1), (w2, b2), (w3, b3)]`` from a dict with those keys, as float32."""
    return [(np.asarray(params[f"w{i}"], np.float32), np.asarray(params[f"b{i}"], np.float32))
            for i in range(1, len(LAYER_SIZES))]


def params_from_layers(layers: Layers) -> dict[str, np.ndarray]:
    """The inverse of :func:`layers_from_params`: ``{"w1": kernel, "b1": bias, ...}``
    (float32 copies)."""
    out = {}
    for i, (k, b) in enumerate(layers, 1):
        out[f"w{i}"] = np.array(k, np.float32)
        out[f"b{i}"] = np.array(b, np.float32)
    return out


def save_keras(path: str | os.PathLike, layers: Layers) -> Path:
    """Write a network in the Keras HDF5 layout of the published Neural-BRDF files.

    The groups :data:`KERAS_LAYERS` (with Keras' ``layer_names`` and ``weight_names``
    attributes, and the weightless output layer ``lambda_1``), each holding its float32
    ``kernel:0`` (n_in, n_out) and ``bias:0`` (n_out,). Written atomically: a failed
    write leaves no file. Read back bit for bit by
    :func:`sparse_brdf.sources.nbrdf.read_nbrdf_weights` (and ``load_brdf``), rendered
    by the ``neural_brdf`` Mitsuba plugin.

    Parameters
    ----------
    path : str or PathLike
        The ``.h5`` file to write (replaced if it exists).
    layers : list of (kernel, bias)
        One pair per name of :data:`KERAS_LAYERS`.

    Returns
    -------
    Path
        ``path``.
    """
    import h5py  # lazy: h5py adds ~25 ms to `import sparse_brdf`

    if len(layers) != len(KERAS_LAYERS):
        raise ValueError(f"a Neural-BRDF file holds {len(KERAS_LAYERS)} layers, not "
                         f"{len(layers)}")
    path = Path(path)
    names = [*KERAS_LAYERS, "lambda_1"]
    with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
        f.attrs["layer_names"] = np.array([n.encode() for n in names])
        for name, (k, b) in zip(KERAS_LAYERS, layers, strict=True):
            g = f.create_group(name)
            g.attrs["weight_names"] = np.array([f"{name}/kernel:0".encode(),
                                                f"{name}/bias:0".encode()])
            inner = g.create_group(name)
            inner.create_dataset("kernel:0", data=np.asarray(k, np.float32))
            inner.create_dataset("bias:0", data=np.asarray(b, np.float32))
        f.create_group("lambda_1").attrs["weight_names"] = np.array([], np.float64)
    return path
