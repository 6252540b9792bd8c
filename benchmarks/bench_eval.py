"""Evaluation speed of every model with its own evaluator (the speed axis).

    .venv/bin/python benchmarks/bench_eval.py [--material SOURCE] [--corpus NAME]
        [--n 1048576] [--repeats 5] [--rounds 3] [--pca-train 30] [--json PATH]

Times :func:`sparse_brdf.benchmark.speed.evals_per_second` on one material for: the
full table (``tabulated_brdf`` plugin), the sparse model at 32 / 128 / 262 coefficients
per channel (``sparse_brdf`` plugin, grouped and strict decoders; the shipped ensemble),
and the baselines through their own Dr.Jit evaluators (``mitsuba_plugin.evaluators``):
naive (Bagher et al.), rank-1 CPD, 1x1x1 Tucker, PCA (Nielsen et al.) with 40 and 300
coefficients, Neural-BRDF (Sztrajman et al.; a network trained for one epoch on 20,000
samples: its evaluator's cost does not depend on the weights' values). Each figure: 2^20
random upper-hemisphere direction pairs per call, the median call time of ``--repeats``
calls (fresh pairs each, after one untimed call that compiles), then the median over
``--rounds`` rounds (every model once per round, so that the machine's slow and fast
phases hit all models alike).

Material: by default the first test-split material of the MERL corpus when
``../shared/data`` is present, else of the built-in ``mitsuba`` corpus. PCA is trained
on at most ``--pca-train`` materials of that corpus's training split (its basis over the
full grid is large: k x 4.4 M floats), so it has at most ``--pca-train`` - 1 components:
the table states the k it used. Bytes per material: what each model stores per material
(``Compact.nbytes``; shared bases and the ensemble not counted).
"""

from __future__ import annotations

import copy
import sys
import warnings

import numpy as np
from harness import header, machine, parser, write_json

from sparse_brdf.benchmark.speed import evals_per_second
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.compared.baselines import PCAModel, TabulatedModel
from sparse_brdf.compared.sparse_model import SparseModel
from sparse_brdf.compared.specs import make_model
from sparse_brdf.paths import shared_data_dir
from sparse_brdf.sources.corpora import get_corpus
from sparse_brdf.sources.load import load_brdf


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def build_cases(brdf, corpus: str, pca_train: int, ens: Ensemble) -> list[dict]:
    """Fit every model on ``brdf``: [{name, evaluator, compact, decoder}]."""
    cases = [{"name": "tabulated", "evaluator": "tabulated_brdf plugin",
              "compact": TabulatedModel().compress(brdf)}]
    for n in (32, 128, 262):
        _log(f"encoding sparse {n}")
        c = SparseModel(ens, n).compress(brdf)
        for decoder in ("grouped", "strict"):
            cases.append({"name": f"sparse {decoder} {n}", "decoder": decoder,
                          "evaluator": f"sparse_brdf plugin ({decoder})", "compact": c})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # tensorly's rank notices
        for name in ("naive", "cpd:1", "tucker:1x1x1"):
            _log(f"fitting {name}")
            cases.append({"name": name, "evaluator": "own evaluator",
                          "compact": make_model(name).compress(brdf)})
    _log("training nbrdf (one short epoch: the cost does not depend on the weights)")
    nbrdf = make_model("nbrdf:epochs=1,n_samples=20000")
    nbrdf.progress = False
    cases.append({"name": "nbrdf", "evaluator": "own evaluator",
                  "compact": nbrdf.compress(brdf)})
    mats = [m for m in get_corpus(corpus).split("train") if m.name != brdf.name][:pca_train]
    _log(f"training PCA on {len(mats)} {corpus} training materials")
    pca = PCAModel(300).fit([m.load(brdf.shape) for m in mats])
    for k in (40, 300):
        model = copy.copy(pca)  # the trained state shared, not copied
        model.n_coeffs, model.name = k, f"pca-{k}"
        c = model.compress(brdf)
        cases.append({"name": f"pca:{k} (k = {c.info['n_coeffs']})",
                      "evaluator": "own evaluator", "compact": c})
    return cases


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--material", default=None,
                   help="BRDF source (default: the first test-split material of --corpus)")
    p.add_argument("--corpus", default=None,
                   help="corpus of the default material and of PCA's training split "
                        "(default: merl if ../shared/data is present, else mitsuba)")
    p.add_argument("--n", type=int, default=1 << 20, help="direction pairs per call")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per measurement")
    p.add_argument("--rounds", type=int, default=3, help="measurements per model")
    p.add_argument("--pca-train", type=int, default=30,
                   help="at most this many training materials for PCA")
    args = p.parse_args()

    corpus = args.corpus or ("merl" if shared_data_dir() else "mitsuba")
    if args.material is None:
        mat = get_corpus(corpus).split("test")[0]
        src, brdf = mat.source, mat.load()
    else:
        src = args.material
        brdf = load_brdf(src)
    ens = Ensemble.default()
    info = machine()  # the load average as the timing starts
    cases = build_cases(brdf, corpus, args.pca_train, ens)

    rates: dict[str, list[float]] = {c["name"]: [] for c in cases}
    for r in range(args.rounds):
        _log(f"round {r + 1}/{args.rounds}")
        for c in cases:
            rates[c["name"]].append(evals_per_second(
                c["compact"], args.n, args.repeats,  # sparse: the shipped ensemble
                decoder=c.get("decoder", "grouped")))
    med = {name: float(np.median(v)) for name, v in rates.items()}
    tab = med["tabulated"]

    # lazy: Dr.Jit/Mitsuba load only once a benchmark runs, not on import or --help
    import drjit as dr

    llvm = ".".join(map(str, dr.detail.llvm_version()))
    print(f"Material {src} ({brdf.name}); {args.n:,} random direction pairs per call, "
          f"median of {args.repeats} calls, median of {args.rounds} rounds; PCA trained "
          f"on {args.pca_train} or fewer {corpus} training materials; Dr.Jit "
          f"{dr.__version__}, LLVM {llvm}; {header(info)}")
    print("| model | evaluated with | bytes per material | evaluations/s | vs tabulated |")
    print("|---|---|---|---|---|")
    for c in cases:
        rate = med[c["name"]]
        print(f"| {c['name']} | {c['evaluator']} | {c['compact'].nbytes:,} | "
              f"{rate / 1e6:.1f} M | {rate / tab:.2f}x |")
    if args.json is not None:
        record = {"material": src, "corpus": corpus, "n": args.n, "repeats": args.repeats,
                  "rounds": args.rounds, "pca_train_max": args.pca_train,
                  "drjit": dr.__version__, "llvm": llvm,
                  "rows": [{"model": c["name"], "evaluator": c["evaluator"],
                            "bytes_per_material": int(c["compact"].nbytes),
                            "evals_per_s": med[c["name"]],
                            "evals_per_s_rounds": rates[c["name"]],
                            "vs_tabulated": med[c["name"]] / tab} for c in cases]}
        write_json(args.json, record, args, info)
        _log(f"wrote {args.json}")


if __name__ == "__main__":
    main()
