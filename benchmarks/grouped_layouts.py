"""Which grouped layout do real materials get, and how many packets does a lookup read?

For the test split of each corpus, encodes every material with the shipped ensemble and
prints, per material: the dictionary of each channel, the distinct atoms of the grouped
mode per channel (K) and over the three channels (union), the layout ``layout="auto"``
picks (``sparse_brdf.decoders.layouts.layout_kind``), the packets of 8 floats a lookup reads in
it and in the other layout, and the grouped decoder's bytes.

    .venv/bin/python benchmarks/grouped_layouts.py [--coeffs 262] [--corpora merl rgl]
"""

from __future__ import annotations

import sys

from harness import header, parser, write_json
from tqdm import tqdm

from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.decoders.layouts import (
    PACKET,
    SLOT,
    atom_keys,
    grouped_bytes,
    layout_for,
    layout_packets,
    n_slots,
    shared_grouped_mode,
    union_chunks,
)
from sparse_brdf.sources.corpora import get_corpus


def layout_row(model, ens) -> dict:
    """The layout figures of one encoded material (see the module docstring)."""
    g = shared_grouped_mode(model, ens)
    keys = atom_keys(model, ens, g)
    ks = [len(k) for k in keys]
    union = len(set().union(*keys))
    kind, _ = layout_for(keys)
    packets = {"slots": layout_packets("slots", n_slots(ks) * SLOT // PACKET),
               "union": layout_packets("union", union_chunks(union))}
    return {"dicts": [int(d) for d in model.dict_index], "mode": g + 1, "k": ks,
            "union": union, "layout": kind, "packets": packets[kind],
            "other": packets["union" if kind == "slots" else "slots"],
            "bytes": grouped_bytes(model, ens)}


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--coeffs", type=int, default=262, help="coefficients per channel")
    p.add_argument("--corpora", nargs="+", default=["merl", "rgl"])
    args = p.parse_args()
    ens = Ensemble.default()
    mats = [m for c in args.corpora for m in get_corpus(c).split("test")]
    rows = []
    for m in tqdm(mats, desc="encoding", file=sys.stderr):
        rows.append((m, layout_row(encode(m.load(), ens, args.coeffs), ens)))
    print(f"{args.coeffs} coefficients per channel, shipped ensemble, test splits of "
          f"{', '.join(args.corpora)}; {header()}")
    print("| material | dictionaries | grouped mode | K per channel | union | layout | "
          "packets | other layout | bytes |")
    print("|---|---|---|---|---|---|---|---|---|")
    for m, r in rows:
        print(f"| {m.corpus}/{m.name} | {r['dicts']} | {r['mode']} | {r['k']} | "
              f"{r['union']} | {r['layout']} | {r['packets']} | {r['other']} | "
              f"{r['bytes']:,} |")
    one = sum(len(set(r["dicts"])) == 1 for _, r in rows)
    union = sum(r["layout"] == "union" for _, r in rows)
    auto = [r["packets"] for _, r in rows]
    slots = [r["packets"] if r["layout"] == "slots" else r["other"] for _, r in rows]
    print(f"\nOne dictionary for the three channels: {one} of {len(rows)}; union layout "
          f"chosen: {union} of {len(rows)}; packets per lookup: mean "
          f"{sum(auto) / len(rows):.1f} (slot layout only: {sum(slots) / len(rows):.1f}).")
    if args.json:
        write_json(args.json, [{"material": f"{m.corpus}/{m.name}", **r} for m, r in rows],
                   args)

if __name__ == "__main__":
    main()
