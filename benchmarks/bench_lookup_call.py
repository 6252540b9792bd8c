"""Cost of one BRDF lookup in Mitsuba's scalar variants: ``sparse_brdf`` against
``tabulated_brdf``, one Python call per direction pair, in one thread (docs/benchmarks.md,
"Render speed per variant").

In a scalar variant every BSDF call is a Python call, so the decode's share of a render is
counted in microseconds per call. Renders (``bench_variants.py``) also carry Mitsuba's own
per-sample work and the render threads' contention for Python's lock, which on a small
shared machine moves their ratio by 0.1-0.2 from one process to the next; this script
times the plugins' ``_rho`` (coordinates, bin, decode, inverse transform: what differs
between them) on the same random direction pairs, interleaved over rounds.

    .venv/bin/python benchmarks/bench_lookup_call.py [--material SOURCE] [--variant V]
        [--plugin-root CHECKOUT] [--json PATH]

``--plugin-root`` puts another checkout's ``mitsuba_plugin`` and ``sparse_brdf`` first on
the import path (e.g. ``git worktree add /tmp/before HEAD~1``), so two trees compare with
two runs of this script.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, machine, parser, write_json

if "--plugin-root" in sys.argv:  # another checkout's plugin and library, before any import
    sys.path.insert(0, sys.argv[sys.argv.index("--plugin-root") + 1])

from render_timing import default_material  # noqa: E402


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) unit vectors in the upper hemisphere, uniform over directions."""
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def time_calls(src: str, variant: str, pairs: int, rounds: int, seed: int) -> dict:
    """Median microseconds per ``_rho`` call of the table and the sparse model of ``src``
    (encoded by this tree's default) over ``pairs`` random direction pairs per round."""
    import mitsuba as mi  # lazy: Mitsuba loads only once a benchmark runs

    import mitsuba_plugin
    from sparse_brdf.coding.encode import encode
    from sparse_brdf.coding.fileformat import save_sbrdf
    from sparse_brdf.mitsuba_env import set_variant
    from sparse_brdf.sources.load import load_brdf

    set_variant(variant)
    mitsuba_plugin.register()
    with tempfile.TemporaryDirectory() as tmp:
        sbrdf = str(save_sbrdf(Path(tmp) / "m.sbrdf", encode(load_brdf(src))))
        bsdfs = {"tabulated_brdf": mi.load_dict({"type": "tabulated_brdf", "filename": src,
                                                 "sampling": "cosine"}),
                 "sparse_brdf": mi.load_dict({"type": "sparse_brdf", "filename": sbrdf,
                                              "sampling": "cosine"})}
    rng = np.random.default_rng(seed)
    wis, wos = _directions(rng, pairs), _directions(rng, pairs)
    dirs = [(mi.Vector3f(*a), mi.Vector3f(*b)) for a, b in zip(wis, wos, strict=True)]
    times = {k: [] for k in bsdfs}
    for _ in range(rounds):
        for name, bsdf in bsdfs.items():
            t0 = time.perf_counter()
            for wi, wo in dirs:
                bsdf._rho(wi, wo, True)
            times[name].append((time.perf_counter() - t0) / pairs * 1e6)
    out = {k: float(np.median(t)) for k, t in times.items()}
    out["ratio"] = out["sparse_brdf"] / out["tabulated_brdf"]
    return {"variant": variant, "pairs": pairs, "rounds": rounds, **out}


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--material", default=None,
                   help="BRDF source (default: MERL blue-metallic-paint2 if the shared data "
                        "is present, else mitsuba:cu-ggx-0.12)")
    p.add_argument("--variant", default="scalar_rgb",
                   help="a scalar Mitsuba variant (default: scalar_rgb)")
    p.add_argument("--pairs", type=int, default=5000,
                   help="direction pairs per round (default: 5000)")
    p.add_argument("--rounds", type=int, default=7,
                   help="interleaved rounds, each timing both plugins (default: 7)")
    p.add_argument("--seed", type=int, default=0, help="seed of the directions (default: 0)")
    p.add_argument("--plugin-root", type=Path, default=None,
                   help="a checkout whose mitsuba_plugin and sparse_brdf are used instead "
                        "(default: this one)")
    args = p.parse_args()
    if not args.variant.startswith("scalar"):
        p.error(f"--variant: {args.variant!r} is not a scalar variant")
    info = machine()
    src = default_material(args.material)
    row = time_calls(src, args.variant, args.pairs, args.rounds, args.seed)
    import mitsuba_plugin  # lazy: only to print where it came from

    print(header(info))
    print(f"material {src}, plugin {Path(mitsuba_plugin.__file__).parent}")
    print(f"{row['variant']}: tabulated_brdf {row['tabulated_brdf']:.2f} us, sparse_brdf "
          f"{row['sparse_brdf']:.2f} us per call, sparse / table {row['ratio']:.2f}")
    if args.json:
        write_json(args.json, [row], args, info)


if __name__ == "__main__":
    main()
