"""The ``sparse-brdf`` parser: the commands in the order of the help, the help's layout
(every option's default stated) and usage errors as one line."""

from __future__ import annotations

import argparse
import textwrap

from ..coding.spec import DEFAULT_N_COEFFS
from ..errors import one_line
from ._bench import add_bench_commands
from ._codec import add_blend, add_decode, add_encode
from ._data import add_data_commands
from ._fit import add_fit_images, add_fit_scene
from ._render import add_render, add_snr
from ._samples import add_samples_commands
from ._train import add_train

EPILOG = f"""examples (built-in materials and shipped scenes; nothing to download):
  sparse-brdf corpus list mitsuba
  sparse-brdf info mitsuba:au-ggx-0.08
  sparse-brdf convert mitsuba:au-ggx-0.08 gold.binary
  sparse-brdf encode gold.binary -o gold.sbrdf --coeffs {DEFAULT_N_COEFFS}
  sparse-brdf decode gold.sbrdf -o gold-decoded.binary
  sparse-brdf render sphere -o gold.png --material material=gold.sbrdf
  sparse-brdf train --corpus mitsuba -o my_ensemble.npz --checkpoint-dir ckpt/

Outputs follow their names: each -o takes the suffix of what the command
writes (a .sbrdf, a MERL .binary, an .exr or .png/.jpg image, ...); another
suffix, or a name ending in / (a folder), is refused before any work.
"""


class _Help(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs line by line: a long line is wrapped, an indented one
    (an example command) kept as written; every option's help ends with its default
    (unless it says it itself; flags are off by default; required options have none)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n".join(
            line if line[:1].isspace() or len(line) + len(indent) <= width
            else textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent)
            for line in text.splitlines())

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        said = any(w in text for w in ("%(default)", "(default", "default:", "default per"))
        if (said or not action.option_strings or action.required
                or any(action.default is v for v in (None, False, argparse.SUPPRESS))):
            return text
        return f"{text} (default: %(default)s)"


def parsers(parser: argparse.ArgumentParser):
    """``parser`` and every sub-command's parser below it."""
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):
                yield from parsers(sub)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit status 2); its
    subparsers are of the same class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``sparse-brdf`` parser: every command, its options and its help."""
    p = _Parser(
        prog="sparse-brdf",
        description="Measured BRDFs as sparse coefficients over a learned dictionary "
                    "ensemble: convert, inspect, train, encode, decode and render.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--debug", action="store_true",
                   help="on an error, print the traceback too (anywhere on the line; or set "
                        "SPARSE_BRDF_DEBUG=1)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (add_data_commands, add_train, add_encode, add_samples_commands, add_decode,
                add_render, add_snr, add_fit_scene, add_fit_images, add_blend,
                add_bench_commands):  # in the order of the help
        add(sub)
    for q in parsers(p):
        q.formatter_class = _Help
    return p
