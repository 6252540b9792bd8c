"""The ``.sbrdf`` coefficient file: versioned, self-describing, checksummed, compact.

Two versions, byte by byte in ``docs/file-format.md``; all integers little-endian. Both
start with the same 53 bytes (magic, version, transform, flags, grid, ensemble id,
dictionaries, counts, name length) and end with a CRC-32 of every preceding byte.

- Version 1: the name, then per channel one record per coefficient, a u32 flat location
  and the f32 value. 57 + L + 8 T bytes.
- Version 2 (written by default): a payload codec (u8), the channels' quantisation step
  exponents (3 x i16), the payload's raw and stored lengths (2 x u32), the name, the
  payload. The payload holds each channel's locations, sorted and delta-coded, then each
  channel's quantised values q (value = q 2^(k/4)), all as LEB128 varints (q
  zigzag-mapped), stored as is, deflated (zlib) or LZMA2-compressed (lzma), whichever is
  smallest. 72 + L + P bytes: about 1.7 bytes per coefficient at 300 per channel.

Quantisation (version 2): channel c's step is 2^(k_c/4), the largest such step at most
1/256 of the channel's largest |value| and at most 1/2 of its 10th-percentile |value|
(but not below 2^-22 of the largest, nor 2^-126; :func:`step_exponent`). Every decoded
value is within half a step of the encoded one (plus float32 rounding, 2^-24 relative):
at most max|value| / 512 and 1/4 of the 10th-percentile |value|. The rule is chosen at
equal bytes: in a file of a given size it leaves room for about 20 % more coefficients
than the finer rule of files written before 2026-12-07 (1/4096, 1/8), which renders
better (``docs/file-format.md``). Values already on a grid, down to that finer rule's (a
file read back), are written back unchanged.
"""

from __future__ import annotations

import dataclasses
import lzma
import math
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..errors import BRDFFileError, EnsembleMismatchError, UsageError, one_line
from ..fileio import atomic_write, require_file
from ..params import check_choice
from ..transforms import LOBE_SIZE, TRANSFORMS, has_floor, has_lobe, per_material
from .coefficients import SparseBRDF
from .ensemble import Ensemble, resolve_ensemble, shipped_ids

MAGIC = b"SBRDF\r\n\x1a"
#: The version :func:`to_bytes` and :func:`save_sbrdf` write unless told otherwise.
VERSION = 2
#: Every version this reader knows (and the writer can write).
VERSIONS = (1, 2)
#: A coefficient file as an output: its suffixes and what it is called (an output's
#: checks, ``fileio.check_new_output``).
SBRDF_FILE = ((".sbrdf",), "a .sbrdf coefficient file")


def check_version(version: int) -> int:
    """``version`` if this writer can write it (:data:`VERSIONS`), else a
    :class:`~sparse_brdf.errors.UsageError` naming the versions."""
    return check_choice(".sbrdf version", version, VERSIONS)

_PREFIX = struct.Struct("<8sH")  # magic, version: enough to dispatch
_HEAD = struct.Struct("<8sHBB3H16s3H3IB")  # version 1; also the first 53 bytes of v2
_HEAD2 = struct.Struct("<8sHBB3H16s3H3IBB3hII")
_GAIN = struct.Struct("<f")  # a level or lobe transform's gain 1/L (sr), after the name
_LOBE = struct.Struct(f"<{LOBE_SIZE}e")  # a lobe transform's base lobe, after the gain
_FLOOR = struct.Struct("<e")  # a floor transform's floor f, after the lobe
_RECORD = np.dtype([("loc", "<u4"), ("val", "<f4")])
#: Bytes per stored coefficient in a version-1 file (u32 location + f32 value).
RECORD_BYTES = _RECORD.itemsize
#: Flag bit of byte 11: the coded channels are in the opponent colour basis.
FLAG_OPPONENT = 0x01
KNOWN_FLAGS = FLAG_OPPONENT
#: Version-2 payload codecs, by their code (byte 53).
CODECS = ("stored", "deflate", "lzma")
_LZMA_WRITE = [{"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME,
                "dict_size": 1 << 20, "lc": 0, "lp": 0, "pb": 0}]
