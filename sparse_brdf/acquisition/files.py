"""Sample files (``docs/method.md``, "Encoding from samples"): a CSV with the header
``wi_x,wi_y,wi_z,wo_x,wo_y,wo_z,r,g,b`` (and an optional ``weight`` column), or an
``.npz`` with arrays ``wi`` (N, 3), ``wo`` (N, 3), ``rgb`` (N, 3) and optionally
``weight`` (N,). Directions are unit vectors in the local frame (z the normal), values
linear RGB in 1/sr: :func:`read_samples`, :func:`write_samples`. Where to measure and
simulated measurements: :mod:`sparse_brdf.acquisition.planning`.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from ..errors import BRDFFileError, UsageError
from ..fileio import atomic_write, require_file
from .measurements import Samples

#: The CSV header (an optional ``weight`` column may follow).
COLUMNS = ("wi_x", "wi_y", "wi_z", "wo_x", "wo_y", "wo_z", "r", "g", "b")


def read_samples(path: str | os.PathLike) -> Samples:
    """Read a samples file (CSV or ``.npz``, module doc).

    Parameters
    ----------
    path : str or path-like
        The file; ``.npz`` is read as numpy arrays, anything else as CSV.

    Returns
    -------
    Samples
        The measurements, named by the file's stem.

    Raises
    ------
    MissingFileError
        If the file does not exist.
    BRDFFileError
        For a file that is not a samples file: wrong columns, a value that is not a
        number (naming the row), missing arrays, no rows.
    UsageError
        For a row below the horizon, NaN, a negative value or a non-unit direction
        (naming the file and row; :class:`~sparse_brdf.acquisition.measurements.Samples`).
    """
    path = require_file(path, "samples file")
    if path.suffix.lower() == ".npz":
        arrays = _read_npz(path)
    else:
        arrays = _read_csv(path)
    try:
        return Samples(**arrays, name=path.stem, source=str(path))
    except UsageError as exc:
        raise BRDFFileError(str(exc)) from exc


def _read_npz(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("wi", "wo", "rgb") if k not in z.files]
            if missing:
                raise BRDFFileError(f"{path}: missing array(s) {', '.join(missing)} (a "
                                    "samples .npz holds wi, wo, rgb and optionally weight)")
            out = {k: np.asarray(z[k]) for k in ("wi", "wo", "rgb")}
            out["weight"] = np.asarray(z["weight"]) if "weight" in z.files else None
    except BRDFFileError:
        raise
    except Exception as exc:  # noqa: BLE001 - numpy and zipfile raise many kinds
        raise BRDFFileError(f"{path}: not a samples .npz file ({type(exc).__name__}: "
                            f"{exc})") from exc
    for k, v in out.items():
        if v is not None and v.dtype.kind not in "fiu":
            raise BRDFFileError(f"{path}: array {k} is not numeric ({v.dtype})")
    return out


def _read_csv(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BRDFFileError(f"{path}: not a samples CSV file (not UTF-8 text)") from exc
    rows = [r for r in csv.reader(io.StringIO(text)) if r and any(x.strip() for x in r)]
    if not rows:
        raise BRDFFileError(f"{path}: empty samples file (expected the header "
                            f"{','.join(COLUMNS)})")
    head = tuple(x.strip().lower() for x in rows[0])
    if head not in (COLUMNS, (*COLUMNS, "weight")):
        raise BRDFFileError(f"{path}: header {','.join(head)[:120]!r}: expected "
                            f"{','.join(COLUMNS)} (then optionally weight)")
    if len(rows) == 1:
        raise BRDFFileError(f"{path}: no samples after the header")
    data = np.empty((len(rows) - 1, len(head)))
    for i, r in enumerate(rows[1:]):
        if len(r) != len(head):
            raise BRDFFileError(f"{path}: row {i + 1}: {len(r)} values, expected "
                                f"{len(head)}")
        try:
            data[i] = [float(x) for x in r]
        except ValueError:
            raise BRDFFileError(f"{path}: row {i + 1}: not a number in "
                                f"{','.join(r)[:80]!r}") from None
    return {"wi": data[:, 0:3], "wo": data[:, 3:6], "rgb": data[:, 6:9],
            "weight": data[:, 9] if len(head) == 10 else None}


def write_samples(path: str | os.PathLike, samples: Samples) -> Path:
    """Write samples as a CSV (the header of :data:`COLUMNS`, plus ``weight`` unless every
    weight is 1) or, for a ``.npz`` path, as arrays; atomically.

    Parameters
    ----------
    path : str or path-like
        The file to write.
    samples : Samples
        The measurements.

    Returns
    -------
    pathlib.Path
        The file written; :func:`read_samples` reads it back (CSV values to 17 digits).
    """
    path = Path(path)
    weighted = bool(np.any(samples.weight != 1.0))
    if path.suffix.lower() == ".npz":
        extra = {"weight": samples.weight} if weighted else {}
        with atomic_write(path) as f:
            np.savez_compressed(f, wi=samples.wi, wo=samples.wo, rgb=samples.rgb, **extra)
        return path
    cols = [samples.wi, samples.wo, samples.rgb] + ([samples.weight[:, None]] if weighted
                                                    else [])
    head = ",".join(COLUMNS) + (",weight" if weighted else "")
    buf = io.StringIO()
    np.savetxt(buf, np.concatenate(cols, 1), delimiter=",", fmt="%.17g", header=head,
               comments="")
    with atomic_write(path, "w") as f:
        f.write(buf.getvalue())
    return path
