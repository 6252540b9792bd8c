"""``bench``, ``bench-merge`` and ``bench-compare``: compared models measured by a bench
suite (or the acquisition bench), several suites' results ranked in one table, and two
results compared cell by cell (the regression gate)."""

from __future__ import annotations

import argparse

from ..benchmark.acquisition_bench import KIND as ACQUISITION
from ..benchmark.acquisition_bench import (
    AcquisitionBench,
    AcquisitionConfig,
    check_acquisition_config,
)
from ..benchmark.bench import Bench, BenchConfig
from ..benchmark.bench_config import SETTINGS, check_config, config_kind, shipped_configs
from ..benchmark.compare import PARAMETERS as GATE
from ..benchmark.compare import compare_results, format_worse
from ..benchmark.ranking import RANK_BY, merge_results, write_ranking
from ..compared.specs import parse_spec
from ..errors import UsageError
from ..parallel import executor
from ._options import add_where, default_of, typed


def cmd_bench(args: argparse.Namespace) -> int:
    """``bench``: a config checked in full, then run (or only checked, ``--check``)."""
    if args.config is not None and config_kind(args.config) == ACQUISITION:
        return _bench_acquisition(args)
    cfg = BenchConfig.load(args.config)
    if args.out:
        cfg.out = args.out
    if args.no_render:
        cfg.render = False
    if args.seeds is not None:
        cfg.seeds = args.seeds
    if args.model:
        if not args.out:  # the config's folder holds its own models' results
            raise UsageError(f"--model: give --out too, a folder of its own (the results of "
                             f"{cfg.label}'s models in {cfg.out} would be replaced)")
        for spec in args.model:
            try:  # the grammar; check_config imports and checks each model
                parse_spec(spec)
            except UsageError as exc:
                raise UsageError(f"--model: {exc}") from None
        cfg.models = list(args.model)
    plan = check_config(cfg)  # a config the run would refuse fails here, before any work
    if args.check:
        skipped = "".join(f"; skips {k}: {v}" for k, v in plan["skipped_scenes"].items())
        print(f"{cfg.label}: ok: {plan['materials']} materials x {len(plan['models'])} "
              f"models, {plan['training']} training materials, scenes "
              f"{', '.join(plan['scenes']) or 'none'}{skipped}")
        return 0
    with executor(args.workers, args.scheduler) as ex:
        Bench(cfg, keep_work=args.keep_work).run(ex)
    print(f"wrote {cfg.out}/report.md, report.html, results.csv, results.json")
    return 0


def cmd_bench_merge(args: argparse.Namespace) -> int:
    """``bench-merge``: several results files ranked in one table."""
    merged = merge_results(args.results, by=args.by)
    paths = write_ranking(merged, args.output)
    print(f"ranked {len(merged['rows'])} models of {len(args.results)} results files: wrote "
          f"{', '.join(str(p) for p in paths)}")
    return 0


def cmd_bench_compare(args: argparse.Namespace) -> int:
    """``bench-compare``: exit status 1 when a shared cell got worse, listing them."""
    found = compare_results(args.old, args.new, args.fail_if_worse, args.fail_if_flip_rises)
    flip = (f", HDR-FLIP risen by more than {args.fail_if_flip_rises}"
            if args.fail_if_flip_rises is not None else "")
    what = f"SNR dropped by more than {args.fail_if_worse} dB{flip}"
    for row in found["worse"]:
        print(format_worse(row))
    if found["worse"]:
        print(f"bench-compare: {len(found['worse'])} of {found['figures']} figures of "
              f"{found['cells']} shared cells are worse ({what})")
        return 1
    print(f"bench-compare: {found['cells']} shared cells, {found['figures']} figures, none "
          f"worse ({what})")
    return 0


def _bench_acquisition(args: argparse.Namespace) -> int:
    """``bench`` of an acquisition config: the options it takes, checked, then run."""
    cfg = AcquisitionConfig.load(args.config)
    if args.out:
        cfg.out = args.out
    if args.model:
        raise UsageError(f"--model: the acquisition bench ({cfg.label}) compares encodings "
                         "from samples, the sparse model and PCA; it takes no --model")
    if args.no_render or args.seeds is not None or args.workers or args.scheduler:
        given = ("--no-render" if args.no_render else "--seeds" if args.seeds is not None
                 else "--workers/--scheduler")
        raise UsageError(f"{given}: the acquisition bench ({cfg.label}) renders every fit "
                         "here; run it without that option")
    plan = check_acquisition_config(cfg)
    if args.check:
        skipped = "".join(f"; skips {k}: {v}" for k, v in plan["skipped_scenes"].items())
        print(f"{cfg.label}: ok: {plan['materials']} materials x {plan['cells']} fits, "
              f"scenes {', '.join(plan['scenes'])}{skipped}")
        return 0
    AcquisitionBench(cfg).run()
    print(f"wrote {cfg.out}/report.md, results.csv, results.json")
    return 0