_LZMA_READ = [{"id": lzma.FILTER_LZMA2, "dict_size": 1 << 20}]
#: Longest varint a version-2 payload may hold (5 bytes: 35 bits).
_VARINT_MAX = 5
#: Quantisation (version 2): step <= max|value| / 2^_STEP_BITS and <= the 10th-percentile
#: |value| / _STEP_REF_DIV; |q| <= 2^_Q_BITS, so that float32(q step) / step rounds to q
#: (a file read back is recognised: :func:`step_exponent`). The rule is chosen at equal
#: bytes (docs/file-format.md, "Quantisation and its bound"): a coarser step leaves room
#: for more coefficients, which gain more than the step loses.
_STEP_BITS, _STEP_REF_DIV, _Q_BITS = 8, 2, 22
#: The finest rule a writer has used (files written before 2026-12-07: 1/4096 of the
#: largest, 1/8 of the 10th percentile): values on a grid down to it are written back
#: on that grid, so reading any file and writing it again gives the same values.
_STEP_FINEST = (12, 8)
#: 2^(r/4), r = 0..3 (the steps are 2^(k/4) = 2^(k >> 2) times one of these).
_QUARTERS = (1.0, 1.189207115002721, 1.4142135623730951, 1.681792830507429)
#: Step exponents: i16 in the file; the writer keeps 2^(k/4) a normal float32.
_K_MIN, _K_MAX = -4 * 126, 4 * 127
_F32_MAX = float(np.finfo(np.float32).max)


def file_size(n_coeffs: int, name_len: int = 0, transform: str | None = None) -> int:
    """Bytes of a version-1 file holding ``n_coeffs`` coefficients in all and a name of
    ``name_len`` bytes, under ``transform`` (a level transform's file holds its gain; a
    version-2 file's size depends on the values: :func:`to_bytes`)."""
    return (_HEAD.size + name_len + _material_bytes(transform)
            + _RECORD.itemsize * n_coeffs + 4)


def min_file_size(name_len: int = 0, version: int = VERSION,
                  transform: str | None = None) -> int:
    """Bytes of a file with no coefficient and a name of ``name_len`` bytes: what every
    file of that version, name and ``transform`` (None: one without a gain) costs before
    its coefficients."""
    if version == 1:
        return file_size(0, name_len, transform)
    return (_HEAD2.size + name_len + _material_bytes(transform) + len(_compress(b"")[1])
            + 4)


def _material_bytes(transform: str | None) -> int:
    """The bytes after the name: 4 (the f32 gain) for a level transform, 18 (the gain
    and the base lobe's 7 float16) for a lobe transform, 20 (and the floor, float16)
    for a floor transform, else 0."""
    if transform is None or not per_material(transform):
        return 0
    return (_GAIN.size + (_LOBE.size if has_lobe(transform) else 0)
            + (_FLOOR.size if has_floor(transform) else 0))


def to_bytes(model: SparseBRDF, version: int = VERSION) -> bytes:
    """Serialise ``model`` as a ``.sbrdf`` file of ``version`` (1 or 2; see module doc)."""
    check_version(version)
    name = model.name.encode("utf-8")[:255]
    if any(n > 0xFFFF for n in model.shape) or int(np.prod(model.shape)) > 0xFFFFFFFF:
        raise UsageError(f"{model.name}: grid {model.shape} is too large for the .sbrdf "
                         "format (sides of at most 65535 bins)")
    common = (MAGIC, version, TRANSFORMS.index(model.transform),
              FLAG_OPPONENT if model.basis == "opponent" else 0, *model.shape,
              bytes.fromhex(model.ensemble_id[:32]), *(int(d) for d in model.dict_index),
              *(int(n) for n in model.n_coeffs), len(name))
    gain = _GAIN.pack(model.gain) if per_material(model.transform) else b""
    if model.lobe is not None:
        gain += _LOBE.pack(*model.lobe)
    if has_floor(model.transform):
        gain += _FLOOR.pack(model.floor)
    if version == 1:
        parts = [_HEAD.pack(*common), name, gain]
        for loc, val in zip(model.locations, model.values, strict=True):
            rec = np.empty(loc.size, _RECORD)
            rec["loc"], rec["val"] = loc, val
            parts.append(rec.tobytes())
    else:
        exps, raw = _payload(model)
        codec, packed = _compress(raw)
        parts = [_HEAD2.pack(*common, codec, *exps, len(raw), len(packed)), name, gain,
                 packed]
    body = b"".join(parts)
    return body + struct.pack("<I", zlib.crc32(body))


