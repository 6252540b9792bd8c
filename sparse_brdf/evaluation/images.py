"""Images and masks on disk: EXR read and written, sRGB previews (``.png``/``.jpg``) by
suffix, and object masks (``.exr`` or ``.npy``).

OpenEXR and Pillow are imported inside the functions that need them.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import (
    ImageFileError,
    OutputError,
)
from ..fileio import atomic_path, atomic_write, output_name, require_file

# ------------------------------------------------------------------------------- EXR


def _pixels(path: Path, img: np.ndarray) -> np.ndarray:
    """``img`` as float32 (H, W, 3), or (H, W, 1) (a mono variant's render); else an
    :class:`ImageFileError` naming ``path``."""
    arr = np.ascontiguousarray(np.asarray(img, dtype=np.float32))
    if arr.ndim != 3 or arr.shape[2] not in (1, 3):
        raise ImageFileError(f"{path}: expected an image of shape (H, W, 3), or (H, W, 1) "
                             f"in a mono variant, got {arr.shape}")
    return arr


def write_exr(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Write a linear float32 RGB image (H, W, 3), or a mono one (H, W, 1) as its one
    channel ``Y`` (as Mitsuba writes it), as an EXR file, atomically;
    :class:`OutputError` naming ``path`` if the system refuses (a full disk, a file size
    limit), with nothing left behind."""
    path = Path(path)
    arr = _pixels(path, img)
    import OpenEXR  # lazy: only image commands need it, every command imports this module

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {"RGB": arr} if arr.shape[2] == 3 else {"Y": arr[..., 0]}
    with atomic_path(path, suffix=".exr") as tmp, OpenEXR.File(header, channels) as f:
        try:
            f.write(str(tmp))
        except RuntimeError as exc:  # OpenEXR's I/O errors (ENOSPC, EFBIG, ...)
            raise OutputError(f"{output_name(path)}: cannot write the EXR image: "
                              f"{_exr_reason(exc, tmp)}") from exc
    return path


def _exr_reason(exc: RuntimeError, tmp: Path) -> str:
    """The reason in an OpenEXR write error (``Failed to write pixel data to image file
    "TMP". File too large.``), without the temporary file's name; the whole message if it
    does not name it."""
    text = str(exc)
    _, quoted, reason = text.partition(f'"{tmp}"')
    reason = reason.strip(" .")
    return reason if quoted and reason else text


#: The images a render writes, by suffix: ``.exr`` linear HDR (float32), the others an
#: 8-bit tone-mapped sRGB preview (:func:`preview`).
IMAGE_SUFFIXES = (".exr", ".png", ".jpg", ".jpeg")
#: The object masks :func:`write_mask` writes, by suffix.
MASK_SUFFIXES = (".exr", ".npy")


def preview(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """An 8-bit sRGB preview of a linear image (H, W, 3): scaled by ``2 ** exposure``
    (stops), clipped to [0, 1] and encoded with the sRGB transfer function; uint8
    (H, W, 3). NaN and negative values show as black."""
    x = np.nan_to_num(np.asarray(img, np.float64) * 2.0 ** float(exposure), nan=0.0)
    x = np.clip(x, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(x * 255.0).astype(np.uint8)


def write_image(path: str | os.PathLike, img: np.ndarray, exposure: float = 0.0) -> Path:
    """Write a linear RGB image (H, W, 3) by its suffix, atomically: ``.exr`` as linear
    float32 (``exposure`` unused), ``.png``/``.jpg``/``.jpeg`` as an 8-bit sRGB preview
    (:func:`preview`, ``exposure`` in stops); another suffix is an
    :class:`~sparse_brdf.errors.OutputError`. A mono image (H, W, 1) is written as one
    channel: ``Y`` in an EXR, a greyscale preview."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        return write_exr(path, img)
    if suffix not in IMAGE_SUFFIXES:
        raise OutputError(f"{path}: an image is written as {', '.join(IMAGE_SUFFIXES)}")
    arr = preview(_pixels(path, img), exposure)
    from PIL import Image  # lazy: only previews need it (Pillow comes with matplotlib)

    fmt = "PNG" if suffix == ".png" else "JPEG"
    grey = arr.shape[2] == 1
    with atomic_write(path, "wb") as f:
        Image.fromarray(arr[..., 0] if grey else arr, "L" if grey else "RGB").save(
            f, format=fmt, quality=95)
    return path


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read the RGB channels of an EXR file (RGB or RGBA, as Mitsuba writes) as float32
    (H, W, 3); :class:`ImageFileError` naming the file if it is not such an image."""
    import OpenEXR  # lazy: only image commands need it, every command imports this module

    path = require_file(path, "EXR file")
    printed: list[str] = []  # OpenEXR's own words about this file (see _c_output_to)
    try:
        with _c_output_to(printed, (str(path), "EXR_ERR", "pixel data")), \
                OpenEXR.File(str(path)) as f:
            ch = f.channels()
            key = next((k for k in ("RGB", "RGBA") if k in ch), None)
            if key is not None:
                arr = np.asarray(ch[key].pixels)[..., :3]
            elif all(c in ch for c in "RGB"):
                arr = np.stack([np.asarray(ch[c].pixels) for c in "RGB"], -1)
            else:
                raise ImageFileError(f"no R, G, B channels (has {', '.join(ch) or 'none'})")
    except Exception as exc:  # noqa: BLE001 - OpenEXR raises plain exceptions
        said = printed[0].strip().splitlines() if printed and printed[0].strip() else []
        raise ImageFileError(f"{path}: cannot read EXR: {exc}"
                             + (f" ({said[0].removeprefix(f'{path}: ')})" if said else "")
                             ) from exc
    if printed and printed[0].strip():  # OpenEXR warned of damaged pixel data
        line = printed[0].strip().splitlines()[0].removeprefix(f"{path}: ")
        raise ImageFileError(f"{path}: cannot read EXR: {line}")
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.size == 0:
        raise ImageFileError(f"{path}: not an RGB image (pixel array of shape {arr.shape})")
    return np.ascontiguousarray(arr, dtype=np.float32)


@contextlib.contextmanager
def _c_output_to(printed: list[str], marks: tuple[str, ...]) -> Iterator[None]:
    """Collect the lines that C/C++ libraries print on file descriptors 1 and 2 and that
    hold one of ``marks`` (OpenEXR's warnings about a damaged file, on both) into
    ``printed`` (one string) instead of the terminal; other lines (another thread's) go
    to stderr afterwards. An unnamed temporary file holds them, so an interrupt leaves
    nothing behind."""
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no stdout or stderr: nothing to protect
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd in (1, 2):
            os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            for fd, old in zip((1, 2), saved, strict=True):
                os.dup2(old, fd)
                os.close(old)
            tmp.seek(0)
            lines = tmp.read().decode("utf-8", errors="replace").splitlines(keepends=True)
            ours = [ln for ln in lines if any(m in ln for m in marks)]
            others = "".join(ln for ln in lines if ln not in ours)
            if others:
                sys.stderr.write(others)
            printed.append("".join(ours))


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> Path:
    """Write a bool mask (H, W) as an EXR (1.0 = object, in every channel) or, for a
    ``.npy`` path, as a numpy array; atomically."""
    path = Path(path)
    mask = np.asarray(mask, dtype=bool)
    if path.suffix.lower() == ".npy":
        with atomic_write(path, "wb") as f:
            np.save(f, mask)
        return path
    return write_exr(path, np.repeat(mask[..., None], 3, -1).astype(np.float32))


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """An object mask, bool (H, W), from an EXR (nonzero in any channel = object) or a
    ``.npy`` file of booleans."""
    path = require_file(path, "mask file")
    if path.suffix.lower() == ".npy":
        try:
            mask = np.load(path, allow_pickle=False)
        except Exception as exc:  # noqa: BLE001 - numpy raises several kinds
            raise ImageFileError(f"{path}: cannot read mask: {exc}") from exc
        if mask.ndim != 2 or mask.dtype.kind not in "biuf":
            raise ImageFileError(f"{path}: a mask must be a 2-D (H, W) array of booleans, "
                                 f"got {mask.dtype} of shape {mask.shape}")
        return mask.astype(bool)
    img = read_exr(path)
    if not np.all(np.isfinite(img)):
        raise ImageFileError(f"{path}: mask holds NaN/inf values")
    return np.any(img != 0, axis=-1)
