"""``encode``, ``decode`` and ``blend``: materials to ``.sbrdf`` coefficient files (one, or
a folder in a batch), back to MERL tables, and two of them blended in coefficient space."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from ..batch import encode_batch, is_batch
from ..coding import budget as budget_module
from ..coding.encode import encode
from ..coding.fileformat import decode_file
from ..coding.interpolate import PARAMETERS as INTERPOLATE
from ..coding.interpolate import blend_files, interpolate
from ..coding.spec import DEFAULT_FILL_ITERS, DEFAULT_N_BYTES, DEFAULT_N_COEFFS, PAPER_OPTIONS
from ..coords import GRID_BINS
from ..errors import (
    BRDFFileError,
    InvalidBRDFError,
)
from ..parallel import executor
from ..sources.merl import write_merl
from ._options import (
    COEFFS,
    ENCODE,
    MERL,
    add_source_help,
    add_symmetrize,
    add_where,
    check_outputs,
    default_of,
    typed,
)
from .files import encode_file


def cmd_encode(args: argparse.Namespace) -> int:
    """``encode``: one material to a ``.sbrdf`` file, or a batch into a folder."""
    t0 = time.perf_counter()
    options = {"max_error": args.max_error, "transform": args.transform,
               "fill_iters": args.fill_iters, "budget": args.budget,
               "selector": args.selector, "fill": args.fill, "basis": args.basis}
    if args.paper:
        options.update(PAPER_OPTIONS)
        if args.coeffs is None and args.bytes is None:  # the paper's size: a count
            args.coeffs = DEFAULT_N_COEFFS
    if args.symmetrize is not None:
        options["symmetrize"] = args.symmetrize
    if is_batch(args.source):  # encode_batch checks its output folder and options, once
        with executor(args.workers, args.scheduler) as ex:
            summary = encode_batch(args.source, args.output, args.ensemble,
                                   {"n_coeffs": args.coeffs, "n_bytes": args.bytes,
                                    **options}, ex)
        _note_capped(args, summary["grid"])
        return _report_batch(args, summary)
    # encode_file checks the output and the options, once, before any work
    path, model = encode_file(args.source, args.output, args.ensemble, args.coeffs,
                              args.bytes, **options)
    _note_capped(args, model.shape)
    seconds = time.perf_counter() - t0
    info = {"output": str(path), "bytes": path.stat().st_size, "seconds": seconds,
            "transform": model.transform, "coefficients": model.n_coeffs.tolist(),
            "dictionaries": model.dict_index.tolist(), **model.stats}
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    st = model.stats["transforms"][model.transform]
    print(f"wrote {path} ({info['bytes']} bytes): {model.transform}, coefficients "
          f"{info['coefficients']}, dictionaries {info['dictionaries']}, "
          f"RAE {st['rae']:.4f}, gamma-MSE {st['gamma_mse']:.3g}, {seconds:.2f} s")
    return 0


def _report_batch(args: argparse.Namespace, summary: dict) -> int:
    """Print a batch's summary; exit status 1 if any material failed."""
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{args.output}: {summary['encoded']} encoded, {summary['skipped']} skipped "
              f"(done before), {summary['failed']} failed of {summary['materials']} "
              f"in {summary['seconds']:.1f} s; wrote summary.csv, summary.json")
        for r in summary["rows"]:
            if r["status"] == "failed":
                print(f"  failed: {r['source']}: {r['error']}", file=sys.stderr)
    return 1 if summary["failed"] else 0


def _note_capped(args: argparse.Namespace, shape: tuple[int, ...]) -> None:
    """``--coeffs`` is a maximum: the library caps it at a channel's entries. Say so on
    stderr when the user gave a number beyond the grid; the default stays silent."""
    most = math.prod(shape)
    if args.coeffs_given and args.coeffs is not None and args.coeffs > most:
        print(f"sparse-brdf: note: --coeffs {args.coeffs}: a channel of the "
              f"{'x'.join(map(str, shape))} grid holds {most} coefficients; encoded at "
              f"most {most}", file=sys.stderr)


