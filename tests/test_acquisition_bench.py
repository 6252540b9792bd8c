"""The acquisition bench (``sparse-brdf bench acquisition``): its config, its cells, a
real run of both methods on one material, resuming after an interruption, and the
report's curves and goals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sparse_brdf.acquisition import defaults as acquisition
from sparse_brdf.benchmark import acquisition_bench as ab
from sparse_brdf.benchmark.acquisition_report import curve, goals
from sparse_brdf.cli import main
from sparse_brdf.errors import ConfigError


def _write(tmp_path, text: str, name: str = "acq.toml"):
    path = tmp_path / name
    path.write_text('bench = "acquisition"\n' + text)
    return path


def test_cells_cover_the_curves_the_bins_and_the_noise_once():
    cfg = ab.AcquisitionConfig(n_samples=[20, 1000], seeds=[0, 1], bins_n=[1000],
                               noise_n=[1000])
    cells = ab.cells(cfg)
    assert len(cells) == len(set(cells))
    curves = [c for c in cells if c.placement != "bins" and c.noise == 0]
    assert len(curves) == 2 * 2 * 2 * 2  # placements x N x seeds x methods
    assert {c.n for c in cells if c.placement == "bins"} == {1000}
    noisy = [c for c in cells if c.noise > 0]
    assert len(noisy) == 2 * 1 * 2 * 2 and {c.noise for c in noisy} == {0.02}
    assert not [c for c in ab.cells(ab.AcquisitionConfig(noise=0.0)) if c.noise > 0]


@pytest.mark.parametrize("text, match", [
    ("n_samples = [10]\n", "n_samples"),
    ("noise = 1.5\n", "noise"),
    ("placements = ['grid']\n", "placements"),
    ("methods = []\n", "methods"),
    ("spp = 'many'\n", "spp"),
    ("colour = 1\n", "colour"),
])
def test_bad_settings_name_the_file_and_setting(tmp_path, text, match):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as info:
        ab.AcquisitionConfig.load(path)
    assert str(path) in str(info.value)


def test_cli_refuses_bad_configs_and_options_with_one_line(tmp_path, capsys):
    path = _write(tmp_path, "noise = -1\n")
    assert main(["bench", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(path) in err and "noise" in err
    good = _write(tmp_path, "n_samples = [100]\n", "good.toml")
    assert main(["bench", str(good), "--no-render"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--no-render" in err


def test_shipped_config_checks(shared_data, capsys):
    assert main(["bench", "acquisition", "--check"]) == 0
    out = capsys.readouterr().out
    assert "14 materials x 138 fits" in out


@pytest.fixture()
def few_training(shared_data, monkeypatch):
    """The prior and the PCA basis on three training materials (seconds, not minutes)."""
    mats = acquisition.training_materials()[:3]
    monkeypatch.setattr(acquisition, "training_materials", lambda: mats)
    return mats


@pytest.mark.bench
@pytest.mark.render
def test_a_real_run_scores_both_methods_and_the_full_table(tmp_path, few_training):
    cfg = ab.AcquisitionConfig(max_materials=1, n_samples=[300], seeds=[0],
                               placements=["stratified"], bins_n=[], noise=0.0, res=16,
                               spp=2, scenes=["paper_sphere.xml"], out=str(tmp_path / "b"))
    results = ab.AcquisitionBench(cfg, progress=False).run()
    rows = list(results["cells"].values())
    assert [r["status"] for r in rows] == ["finished", "finished"], rows
    assert {r["method"] for r in rows} == {"sparse", "pca"}
    for row in [*rows, *results["full"].values()]:
        snr = row["renders"]["paper_sphere"]
        assert math.isfinite(snr["snr_object"]) and math.isfinite(snr["snr_whole"])
        assert math.isfinite(row["cos_snr"])
    full = next(iter(results["full"].values()))
    assert full["cos_snr"] > max(r["cos_snr"] for r in rows)  # 300 samples lose to 1.1 M
    report = (tmp_path / "b" / "report.md").read_text()
    assert "## Goals" in report and "## Fit time" in report
    assert (tmp_path / "b" / "acquisition-paper_sphere.png").stat().st_size > 1000
    kept = sorted(p.name for p in (tmp_path / "b" / "work").glob("*.sbrdf"))
    assert kept == ["blue-acrylic__full.sbrdf"]  # the cells' files are removed


def _stub_bench(monkeypatch, calls: list, stop_after: int | None = None):
    """Rendering and fitting replaced by a closed form: SNR grows with log N, sparse by
    5 dB per decade and PCA by 2, seed s adds s dB."""
    ref = (np.ones((4, 4, 3)), np.ones((4, 4), bool))
    monkeypatch.setattr(ab.AcquisitionBench, "_references",
                        lambda self, name, brdf: {"paper_sphere": ref})
    monkeypatch.setattr(acquisition, "default_prior", lambda ens=None: None)
    monkeypatch.setattr(acquisition, "trained_pca", lambda training=None: None)

    def full(self, name, brdf, refs):
        return {"cos_snr": 40.0, "renders": {"paper_sphere": {"snr_object": 40.0,
                                                              "snr_whole": 50.0}},
                "fit_s": 1.0, "coeffs": 786}

    def cell(self, m, brdf, refs, c, prior):
        if stop_after is not None and len(calls) == stop_after:
            raise KeyboardInterrupt
        calls.append(c.key)
        slope = 5.0 if c.method == "sparse" else 2.0
        v = 10 + slope * math.log10(c.n) + c.seed
        return {"material": m.name, "method": c.method, "placement": c.placement, "n": c.n,
                "seed": c.seed, "noise": c.noise, "status": "finished", "fit_s": 0.5,
                "cos_snr": v, "renders": {"paper_sphere": {"snr_object": v,
                                                           "snr_whole": v + 10}}}

    monkeypatch.setattr(ab.AcquisitionBench, "_full", full)
    monkeypatch.setattr(ab.AcquisitionBench, "_cell", cell)

    class _Mat:
        def __init__(self, name):
            self.name, self.source = name, f"/nowhere/{name}.h5"

        def load(self):
            return None

    class _Corpus:
        def split(self, split):
            return [_Mat("a"), _Mat("b")]

    monkeypatch.setattr(ab, "get_corpus", lambda name: _Corpus())


@pytest.mark.bench
def test_an_interrupted_run_resumes_where_it_stopped(tmp_path, shared_data, monkeypatch):
    cfg = ab.AcquisitionConfig(n_samples=[100, 1000, 10000], seeds=[0, 1], bins_n=[10000],
                               noise_n=[], scenes=["paper_sphere.xml"],
                               out=str(tmp_path / "b"))
    every = 2 * len(ab.cells(cfg))
    first: list = []
    _stub_bench(monkeypatch, first, stop_after=7)
    with pytest.raises(KeyboardInterrupt):
        ab.AcquisitionBench(cfg, progress=False).run()
    saved = json.loads((tmp_path / "b" / "results.json").read_text())
    assert len(saved["cells"]) == 7 and len(saved["full"]) == 1
    rest: list = []
    _stub_bench(monkeypatch, rest)
    results = ab.AcquisitionBench(cfg, progress=False).run()
    assert len(rest) == every - 7 and len(results["cells"]) == every
    assert not set(first) & set(rest[: len(ab.cells(cfg)) - 7])  # material a: no cell twice
    again: list = []
    _stub_bench(monkeypatch, again)
    ab.AcquisitionBench(cfg, progress=False).run()
    assert again == []  # all done
    cfg.spp = 32  # a setting that changes every cell's value: nothing is kept
    ab.AcquisitionBench(cfg, progress=False).run()
    assert len(again) == every


@pytest.mark.bench
def test_curves_and_goals_of_known_results(tmp_path, shared_data, monkeypatch):
    cfg = ab.AcquisitionConfig(n_samples=[100, 1000, 10000], seeds=[0, 1], bins_n=[10000],
                               noise_n=[], scenes=["paper_sphere.xml"],
                               out=str(tmp_path / "b"))
    _stub_bench(monkeypatch, [])
    results = ab.AcquisitionBench(cfg, progress=False).run()
    c = curve(results, "paper_sphere", "snr_object", "sparse", "stratified")
    assert c[1000]["mean"] == pytest.approx(10 + 15 + 0.5)  # mean over seeds 0 and 1
    assert (c[1000]["lo"], c[1000]["hi"]) == pytest.approx((25.0, 26.0))
    assert c[1000]["seeds"] == 2 and c[1000]["materials"] == 2
    by_goal = {g["goal"]: g for g in goals(results)}
    assert by_goal["stratified: sparse at or above PCA at every N"]["met"] is True
    # sparse - PCA = 3 log10 N: 9 dB at 1,000, so the 6 dB goal holds from 1,000 on
    six = by_goal["stratified: sparse 6 dB above PCA from 1,000 samples"]
    assert six["met"] is True and "+9.0 dB at N = 1,000" in six["detail"]
    # at the bins: 10 + 20 + 0.5 = 30.5 against the full table's 40: not within 3 dB
    bins = by_goal["bins: 10,000 samples within 3 dB of the full-table encoding"]
    assert bins["met"] is False and "-9.5" in bins["detail"]
    csv_rows = (tmp_path / "b" / "results.csv").read_text().splitlines()
    assert len(csv_rows) == 1 + len(results["cells"])
