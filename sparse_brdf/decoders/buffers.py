"""The arrays a renderer's kernels read besides the layouts: buffers as uploaded (aligned
float32, contiguous uint32), the angle tables of the grid, the per-bin arithmetic the
kernels mirror in numpy (transform weight, colour mix) and the RGB-to-spectrum table of
the plugin's spectral upsampling.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..coords import bin_angles, cos_io
from ..transforms import COS_CLIP, colour_matrix, material_scale, uses_cosine

# ------------------------------------------------------------------ buffers as uploaded


def float_buffer(a, align: int = 64) -> np.ndarray:
    """``a`` as a flat float32 array whose data starts on an ``align``-byte boundary.

    Dr.Jit's LLVM backend may map a numpy buffer instead of copying it, and reads an
    unaligned source with per-lane gathers instead of packet loads; which of the two a
    kernel gets would then depend on where numpy happened to allocate, and a material
    swap could compile a new kernel.
    """
    a = np.asarray(a, np.float32).ravel()
    item = a.dtype.itemsize
    buf = np.empty(a.size + align // item, a.dtype)
    off = (-buf.ctypes.data % align) // item
    out = buf[off:off + a.size]
    out[:] = a
    return out


def uint_buffer(a) -> np.ndarray:
    """``a`` as a flat, contiguous uint32 array."""
    return np.ascontiguousarray(np.asarray(a, np.uint32).ravel())


def angle_tables(shape) -> tuple[np.ndarray, ...]:
    """cos theta_h, sin theta_h, cos theta_d, sin theta_d and cos phi_d at the bins'
    lower-edge angles (:func:`sparse_brdf.coords.bin_angles`): the five small tables
    from which a renderer gets a bin's ``cos_i cos_o`` without trigonometry."""
    th, td, pd = bin_angles(tuple(shape))
    return np.cos(th), np.sin(th), np.cos(td), np.sin(td), np.cos(pd)


# ----------------------------------------------------------------------- numpy mirrors


def bin_weight(i, j, k, shape, transform: str, gain: float = 1.0) -> np.ndarray:
    """The weight w of ``transform`` (:func:`sparse_brdf.transforms.weight`) for a
    material of gain ``gain`` at integer bins, float32 of their broadcast shape."""
    s = np.float32(material_scale(transform, gain))
    if not uses_cosine(transform):
        return np.full(np.broadcast(i, j, k).shape, s, np.float32)
    th, td, pd = bin_angles(shape)
    ci, co = cos_io(th[i], td[j], pd[k])
    return np.clip(ci * co, *COS_CLIP).astype(np.float32) * s


def colour_mix(basis: str) -> tuple[tuple[float, float, float], ...] | None:
    """The matrix M^T that maps coded channels back to the transformed R, G, B in
    ``basis``, as Python floats (kernel constants: the same for every material of that
    basis), or None for "rgb", whose kernels skip the mix."""
    m = colour_matrix(basis)
    if np.array_equal(m, np.eye(3)):
        return None
    return tuple(tuple(float(v) for v in row) for row in m.T.astype(np.float32))


def mix_channels(xs, basis: str) -> np.ndarray:
    """Coded X (3, ...) -> transformed R, G, B (3, ...) with :func:`colour_mix` (numpy
    mirror of the kernels' mix; "rgb": ``xs`` unchanged)."""
    mt = colour_mix(basis)
    xs = np.asarray(xs)
    if mt is None:
        return xs
    return np.tensordot(np.array(mt, np.float64), xs.astype(np.float64), axes=1)


# ------------------------------------------------------------- spectral upsampling table


def read_rgb2spec_table(path: str | Path) -> tuple[int, np.ndarray, np.ndarray]:
    """Read an RGB-to-spectrum coefficient table (the format of Jakob and Hanika 2019;
    Mitsuba ships one as ``data/srgb.coeff``), for the plugin's spectral upsampling.

    Parameters
    ----------
    path : str or Path
        The table file: a 4-byte magic number, the resolution ``res`` as uint32, ``res``
        float32 samples of the largest colour component, then the coefficient grid as
        float32. Anything after the grid (newer files append a forward model) is ignored.

    Returns
    -------
    res : int
        The table's resolution, in [2, 1024].
    scale : ndarray, shape (res,), float32
        The samples of the largest component, increasing, in [0, 1].
    coefficients : ndarray, shape (3, res, res, res, 3), float32
        The sigmoid-polynomial coefficients, indexed by (largest component, its sample,
        the next component, the one after, coefficient).

    Raises
    ------
    ValueError
        The file does not start with the table's magic number, or is shorter than its
        resolution says.
    """
    raw = Path(path).read_bytes()
    if raw[:4] != b"SPEC" or len(raw) < 8:
        raise ValueError(f"{path}: not an RGB-to-spectrum coefficient table (bad magic number)")
    res = int(np.frombuffer(raw, "<u4", 1, 4)[0])
    n_grid = 3 * res ** 3 * 3
    if not 2 <= res <= 1024 or len(raw) < 8 + 4 * (res + n_grid):
        raise ValueError(f"{path}: truncated RGB-to-spectrum table (resolution {res}, "
                         f"{len(raw)} bytes)")
    scale = np.frombuffer(raw, "<f4", res, 8).astype(np.float32)
    data = np.frombuffer(raw, "<f4", n_grid, 8 + 4 * res).astype(np.float32)
    return res, scale, data.reshape(3, res, res, res, 3)
