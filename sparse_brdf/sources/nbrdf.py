"""Neural-BRDF networks (Sztrajman et al. 2021) tabulated on the MERL grid.

A Keras HDF5 file with dense layers 6 -> 21 -> 21 -> 3 (ReLU, ReLU, max(exp(x) - 1, 0)).
The input is (hx, hy, hz, dx, dy, dz), the half and difference vectors with phi_h = 0;
the output is the linear RGB BRDF value. The network's formulas are
:mod:`sparse_brdf.mlp`'s; this module reads the files.
"""

from __future__ import annotations

import os

import numpy as np

from ..brdf import BRDF
from ..coords import MERL_SHAPE
from ..errors import BRDFFileError, InvalidBRDFError
from ..fileio import require_file
from ..mlp import KERAS_LAYERS, tabulate

#: Largest weight array read (the real networks hold 21 x 21); more is not a Neural-BRDF.
_MAX_WEIGHTS = 1 << 16


def read_nbrdf_weights(path: str | os.PathLike) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (kernel, bias) float32 pairs of the three dense layers of a Neural-BRDF file."""
    import h5py  # lazy: h5py adds ~25 ms to `import sparse_brdf`

    path = require_file(path, "Neural-BRDF file")
    try:
        with h5py.File(path, "r") as f:
            layers = []
            for name in KERAS_LAYERS:
                g = f[name][name]
                kernel, bias = g["kernel:0"], g["bias:0"]
                for d in (kernel, bias):  # refuse huge or non-numeric datasets before reading
                    if (not isinstance(d, h5py.Dataset) or d.size > _MAX_WEIGHTS
                            or d.dtype.kind not in "fiu"):
                        raise BRDFFileError(f"{path}: layer {name} is not a small numeric "
                                            "array")
                layers.append((np.asarray(kernel, np.float32), np.asarray(bias, np.float32)))
    except BRDFFileError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises many kinds on damaged files
        raise BRDFFileError(f"{path}: not a Neural-BRDF Keras HDF5 file "
                            f"({type(exc).__name__}: {exc})") from exc
    shapes = [(k.shape, b.shape) for k, b in layers]
    widths = [6] + [k.shape[1] if k.ndim == 2 else -1 for k, _ in layers]
    if (any(k.ndim != 2 or b.ndim != 1 for k, b in layers) or widths[-1] != 3
            or any(k.shape[0] != w for (k, _), w in zip(layers, widths, strict=False))
            or any(k.shape[1] != b.shape[0] for k, b in layers)):
        raise BRDFFileError(f"{path}: unexpected Neural-BRDF layer shapes {shapes} (expected "
                            "6 -> n -> m -> 3 dense layers)")
    for k, b in layers:
        if not (np.all(np.isfinite(k)) and np.all(np.isfinite(b))):
            raise BRDFFileError(f"{path}: network weights contain NaN or inf")
    return layers


def tabulate_nbrdf(path: str | os.PathLike, shape: tuple[int, int, int] = MERL_SHAPE,
                   symmetrize: bool = True) -> BRDF:
    """Load a Neural-BRDF ``.h5`` file and tabulate it at the bins' lower-edge angles.

    ``symmetrize`` averages the network over the mirror phi_d -> -phi_d and reciprocity
    phi_d -> phi_d + pi (:func:`sparse_brdf.mlp.tabulate`), as an isotropic BRDF is;
    False keeps the raw network."""
    layers = read_nbrdf_weights(path)
    values, valid = tabulate(layers, shape, symmetric=symmetrize)
    name = os.path.basename(os.fspath(path)).removesuffix(".h5")
    try:
        return BRDF(values=values, valid=valid, name=name, source=os.fspath(path))
    except InvalidBRDFError as exc:  # e.g. weights whose output overflows: name the file
        raise BRDFFileError(f"{path}: the network's values are unusable: {exc}") from exc
