"""Option declarations the commands share.

Argparse types from the declared parameters (:class:`~sparse_brdf.params.Interval`),
defaults read from the library functions' signatures, the kinds of file a command writes
(each output checked before any work), and the options several commands take: the BRDF
source note, ``--no-symmetrize``, ``--workers`` / ``--scheduler``.
"""

from __future__ import annotations

import argparse
import inspect

from ..coding import spec as encode_spec
from ..coding.fileformat import SBRDF_FILE
from ..coords import GRID_BINS
from ..evaluation.images import IMAGE_SUFFIXES, MASK_SUFFIXES
from ..evaluation.render import RENDER_PARAMETERS
from ..fileio import check_new_output
from ..params import Interval
from ..training import train as train_module

#: The declared parameters the options take their bounds and choices from.
ENCODE, TRAIN, RENDER = (encode_spec.PARAMETERS, train_module.PARAMETERS, RENDER_PARAMETERS)
#: Coefficients per channel: at most the MERL grid's entries (no channel holds more).
COEFFS = ENCODE["n_coeffs"].capped(GRID_BINS.hi)


def typed(c: Interval):
    """An argparse type from a declared :class:`~sparse_brdf.params.Interval`: the value,
    or a one-line message saying what the option takes."""
    def value(text: str) -> int | float:
        try:
            v = int(text) if c.kind is int else float(text)
        except ValueError:
            what = "an integer" if c.kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v not in c:
            raise argparse.ArgumentTypeError(f"must be {c.describe()}, got {text}")
        return v
    return value


def default_of(func, name: str):
    """The default of ``func``'s parameter ``name`` (a tuple as a list): what an option
    that stands for it defaults to."""
    d = inspect.signature(func).parameters[name].default
    return list(d) if isinstance(d, tuple) else d


#: The kinds of file the commands write: their suffixes and what they are called.
SBRDF = SBRDF_FILE
MERL = ((".binary",), "a MERL .binary file")
ENSEMBLE_NPZ = ((".npz",), "an ensemble .npz file")
SAMPLES_FILE = ((".csv", ".npz"), "a samples .csv or .npz file")
IMAGE = (IMAGE_SUFFIXES, "an image (.exr: linear HDR; .png, .jpg: an sRGB preview)")
MASK = (MASK_SUFFIXES, "an object mask (.exr or .npy)")


def check_outputs(outputs, inputs) -> None:
    """Check every output of a command before its work: ``outputs`` are (path, kind,
    option) with ``kind`` one of the kinds above (None paths skipped). Each must take
    its kind's suffix, not name a folder, be none of the ``inputs`` nor another output,
    and be writable."""
    done: list = []
    for out, (suffixes, kind), option in outputs:
        if not out:
            continue
        check_new_output(out, suffixes, kind, [*inputs, *done], option)
        done.append(out)


def add_source_help(p: argparse.ArgumentParser) -> None:
    """The note below a command's options saying what a BRDF source may be."""
    p.epilog = ("A BRDF source is a MERL/DTU .binary file, a Neural-BRDF .h5 file, a .sbrdf "
                "coefficient file, or mitsuba:<name> for a built-in material.")


def add_symmetrize(p: argparse.ArgumentParser) -> None:
    """``--no-symmetrize``: a Neural-BRDF network read as it is."""
    p.add_argument("--no-symmetrize", dest="symmetrize", action="store_const", const=False,
                   default=None,
                   help="keep a Neural-BRDF network as it is (default: averaged over the "
                        "mirror phi_d -> -phi_d and reciprocity phi_d -> phi_d + pi, as an "
                        "isotropic BRDF is; docs/method.md, \"Symmetric references\")")


def add_where(p: argparse.ArgumentParser, what: str) -> None:
    """``--workers N`` / ``--scheduler ADDRESS``: where ``what`` runs (``parallel.py``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, metavar="N",
                   help=f"run {what} on a local Dask cluster of N processes (default: in "
                        "this process, no cluster)")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help=f"run {what} on an existing Dask cluster (e.g. tcp://host:8786; "
                        "default: in this process)")
