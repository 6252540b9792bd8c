"""The model-spec grammar (sparse_brdf.compared.specs): one parser for config checks and
model construction."""

from __future__ import annotations

import pytest

from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.compared import specs
from sparse_brdf.compared.baselines import (
    CPDModel,
    NaiveModel,
    PCAModel,
    TabulatedModel,
    TuckerModel,
)
from sparse_brdf.compared.sparse_model import SparseModel
from sparse_brdf.compared.specs import KINDS, make_model, parse_spec
from sparse_brdf.errors import ConfigError, UsageError

GOOD = {
    "sparse:262": ("sparse", "sparse-262"),
    "sparse": ("sparse", "sparse-b1700"),  # the default size
    "sparse:32:log-plus": ("sparse", "sparse-32-log-plus"),
    "sparse:262:paper": ("sparse", "sparse-262-paper"),
    "sparse:262:auto:fill=missing": ("sparse", "sparse-262-fill=missing"),
    "sparse:b1600:basis=rgb,version=1": ("sparse", "sparse-b1600-basis=rgb-version=1"),
    "sparse:262:fill_iters=5": ("sparse", "sparse-262-fill_iters=5"),
    "naive": ("naive", "naive"),
    "cpd": ("cpd", "cpd-1"),
    "cpd:3": ("cpd", "cpd-3"),
    "tucker": ("tucker", "tucker-1x1x1"),
    "tucker:2x3x4": ("tucker", "tucker-2x3x4"),
    "pca": ("pca", "pca-40"),
    "pca:300": ("pca", "pca-300"),
    "tabulated": ("tabulated", "tabulated"),
    "nbrdf": ("nbrdf", "nbrdf"),
    "nbrdf:epochs=20,seed=3": ("nbrdf", "nbrdf-epochs=20-seed=3"),
    "nbrdf:time_budget=90": ("nbrdf", "nbrdf-time_budget=90"),
    "nbrdf:epochs=100": ("nbrdf", "nbrdf"),
}

BAD = ("svd", "", ":", "sparse:0", "sparse:-1", "sparse:x", "sparse:b", "sparse:b0",
       "sparse:bx", "sparse:262:colour=rgb", "sparse:262:fill", "sparse:262:fill=all",
       "sparse:262:log", "sparse:262:fill=invalid,fill=missing", "sparse:262:fill_iters=x",
       "sparse:262:fill_iters=100000", "sparse:262:version=3", "sparse:262:paper:basis=rgb",
       "sparse:²", "naive:3", "tabulated:1", "cpd:0", "cpd:x", "cpd:1:2", "cpd:1458001",
       "tucker:1x1", "tucker:0x1x1", "tucker:91x1x1", "tucker:1x1x1x1", "pca:0", "pca:-3",
       "pca:4.5", "PCA:40", "nbrdf:3", "nbrdf:epochs=0", "nbrdf:epochs=x", "nbrdf:depth=3",
       "nbrdf:epochs", "nbrdf:seed=1,seed=2", "nbrdf:time_budget=0",
       "nbrdf:learning_rate=-1", "nbrdf:batch_size=1.5")


def _no_ensemble(*args, **kwargs):
    raise AssertionError("parsing a spec must not read an ensemble")


@pytest.mark.parametrize("spec", sorted(GOOD))
def test_parse_gives_kind_and_name_without_an_ensemble(spec, monkeypatch):
    monkeypatch.setattr("sparse_brdf.compared.sparse_model.encoder_ensemble", _no_ensemble)
    parsed = parse_spec(spec)
    assert (parsed.kind, parsed.name) == GOOD[spec]
    assert parsed.text == spec


@pytest.mark.parametrize("spec", BAD)
def test_bad_specs_are_usage_errors_naming_the_spec(spec, monkeypatch):
    monkeypatch.setattr("sparse_brdf.compared.sparse_model.encoder_ensemble", _no_ensemble)
    with pytest.raises(UsageError) as err:
        parse_spec(spec)
    assert repr(spec) in str(err.value)
    with pytest.raises(UsageError):
        make_model(spec)


def test_unknown_kind_lists_every_grammar():
    with pytest.raises(UsageError) as err:
        parse_spec("svd")
    for kind in KINDS.values():
        assert kind.grammar in str(err.value)


@pytest.mark.parametrize("spec,cls", [("naive", NaiveModel), ("cpd:2", CPDModel),
                                      ("tucker:1x2x3", TuckerModel), ("pca:7", PCAModel),
                                      ("tabulated", TabulatedModel)])
def test_make_model_builds_the_named_class(spec, cls):
    model = make_model(spec)
    assert type(model) is cls and model.name == parse_spec(spec).name


def test_sparse_model_takes_the_parsed_options(small_ensemble):
    for spec in ("sparse:16", "sparse:16:log-plus-cosine:basis=rgb,fill=missing",
                 "sparse:b900:version=1", "sparse:16:paper"):
        model = make_model(spec, small_ensemble)
        assert isinstance(model, SparseModel) and model.name == parse_spec(spec).name
        assert model.ensemble is small_ensemble
    m = make_model("sparse:b900:basis=rgb,version=1", small_ensemble)
    assert (m.n_bytes, m.version, m.options) == (900, 1, {"basis": "rgb"})
    assert make_model(parse_spec("pca:5")).name == "pca-5"  # a parsed spec builds too


def test_bench_config_check_uses_the_grammar(tmp_path, monkeypatch):
    """The config check and the model construction agree: every spec the check accepts
    builds, and every spec it refuses names the config file."""
    monkeypatch.setattr("sparse_brdf.compared.sparse_model.encoder_ensemble", _no_ensemble)
    good = tmp_path / "good.toml"
    good.write_text("models = [" + ", ".join(f'"{s}"' for s in GOOD) + "]\n")
    assert BenchConfig.load(good).models == list(GOOD)
    for spec in ("sparse:262:fill=all", "naive:3", "tucker:1x1"):
        bad = tmp_path / "bad.toml"
        bad.write_text(f'stability_models = ["{spec}"]\n')
        with pytest.raises(ConfigError, match=r"bad\.toml: model"):
            BenchConfig.load(bad)


def test_a_new_kind_is_one_entry(monkeypatch):
    kinds = dict(KINDS)
    kinds["flat"] = specs.Kind("flat", lambda arg: {}, lambda kw, ens: TabulatedModel(),
                               lambda kw: "flat")
    monkeypatch.setattr(specs, "KINDS", kinds)
    assert parse_spec("flat").name == "flat"
    with pytest.raises(UsageError, match="flat"):
        parse_spec("nope")
