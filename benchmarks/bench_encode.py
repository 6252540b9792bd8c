"""Encode time per material with the shipped ensemble: in-process, or as whole commands.

    .venv/bin/python benchmarks/bench_encode.py [--n 8]
    .venv/bin/python benchmarks/bench_encode.py \
        --options selector=render,fill=invalid,basis=opponent
    .venv/bin/python benchmarks/bench_encode.py --whole --n 8 [--code OTHER_CHECKOUT]
    .venv/bin/python benchmarks/bench_encode.py --whole --also "--transform lobe"

In-process (the default): times `encode` at 262 coefficients per channel, both
transforms (the default) and one forced transform; tabulation is excluded (materials are
loaded first).

``--whole``: times the commands a user runs, each a new process (imports, loading the
material from the tabulation cache, encoding, writing the file): ``sparse-brdf encode SRC
-o OUT`` (the default size: at most 1,700 bytes; 262 per channel before 2026-12-07,
as a ``--code`` checkout of then runs it) and ``sparse-brdf encode SRC -o OUT --bytes
6300``. The
package is compiled to bytecode first, as an installed package is. With
``--also "ARGS"`` each command also runs with ARGS appended (e.g. the lobe pair,
``--transform lobe``), interleaved with the plain one. With
``--code DIR`` (another checkout, e.g. ``git worktree`` of an older commit) every command
also runs with that checkout's package first on ``PYTHONPATH``, interleaved with this
one's (which goes first alternates), and the files both write are compared byte for
byte: on a machine loaded by others, the ratio within one run is the figure to trust.

Each material is timed ``--repeats`` times (interleaved: every material and variant once
per round) and its median taken, since the virtual machine's speed drifts by 10-40 %
from minute to minute; the table gives the mean and the max over materials of those
medians, and the load average before and after.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import header, parser, write_json

from sparse_brdf import Ensemble, encode, get_corpus
from sparse_brdf.paths import shared_data_dir

#: The whole commands timed by ``--whole``: name -> extra arguments of ``encode``.
COMMANDS = {"encode (the default size)": [], "encode --bytes 6300": ["--bytes", "6300"]}


def _materials(args) -> tuple[str, list]:
    names = args.corpus or ["merl" if shared_data_dir() else "mitsuba"]
    return "+".join(names), [m for c in names for m in get_corpus(c).split("test")[: args.n]]


def _header(what: str, n: int, corpus: str, args, load: tuple[float, float]) -> str:
    return (f"{header()}\n{n} {corpus} test materials, {what}, median of {args.repeats} "
            f"per material, load average (1 min) {load[0]:.1f} before, {load[1]:.1f} after")


def in_process(args) -> None:
    opts = dict(kv.split("=", 1) for kv in args.options.split(",") if kv)
    corpus, mats = _materials(args)
    ens = Ensemble.default()
    brdfs = [m.load() for m in mats]
    encode(brdfs[0], ens, **opts)  # warm-up (thread pool, caches)
    load0 = os.getloadavg()[0]
    auto = np.zeros((args.repeats, len(brdfs)))
    forced = np.zeros_like(auto)
    completed = []
    for r in range(args.repeats):
        for i, b in enumerate(brdfs):
            t0 = time.perf_counter()
            m = encode(b, ens, **opts)
            auto[r, i] = time.perf_counter() - t0
            if r == 0:
                completed += [s["projections_completed"] for s in m.stats["transforms"].values()]
            t0 = time.perf_counter()
            encode(b, ens, transform="log-plus-cosine", **opts)
            forced[r, i] = time.perf_counter() - t0
    auto, forced = np.median(auto, axis=0), np.median(forced, axis=0)
    print(_header(f"in-process, {ens.n_dicts} dictionaries, options: "
                  f"{args.options or 'defaults'}", len(brdfs), corpus, args,
                  (load0, os.getloadavg()[0])))
    print(f"| mode | mean (s) | max (s) |\n|---|---|---|\n"
          f"| both transforms (auto) | {np.mean(auto):.2f} | {np.max(auto):.2f} |\n"
          f"| one transform (forced) | {np.mean(forced):.2f} | {np.max(forced):.2f} |")
    print(f"\nProjections completed per transform (of {3 * ens.n_dicts}; the rest pruned): "
          f"median {np.median(completed):.0f}, range {min(completed)}-{max(completed)}")
    if args.json:
        write_json(args.json, {"materials": [m.name for m in mats],
                               "auto_s": auto.tolist(), "forced_s": forced.tolist(),
                               "projections_completed": completed}, args)


def _run(code: Path | None, src: str, out: Path, extra: list[str]) -> float:
    """Seconds of one whole ``sparse-brdf encode`` process (this checkout, or ``code``)."""
    env = dict(os.environ)
    if code is not None:
        env["PYTHONPATH"] = str(code)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "sparse_brdf.cli", "encode", src, "-o", str(out),
                    *extra], check=True, env=env, cwd=tempfile.gettempdir(),
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _compile(root: Path) -> None:
    """Compile a checkout's package to bytecode, as pip does when it installs one: where
    PYTHONDONTWRITEBYTECODE is set (as on the machine of docs/benchmarks.md) Python would
    otherwise compile the package's modules again in every command, about 0.3 s."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(root / "sparse_brdf")],
                   check=True, stdout=subprocess.DEVNULL)