class _Given(argparse.Action):
    """Store an option's value and record that the user gave it (``DEST_given``)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        setattr(namespace, f"{self.dest}_given", True)


def cmd_decode(args: argparse.Namespace) -> int:
    """``decode``: a ``.sbrdf`` file to a MERL ``.binary`` file."""
    check_outputs([(args.output, MERL, "-o")], [args.source, args.ensemble])
    try:
        brdf = decode_file(args.source, args.ensemble)
    except InvalidBRDFError as exc:  # e.g. coefficients so large that the values overflow
        raise BRDFFileError(f"{args.source}: decodes to unusable values: {exc}") from exc
    write_merl(args.output, brdf)
    print(f"wrote {args.output}")
    return 0


def cmd_blend(args: argparse.Namespace) -> int:
    """``blend``: two ``.sbrdf`` files of one ensemble and transform, interpolated."""
    # blend_files checks the output, the ensemble, the count and the pair, once
    out, model = blend_files(args.a, args.b, args.output, args.alpha, args.ensemble,
                             args.coeffs)
    _note_capped(args, model.shape)
    print(f"wrote {out}")
    return 0


def add_encode(sub) -> None:
    """``encode``."""
    e = sub.add_parser("encode", help="encode a BRDF as sparse coefficients (.sbrdf)",)
    e.add_argument("source", help="BRDF source (see below), or a folder or quoted glob "
                                  "of materials to encode them all (batch)")
    e.add_argument("-o", "--output", required=True,
                   help="output .sbrdf path; batch: output folder (<stem>.sbrdf per material, "
                        "summary.csv, summary.json; finished outputs are kept; exit status "
                        "1 if any material failed)")
    size = e.add_mutually_exclusive_group()
    size.add_argument("--coeffs", type=typed(COEFFS), default=default_of(encode, "n_coeffs"),
                      action=_Given,
                      help="the coefficient budget N. With the joint budget (--budget joint, "
                           "the default of the default --basis opponent) the file holds 3 x N "
                           "coefficients shared over the three coded channels where they "
                           "lower the error most, so one channel may hold more than N (e.g. "
                           "262 may give [475, 161, 150]); with --budget channel (--paper) at "
                           "most N per channel. Capped to a channel's entries on a small grid "
                           f"(default: --bytes {DEFAULT_N_BYTES}; with --paper {DEFAULT_N_COEFFS}, "
                           "the paper's)")
    size.add_argument("--bytes", type=typed(budget_module.PARAMETERS["n_bytes"]),
                      default=None, metavar="N",
                      help="byte budget instead: the .sbrdf file holds at most N bytes "
                           "(header included), the coefficients kept the largest over the "
                           "channels (docs/file-format.md, Byte budgets; default: "
                           f"{DEFAULT_N_BYTES}, unless --coeffs or --paper)")
    e.add_argument("--max-error", type=typed(ENCODE["max_error"]),
                   default=default_of(encode, "max_error"),
                   help="stop adding coefficients once the relative squared residual in the "
                        "transformed domain is below this (e.g. 1e-4; default: never, the "
                        "budget decides)")
    e.add_argument("--transform", default=default_of(encode, "transform"),
                   choices=ENCODE["transform"],
                   help="auto: the one --selector prefers of log-lobe-floor(-cosine), "
                        "each material coded relative to a GGX lobe fitted to it and decoded "
                        "as 0 below a floor the encoder chooses (over an "
                        "ensemble trained for the paper's transforms: those); lobe: the "
                        "lobe pair over any ensemble; or one transform (docs/method.md, "
                        "Transforms)")
    e.add_argument("--selector", default=default_of(encode, "selector"),
                   choices=ENCODE["selector"],
                   help="how auto picks the transform: render-albedo, the smaller product "
                        "of the errors predicted under point lights and under uniform "
                        "light; render, the first alone; gamma-mse, the smaller "
                        "gamma-mapped MSE (the paper's)")
    e.add_argument("--fill", default=default_of(encode, "fill"), choices=ENCODE["fill"],
                   help="bins filled from the model instead of fitted as zeros: every "
                        "invalid bin, or only unmeasured bins above the horizon")
    e.add_argument("--fill-iters", type=typed(ENCODE["fill_iters"]),
                   default=default_of(encode, "fill_iters"),
                   help="fill rounds (0: no fill; default per --fill: "
                        + ", ".join(f"{k} {v}" for k, v in DEFAULT_FILL_ITERS.items()) + ")")
    e.add_argument("--basis", default=default_of(encode, "basis"), choices=ENCODE["basis"],
                   help="colour basis of the coded channels (opponent: luminance and two "
                        "colour differences)")
    e.add_argument("--paper", action="store_true",
                   help="the paper's model: --selector gamma-mse --fill missing --basis rgb, "
                        "over the shipped ensemble trained for the paper's transforms unless "
                        "--ensemble names another")
    add_symmetrize(e)
    e.add_argument("--budget", default=default_of(encode, "budget"), choices=ENCODE["budget"],
                   help="--coeffs per channel, or 3 x --coeffs over the channels "
                        "(default: joint for --basis opponent, else channel)")
    e.add_argument("--ensemble", help="ensemble .npz (default: the shipped default)")
    e.add_argument("--json", action="store_true", help="print the encoding statistics as JSON")
    add_where(e, "a batch")
    add_source_help(e)
    e.set_defaults(func=cmd_encode, coeffs_given=False)


def add_decode(sub) -> None:
    """``decode``."""
    d = sub.add_parser("decode", help="decode a .sbrdf file to a MERL .binary file")
    d.add_argument("source", help=".sbrdf file")
    d.add_argument("-o", "--output", required=True, help="output .binary path")
    d.add_argument("--ensemble", help="ensemble .npz (default: the shipped one the file names)")
    d.set_defaults(func=cmd_decode)


def add_blend(sub) -> None:
    """``blend``."""
    bl = sub.add_parser("blend", help="interpolate two .sbrdf materials in coefficient space")
    bl.add_argument("a", help="first .sbrdf (its dictionaries and transform are used)")
    bl.add_argument("b", help="second .sbrdf (same ensemble and transform)")
    bl.add_argument("--alpha", type=typed(INTERPOLATE["alpha"]), required=True,
                    help="0 gives A, 1 gives B")
    bl.add_argument("--coeffs", type=typed(INTERPOLATE["n_coeffs"].capped(GRID_BINS.hi)),
                    default=default_of(interpolate, "n_coeffs"), action=_Given,
                    help="at most this many coefficients per channel of the result "
                         "(default: the larger of the two files' counts)")
    bl.add_argument("--ensemble", help="ensemble .npz (default: the shipped one the files name)")
    bl.add_argument("-o", "--output", required=True, help="output .sbrdf")
    bl.set_defaults(func=cmd_blend, coeffs_given=False)