def add_bench_commands(sub) -> None:
    """``bench``, ``bench-merge`` and ``bench-compare``."""
    b = sub.add_parser("bench", help="compare models: tables, figures, speed-vs-accuracy chart",
                       description="Run a bench suite: a built-in config by name ("
                                   + ", ".join(shipped_configs()) + ") or a TOML file; "
                                   "finished cells are skipped on a re-run. `acquisition` "
                                   "(or a config with bench = \"acquisition\") benches "
                                   "encoding from N measured samples, the sparse model against "
                                   "PCA (docs/results.md); it renders every fit and takes "
                                   "neither --no-render nor a Dask cluster.")
    b.add_argument("config", nargs="?",
                   help="a built-in config's name or a TOML file (default: the small suite)")
    b.add_argument("--out", help="output folder (default: the config's)")
    b.add_argument("--no-render", action="store_true", help="BRDF-space metrics only")
    b.add_argument("--seeds", metavar="N", type=typed(SETTINGS["seeds"]),
                   help="render each cell at N seeds (from the config's seed on) and report "
                        "each figure's mean and standard error (default: the config's "
                        "seeds, 1 unless it sets it)")
    b.add_argument("--model", action="append", metavar="SPEC",
                   help="compare this model instead of the config's models (repeat it for "
                        "several): a built-in spec (sparse, the default size; sparse:262, "
                        "naive, pca:40, ...) or module:Class[:KEY=VALUE,...], a class of "
                        "your own imported "
                        "from the Python path or the current directory "
                        "(docs/bench-guide.md; default: the config's models)")
    b.add_argument("--keep-work", action="store_true",
                   help="keep the decoded tables (work/*.binary, about 35 MB per material "
                        "and model) after each cell; renders, HDR-FLIP maps and .sbrdf files "
                        "are kept either way (default: off, each cell's tables are deleted "
                        "once it is done)")
    b.add_argument("--check", action="store_true",
                   help="check the config (settings, models, corpora, training materials, "
                        "scenes) and exit without running it")
    add_where(b, "the cells (material x model)")
    b.set_defaults(func=cmd_bench)

    bm = sub.add_parser("bench-merge", help="rank the models of several bench results in "
                                            "one table (Markdown and CSV)",
                        description="Merge results.json files of benches that measured "
                                    "the same protocol (corpora, split, scenes, spp, res, "
                                    "seed), e.g. the standard suite's shipped models and "
                                    "your own model's run, from any machines, into one "
                                    "ranked table: ranking.md and ranking.csv. Models are "
                                    "ranked over the materials every ranked model finished; "
                                    "the others are listed apart with their count of "
                                    "finished materials. One run given twice, or runs "
                                    "whose speed settings (speed, speed_evals) differ, are "
                                    "refused.")
    bm.add_argument("results", nargs="+", help="results.json files or bench output folders")
    bm.add_argument("--by", choices=tuple(RANK_BY), default=default_of(merge_results, "by"),
                    help="rank by the mean over the scenes of this figure (higher SNR, "
                         "lower HDR-FLIP first)")
    bm.add_argument("-o", "--output", required=True, help="output folder")
    bm.set_defaults(func=cmd_bench_merge)

    bc = sub.add_parser("bench-compare", help="the regression gate: exit status 1 when a "
                                              "cell of NEW is worse than in OLD",
                        description="Compare two bench results of one protocol cell by "
                                    "cell (material x model, in every scene both rendered): "
                                    "print every figure that got worse and exit with status "
                                    "1, else 0. Worse: an SNR form (object-only, "
                                    "whole-image; cos-SNR without renders) dropped by more "
                                    "than --fail-if-worse dB, HDR-FLIP rose by more than "
                                    "--fail-if-flip-rises, or the cell failed in NEW.")
    bc.add_argument("old", help="the baseline: a results.json file or a bench output folder")
    bc.add_argument("new", help="the results to check, likewise")
    bc.add_argument("--fail-if-worse", metavar="DB", required=True,
                    type=typed(GATE["worse_db"]),
                    help="largest SNR drop in dB that passes")
    bc.add_argument("--fail-if-flip-rises", metavar="X", type=typed(GATE["flip_rise"]),
                    help="largest HDR-FLIP rise that passes (default: FLIP not gated)")
    bc.set_defaults(func=cmd_bench_compare)
