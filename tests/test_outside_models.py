"""Models from outside the package: the protocol, ``module:Class`` specs, a small bench of
the example model beside built-in ones, and the ranking of merged results."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from sparse_brdf import ComparedModel, CompressedBRDF
from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import BenchConfig, check_config
from sparse_brdf.benchmark.ranking import merge_results
from sparse_brdf.benchmark.results_file import SCHEMA, read_results
from sparse_brdf.cli import main
from sparse_brdf.compared.protocol import check_compressed, check_model, table_of
from sparse_brdf.compared.specs import KINDS, make_model, parse_spec
from sparse_brdf.sources.load import load_brdf

ROOT = Path(__file__).resolve().parent.parent

# A model of the test's own, written into a module in the current directory: a grey
# Lambertian BRDF that evaluates at direction pairs and offers a Dr.Jit evaluator.
GREY = '''
import numpy as np

class GreyLambert:
    learns = False

    def __init__(self, albedo=0.5):
        self.albedo = albedo
        self.name = f"grey-{albedo}"

    def fit(self, brdfs):
        return self

    def compress(self, brdf):
        return GreyFit(self.albedo)


class GreyFit:
    nbytes = 4

    def __init__(self, albedo):
        self.albedo = albedo

    def evaluate(self, wi, wo):
        return np.full((len(wi), 3), self.albedo / np.pi)

    def drjit_evaluator(self):
        import drjit as dr
        import mitsuba as mi
        value = self.albedo / np.pi

        class Evaluator:
            def eval(self, wi, wo):
                return dr.select(wo.z > 0, mi.Color3f(value), mi.Color3f(0.0))

        return Evaluator()


class BudgetedGrey(GreyLambert):
    """A model with a byte budget of its own, named as the package's sparse model names
    its budget: the bench's check of sparse budgets must leave it alone."""

    n_bytes = 4


class NotAModel:
    name = "not-a-model"