def whole(args) -> None:
    corpus, mats = _materials(args)
    commands = dict(COMMANDS)
    for extra in args.also:  # the same commands with more arguments
        commands.update({f"{k} {extra}": [*v, *extra.split()] for k, v in COMMANDS.items()})
    for m in mats:
        m.load()  # tabulate into the cache first: the commands then read it
    codes: dict[str, Path | None] = {"this checkout": None}
    if args.code:
        codes["--code"] = Path(args.code).resolve()
    for root in codes.values():
        _compile(root or Path(__file__).resolve().parents[1])
    cases = [(c, k) for c in codes for k in commands]
    times = {case: np.zeros((args.repeats, len(mats))) for case in cases}
    same, compared = 0, 0
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:

        def out(i: int, case: tuple) -> Path:
            return Path(tmp) / f"{i}-{list(codes).index(case[0])}-{list(commands).index(case[1])}"

        _run(None, str(mats[0].source), Path(tmp) / "warm.sbrdf", [])  # page cache
        for r in range(args.repeats):
            for i, m in enumerate(mats):
                # alternate which checkout goes first: on a shared machine the first
                # command of a pair measured up to 15 % slower than the second
                for case in (cases if (r + i) % 2 == 0 else cases[::-1]):
                    times[case][r, i] = _run(codes[case[0]], str(m.source),
                                             out(i, case).with_suffix(".sbrdf"),
                                             commands[case[1]])
                if r == 0 and args.code:
                    for k in commands:
                        a, b = (out(i, (c, k)).with_suffix(".sbrdf").read_bytes()
                                for c in codes)
                        compared += 1
                        same += a == b
    load1 = os.getloadavg()[0]
    print(_header("whole `sparse-brdf encode` processes", len(mats), corpus, args,
                  (load0, load1)))
    print("| code | command | mean (s) | max (s) |\n|---|---|---|---|")
    med = {case: np.median(t, axis=0) for case, t in times.items()}
    for (c, k), v in med.items():
        print(f"| {c} | {k} | {np.mean(v):.2f} | {np.max(v):.2f} |")
    if args.code:
        print()
        for k in commands:
            ratio = np.median(med[("this checkout", k)] / med[("--code", k)])
            print(f"{k}: this checkout / --code, median over materials {ratio:.2f}")
        print(f"files byte-identical between the two: {same} of {compared}")
    if args.json:
        write_json(args.json, {"materials": [m.name for m in mats],
                               "median_s": {f"{c} | {k}": v.tolist()
                                            for (c, k), v in med.items()},
                               "identical_files": [same, compared]}, args)


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--n", type=int, default=8, help="materials per corpus")
    p.add_argument("--corpus", nargs="+", default=None,
                   help="test splits to time (default: merl, or mitsuba without ../shared)")
    p.add_argument("--options", default="", help="encoder options KEY=VALUE,... (as in the "
                   "bench's sparse model specs), applied to every timed encode (in-process)")
    p.add_argument("--repeats", type=int, default=3, help="timings per material (median)")
    p.add_argument("--whole", action="store_true",
                   help="time whole `sparse-brdf encode` commands (the default size and "
                        "--bytes 6300), each a new process")
    p.add_argument("--code", help="with --whole: another checkout to time interleaved "
                                  "with this one, and to compare files with")
    p.add_argument("--also", action="append", default=[], metavar="ARGS",
                   help="with --whole: also time each command with ARGS appended (e.g. "
                        "'--transform lobe'); repeatable")
    args = p.parse_args()
    (whole if args.whole else in_process)(args)


if __name__ == "__main__":
    main()
