"""The CI-sized bench (benchmarks/ci.toml) end to end: cells, report, resume."""

import json
from pathlib import Path

import pytest

from sparse_brdf.bench import Bench, BenchConfig, make_model
from sparse_brdf.report import pareto

ROOT = Path(__file__).resolve().parent.parent


def test_pareto_front():
    pts = [(1.0, 10.0), (2.0, 20.0), (3.0, 15.0), (0.5, 5.0)]
    assert pareto(pts) == [0, 1, 3]


def test_unknown_model_and_setting(tmp_path):
    with pytest.raises(ValueError, match="unknown model 'svd'"):
        make_model("svd")
    bad = tmp_path / "bad.toml"
    bad.write_text('spp = 4\ncolour = "red"\n')
    with pytest.raises(ValueError, match="unknown bench settings"):
        BenchConfig.load(bad)


@pytest.mark.render
def test_ci_bench_report(tmp_path):
    cfg = BenchConfig.load(ROOT / "benchmarks" / "ci.toml")
    cfg.out = str(tmp_path / "bench")
    results = Bench(cfg, progress=False).run()
    out = Path(cfg.out)
    cells = results["cells"]
    assert len(cells) == 2 * len(cfg.models)
    assert all(c["status"] == "finished" for c in cells.values()), cells
    for name in ("report.md", "results.csv", "results.json", "speed_accuracy.png",
                 "error_vs_coeffs.png"):
        assert (out / name).is_file(), name
    report = (out / "report.md").read_text()
    for heading in ("Table 3", "Table 4", "Table 2", "Fig. 2", "Stability", "Noise floor"):
        assert heading in report, heading
    # the tabulated model renders exactly like the reference (same seed, same table)
    tab = [c for c in cells.values() if c["model"] == "tabulated"]
    assert all(c["render_snr"] == float("inf") or c["render_snr"] > 100 for c in tab)
    # more coefficients, better renders
    for mat in {c["material"] for c in cells.values()}:
        assert cells[f"{mat}|sparse-262"]["render_snr"] > cells[f"{mat}|sparse-64"][
            "render_snr"] - 0.5
    # a re-run skips every finished cell
    before = json.loads((out / "results.json").read_text())
    again = Bench(cfg, progress=False)
    again.run()
    assert again.results["cells"] == before["cells"]
