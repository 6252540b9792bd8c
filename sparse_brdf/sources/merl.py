"""MERL ``.binary`` files (also the DTU data set): read and write (``docs/method.md``,
"Grid, lookup convention, validity").

Layout: three little-endian int32 dimensions (n_h, n_d, n_p), then 3 x n float64
values, all red, then all green, then all blue, C order, phi_d fastest. A stored value
times the channel scale is the BRDF; negative stored values mark unmeasured bins.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..coords import MERL_SHAPE, geometric_valid
from ..errors import BRDFFileError, InvalidBRDFError
from ..fileio import atomic_write, require_file

#: Stored value x scale = linear BRDF, per channel (R, G, B).
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_HEADER = 12
_MAX_BINS = 10_000_000
_MAX_VALUE = float(np.finfo(np.float32).max)


def read_merl(path: str | os.PathLike, name: str | None = None) -> BRDF:
    """Read a MERL ``.binary`` file into a :class:`BRDF`.

    Parameters
    ----------
    path : str or path-like
        The file: a header of three int32 dimensions (n_h, n_d, n_p), then
        3 n_h n_d n_p float64 values, channel-major, in MERL's scaled units.
    name : str, optional
        The material's name; default: the file name without ``.binary``.

    Returns
    -------
    BRDF
        float32 linear RGB values (n_h, n_d, n_p, 3) in 1/sr (MERL's channel scales
        applied), 0 on invalid bins; ``valid`` marks the measured bins above the horizon
        (negative stored values mean unmeasured).

    Raises
    ------
    FileNotFoundError
        If the file is missing.
    BRDFFileError
        For a wrong header, a wrong or truncated size, NaN/inf values, values beyond
        float32's range, or no valid bin; the message names the file.
    """
    path = require_file(path, "MERL file")
    raw = path.read_bytes()
    if len(raw) < _HEADER:
        raise BRDFFileError(f"{path}: too short for a MERL header ({len(raw)} bytes)")
    dims = tuple(int(x) for x in np.frombuffer(raw[:_HEADER], dtype="<i4"))
    n = math.prod(dims)  # Python integers: a hostile header cannot overflow the product
    if any(d <= 0 for d in dims) or n > _MAX_BINS or dims[2] % 2:
        raise BRDFFileError(f"{path}: not a MERL BRDF header (dimensions {dims})")
    expected = _HEADER + 3 * n * 8
    if len(raw) != expected:
        what = "truncated" if len(raw) < expected else "has trailing bytes"
        raise BRDFFileError(
            f"{path}: {what}: {len(raw)} bytes, a {dims} MERL file has {expected}"
        )
    stored = np.frombuffer(raw[_HEADER:], dtype="<f8").reshape(3, *dims)
    if not np.all(np.isfinite(stored)):
        bad = int((~np.isfinite(stored)).sum())
        raise BRDFFileError(f"{path}: {bad} values are NaN or inf")
    measured = np.all(stored >= 0, axis=0)
    valid = measured & geometric_valid(dims)
    values = np.where(valid[..., None], np.moveaxis(stored, 0, -1) * MERL_SCALE, 0.0)
    big = int(np.count_nonzero(np.abs(values) > _MAX_VALUE))
    if big:
        raise BRDFFileError(f"{path}: {big} values exceed {_MAX_VALUE:.3g}, the largest "
                            "a float32 BRDF holds")
    try:
        return BRDF(values=values.astype(np.float32), valid=valid,
                    name=name or path.name.removesuffix(".binary"), source=str(path))
    except InvalidBRDFError as exc:  # e.g. no valid bin: name the file
        raise BRDFFileError(f"{path}: {exc}") from exc


def write_merl(path: str | os.PathLike, brdf: BRDF) -> Path:
    """Write ``brdf`` as a MERL ``.binary`` file, atomically.

    Parameters
    ----------
    path : str or path-like
        The file to write (replaced only once it is complete).
    brdf : BRDF
        Linear RGB values (n_h, n_d, n_p, 3); invalid bins are stored as -1.

    Returns
    -------
    pathlib.Path
        The file written; :func:`read_merl` reads it back exactly.
    """
    path = Path(path)
    stored = np.moveaxis(brdf.values.astype(np.float64), -1, 0) / MERL_SCALE[:, None, None, None]
    stored = np.where(brdf.valid[None], stored, -1.0)
    header = np.asarray(brdf.shape, dtype="<i4").tobytes()
    with atomic_write(path) as f:
        f.write(header)
        f.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
    return path


__all__ = ["MERL_SCALE", "MERL_SHAPE", "read_merl", "write_merl"]
