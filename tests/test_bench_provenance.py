"""Each bench cell records its provenance; a rerun recomputes exactly the cells whose
provenance changed and keeps the others."""

from __future__ import annotations

import sys

import pytest

from sparse_brdf.benchmark import provenance
from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.benchmark.provenance import cell_provenance, stale_cells

# A user's model in a module of its own; its stored bytes are the module's constant.
SOURCE = '''
import numpy as np

BYTES = {nbytes}


class Flat:
    learns = False
    name = "flat"

    def fit(self, brdfs):
        return self

    def compress(self, brdf):
        return FlatFit()


class FlatFit:
    nbytes = BYTES

    def evaluate(self, wi, wo):
        return np.full((len(wi), 3), 0.1)
'''


@pytest.fixture
def user_model(tmp_path, monkeypatch):
    """``provmodels.py`` in the current directory; rewritten by calling the fixture."""
    monkeypatch.chdir(tmp_path)

    def write(nbytes: int) -> None:
        (tmp_path / "provmodels.py").write_text(SOURCE.format(nbytes=nbytes))
        sys.modules.pop("provmodels", None)  # the next bench imports the new source

    write(4)
    yield write
    sys.modules.pop("provmodels", None)


def _run(cfg: BenchConfig, capsys) -> tuple[dict, str]:
    results = Bench(cfg, progress=False).run()
    return results, capsys.readouterr().out


@pytest.mark.bench
def test_a_changed_model_source_recomputes_its_cells_and_keeps_the_others(
        tmp_path, user_model, capsys):
    cfg = BenchConfig(corpora=["mitsuba"], max_materials=2, models=["provmodels:Flat", "naive"],
                      curve_coeffs=[16], render=False, speed=False, stability=False,
                      out=str(tmp_path / "b"))
    first, out = _run(cfg, capsys)
    assert "kept" not in out  # a fresh bench has nothing to keep
    cells = first["cells"]
    assert len(cells) == 4 and all(c["status"] == "finished" for c in cells.values())
    flat = next(c for c in cells.values() if c["model"] == "flat")
    prov = flat["provenance"]
    assert prov["model"] == "provmodels:Flat" and prov["source"]["file"] == "provmodels.py"
    assert len(prov["source"]["sha256"]) == 64
    assert {"mitsuba", "drjit", "machine"} <= set(prov) and prov["machine"]
    naive = next(c for c in cells.values() if c["model"] == "naive")["provenance"]
    assert set(naive["source"]) == {"sparse_brdf", "commit"}
    # both reports say where and with what: the model's source file and hash, the renderer
    for report in ("report.md", "report.html"):
        text = (tmp_path / "b" / report).read_text()
        assert "Environment and provenance" in text, report
        assert prov["source"]["sha256"][:16] in text and prov["mitsuba"] in text, report

    # unchanged: every cell kept, nothing recomputed (fit times identical)
    again, out = _run(cfg, capsys)
    assert "bench: kept 4 of 4 cells, 0 to compute" in out
    assert again["cells"] == first["cells"]

    user_model(8)  # the user edits the model's source
    third, out = _run(cfg, capsys)
    assert "bench: kept 2 of 4 cells, 2 to compute (2 recorded with another" in out
    assert [line for line in out.splitlines() if "kept" in line] == [out.splitlines()[0]]
    for key, cell in third["cells"].items():
        if cell["model"] == "flat":
            assert cell["bytes"] == 8 and cell["fit_s"] != first["cells"][key]["fit_s"]
            assert cell["provenance"]["source"]["sha256"] != prov["source"]["sha256"]
        else:
            assert cell == first["cells"][key]  # kept as it was

    # a model added to the config: the others' cells are kept
    cfg.models = [*cfg.models, "cpd:1"]
    fourth, out = _run(cfg, capsys)
    assert "bench: kept 4 of 6 cells, 2 to compute (0 recorded" in out
    assert {c["model"] for c in fourth["cells"].values()} == {"flat", "naive", "cpd-1"}
    # and one dropped from it: its cells go
    cfg.models = ["naive"]
    fifth, out = _run(cfg, capsys)
    assert "bench: kept 2 of 2 cells" in out
    assert {c["model"] for c in fifth["cells"].values()} == {"naive"}


def test_options_and_environment_are_part_of_the_provenance(monkeypatch):
    base = cell_provenance("sparse:64")
    assert base["options"] != cell_provenance("sparse:128")["options"]
    cells = {"m|sparse-64": {"model": "sparse-64", "status": "finished", "provenance": base},
             "m|naive": {"model": "naive", "status": "finished",
                         "provenance": cell_provenance("naive")},
             "m|gone": {"model": "gone", "status": "finished", "provenance": base},
             "m|failed": {"model": "naive", "status": "failed"}}
    current = {"sparse-64": base, "naive": cell_provenance("naive")}
    assert stale_cells(cells, current) == (["m|gone"], 2)
    monkeypatch.setattr(provenance, "_version", lambda dist: f"{dist}-9.9")
    moved = {"sparse-64": cell_provenance("sparse:64"), "naive": cell_provenance("naive")}
    assert moved["naive"]["mitsuba"] == "mitsuba-9.9"
    assert stale_cells(cells, moved) == (["m|sparse-64", "m|naive", "m|gone"], 0)


def test_provenance_outside_a_git_checkout(tmp_path, monkeypatch):
    """An installed package (no checkout of its own) records no commit, and still runs."""
    provenance.git_commit.cache_clear()
    monkeypatch.setattr(provenance, "_PACKAGE_DIR", tmp_path / "site" / "sparse_brdf")
    try:
        assert provenance.git_commit() is None
        assert cell_provenance("naive")["source"]["commit"] is None
    finally:
        provenance.git_commit.cache_clear()
    assert provenance.git_commit() is None or len(provenance.git_commit()) == 40
