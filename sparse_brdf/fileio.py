"""Atomic file writes: write to a temporary name in the target folder, then rename.

Every temporary file is registered while it exists; :func:`cleanup_on_signals` (used by
the command line) removes the registered ones when SIGTERM or SIGHUP arrives, and an
interrupt (SIGINT) unwinds through :func:`atomic_path`, which removes its own. So an
interrupted command leaves neither a partial output nor a temporary file.

A temporary file is never what an error names: each one is registered with the output it
stands for, and a failure while writing it (a full disk, a file size limit) is reported
as an :class:`~sparse_brdf.errors.OutputError` naming that output
(:func:`output_name`), also when a writer that is itself atomic writes to a staging file
of :func:`staged`.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import signal
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

from .errors import InputFileError, Interrupted, MissingFileError, OutputError, SparseBRDFError

#: Temporary files of :func:`atomic_path` that exist right now (str paths), each with the
#: output it stands for. A dict's item assignment and pop are atomic under the GIL, so a
#: signal handler may read it without a lock.
_TEMPORARIES: dict[str, Path] = {}
#: Signals whose arrival removes the temporaries (SIGINT unwinds as KeyboardInterrupt).
_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


def _umask() -> int:
    """The process umask, read without changing it where the system allows (Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    umask = os.umask(0)  # elsewhere: set and restore (briefly process-wide)
    os.umask(umask)
    return umask


def output_name(path: str | os.PathLike) -> Path:
    """The output the user named for ``path``: ``path`` itself, or, when it is a temporary
    file of :func:`atomic_path` or :func:`staged` (a writer given a staging file), the
    output that file will be renamed onto. Error messages name this path."""
    path = Path(path)
    return _TEMPORARIES.get(str(path), path)


def _reworded(exc: BaseException, temporaries: tuple[str, ...],
              shown: Path) -> BaseException | None:
    """The error to raise instead of ``exc``, raised while writing ``temporaries`` (the
    temporary file, and the staging file it replaces, if any) of the output ``shown``, or
    None to raise ``exc`` itself: the system's refusal (an OSError about one of them or
    about no file) becomes an OutputError naming ``shown``, and a message of the
    package's that names one of them names ``shown`` instead."""
    def named(text: str) -> str:
        for tmp in temporaries:
            text = text.replace(tmp, str(shown))
        return text

    if isinstance(exc, SparseBRDFError):
        text = str(exc)
        if len(exc.args) == 1 and named(text) != text:
            return type(exc)(named(text))
        return None
    if isinstance(exc, OSError) and exc.filename in (None, str(shown), *temporaries):
        return OutputError(f"{shown}: cannot write: {exc.strerror or named(str(exc))}")
    return None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary path beside ``path`` to write to (for writers that need a file name);
    on success it is renamed onto ``path``.

    The result has the permissions of a newly created file (``0o666 & ~umask``), not
    ``mkstemp``'s 0600. On any exception the temporary file is removed and ``path`` is
    left untouched, so a reader never sees a partial file (also under concurrent writers
    of the same path). An OSError about the temporary file or about no file (ENOSPC,
    EFBIG, ...) is raised as an :class:`~sparse_brdf.errors.OutputError` naming the
    output, :func:`output_name` of ``path``; a package error whose message names the
    temporary file names the output instead.
    """
    path = Path(path)
    shown = output_name(path)
    _check_replaceable(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _create_temporary(path, suffix, shown)
    except OSError as exc:
        raise OutputError(f"{shown}: cannot write: {exc.strerror or exc}") from exc
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        staging = () if shown == path else (str(path),)
        other = _reworded(exc, (tmp, *staging), shown)  # the output's error
        if other is not None:
            raise other from exc
        raise
    finally:
        _TEMPORARIES.pop(tmp, None)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success (flushed and synced) rename it
    onto ``path``, with the usual permissions (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, mode) as f:
        yield f
        f.flush()
        os.fsync(f.fileno())


def require_file(path: str | os.PathLike, what: str = "file") -> Path:
    """Return ``path`` as a Path, raising :class:`~sparse_brdf.errors.MissingFileError` (a
    FileNotFoundError) naming it when it is absent and
    :class:`~sparse_brdf.errors.InputFileError` when it is a folder, pipe or device (reading
    a FIFO would hang)."""
    path = Path(path)
    if not path.is_file():
        if path.exists():
            raise InputFileError(f"{path}: not a regular file (a folder, pipe or device), "
                                 f"expected a {what}")
        raise MissingFileError(f"{path}: no such {what}")
    return path


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` name the same file (links followed; for paths that do not
    exist yet, the same resolved path)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_output(path: str | os.PathLike, inputs: Iterable[str | os.PathLike | None] = (),
                 what: str = "output") -> Path:
    """``path`` as a Path, or :class:`~sparse_brdf.errors.OutputError` when it is an
    existing folder or the same file as one of ``inputs`` (None and ``mitsuba:`` names
    are skipped): a command never overwrites its own input."""
    path = Path(path)
    _check_replaceable(path, what)
    for src in inputs:
        if src is None or str(src).startswith("mitsuba:") or str(src) == "":
            continue
        if same_file(path, src):
            raise OutputError(f"{path}: the {what} is also an input of this command "
                              f"({src}); refusing to overwrite it: choose another {what}")
    return path


def check_suffix(path: str | os.PathLike, suffixes: Iterable[str], option: str = "-o",
                 kind: str = "") -> Path:
    """``path`` as a Path, or :class:`~sparse_brdf.errors.OutputError` when its name does
    not end in one of ``suffixes`` (case-insensitive; e.g. ``(".sbrdf",)``) or ends in a
    path separator (``-o DIR/`` names a folder: a command that writes one file asks for
    the file's name). ``kind`` describes the file (e.g. "a .sbrdf coefficient file")."""
    text = os.fspath(path)
    suffixes = tuple(suffixes)
    want = kind or " or ".join(suffixes) + " file"
    if text.endswith((os.sep, "/")) or (os.altsep and text.endswith(os.altsep)):
        raise OutputError(f"{option} {text}: names a folder; give the file's name, e.g. "
                          f"{text.rstrip('/' + os.sep)}/NAME{suffixes[0]} ({want})")
    p = Path(text)
    if p.suffix.lower() not in suffixes:
        raise OutputError(f"{option} {text}: this command writes {want}; give a name ending "
                          f"in {' or '.join(suffixes)}")
    return p


def check_writable(path: str | os.PathLike, what: str = "output") -> Path:
    """``path`` as a Path, or :class:`~sparse_brdf.errors.OutputError` when it could not be
    written: its folder (or the nearest existing folder above it) is not a folder, or a
    probe file cannot be created there (permissions, a read-only file system). Commands
    check every output this way before their work."""
    path = Path(path)
    _check_replaceable(path, what)
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError(f"{path}: cannot write the {what}: {folder} is not a folder")
    try:
        probe = _create_temporary(folder / path.name, ".probe", path)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write the {what}: {exc.strerror or exc}") from exc
    try:
        os.unlink(probe)
    finally:
        _TEMPORARIES.pop(probe, None)
    return path


def check_new_output(path: str | os.PathLike, suffixes: Iterable[str], kind: str = "",
                     inputs: Iterable[str | os.PathLike | None] = (),
                     option: str = "-o") -> Path:
    """An output checked once, before any work: its suffix (:func:`check_suffix`), neither
    a folder nor one of ``inputs`` (:func:`check_output`), and writable
    (:func:`check_writable`). Returns it as a Path."""
    check_suffix(path, suffixes, option, kind)
    check_output(path, inputs)
    return check_writable(path)


@contextlib.contextmanager
def staged(paths: Iterable[str | os.PathLike]) -> Iterator[list[Path]]:
    """Temporary paths beside each of ``paths`` (same suffix), to write a command's
    outputs to; they are renamed onto ``paths`` only once the block has written them all
    without an error, else every one is removed: no command leaves part of its outputs.
    A writer given a staging path names the output in its errors (:func:`output_name`)."""
    with contextlib.ExitStack() as stack:
        yield [stack.enter_context(atomic_path(p, suffix=Path(p).suffix or ".tmp"))
               for p in paths]


def _check_replaceable(path: Path, what: str = "output") -> None:
    """Refuse to replace a folder, a device or a pipe (renaming onto /dev/null would
    replace the device itself)."""
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, not an {what} file")
    if path.exists() and not path.is_file():
        raise OutputError(f"{path}: is a device, pipe or socket, not a regular file: "
                          f"refusing to replace it with the {what}")


def remove_temporaries() -> None:
    """Remove every temporary file :func:`atomic_path` has registered (signal-safe)."""
    while True:
        try:
            pending = tuple(_TEMPORARIES)
            break
        except RuntimeError:  # another thread changed the set during the copy
            continue
    for tmp in pending:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        _TEMPORARIES.pop(tmp, None)


def _on_signal(signum: int, frame) -> None:
    remove_temporaries()
    raise Interrupted(signum, signal.Signals(signum).name)


@contextlib.contextmanager
def cleanup_on_signals() -> Iterator[None]:
    """While active (main thread only), SIGTERM and SIGHUP remove the registered temporary
    files and raise :class:`~sparse_brdf.errors.Interrupted` (a KeyboardInterrupt), so the
    program unwinds as on Ctrl-C; the previous handlers are restored afterwards."""
    saved = {}
    try:
        for sig in _SIGNALS:
            saved[sig] = signal.signal(sig, _on_signal)
    except ValueError:  # not the main thread: signals cannot be handled here
        pass
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


def _create_temporary(path: Path, suffix: str, output: Path) -> str:
    """Create an empty hidden file beside ``path`` (mode 0600, as ``mkstemp``) and return
    its name, registered with ``output`` (the file it stands for) *before* it is created:
    a signal handler that runs at any moment finds every temporary that exists."""
    for _ in range(100):
        tmp = str(path.parent / f".{path.name}.{secrets.token_hex(4)}{suffix}")
        _TEMPORARIES[tmp] = output
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            return tmp
        except BaseException as exc:
            _TEMPORARIES.pop(tmp, None)
            if not isinstance(exc, FileExistsError):
                raise
    raise FileExistsError(f"{path}: no free temporary name beside it")


def _strict(value, pointer: str, non_finite: dict):
    """``value`` with every non-finite float replaced by None, each recorded in
    ``non_finite`` as ``{JSON Pointer: "inf" | "-inf" | "nan"}``."""
    if isinstance(value, float) and not math.isfinite(value):
        non_finite[pointer] = "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        return None
    if isinstance(value, dict):  # RFC 6901 escapes "~" and "/" in a key
        return {k: _strict(v, f"{pointer}/{str(k).replace('~', '~0').replace('/', '~1')}",
                           non_finite) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(v, f"{pointer}/{i}", non_finite) for i, v in enumerate(value)]
    return value


def strict_json(data: dict) -> str:
    """``data`` as strict JSON text (RFC 8259, which ``JSON.parse`` and ``jq`` read),
    indented, losing no number.

    Parameters
    ----------
    data : dict
        Any JSON-able mapping whose numbers may be infinite or nan.

    Returns
    -------
    str
        JSON where every non-finite number is ``null`` and the top-level ``non_finite``
        maps each one's JSON Pointer (``/cells/KEY/cos_snr``) to ``"inf"``, ``"-inf"``
        or ``"nan"``; :func:`parse_strict_json` puts them back.
    """
    non_finite: dict[str, str] = {}
    body = _strict({k: v for k, v in data.items() if k != "non_finite"}, "", non_finite)
    return json.dumps({**body, "non_finite": non_finite}, indent=1, allow_nan=False)


def parse_strict_json(text: str):
    """The data of :func:`strict_json`'s ``text``, the numbers its ``non_finite`` lists
    put back and ``non_finite`` dropped; JSON without it (``Infinity`` and ``NaN`` too)
    reads as :func:`json.loads` reads it. Raises :class:`json.JSONDecodeError` on text
    that is not JSON."""
    data = json.loads(text)
    nf = data.pop("non_finite", None) if isinstance(data, dict) else None
    for pointer, what in (nf or {}).items():
        *path, last = [t.replace("~1", "/").replace("~0", "~") for t in pointer.split("/")[1:]]
        node = data
        with contextlib.suppress(KeyError, IndexError, ValueError, TypeError):
            for t in path:  # a pointer to nothing leaves the null
                node = node[int(t)] if isinstance(node, list) else node[t]
            if isinstance(node, list) or last in node:
                node[int(last) if isinstance(node, list) else last] = float(what)
    return data
