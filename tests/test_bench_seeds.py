"""A bench rendered at several seeds: each figure the mean over them with its standard
error, in results, tables and charts."""

from __future__ import annotations

import html
import math
import re

import numpy as np
import pytest

from sparse_brdf.benchmark.bench_config import BenchConfig, render_seeds
from sparse_brdf.benchmark.cells import seed_mean
from sparse_brdf.benchmark.results_file import read_results
from sparse_brdf.cli import main


def test_seeds_start_at_the_seed_and_skip_the_noise_seed():
    assert render_seeds(BenchConfig(seed=0, noise_seed=1, seeds=3)) == [0, 2, 3]
    assert render_seeds(BenchConfig(seed=5, noise_seed=1, seeds=2)) == [5, 6]
    assert render_seeds(BenchConfig()) == [0]


def test_seed_mean_gives_means_and_standard_errors():
    per = [{"snr_object": 30.0, "snr_whole": 40.0, "flip": 0.1, "render_s": 1.0},
           {"snr_object": 32.0, "snr_whole": 40.0, "flip": 0.3, "render_s": 3.0}]
    out = seed_mean(per)
    assert out["seeds"] == 2 and out["snr_object"] == 31.0 and out["render_s"] == 2.0
    assert math.isclose(out["snr_object_se"], np.std([30, 32], ddof=1) / np.sqrt(2))
    assert out["snr_whole_se"] == 0.0 and math.isclose(out["flip_se"], 0.1)
    same = [{"snr_object": math.inf, "snr_whole": math.inf, "flip": 0.0, "render_s": 1.0}] * 2
    assert seed_mean(same)["snr_object"] == math.inf and seed_mean(same)["snr_object_se"] == 0
    assert seed_mean(per[:1]) == per[0]  # one seed: as it is


@pytest.mark.bench
@pytest.mark.render
def test_a_bench_at_three_seeds(tmp_path, capsys):
    out = tmp_path / "b"
    cfg = tmp_path / "c.toml"
    cfg.write_text('corpora = ["mitsuba"]\nmax_materials = 1\nmodels = ["naive", "tabulated"]\n'
                   'scenes = ["sphere.xml"]\nres = 16\nspp = 2\ncurve_coeffs = [16]\n'
                   'stability = false\nspeed = false\n')
    assert main(["bench", str(cfg), "--out", str(out), "--seeds", "3"]) == 0
    results = read_results(out)
    assert results["config"]["seeds"] == 3
    naive = next(c for c in results["cells"].values() if c["model"] == "naive")
    r = naive["renders"]["sphere"]
    assert r["seeds"] == 3 and r["snr_object_se"] > 0 and math.isfinite(r["snr_object"])
    assert len(list((out / "work" / "sphere").glob("*__naive@s*.exr"))) == 2
    md = (out / "report.md").read_text()
    assert "rendered at 3 seeds" in md
    assert f"{r['snr_object']:.1f} ± {r['snr_object_se']:.1f}" in md
    page = html.unescape(re.sub(r"<[^>]+>", " ", (out / "report.html").read_text()))
    assert "obj ± (dB)" in page and f"{r['snr_object_se']:.1f}" in page
    capsys.readouterr()
    # the acquisition bench renders its own way: --seeds is refused, one line, exit 2
    assert main(["bench", "acquisition", "--seeds", "2"]) == 2
    assert "--seeds" in capsys.readouterr().err


def test_the_charts_carry_error_bars_with_several_seeds():
    import matplotlib.pyplot as plt

    from sparse_brdf.benchmark.charts import speed_accuracy_figure

    rows = [{"model": m, "evals_per_s": s, "bytes": b, "snr_object_mean": y,
             "snr_whole_mean": y + 3, "snr_object_se": 0.4, "snr_whole_se": 0.2}
            for m, s, b, y in (("a", 1e6, 100.0, 30.0), ("b", 3e7, 900.0, 35.0))]
    fig = speed_accuracy_figure(rows)
    try:
        bars = [c for ax in fig.axes for c in ax.containers]
        assert len(bars) == 8  # two models on each of the four panels
        lines = bars[0].lines[2][0].get_segments()[0]
        assert np.isclose(abs(lines[1][1] - lines[0][1]), 0.8)  # +- one standard error
        no_se = speed_accuracy_figure([{k: v for k, v in r.items() if not k.endswith("_se")}
                                       for r in rows])
        assert not [c for ax in no_se.axes for c in ax.containers]
        plt.close(no_se)
    finally:
        plt.close(fig)
