"""Exceptions raised by sparse-brdf; each message names the file or parameter and the problem.

They form one hierarchy under :class:`SparseBRDFError`; :func:`one_line` is how the command
line prints any message (one line, control characters escaped).
"""

import re

#: Control characters (C0, DEL, C1) and the bidirectional overrides, which could rewrite
#: a terminal line; material names and file names may hold them.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")


def one_line(text: object) -> str:
    """``text`` as one printable line: line breaks become " | ", tabs spaces, and other
    control characters ``\\xNN`` escapes."""
    lines = [ln.strip() for ln in str(text).replace("\r\n", "\n").split("\n")]
    s = " | ".join(ln for ln in lines if ln).replace("\t", " ")
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}" if ord(m.group()) < 256
                        else f"\\u{ord(m.group()):04x}", s)


def short(text: object, n: int = 48) -> str:
    """``text`` as one line of at most ``n`` characters (middle elided with "..."), for
    the one-line reprs of the package's classes (names and paths can be 255 bytes)."""
    s = one_line(text)
    return s if len(s) <= n else s[: n // 2 - 2] + "..." + s[-(n - n // 2 - 1):]


class SparseBRDFError(Exception):
    """Base class of every error this package raises on purpose: the command line prints
    its message as one line and exits with status 2. Any other exception is a bug."""

    def __str__(self) -> str:  # the message itself, also for the KeyError subclasses
        return str(self.args[0]) if len(self.args) == 1 else super().__str__()


class BRDFFileError(SparseBRDFError, ValueError):
    """A BRDF or coefficient file is missing, truncated, corrupt or of a foreign format."""


class EnsembleMismatchError(SparseBRDFError, ValueError):
    """A coefficient file was encoded with another ensemble than the one given."""


class InvalidBRDFError(SparseBRDFError, ValueError):
    """BRDF values are unusable (NaN/inf, wrong shape, no valid bins)."""


class MissingDataError(SparseBRDFError, FileNotFoundError):
    """Data a scene or corpus needs is not on this machine (e.g. the paper's Grace
    Cathedral map, which is not redistributable and is read from the shared data folder)."""


class UsageError(SparseBRDFError, ValueError):
    """An option or argument has an unusable value (out of range, NaN, inconsistent)."""


class MissingFileError(SparseBRDFError, FileNotFoundError):
    """An input the user named does not exist: a file, a scene, a config, or a folder or
    glob that holds no material."""


class InputFileError(SparseBRDFError, OSError):
    """An input path exists but is not a regular file (a folder, a pipe, a device)."""


class OutputError(SparseBRDFError, OSError):
    """An output cannot be written: it is a folder, one of the command's own inputs, or
    the system refused (read-only folder, full disk). Nothing partial is left behind."""


class SceneError(SparseBRDFError, ValueError):
    """A scene XML file is malformed."""


class ImageFileError(SparseBRDFError, ValueError):
    """An image (EXR) or mask file is unreadable, of the wrong shape, or holds NaN/inf."""


class ConfigError(SparseBRDFError, ValueError):
    """A bench configuration file is unreadable or holds unusable settings."""


class UnknownNameError(SparseBRDFError, KeyError):
    """A named thing (built-in material, corpus, a scene element's id) does not exist."""


class RenderError(SparseBRDFError, RuntimeError):
    """A scene failed to load or render, or rendered NaN/inf pixels; the message holds
    the underlying cause."""


class PluginError(SparseBRDFError, ValueError):
    """A Mitsuba plugin parameter or file is unusable; the message names the plugin and
    the file."""


class MitsubaSetupError(SparseBRDFError, RuntimeError):
    """Mitsuba or its LLVM back-end is missing or unusable."""


class WorkerLostError(SparseBRDFError, RuntimeError):
    """A Dask worker died (killed, out of memory, its machine gone) holding work that
    cannot be redone elsewhere, such as the trainer's shards of tensors; the run stops and
    a second run resumes from what was saved (checkpoints, finished outputs)."""


class Interrupted(KeyboardInterrupt):
    """Not an error: SIGTERM or SIGHUP arrived (raised by the handler that
    :func:`sparse_brdf.fileio.cleanup_on_signals` installs, after removing temporaries)."""

    def __init__(self, signum: int, name: str) -> None:
        super().__init__(name)
        self.signum = signum
