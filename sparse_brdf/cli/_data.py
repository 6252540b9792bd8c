"""``corpus list``, ``info`` and ``convert``: the corpora, one material's summary, and any
BRDF source tabulated into a MERL ``.binary`` file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..coding.fileformat import describe
from ..errors import one_line
from ..sources.corpora import get_corpus, list_corpora
from ..sources.load import load_brdf
from ..sources.merl import write_merl
from ..transforms import has_floor, per_material
from ._options import MERL, add_source_help, add_symmetrize, check_outputs


def cmd_corpus_list(args: argparse.Namespace) -> int:
    """``corpus list``: the corpora, or one corpus's materials and split."""
    if args.corpus:
        c = get_corpus(args.corpus)
        test = {m.name for m in c.split("test")}
        for m in c.materials:
            print(one_line(f"{m.name:40s} {'test' if m.name in test else 'train':5s} "
                           f"{m.source}"))
        return 0
    for name, desc in list_corpora().items():
        print(f"{name:8s} {desc}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    """``info``: a material's shape, valid bins, value range and albedo; for a ``.sbrdf``
    file also what the file holds (version, ensemble, transform, basis, coefficients,
    bytes, dictionaries)."""
    held = describe(args.source) if str(args.source).lower().endswith(".sbrdf") else None
    info = load_brdf(args.source, symmetrize=args.symmetrize).summary()
    if held is not None:
        info = {**info, **held}
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"name         {one_line(info['name'])}\nsource       {one_line(info['source'])}")
    if held is not None:
        _print_held(held)
    print(f"shape        {tuple(info['shape'])}")
    print(f"valid bins   {info['valid_bins']} of {info['total_bins']}")
    for i, ch in enumerate("RGB"):
        print(f"{ch}            min {info['min'][i]:.4g}  max {info['max'][i]:.4g}  "
              f"mean {info['mean'][i]:.4g}  albedo {info['albedo'][i]:.3f}")
    return 0


def _print_held(held: dict) -> None:
    """What a ``.sbrdf`` file holds (:func:`~sparse_brdf.coding.fileformat.describe`), one
    line per key, labelled with the ``--json`` keys."""
    codec = f" ({held['codec']} payload)" if held["codec"] else ""
    shipped = "shipped with this version" if held["ensemble_shipped"] else "not shipped"
    per = ", ".join(f"{ch} {n}" for ch, n in zip(held["channels"], held["coefficients"],
                                                   strict=True))
    dicts = ", ".join(f"{ch} {d}" for ch, d in zip(held["channels"], held["dictionaries"],
                                                    strict=True))
    print(f"version      {held['version']}{codec}\n"
          f"bytes        {held['bytes']}\n"
          f"ensemble     {held['ensemble']} ({shipped})\n"
          f"grid         {tuple(held['grid'])}\n"
          f"transform    {held['transform']} (every channel{_level(held)})\n"
          f"basis        {held['basis']} (channels {', '.join(held['channels'])})\n"
          f"coefficients {held['coefficients_total']} ({per})\n"
          f"dictionaries {dicts}")
    print("decoded      the values the file decodes to, with its ensemble:")


def _level(held: dict) -> str:
    """``; material level L = ... /sr`` for a file with a per-material gain 1/L (and its
    base lobe, for a lobe transform, and its floor, for a floor transform), else ""."""
    if not per_material(held["transform"]):
        return ""
    lobe = held.get("lobe")
    more = "" if lobe is None else (
        f"; base lobe alpha {lobe['alpha']:.4g}, kd {', '.join(f'{v:.4g}' for v in lobe['kd'])}"
        f", ks {', '.join(f'{v:.4g}' for v in lobe['ks'])} /sr")
    if has_floor(held["transform"]):
        more += f"; floor {held['floor']:.4g} L (values below decode as 0)"
    return f"; material level {1.0 / held['gain']:.4g} /sr{more}"


def cmd_convert(args: argparse.Namespace) -> int:
    """``convert``: any BRDF source tabulated into a MERL ``.binary`` file."""
    out = Path(args.output)
    check_outputs([(out, MERL, "output")], [args.source])
    write_merl(out, load_brdf(args.source, symmetrize=args.symmetrize))
    print(f"wrote {out}")
    return 0


def add_data_commands(sub) -> None:
    """``corpus list``, ``info`` and ``convert``."""
    c = sub.add_parser("corpus", help="list corpora and their train/test split")
    csub = c.add_subparsers(dest="corpus_command", required=True, metavar="ACTION")
    cl = csub.add_parser("list", help="list corpora, or the materials of one corpus")
    cl.add_argument("corpus", nargs="?",
                    help="a corpus name (mitsuba, merl-demo, merl, rgl, abc, sgd) or a folder")
    cl.set_defaults(func=cmd_corpus_list)

    i = sub.add_parser("info", help="shape, valid bins, value range and albedo of a BRDF; "
                                    "for a .sbrdf also what the file holds")
    i.add_argument("source", help="BRDF source (see below)")
    i.add_argument("--json", action="store_true", help="print JSON")
    add_symmetrize(i)
    add_source_help(i)
    i.set_defaults(func=cmd_info)

    v = sub.add_parser("convert", help="tabulate any BRDF source into a MERL .binary file")
    v.add_argument("source", help="BRDF source (see below)")
    v.add_argument("output", help="output .binary path (written atomically)")
    add_symmetrize(v)
    add_source_help(v)
    v.set_defaults(func=cmd_convert)