def from_bytes(data: bytes, source: str = "<bytes>") -> SparseBRDF:
    """Parse a ``.sbrdf`` file's bytes (either version); errors name ``source`` and the
    problem (:class:`BRDFFileError`, one line)."""
    if len(data) < _PREFIX.size:
        raise BRDFFileError(f"{source}: too short for a .sbrdf file ({len(data)} bytes)")
    if data[:8] != MAGIC:
        raise BRDFFileError(f"{source}: not a .sbrdf file (bad magic bytes)")
    version = _PREFIX.unpack_from(data)[1]
    if version not in VERSIONS:
        raise BRDFFileError(f"{source}: .sbrdf version {version}; this reader knows "
                            f"{', '.join(map(str, VERSIONS))}")
    head = _HEAD if version == 1 else _HEAD2
    if len(data) < head.size + 4:
        raise BRDFFileError(f"{source}: too short for a .sbrdf file ({len(data)} bytes)")
    fields = head.unpack_from(data)
    (tcode, flags, n1, n2, n3, ens_id, d0, d1, d2, t0, t1, t2, name_len) = fields[2:15]
    counts = (t0, t1, t2)
    if tcode >= len(TRANSFORMS):
        raise BRDFFileError(f"{source}: unknown transform code {tcode}")
    transform = TRANSFORMS[tcode]
    if version == 1:
        expected = file_size(sum(counts), name_len, transform)
    else:
        expected = _HEAD2.size + name_len + _material_bytes(transform) + fields[-1] + 4
    if len(data) != expected:
        what = "truncated" if len(data) < expected else "has trailing bytes"
        raise BRDFFileError(f"{source}: {what}: {len(data)} bytes, its header announces "
                            f"{expected}")
    (crc,) = struct.unpack_from("<I", data, len(data) - 4)
    if zlib.crc32(data[:-4]) != crc:
        raise BRDFFileError(f"{source}: checksum mismatch: the file is corrupt")
    if flags & ~KNOWN_FLAGS:
        raise BRDFFileError(f"{source}: unknown flags 0x{flags:02x} in byte 11 (this reader "
                            f"knows 0x{KNOWN_FLAGS:02x}, the opponent colour basis): written "
                            "by a newer version?")
    off = head.size
    name = data[off: off + name_len].decode("utf-8", errors="replace")
    off += name_len
    gain, lobe, floor = 1.0, None, 0.0
    if per_material(transform):
        (gain,) = _GAIN.unpack_from(data, off)
        off += _GAIN.size
    if has_lobe(transform):
        lobe = _LOBE.unpack_from(data, off)
        off += _LOBE.size
    if has_floor(transform):
        (floor,) = _FLOOR.unpack_from(data, off)
        off += _FLOOR.size
    if version == 1:
        locs, vals = _records(data, off, counts)
    else:
        locs, vals = _read_payload(data, off, fields, (n1, n2, n3), source)
    try:
        return SparseBRDF(transform, (n1, n2, n3), ens_id.hex(), [d0, d1, d2],
                          locs, vals, name=name,
                          basis="opponent" if flags & FLAG_OPPONENT else "rgb", gain=gain,
                          lobe=lobe, floor=floor)
    except ValueError as exc:  # its message names the material: the file's own bytes
        raise BRDFFileError(f"{source}: {one_line(exc)}") from exc


def _records(data: bytes, off: int, counts) -> tuple[list, list]:
    """Version 1's records: per channel, u32 locations and f32 values."""
    locs, vals = [], []
    for t in counts:
        rec = np.frombuffer(data, _RECORD, count=t, offset=off)
        locs.append(rec["loc"].astype(np.int64))
        vals.append(rec["val"].astype(np.float32))
        off += t * _RECORD.itemsize
    return locs, vals


# ---------------------------------------------------------------------- version 2
def step(k: int) -> float:
    """The quantisation step of exponent ``k``: 2^(k/4), from exact float64 constants."""
    return math.ldexp(_QUARTERS[k & 3], k >> 2)