'''


@pytest.fixture
def user_dir(tmp_path, monkeypatch):
    """The current directory holds ``greymodels.py``; the checkout's ``examples`` is on
    the Python path."""
    (tmp_path / "greymodels.py").write_text(GREY)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    return tmp_path


@pytest.mark.parametrize("spec", ["sparse:16", "sparse:262:paper", "nbrdf:epochs=1", "naive",
                                  "cpd:1", "tucker:1x1x1", "pca:4", "tabulated"])
def test_built_in_models_follow_the_protocol(spec, small_ensemble):
    model = make_model(spec, small_ensemble)
    assert isinstance(model, ComparedModel) and check_model(model) is None
    assert parse_spec(spec).kind in KINDS


def test_built_in_compact_follows_the_protocol():
    brdf = load_brdf("mitsuba:diffuse-red")
    compact = make_model("tabulated").compress(brdf)
    assert isinstance(compact, CompressedBRDF) and check_compressed(compact) is None
    np.testing.assert_array_equal(table_of(compact, brdf), brdf.values)


def test_a_model_that_evaluates_at_direction_pairs_is_tabulated(user_dir):
    brdf = load_brdf("mitsuba:diffuse-red")
    fit = make_model("greymodels:GreyLambert:albedo=0.25").compress(brdf)
    table = table_of(fit, brdf)
    assert np.allclose(table[brdf.valid], 0.25 / np.pi) and not table[~brdf.valid].any()


@pytest.mark.parametrize("spec, message", [
    ("nomodule_here:Model", "no module named 'nomodule_here' on the Python path"),
    ("greymodels:Missing", "module greymodels has no class Missing"),
    ("greymodels:np", "not a class"),
    ("greymodels:NotAModel", "does not follow the compared-model protocol.*no method fit"),
    ("greymodels:GreyLambert:colour=red", "GreyLambert\\(colour='red'\\) failed: TypeError"),
    ("greymodels:GreyLambert:albedo", "expected distinct KEY=VALUE options"),
    ("examples.quantised_table:QuantisedLogTable:bits=0", "bits must be an integer from 1"),
])
def test_bad_outside_specs_are_one_line_and_exit_2(user_dir, capsys, spec, message):
    assert main(["bench", "ci", "--check", "--model", spec, "--out", "mine"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert ("ci.toml: setting models" in err or "--model: " in err) and spec in err
    assert re.search(message, err), err


def test_model_option_needs_an_output_folder_of_its_own(capsys):
    assert main(["bench", "ci", "--check", "--model", "naive"]) == 2
    assert "--model: give --out too" in capsys.readouterr().err
    assert main(["bench", "acquisition", "--check", "--model", "naive", "--out", "x"]) == 2
    assert "it takes no --model" in capsys.readouterr().err


def test_outside_specs_in_a_config_pass_check(user_dir, capsys):
    cfg = user_dir / "mine.toml"
    cfg.write_text('corpora = ["mitsuba"]\nmax_materials = 1\nstability = false\n'
                   'models = ["greymodels:GreyLambert:albedo=0.5", "naive", '
                   '"examples.quantised_table:QuantisedLogTable:bits=6"]\n'
                   'scenes = ["sphere.xml"]\n')
    assert main(["bench", str(cfg), "--check"]) == 0
    out = capsys.readouterr().out
    assert "1 materials x 3 models" in out
    plan = check_config(BenchConfig.load(cfg))
    assert plan["models"] == ["grey-0.5", "naive", "quantised-6bit"]


def test_an_outside_model_with_its_own_n_bytes_passes_check(user_dir, capsys):
    """``n_bytes`` on an outside model is that model's business: the check of the sparse
    model's byte budgets (a file's header must fit) does not apply to it."""
    cfg = user_dir / "mine.toml"
    cfg.write_text('corpora = ["mitsuba"]\nmax_materials = 1\nstability = false\n'
                   'models = ["greymodels:BudgetedGrey:albedo=0.5", "sparse:b200"]\n'
                   'scenes = ["sphere.xml"]\n')
    assert main(["bench", str(cfg), "--check"]) == 0, capsys.readouterr().err
    assert "1 materials x 2 models" in capsys.readouterr().out
    cfg.write_text(cfg.read_text().replace("sparse:b200", "sparse:b60"))
    assert main(["bench", str(cfg), "--check"]) == 2
    assert "sparse-b60: 60 bytes hold no coefficient" in capsys.readouterr().err


@pytest.mark.bench
@pytest.mark.render
def test_the_example_model_in_a_small_bench_beside_naive_and_the_table(user_dir):
    """A tiny bench: the example (quantised table), the test's grey model (evaluates at
    pairs, has a Dr.Jit evaluator), naive and the table, in the studio scene and one angle
    of the one-light set; then its results ranked with a second run's."""
    models = ["examples.quantised_table:QuantisedLogTable:bits=6",
              "greymodels:GreyLambert:albedo=0.5", "naive", "tabulated"]
    cfg = BenchConfig(corpora=["mitsuba"], max_materials=1, models=models,
                      scenes=["sphere.xml", "sphere_light.xml:lightangle=40"], res=20, spp=2,
                      curve_coeffs=[16], stability=False, speed_evals=4096,
                      out=str(user_dir / "b1"))
    results = Bench(cfg, progress=False).run()
    cells = {c["model"]: c for c in results["cells"].values()}
    assert all(c["status"] == "finished" for c in cells.values()), cells
    assert set(cells) == {"quantised-6bit", "grey-0.5", "naive", "tabulated"}
    quant, table = cells["quantised-6bit"], cells["tabulated"]
    assert quant["bytes"] < table["bytes"] / 4 and cells["grey-0.5"]["bytes"] == 4
    for scene in ("sphere", "sphere_light-lightangle=40"):
        assert table["renders"][scene]["flip"] < 1e-6
        assert 0 < quant["renders"][scene]["flip"] < cells["grey-0.5"]["renders"][scene]["flip"]
    assert results["speed"]["quantised-6bit"] is None  # no Dr.Jit evaluator offered
    assert results["speed"]["grey-0.5"] > 0 and results["speed"]["naive"] > 0
    data = read_results(user_dir / "b1")
    assert data["schema"] == SCHEMA and data["environment"]["python"]
    assert (user_dir / "b1" / "report.html").is_file()
    # the same protocol with other models, as another machine might have run it
    cfg2 = BenchConfig(**{**cfg.__dict__, "models": ["cpd:1"], "out": str(user_dir / "b2")})
    Bench(cfg2, progress=False).run()
    assert main(["bench-merge", str(user_dir / "b1"), str(user_dir / "b2" / "results.json"),
                 "-o", str(user_dir / "ranked")]) == 0
    merged = merge_results([user_dir / "b1", user_dir / "b2"])
    ranked = [r["model"] for r in merged["rows"]]
    assert ranked[0] == "tabulated" and set(ranked) == set(cells) | {"cpd-1"}
    snrs = [r["snr_object"] for r in merged["rows"]]
    assert snrs == sorted(snrs, reverse=True)
    md = (user_dir / "ranked" / "ranking.md").read_text()
    assert "| 1 | tabulated |" in md and "quantised-6bit" in md
    csv_rows = (user_dir / "ranked" / "ranking.csv").read_text().splitlines()
    assert csv_rows[0].startswith("rank,model,source") and len(csv_rows) == 6
    by_flip = merge_results([user_dir / "b1", user_dir / "b2"], by="flip")["rows"]
    assert by_flip[0]["model"] == "tabulated" and math.isclose(by_flip[0]["flip"], 0,
                                                               abs_tol=1e-6)


def test_merge_refuses_other_protocols_and_other_files(tmp_path, capsys):
    base = {"schema": SCHEMA, "config": {"corpora": ["mitsuba"], "split": "test",
                                         "max_materials": 1, "scenes": ["sphere.xml"],
                                         "spp": 4, "res": 16, "seed": 0},
            "provenance": {}, "cells": {}, "noise_floor": {}, "speed": {}}
    a, b, c = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "c.json"
    a.write_text(json.dumps(base))
    b.write_text(json.dumps({**base, "config": {**base["config"], "spp": 8}}))
    c.write_text(json.dumps({**base, "schema": "sparse-brdf-bench/0"}))
    for files, message in (([a, b], "spp = 8"), ([a, c], "schema"),
                           ([a, tmp_path / "none.json"], "none.json")):
        assert main(["bench-merge", *map(str, files), "-o", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "out").exists()
