"""The public classes print as one short line: what they are, never their arrays."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SMALL
from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.brdf import BRDF
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.compared.specs import make_model
from sparse_brdf.sources.load import load_brdf

LIMIT = 300


@pytest.fixture(scope="module")
def brdf():
    return load_brdf("mitsuba:au-ggx-0.25", shape=SMALL)


def _check(obj, *must: str) -> str:
    text = repr(obj)
    assert len(text) < LIMIT and "\n" not in text, text
    assert "array" not in text and "[[" not in text, text
    for word in must:
        assert word in text, (word, text)
    return text


def test_brdf_repr(brdf):
    _check(brdf, "BRDF(", "au-ggx-0.25", "(18, 18, 36)", "bins", "mitsuba:au-ggx-0.25")
    long = BRDF(brdf.values, brdf.valid, name="n" * 255, source="/very/long/" * 40)
    _check(long, "BRDF(", "...")
    assert str(brdf) == repr(brdf)


def test_sparse_brdf_and_ensemble_reprs(brdf, small_ensemble):
    m = encode(brdf, small_ensemble, 16)
    _check(m, "SparseBRDF(", "au-ggx-0.25", m.transform, m.basis, small_ensemble.id[:8],
           str(m.n_coeffs.tolist()))
    _check(small_ensemble, "Ensemble(", small_ensemble.id[:8],
           f"{small_ensemble.n_dicts} dictionaries", str(small_ensemble.shape), "MB")
    _check(Ensemble.default(), "32 dictionaries", "(90, 90, 180)")


@pytest.mark.parametrize("spec", ["sparse:16:paper", "sparse:b900:version=1", "naive",
                                  "cpd:1", "tucker:1x1x1", "pca:40", "tabulated"])
def test_model_and_compact_reprs(spec, brdf, small_ensemble):
    model = make_model(spec, small_ensemble)
    _check(model, model.name)
    if model.learns:
        model.fit([load_brdf(f"mitsuba:{n}", shape=SMALL)
                   for n in ("cu-ggx-0.35", "plastic-red-ggx-0.3", "ag-ggx-0.1")])
        _check(model, "components")
    compact = model.compress(brdf)
    _check(compact, "Compact(", model.name, f"nbytes={compact.nbytes}")


def test_bench_config_repr():
    cfg = BenchConfig()
    _check(cfg, "BenchConfig(", "mitsuba", f"{len(cfg.models)} models", "sphere.xml")
    many = BenchConfig(corpora=[f"/data/corpus-{i}" for i in range(50)],
                       models=["naive"] * 500, scenes=[f"s{i}.xml" for i in range(99)],
                       out="x" * 400)
    _check(many, "500 models")


def test_reprs_never_hold_arrays(brdf, small_ensemble):
    """The reprs stay short however large the arrays (the full grid's ensemble printed
    30,610 characters before)."""
    big = BRDF(np.ones((90, 90, 180, 3), np.float32), np.ones((90, 90, 180), bool), "big")
    _check(big, "(90, 90, 180)", "1458000/1458000")


def test_corpus_and_training_data_reprs():
    from sparse_brdf.sources.corpora import get_corpus
    from sparse_brdf.sources.dataset import TrainingData

    corpus = get_corpus("mitsuba")
    _check(corpus, "Corpus('mitsuba'", f"{len(corpus.materials)} materials")
    _check(corpus.materials[0], corpus.materials[0].name)
    data = TrainingData(np.zeros((6, 18, 18, 36), np.float32), ["x"] * 6)
    _check(data, "6 tensors", "(18, 18, 36)")
