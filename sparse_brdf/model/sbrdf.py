"""The ``.sbrdf`` coefficient file: versioned, self-describing, checksummed, compact.

Layout (version 1, all integers little-endian)::

    offset  size      field
    0       8         magic  b"SBRDF\\r\\n\\x1a" (catches text-mode mangling)
    8       2         u16    format version (1)
    10      1         u8     transform: 0 = log-plus, 1 = log-plus-cosine
    11      1         u8     flags: bit 0 = opponent colour basis (the coded channels are
                             transforms.colour_matrix("opponent") times the transformed
                             R, G, B); the other bits are reserved (0) and refused
    12      6         u16x3  grid shape n1, n2, n3
    18      16        bytes  ensemble id (first 128 bits of its SHA-256 content hash)
    34      6         u16x3  dictionary index of coded channels 0, 1, 2
    40      12        u32x3  coefficient count T_0, T_1, T_2 (any may be 0)
    52      1         u8     name length L (UTF-8 bytes, <= 255)
    53      L         bytes  material name
    53+L    8*T       records, channel 0 then 1 then 2: u32 flat location
                      (a*n2*n3 + b*n3 + c), f32 value
    end-4   4         u32    CRC-32 of every preceding byte

So a file is 57 + L + 8 * (T_0 + T_1 + T_2) bytes: 6,365 bytes for 262 coefficients per
channel and a 20-byte name (the paper's layout used 12 bytes per coefficient).
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..errors import BRDFFileError
from ..fileio import atomic_write, require_file
from ..transforms import TRANSFORMS
from .ensemble import Ensemble, resolve_ensemble
from .sparse import SparseBRDF

MAGIC = b"SBRDF\r\n\x1a"
VERSION = 1
_HEAD = struct.Struct("<8sHBB3H16s3H3IB")
_RECORD = np.dtype([("loc", "<u4"), ("val", "<f4")])
#: Bytes per stored coefficient (u32 location + f32 value).
RECORD_BYTES = _RECORD.itemsize
#: Flag bit of byte 11: the coded channels are in the opponent colour basis.
FLAG_OPPONENT = 0x01
KNOWN_FLAGS = FLAG_OPPONENT


def file_size(n_coeffs: int, name_len: int = 0) -> int:
    """Bytes of a file holding ``n_coeffs`` coefficients in all and a name of ``name_len``."""
    return _HEAD.size + name_len + _RECORD.itemsize * n_coeffs + 4


def to_bytes(model: SparseBRDF) -> bytes:
    """Serialise ``model`` (the file format above)."""
    name = model.name.encode("utf-8")[:255]
    if any(n > 0xFFFF for n in model.shape) or int(np.prod(model.shape)) > 0xFFFFFFFF:
        raise ValueError(f"grid {model.shape} is too large for the .sbrdf format")
    head = _HEAD.pack(
        MAGIC, VERSION, TRANSFORMS.index(model.transform),
        FLAG_OPPONENT if model.basis == "opponent" else 0, *model.shape,
        bytes.fromhex(model.ensemble_id[:32]), *(int(d) for d in model.dict_index),
        *(int(n) for n in model.n_coeffs), len(name))
    parts = [head, name]
    for loc, val in zip(model.locations, model.values, strict=True):
        rec = np.empty(loc.size, _RECORD)
        rec["loc"], rec["val"] = loc, val
        parts.append(rec.tobytes())
    body = b"".join(parts)
    return body + struct.pack("<I", zlib.crc32(body))


def from_bytes(data: bytes, source: str = "<bytes>") -> SparseBRDF:
    """Parse a ``.sbrdf`` file's bytes; errors name ``source`` and the problem."""
    if len(data) < _HEAD.size + 4:
        raise BRDFFileError(f"{source}: too short for a .sbrdf file ({len(data)} bytes)")
    if data[:8] != MAGIC:
        raise BRDFFileError(f"{source}: not a .sbrdf file (bad magic bytes)")
    (_, version, tcode, flags, n1, n2, n3, ens_id, d0, d1, d2, t0, t1, t2,
     name_len) = _HEAD.unpack_from(data)
    if version != VERSION:
        raise BRDFFileError(f"{source}: .sbrdf version {version}; this reader knows {VERSION}")
    expected = file_size(t0 + t1 + t2, name_len)
    if len(data) != expected:
        what = "truncated" if len(data) < expected else "has trailing bytes"
        raise BRDFFileError(f"{source}: {what}: {len(data)} bytes, its header announces "
                            f"{expected}")
    (crc,) = struct.unpack_from("<I", data, len(data) - 4)
    if zlib.crc32(data[:-4]) != crc:
        raise BRDFFileError(f"{source}: checksum mismatch: the file is corrupt")
    if tcode >= len(TRANSFORMS):
        raise BRDFFileError(f"{source}: unknown transform code {tcode}")
    if flags & ~KNOWN_FLAGS:
        raise BRDFFileError(f"{source}: unknown flags 0x{flags:02x} in byte 11 (this reader "
                            f"knows 0x{KNOWN_FLAGS:02x}, the opponent colour basis): written "
                            "by a newer version?")
    basis = "opponent" if flags & FLAG_OPPONENT else "rgb"
    off = _HEAD.size
    name = data[off: off + name_len].decode("utf-8", errors="replace")
    off += name_len
    locs, vals = [], []
    for t in (t0, t1, t2):
        rec = np.frombuffer(data, _RECORD, count=t, offset=off)
        locs.append(rec["loc"].astype(np.int64))
        vals.append(rec["val"].astype(np.float32))
        off += t * _RECORD.itemsize
    try:
        return SparseBRDF(TRANSFORMS[tcode], (n1, n2, n3), ens_id.hex(), [d0, d1, d2],
                          locs, vals, name=name, basis=basis)
    except ValueError as exc:
        raise BRDFFileError(f"{source}: {exc}") from exc


def save_sbrdf(path: str | os.PathLike, model: SparseBRDF) -> Path:
    """Write ``model`` to ``path`` atomically (temporary name, then rename)."""
    path = Path(path)
    data = to_bytes(model)
    with atomic_write(path) as f:
        f.write(data)
    return path


def load_sbrdf(path: str | os.PathLike, ensemble: Ensemble | None = None) -> SparseBRDF:
    """Read a ``.sbrdf`` file; with ``ensemble``, refuse it unless it is the encoding one."""
    path = require_file(path, ".sbrdf file")
    model = from_bytes(path.read_bytes(), str(path))
    if ensemble is not None:
        try:
            model.check_ensemble(ensemble)
        except Exception as exc:
            raise type(exc)(f"{path}: {exc}") from exc
    return model


def decode_file(path: str | os.PathLike, ensemble: Ensemble | None = None) -> BRDF:
    """Load a ``.sbrdf`` file and decode the full tensor (default: the shipped ensemble)."""
    ens = resolve_ensemble(ensemble)
    brdf = load_sbrdf(path, ens).decode(ens)
    brdf.source = os.fspath(path)
    return brdf
