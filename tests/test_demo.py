"""The demo's shipped measured materials (built-in corpus merl-demo) and its tables."""

from __future__ import annotations

import pytest

from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.demo import per_material, render_table
from sparse_brdf.paths import DEMO_MATERIALS_DIR
from sparse_brdf.sources.corpora import get_corpus, list_corpora


def test_shipped_materials_are_unseen_merl_test_materials():
    demo = get_corpus("merl-demo")
    names = [m.name for m in demo.materials]
    assert 1 <= len(names) <= 6  # the data licence allows at most six
    assert demo.split("test") == list(demo.materials) and demo.split("train") == []
    # keys as in the full corpus, and never in the shipped ensemble's training data
    trained = set(Ensemble.default().meta["data"])
    assert all(m.corpus == "merl" for m in demo.materials)
    assert not {f"merl/{n}" for n in names} & trained
    # each file is a small Neural-BRDF network that loads on the MERL grid
    for path in DEMO_MATERIALS_DIR.glob("*.h5"):
        assert path.stat().st_size < 32_000
    brdf = demo.materials[0].load()
    assert brdf.shape == (90, 90, 180) and brdf.valid.any()
    assert "merl-demo" in list_corpora()


def test_licence_names_the_origin():
    text = (DEMO_MATERIALS_DIR / "LICENSE.md").read_text()
    for must in ("Matusik", "Sztrajman", "MIT License", "CC-BY-SA-4.0", "asztr/Neural-BRDF"):
        assert must in text, must


@pytest.mark.shared
def test_shipped_materials_are_in_the_merl_test_split(shared_data):
    test = {m.name for m in get_corpus("merl").split("test")}
    assert {m.name for m in get_corpus("merl-demo").materials} <= test


def test_demo_tables_give_both_forms():
    cell = {"material": "merl/a", "model": "sparse-262", "status": "finished", "bytes": 6288,
            "rae": 0.05, "cos_snr": 30.0, "fit_s": 1.0,
            "renders": {"sphere": {"snr_whole": 40.0, "snr_object": 28.0, "render_s": 1.0}}}
    results = {"cells": {"merl/a|sparse-262": cell}, "speed": {"sparse-262": 1e6},
               "noise_floor": {"sphere": {"merl/a": {"snr_whole": 20.0, "snr_object": 5.0}}}}
    table = "\n".join(render_table(results, ["sparse-262", "naive"]))
    assert "object-only" in table and "whole-image" in table
    assert "28.0 (28.0)" in table and "40.0 (40.0)" in table and "noise floor" in table
    assert "naive" not in table  # models without cells are left out
    rows = per_material(results, "sparse-262")
    assert rows[-1] == "| merl/a | 28.0 / 40.0 |"