def step_exponent(values: np.ndarray) -> int:
    """The quantisation step exponent k (step 2^(k/4)) of one channel's ``values``, as the
    writer chooses it (module doc): the largest k with step <= max|v| / 256 and <= the
    10th-percentile |v| / 2, but step >= max|v| 2^-22 (|q| <= 2^22). Values already on a
    grid between k + 1 and the finest rule's (``_STEP_FINEST``: a file read back, written
    by this writer or an earlier one) keep the coarsest such grid, so they are written
    back unchanged. ``values`` are read as float32, as a model holds them."""
    v = np.asarray(values, np.float32).astype(np.float64)
    a = np.abs(v)
    top = float(a.max()) if a.size else 0.0
    if top == 0.0:
        return 0
    ref = float(np.sort(a)[(a.size - 1) // 10])
    k = _rule_exponent(top, ref, _STEP_BITS, _STEP_REF_DIV)
    finest = min(_rule_exponent(top, ref, *_STEP_FINEST), k) - 1
    for cand in range(min(k + 1, _K_MAX), max(finest, _K_MIN) - 1, -1):
        q = np.rint(v / step(cand))
        if np.abs(q).max() <= 2.0**(_Q_BITS + 1) and np.array_equal(
                (q * step(cand)).astype(np.float32), v):
            return cand
    return k


def _rule_exponent(top: float, ref: float, bits: int, div: int) -> int:
    """The largest k with 2^(k/4) <= top / 2^bits and <= ref / div, clamped to |q| <=
    2^22 and to the exponents a file holds: the step rule of :func:`step_exponent`."""
    want = min(top / 2.0**bits, ref / div)
    k = math.floor(4 * math.log2(want)) if want > 0 else _K_MIN
    return min(max(k, 4 * (math.frexp(top)[1] - _Q_BITS), _K_MIN), _K_MAX)


def _payload(model: SparseBRDF) -> tuple[list[int], bytes]:
    """Version 2's step exponents and uncompressed payload: every channel's delta-coded
    sorted locations, then every channel's zigzag-mapped quantised values, as varints."""
    exps, gaps, qs = [], [], []
    for loc, val in zip(model.locations, model.values, strict=True):
        order = np.argsort(loc, kind="stable")
        loc, val = loc[order], val[order].astype(np.float64)
        k = step_exponent(val)
        val = (np.rint(val / step(k)) * step(k)).astype(np.float32).astype(np.float64)
        k = step_exponent(val)  # the grid a reader finds again: written back byte for byte
        q = np.rint(val / step(k)).astype(np.int64)
        exps.append(k)
        gaps.append(np.diff(loc, prepend=-1) - 1)
        qs.append(np.where(q >= 0, 2 * q, -2 * q - 1))
    return exps, _varints(np.concatenate(gaps + qs))


def _varints(x: np.ndarray) -> bytes:
    """Unsigned LEB128: 7 bits per byte, low bits first, bit 7 set on all but the last."""
    x = np.asarray(x, np.uint64)
    n = np.ones(x.size, np.int64)
    rest = x >> np.uint64(7)
    while rest.any():
        n += rest > 0
        rest >>= np.uint64(7)
    out = np.zeros(int(n.sum()), np.uint8)
    start = np.cumsum(n) - n
    for k in range(int(n.max()) if n.size else 0):
        sel = n > k
        byte = (x[sel] >> np.uint64(7 * k)) & np.uint64(0x7F)
        out[start[sel] + k] = byte.astype(np.uint8) | ((n[sel] > k + 1) << 7).astype(np.uint8)
    return out.tobytes()


def _read_varints(buf: np.ndarray, count: int) -> tuple[np.ndarray, int]:
    """The first ``count`` varints of ``buf`` (uint8) and the bytes they take; ValueError
    if there are fewer or one is longer than ``_VARINT_MAX`` bytes."""
    if count == 0:
        return np.zeros(0, np.int64), 0
    ends = np.flatnonzero(buf < 0x80)[:count]
    if ends.size < count:
        raise ValueError(f"payload ends after {ends.size} of {count} numbers")
    starts = np.concatenate(([0], ends[:-1] + 1))
    lens = ends - starts + 1
    if lens.max() > _VARINT_MAX:
        raise ValueError(f"payload holds a number of {lens.max()} bytes")
    val = np.zeros(count, np.int64)
    for k in range(int(lens.max())):
        sel = lens > k
        val[sel] |= (buf[starts[sel] + k] & 0x7F).astype(np.int64) << (7 * k)
    return val, int(ends[-1]) + 1


def _compress(raw: bytes) -> tuple[int, bytes]:
    """The smallest of the payload stored, deflated and LZMA2-compressed: (codec, bytes)."""
    z = zlib.compressobj(9, zlib.DEFLATED, -15, 9)
    options = [raw, z.compress(raw) + z.flush(),
               lzma.compress(raw, format=lzma.FORMAT_RAW, filters=_LZMA_WRITE)]
    codec = min(range(len(options)), key=lambda i: (len(options[i]), i))
    return codec, options[codec]


def _decompress(codec: int, packed: bytes, raw_len: int) -> bytes:
    """Undo :func:`_compress`; ValueError unless exactly ``raw_len`` bytes come out."""
    if codec == 0:
        raw, done, extra = packed, True, b""
    else:
        d = (zlib.decompressobj(-15) if codec == 1 else
             lzma.LZMADecompressor(format=lzma.FORMAT_RAW, filters=_LZMA_READ))
        try:
            raw = d.decompress(packed, raw_len + 1)
        except (zlib.error, lzma.LZMAError) as exc:
            raise ValueError(f"corrupt {CODECS[codec]} payload ({exc})") from exc
        done = d.eof
        extra = d.unused_data
    if len(raw) != raw_len or not done or extra:
        raise ValueError(f"{CODECS[codec]} payload holds {len(raw)}"
                         f"{'' if done else '+'} bytes, its header announces {raw_len}")
    return raw


def _read_payload(data: bytes, off: int, fields: tuple, shape, source: str):
    """Version 2's locations and dequantised values (module doc), checked."""
    counts = fields[11:14]
    codec, exps, raw_len = fields[15], fields[16:19], fields[19]
    size = int(np.prod(shape))
    try:
        if codec >= len(CODECS):
            raise ValueError(f"unknown payload codec {codec}")
        if any(not _K_MIN <= k <= _K_MAX for k in exps):
            raise ValueError(f"quantisation step exponents {list(exps)} out of range")
        if size > 0xFFFFFFFF or any(t > size for t in counts):
            raise ValueError(f"coefficient counts {list(counts)} exceed the {size} atoms "
                             f"of the grid, or the grid the format's 2^32")
        total = sum(counts)
        if raw_len > 2 * _VARINT_MAX * total:
            raise ValueError(f"payload of {raw_len} bytes for {total} coefficients")
        raw = np.frombuffer(_decompress(codec, data[off:len(data) - 4], raw_len), np.uint8)
        gaps, used = _read_varints(raw, total)
        zq, used2 = _read_varints(raw[used:], total)
        if used + used2 != raw_len:
            raise ValueError(f"payload has {raw_len - used - used2} bytes after its numbers")
    except ValueError as exc:
        raise BRDFFileError(f"{source}: {exc}") from exc
    q = np.where(zq % 2 == 0, zq // 2, -(zq + 1) // 2)
    locs, vals, lo = [], [], 0
    for t, e in zip(counts, exps, strict=True):
        loc = np.cumsum(gaps[lo: lo + t] + 1) - 1
        val = q[lo: lo + t].astype(np.float64) * step(e)
        if val.size and np.abs(val).max() > _F32_MAX:
            raise BRDFFileError(f"{source}: coefficient values beyond the float32 range")
        val = val.astype(np.float32)
        order = np.argsort(-np.abs(val), kind="stable")  # largest first, as in memory
        locs.append(loc[order])
        vals.append(val[order])
        lo += t
    return locs, vals


def as_stored(model: SparseBRDF, version: int = VERSION) -> SparseBRDF:
    """``model`` as a file of ``version`` holds it: for version 2, values quantised
    (within half a step, module doc); ``stats`` are kept. Writing the result again gives
    the same values (and bytes). What a bench should score."""
    back = from_bytes(to_bytes(model, version))
    return dataclasses.replace(back, name=model.name, stats=model.stats)


def save_sbrdf(path: str | os.PathLike, model: SparseBRDF, version: int = VERSION) -> Path:
    """Write ``model`` as a ``.sbrdf`` file, atomically (a temporary name, then a rename).

    Parameters
    ----------
    path : str or path-like
        The file to write; an existing file is replaced only once the new one is
        complete.
    model : SparseBRDF
        The encoded material (its ensemble id, transform, basis, dictionaries and
        coefficients are stored; ``docs/file-format.md``).
    version : int
        2 (the default: quantised values, compressed locations, about 2 bytes per
        coefficient) or 1 (float32 values and int32 locations, 8 bytes per coefficient).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValueError
        For an unknown version or a grid too large for the format.
    """
    path = Path(path)
    data = to_bytes(model, version)
    with atomic_write(path) as f:
        f.write(data)
    return path


def load_sbrdf(path: str | os.PathLike, ensemble: Ensemble | None = None) -> SparseBRDF:
    """Read a ``.sbrdf`` file (either version).

    Parameters
    ----------
    path : str or path-like
        The file.
    ensemble : Ensemble, optional
        If given, the file must have been encoded over it.

    Returns
    -------
    SparseBRDF
        The model as stored (version 2's values dequantised to float32).

    Raises
    ------
    FileNotFoundError
        If the file is missing.
    BRDFFileError
        For a file that is truncated, corrupt (checksum), of an unknown version or not a
        ``.sbrdf`` file; the message names the file.
    EnsembleMismatchError
        If ``ensemble`` is given and is not the one the file names.
    """
    path = require_file(path, ".sbrdf file")
    model = from_bytes(path.read_bytes(), str(path))
    if ensemble is not None:
        try:
            model.check_ensemble(ensemble)
        except Exception as exc:  # its message names the material, read from the file
            raise type(exc)(f"{path}: {one_line(exc)}") from exc
    return model


#: The coded channels of each colour basis, in file order.
CHANNELS = {"rgb": ("R", "G", "B"), "opponent": ("luminance", "red-green", "yellow-blue")}


def describe(path: str | os.PathLike) -> dict:
    """What a ``.sbrdf`` file holds, read without decoding (``sparse-brdf info``).

    Parameters
    ----------
    path : str or path-like
        The file.

    Returns
    -------
    dict
        JSON-ready: ``version`` (1 or 2), ``codec`` (version 2's payload codec, one of
        :data:`CODECS`; None for version 1), ``bytes`` (the file's size), ``ensemble``
        (the id of the ensemble the coefficients refer to) and ``ensemble_shipped``
        (whether this install ships it), ``grid`` ([n1, n2, n3]), ``transform`` (one for
        every channel) and ``gain`` (the material's gain 1/L, sr, of a level transform;
        1 for the others), ``lobe`` (a lobe transform's base lobe: ``alpha``, ``kd``
        and ``ks``, these per channel; None for the others), ``floor`` (a floor
        transform's floor f: values below f L decode as 0; 0 for the others), ``basis`` (the colour
        basis) and ``channels`` (its coded channels), then per channel
        ``coefficients`` and ``dictionaries`` (the index of the ensemble's dictionary
        each channel uses), and ``coefficients_total``.

    Raises
    ------
    FileNotFoundError, BRDFFileError
        As :func:`load_sbrdf`.
    """
    path = require_file(path, ".sbrdf file")
    data = path.read_bytes()
    model = from_bytes(data, str(path))
    version = _PREFIX.unpack_from(data)[1]
    codec = CODECS[_HEAD2.unpack_from(data)[15]] if version == 2 else None
    return {"version": int(version), "codec": codec, "bytes": len(data),
            "ensemble": model.ensemble_id,
            "ensemble_shipped": model.ensemble_id in shipped_ids(),
            "grid": list(model.shape), "transform": model.transform, "gain": model.gain,
            "lobe": None if model.lobe is None else {
                "alpha": model.lobe[0], "kd": list(model.lobe[1:4]), "ks": list(model.lobe[4:7])},
            "floor": model.floor, "basis": model.basis,
            "channels": list(CHANNELS[model.basis]),
            "coefficients": [int(n) for n in model.n_coeffs],
            "coefficients_total": int(model.n_coeffs.sum()),
            "dictionaries": [int(d) for d in model.dict_index]}


def decode_file(path: str | os.PathLike, ensemble: Ensemble | None = None) -> BRDF:
    """Read a ``.sbrdf`` file and decode it to the full tabulated BRDF.

    Parameters
    ----------
    path : str or path-like
        The file.
    ensemble : Ensemble, optional
        The ensemble to decode with; default: the shipped ensemble the file names.

    Returns
    -------
    BRDF
        Linear RGB values (n_h, n_d, n_p, 3) in 1/sr, with the grid's geometric validity;
        ``source`` is the file's path.

    Raises
    ------
    FileNotFoundError, BRDFFileError
        As :func:`load_sbrdf`.
    EnsembleMismatchError
        If the file names an ensemble that is neither ``ensemble`` nor shipped.
    """
    model = load_sbrdf(path)
    try:
        ens = resolve_ensemble(ensemble, for_id=model.ensemble_id)
        model.check_ensemble(ens)
    except EnsembleMismatchError as exc:
        raise EnsembleMismatchError(f"{path}: {exc}") from exc
    brdf = model.decode(ens)
    brdf.source = os.fspath(path)
    return brdf
