"""The entry point, ``main``: one command run, its errors turned into one line on stderr
and an exit status (2 a user's mistake, 70 a bug, 128 + N a signal)."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import traceback
import warnings

from ..errors import SparseBRDFError, one_line
from ..fileio import cleanup_on_signals, remove_temporaries
from ._parser import build_parser
from ._process import keep_freed_memory, no_madvised_hugepages

#: Exit status of an internal error (a bug), as sysexits.h's EX_SOFTWARE.
EXIT_BUG = 70


def _describe(exc: BaseException) -> str:
    """The message of an expected error; an OSError names its file."""
    if isinstance(exc, OSError) and not isinstance(exc, SparseBRDFError) and exc.filename:
        names = f"{exc.filename}" + (f" -> {exc.filename2}" if exc.filename2 else "")
        return f"{names}: {exc.strerror or exc}"
    return str(exc) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run one command. Exit status: 0 done; 2 a bad input, option or output (one line on
    stderr naming it); 70 an internal error (a bug); 128 + N killed by signal N (SIGINT,
    SIGTERM, SIGHUP), no partial output left. ``--debug`` (anywhere) or
    ``SPARSE_BRDF_DEBUG=1`` adds the traceback and numpy's warnings."""
    argv = list(sys.argv[1:] if argv is None else argv)
    no_madvised_hugepages()
    keep_freed_memory()
    debug = "--debug" in argv or os.environ.get("SPARSE_BRDF_DEBUG", "") not in ("", "0")
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    with warnings.catch_warnings(), cleanup_on_signals():
        if not debug:  # overflow etc. in numpy: the results are checked instead
            warnings.simplefilter("ignore", RuntimeWarning)
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM/SIGHUP (errors.Interrupted)
            remove_temporaries()
            signum = int(getattr(exc, "signum", signal.SIGINT))
            _report(debug, f"interrupted by {signal.Signals(signum).name}; no partial "
                           "output was left")
            return 128 + signum
        except BrokenPipeError:  # the reader of stdout went away (`... | head`): quietly
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 128 + signal.SIGPIPE
        except (SparseBRDFError, OSError) as exc:
            _report(debug, f"error: {_describe(exc)}")
            return 2
        except MemoryError:  # a size the options ask for that this machine cannot hold
            _report(debug, "error: not enough memory for what the options ask (a size, "
                           "count or resolution too large for this machine); no output "
                           "was written")
            return 2
        except Exception as exc:  # noqa: BLE001 - anything else is a bug, said so
            _report(debug, f"internal error (a bug, please report it): "
                           f"{type(exc).__name__}: {exc}; run with --debug or "
                           "SPARSE_BRDF_DEBUG=1 for the traceback")
            return EXIT_BUG


def _report(debug: bool, message: str) -> None:
    """Print ``message`` as one line on stderr, after the traceback with ``debug``."""
    if debug:
        traceback.print_exc()
    print(f"sparse-brdf: {one_line(message)}", file=sys.stderr)
