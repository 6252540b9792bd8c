"""Benches a researcher can trust: a user's model that fails (raises on some materials,
returns NaN, fails everywhere) alone or beside built-in models never stops the bench nor
its reports; tables sort failed figures last."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from sparse_brdf.cli import main

# Models of the test's own, written into the current directory: each fails in its own way.
FAILING = '''
import numpy as np


class Fails:
    """Raises on the materials whose name holds ``on`` (every one for "all")."""
    learns = False

    def __init__(self, on="all"):
        self.on = on
        self.name = f"fails-{on}"

    def fit(self, brdfs):
        return self

    def compress(self, brdf):
        if self.on == "all" or self.on in brdf.name:
            raise IndexError(f"no fit for {brdf.name}")
        return Constant(0.1)


class NaNs:
    """Compresses every material to a table of NaN."""
    learns = False
    name = "nans"

    def fit(self, brdfs):
        return self

    def compress(self, brdf):
        return Constant(float("nan"))


class Constant:
    nbytes = 4

    def __init__(self, value):
        self.value = value

    def evaluate(self, wi, wo):
        return np.full((len(wi), 3), self.value)
'''

#: A tiny bench: one scene at 16 x 16, 2 spp; the first material is al-ggx-0.3, the
#: second au-ggx-0.25.
CONFIG = '''corpora = ["mitsuba"]
max_materials = {n}
stability = false
scenes = ["sphere.xml"]
res = 16
spp = 2
curve_coeffs = [16]
speed_evals = 4096
models = ["naive"]
'''


@pytest.fixture
def user_dir(tmp_path, monkeypatch):
    """The current directory holds ``failmodels.py``."""
    (tmp_path / "failmodels.py").write_text(FAILING)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _bench(user_dir: Path, models: list[str], n: int, *extra: str) -> tuple[int, Path]:
    """``sparse-brdf bench`` of the tiny config with ``models`` on ``n`` materials."""
    cfg = user_dir / f"tiny{n}.toml"
    cfg.write_text(CONFIG.format(n=n))
    out = user_dir / "out"
    argv = ["bench", str(cfg), "--out", str(out), *extra]
    for m in models:
        argv += ["--model", m]
    return main(argv), out


AU_ERROR = "IndexError: no fit for au-ggx-0.25"
AL_ERROR = "IndexError: no fit for al-ggx-0.3"
NAN_ERROR = "FloatingPointError: reconstruction holds NaN/inf"


@pytest.mark.render
@pytest.mark.parametrize("models, n, failed", [
    (["failmodels:Fails:on=au"], 2, {"mitsuba/au-ggx-0.25|fails-au": AU_ERROR}),
    (["failmodels:NaNs"], 1, {"mitsuba/al-ggx-0.3|nans": NAN_ERROR}),
    (["failmodels:Fails"], 1, {"mitsuba/al-ggx-0.3|fails-all": AL_ERROR}),
    (["failmodels:Fails:on=au", "failmodels:NaNs", "failmodels:Fails", "naive", "sparse:16"],
     2, {"mitsuba/au-ggx-0.25|fails-au": AU_ERROR, "mitsuba/al-ggx-0.3|nans": NAN_ERROR,
         "mitsuba/au-ggx-0.25|nans": NAN_ERROR, "mitsuba/al-ggx-0.3|fails-all": AL_ERROR,
         "mitsuba/au-ggx-0.25|fails-all": "IndexError: no fit for au-ggx-0.25"}),
], ids=["raises-on-one-alone", "nan-alone", "fails-everywhere-alone", "beside-built-ins"])
@pytest.mark.bench
def test_a_failing_model_never_stops_the_bench_nor_its_reports(user_dir, capsys, models, n,
                                                                failed):
    rc, out = _bench(user_dir, models, n)
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "internal error" not in err and f"{len(failed)} of " in err
    for name in ("report.md", "report.html", "results.json", "results.csv"):
        assert (out / name).is_file(), name
    cells = _strict_json((out / "results.json").read_text())["cells"]
    got = {k: c["error"] for k, c in cells.items() if c["status"] == "failed"}
    assert got == failed
    assert all(c["status"] == "finished" for k, c in cells.items() if k not in failed)
    md, page = (out / "report.md").read_text(), (out / "report.html").read_text()
    assert "## Failed cells" in md and "<h2>Failed cells</h2>" in page
    for key, error in failed.items():
        material, model = key.split("|")
        assert f"| {material} | {model} | {error} |" in md
        assert f"failed: {error}" in md and f"failed: {error}" in page
    # a model none of whose cells finished has no speed, and the report says it failed
    data = json.loads((out / "results.json").read_text())
    for model in {k.split("|")[1] for k in failed}:
        if all(k in failed for k in cells if k.endswith(f"|{model}")):
            assert data["speed"].get(model) is None
            assert any(ln.startswith(f"| {model} |") and ln.split(" | ")[4] == "failed"
                       for ln in md.splitlines())
    # a rerun runs the failed cells again, and again writes every report
    (out / "report.md").unlink()
    rc, _ = _bench(user_dir, models, n)
    assert rc == 0 and (out / "report.md").is_file()


def _results(cells: dict, speed: dict) -> dict:
    """A bench's results of one material in one scene, with ``cells`` as given:
    ``{model: object-only SNR in dB, or None for a failed cell}``."""
    out = {}
    for model, snr in cells.items():
        key = f"mitsuba/al-ggx-0.3|{model}"
        if snr is None:
            out[key] = {"material": "mitsuba/al-ggx-0.3", "model": model, "status": "failed",
                        "error": "IndexError: no fit"}
            continue
        out[key] = {"material": "mitsuba/al-ggx-0.3", "model": model, "status": "finished",
                    "fit_s": 0.1, "bytes": 100, "rae": 0.1, "cos_snr": snr + 5,
                    "gamma_mse": 0.01,
                    "renders": {"sphere": {"snr_object": snr, "snr_whole": snr + 3,
                                           "flip": 0.1, "render_s": 0.2}}}
    return {"schema": "x", "config": {"corpora": ["mitsuba"], "split": "test", "res": 16,
                                      "spp": 2, "seed": 0, "noise_seed": 1,
                                      "scenes": ["sphere.xml"]},
            "cells": out, "curves": {}, "noise_floor": {}, "speed": speed,
            "skipped_scenes": {}}


def test_tables_sort_failed_figures_last_and_a_failed_model_has_no_speed(tmp_path):
    from sparse_brdf.benchmark.html_report import write_html_report
    from sparse_brdf.benchmark.report import summary_table, write_report

    results = _results({"broken": None, "worse": 13.7, "better": 16.8, "exact": math.inf},
                       {"broken": 3e6, "worse": 2e6, "better": 1e6, "exact": 5e5})
    rows = summary_table(results, "sphere")
    assert [r["model"] for r in rows] == ["exact", "better", "worse", "broken"]
    assert math.isnan(rows[-1]["evals_per_s"]) and rows[1]["evals_per_s"] == 1e6
    # without renders, by cos-weighted SNR, failed last
    assert [r["model"] for r in summary_table(results)] == ["exact", "better", "worse",
                                                             "broken"]
    write_report(results, tmp_path)
    md = (tmp_path / "report.md").read_text().splitlines()
    table = [ln for ln in md if ln.startswith(("| better |", "| worse |", "| broken |",
                                               "| exact |"))][:4]
    assert [ln.split(" | ")[0] for ln in table] == ["| exact", "| better", "| worse",
                                                     "| broken"]
    assert table[-1].split(" | ")[4] == "failed" and "3e+06" not in "\n".join(md)
    write_html_report(results, tmp_path)
    page = (tmp_path / "report.html").read_text()
    assert '<td data-v="">failed</td>' in page and "3e+06" not in page


def _run_file(path: Path, cells: dict, run: str, **config) -> Path:
    """A results file of two materials in one scene: ``cells`` maps a model to its
    object-only SNR per material (None: failed)."""
    from sparse_brdf.benchmark.results_file import SCHEMA

    out = {}
    for model, snrs in cells.items():
        for mat, snr in zip(("mitsuba/a", "mitsuba/b"), snrs, strict=True):
            cell = {"material": mat, "model": model, "status": "finished", "bytes": 10,
                    "renders": {"sphere": {"snr_object": snr, "snr_whole": snr,
                                           "flip": 0.1}}}
            if snr is None:
                cell = {"material": mat, "model": model, "status": "failed",
                        "error": "IndexError: no fit"}
            out[f"{mat}|{model}"] = cell
    cfg = {"corpora": ["mitsuba"], "split": "test", "max_materials": 2,
           "scenes": ["sphere.xml"], "spp": 2, "res": 16, "seed": 0, "speed": True,
           "speed_evals": 4096, **config}
    path.write_text(json.dumps({"schema": SCHEMA, "run": run, "config": cfg, "provenance": {},
                                "cells": out, "noise_floor": {},
                                "speed": {m: 1e6 for m in cells}}))
    return path


def test_merge_ranks_over_materials_every_ranked_model_finished(tmp_path):
    from sparse_brdf.benchmark.ranking import merge_results

    # "partial" is best on the one material it finished, and must not rank above the rest
    a = _run_file(tmp_path / "a.json", {"good": [20.0, 10.0], "partial": [30.0, None],
                                        "broken": [None, None]}, "run-a")
    b = _run_file(tmp_path / "b.json", {"other": [12.0, 12.0]}, "run-b")
    merged = merge_results([a, b])
    assert merged["materials"] == ["mitsuba/a", "mitsuba/b"]
    assert [(r["rank"], r["model"], r["snr_object"]) for r in merged["rows"]] == [
        (1, "good", 15.0), (2, "other", 12.0)]
    assert [(r["model"], r["materials"], r["failed"]) for r in merged["unranked"]] == [
        ("partial", 1, 1), ("broken", 0, 2)]
    assert main(["bench-merge", str(a), str(b), "-o", str(tmp_path / "r")]) == 0
    md = (tmp_path / "r" / "ranking.md").read_text()
    assert "| partial | " + str(a) + " | 1 of 2 | 1 |" in md
    assert "| broken | " + str(a) + " | 0 of 2 | 2 |" in md
    assert "| 1 | good |" in md and "| 3 |" not in md
    csv_rows = (tmp_path / "r" / "ranking.csv").read_text().splitlines()
    assert csv_rows[1].startswith("1,good,") and csv_rows[3].startswith(",partial,")


def test_merge_refuses_one_run_twice_and_other_speed_settings(tmp_path, capsys):
    a = _run_file(tmp_path / "a.json", {"good": [20.0, 10.0]}, "run-a")
    folder = tmp_path / "bench"
    folder.mkdir()
    (folder / "results.json").write_text(a.read_text())  # a copy of the same run
    other = _run_file(tmp_path / "o.json", {"x": [1.0, 2.0]}, "run-o", speed_evals=8192)
    nospeed = _run_file(tmp_path / "n.json", {"y": [1.0, 2.0]}, "run-n", speed=False,
                        speed_evals=8192)
    for files, message in (([a, a], "the same results file as"),
                           ([a, folder], "the same run as"),
                           ([a, other], "speed_evals = 8192"),
                           ([a, nospeed], "speed = False")):
        assert main(["bench-merge", *map(str, files), "-o", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
        if "speed" in message:
            assert "with 4096" in err or "with True" in err, err
    assert not (tmp_path / "out").exists()
    # a copy whose run id was lost is still known by its cells
    data = json.loads(a.read_text())
    del data["run"]
    (folder / "results.json").write_text(json.dumps(data))
    assert main(["bench-merge", str(a), str(folder), "-o", str(tmp_path / "out")]) == 2
    assert "the same run as" in capsys.readouterr().err


def _strict_json(text: str):
    """``text`` parsed as strict JSON: Infinity, -Infinity and NaN refused."""
    def refuse(name):
        raise ValueError(f"not strict JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_results_json_is_strict_and_keeps_its_infinities(tmp_path):
    from sparse_brdf.benchmark.results_file import SCHEMA, read_results
    from sparse_brdf.fileio import parse_strict_json, strict_json

    data = {"schema": SCHEMA, "config": {}, "provenance": {}, "noise_floor": {}, "speed": {},
            "cells": {"mitsuba/a~b|tab/x": {"cos_snr": math.inf,
                                             "renders": {"sphere": {"snr_object": -math.inf,
                                                                    "snr_whole": 30.0,
                                                                    "flip": math.nan}}}},
            "curves": {"mitsuba/a": {"rae": [0.1, math.inf]}}}
    text = strict_json(data)
    strict = _strict_json(text)
    cell = strict["cells"]["mitsuba/a~b|tab/x"]
    assert cell["cos_snr"] is None and cell["renders"]["sphere"]["snr_whole"] == 30.0
    assert strict["non_finite"]["/cells/mitsuba~1a~0b|tab~1x/cos_snr"] == "inf"
    back = parse_strict_json(text)
    cell = back["cells"]["mitsuba/a~b|tab/x"]
    assert cell["cos_snr"] == math.inf and cell["renders"]["sphere"]["snr_object"] == -math.inf
    assert math.isnan(cell["renders"]["sphere"]["flip"])
    assert back["curves"]["mitsuba/a"]["rae"] == [0.1, math.inf] and "non_finite" not in back
    # a file of the old schema, Infinity and all, reads as before
    old = tmp_path / "old.json"
    old.write_text(json.dumps({**data, "schema": "sparse-brdf-bench/1"}))
    assert "Infinity" in old.read_text()
    assert read_results(old)["cells"]["mitsuba/a~b|tab/x"]["cos_snr"] == math.inf


@pytest.mark.bench
def test_a_bench_resumes_an_old_results_file_and_rewrites_it_strict(tmp_path):
    from sparse_brdf.benchmark.bench import Bench
    from sparse_brdf.benchmark.bench_config import BenchConfig
    from sparse_brdf.benchmark.provenance import cell_provenance
    from sparse_brdf.benchmark.results_file import SCHEMA

    cfg = BenchConfig(corpora=["mitsuba"], max_materials=1, models=["tabulated"],
                      render=False, stability=False, speed=False, out=str(tmp_path / "b"))
    old = Bench(cfg, progress=False).results
    old.pop("run")
    old["schema"] = "sparse-brdf-bench/1"
    old["cells"]["mitsuba/al-ggx-0.3|tabulated"] = {
        "material": "mitsuba/al-ggx-0.3", "model": "tabulated", "status": "finished",
        "fit_s": 0.1, "bytes": 10, "rae": 0.0, "cos_snr": math.inf, "gamma_mse": 0.0,
        "provenance": cell_provenance("tabulated")}  # as this version would record it
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "results.json").write_text(json.dumps(old))
    bench = Bench(cfg, progress=False)
    assert bench.results["cells"] == old["cells"] and bench.results["schema"] == SCHEMA
    bench.run()  # nothing to run: the one cell is finished
    strict = _strict_json((tmp_path / "b" / "results.json").read_text())
    assert strict["schema"] == SCHEMA and len(strict["run"]) == 32
    assert strict["cells"]["mitsuba/al-ggx-0.3|tabulated"]["cos_snr"] is None
    assert Bench(cfg, progress=False).results["cells"] == old["cells"]


@pytest.mark.bench
@pytest.mark.render
def test_decoded_tables_are_deleted_unless_kept(user_dir, capsys):
    rc, out = _bench(user_dir, ["naive", "failmodels:Fails"], 1)
    assert rc == 0, capsys.readouterr().err
    work = out / "work"
    assert (work / "sphere" / "mitsuba__al-ggx-0.3__naive.exr").is_file()  # renders stay
    assert not list(work.rglob("*.binary"))
    (out / "results.json").unlink()  # run again from scratch, keeping the tables
    rc, out = _bench(user_dir, ["naive", "failmodels:Fails"], 1, "--keep-work")
    assert rc == 0, capsys.readouterr().err
    assert sorted(p.name for p in (out / "work").rglob("*.binary")) == [
        "mitsuba__al-ggx-0.3__naive.binary", "mitsuba__al-ggx-0.3__reference.binary"]
