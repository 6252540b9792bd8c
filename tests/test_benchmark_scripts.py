"""Every benchmark script that a guide cites runs, at a tiny size: its options still parse,
its imports still resolve and its code path reaches its table. The figures are not
checked (the guides' records hold those); what breaks is a script left behind by a change
of the library."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

from sparse_brdf.paths import DEMO_MATERIALS_DIR

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
#: A bench folder that the report scripts read (a standard bench with the one-light scenes).
STANDARD = ROOT / "docs" / "records" / "standard_2026-12-05"
#: Modules that scripts share (no smoke test of their own: every script runs them).
SHARED = {"harness", "render_timing"}
#: Scripts whose smoke test lives elsewhere, with where (being written by other work).
TESTED_ELSEWHERE: dict[str, str] = {}
MATERIAL = "mitsuba:au-ggx-0.25"
DEMO = str(DEMO_MATERIALS_DIR / "blue-metallic-paint2.h5")


def run(name: str, monkeypatch, *argv: str) -> object:
    """Run ``benchmarks/<name>.py`` with ``argv`` in this process, as its command line
    would (the folder on the import path, ``sys.argv`` set); returns what ``main`` did."""
    monkeypatch.syspath_prepend(str(BENCH))
    spec = importlib.util.spec_from_file_location(f"bench_script_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    monkeypatch.setattr(sys, "argv", [str(BENCH / f"{name}.py"), *argv])
    return mod.main()


def _cited() -> set[str]:
    """The scripts of benchmarks/ that a guide (the README, docs/*.md) names."""
    guides = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    return {m for p in guides
            for m in re.findall(r"benchmarks/(\w+)\.py", p.read_text())}


def _smoke_tested() -> set[str]:
    text = Path(__file__).read_text()
    return set(re.findall(r"def test_(\w+)_runs\(", text))


def test_every_cited_script_exists_and_has_a_smoke_test():
    cited = _cited()
    assert {"bench_encode", "one_light", "training_report"} <= cited
    assert sorted(c for c in cited if not (BENCH / f"{c}.py").is_file()) == []
    untested = cited - _smoke_tested() - set(TESTED_ELSEWHERE) - SHARED
    assert sorted(untested) == []


def test_every_script_is_cited_by_a_guide():
    """A script no guide cites feeds nothing a reader sees: it goes (git keeps it)."""
    scripts = {p.stem for p in BENCH.glob("*.py")} - SHARED
    assert sorted(scripts - _cited()) == []
    assert not (BENCH / "archive").exists()


# The report scripts: a bench folder in, tables (and charts) out; no renders, no encodes.

@pytest.mark.render
def test_many_materials_runs(monkeypatch, capsys, tmp_path):
    """One case process of the many-materials benchmark (the library, and the strict
    decoder for comparison) on two small-grid files of the shipped ensemble, 8 x 4."""
    import json

    import numpy as np

    from sparse_brdf.coding.coefficients import SparseBRDF
    from sparse_brdf.coding.ensemble import Ensemble
    from sparse_brdf.coding.fileformat import save_sbrdf

    ens = Ensemble.default()
    files = []
    for i in range(2):
        loc = np.array([0, 1 + i], np.int64)
        files.append(str(save_sbrdf(tmp_path / f"m{i}.sbrdf", SparseBRDF(
            "log-relative", ens.shape, ens.id, [0, 0, 0], [loc] * 3,
            [np.array([30.0, 1.0], np.float32)] * 3))))
    for case in ("library", "strict"):
        run("many_materials", monkeypatch, "--child", case, "--width", "8", "--height", "4",
            "--spp", "1", "--image", str(tmp_path / f"{case}.npy"), *files)
        row = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert row["case"] == case and row["n"] == 2 and row["material_bytes"] > 0


def test_ablation_table_runs(monkeypatch, capsys):
    run("ablation_table", monkeypatch, str(STANDARD))
    assert "| model |" in capsys.readouterr().out


def test_one_light_table_runs(monkeypatch, capsys):
    assert run("one_light_table", monkeypatch, str(STANDARD), "--worst", "sparse-262") == 0
    assert "sparse-262" in capsys.readouterr().out


def test_error_concentration_runs(monkeypatch, capsys, tmp_path):
    """A bench folder of one cell whose error sits in one pixel of 64, under a lit
    object ten stops brighter at its peak than at its median: the cell is reported
    concentrated (share 1.00) and judged over about ten stops; a folder without
    results.json is refused with exit status 2."""
    import json

    import numpy as np

    from sparse_brdf.evaluation.images import write_exr

    work = tmp_path / "work" / "s"
    work.mkdir(parents=True)
    ref = np.full((8, 8, 3), 1e-3, np.float32)
    ref[0, 0] = 1.0  # the highlight: 2^10 above the median
    img = ref.copy()
    img[4, 4] += 0.5  # all the error in one pixel
    write_exr(work / "c__m__reference.exr", ref)
    write_exr(work / "c__m__x.exr", img)
    np.save(work / "object_mask.npy", np.ones((8, 8), bool))
    cell = {"status": "finished", "material": "c/m", "model": "x",
            "renders": {"s": {"flip": 0.3, "snr_whole": 30.0}}}
    (tmp_path / "results.json").write_text(json.dumps({"cells": {"c/m|x": cell}}))
    assert run("error_concentration", monkeypatch, str(tmp_path), "--top", "1") == 0
    out = capsys.readouterr().out
    assert "more than 50% of the squared error in 1," in out
    assert "| c/m | x | s | 1.00 | 10.0 | 0.300 | 30.0 |" in out
    assert run("error_concentration", monkeypatch, str(tmp_path / "none")) == 2


def test_error_concentration_top_share():
    """The top pixels' share of the squared error, summed over colour channels."""
    spec = importlib.util.spec_from_file_location("ec", BENCH / "error_concentration.py")
    import numpy as np
    sys.path.insert(0, str(BENCH))
    try:
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(BENCH))
    ref = np.zeros((1, 5, 3))
    img = ref.copy()
    img[0, 0, 0], img[0, 1:, 1] = 2.0, 1.0  # squared errors 4, 1, 1, 1, 1
    assert mod.top_share(ref, img, 1) == 0.5
    assert mod.top_share(ref, img, 3) == 0.75
    assert mod.top_share(ref, img, 99) == 1.0
    assert np.isnan(mod.top_share(ref, ref, 1))


def test_front_chart_runs(monkeypatch, tmp_path):
    run("front_chart", monkeypatch, str(STANDARD), "--out", str(tmp_path / "front.png"))
    assert (tmp_path / "front.png").stat().st_size > 0


def test_calibrate_runs(monkeypatch, tmp_path):
    out = tmp_path / "calibration.json"
    run("calibrate", monkeypatch, str(STANDARD / "results.json"), "--out", str(out))
    assert "offset_db" in out.read_text()


def test_training_report_runs(monkeypatch, tmp_path):
    run("training_report", monkeypatch, "--out", str(tmp_path))
    assert (tmp_path / "training.md").is_file()


def test_asymmetry_runs(monkeypatch, tmp_path):
    assert run("asymmetry", monkeypatch, "--corpus", str(DEMO_MATERIALS_DIR), "-o",
               str(tmp_path / "a.json")) == 0
    assert "reciprocity" in (tmp_path / "a.json").read_text()


def test_peers_summary_runs(monkeypatch, tmp_path, capsys):
    run("peers_summary", monkeypatch, str(STANDARD / "results.csv"), "--material", MATERIAL,
        "--out", str(tmp_path), "--speed-models", "naive", "--pairs", "4096")
    assert "naive" in capsys.readouterr().out


# Encoding: one small material, the fewest encodes each script allows.

def test_bench_encode_runs(monkeypatch, capsys):
    run("bench_encode", monkeypatch, "--n", "1", "--repeats", "1", "--corpus", "mitsuba")
    assert "both transforms" in capsys.readouterr().out


def test_bench_missing_runs(monkeypatch, capsys):
    run("bench_missing", monkeypatch, MATERIAL, "--fraction", "0.2")
    assert "dB" in capsys.readouterr().out


def test_bench_options_runs(monkeypatch, capsys):
    run("bench_options", monkeypatch, "--n", "1", "--corpus", "mitsuba", "--variants",
        "paper (defaults)")
    assert "paper (defaults)" in capsys.readouterr().out


def test_bytes_passes_runs(monkeypatch, capsys):
    run("bytes_passes", monkeypatch, "--budgets", "1600", "--n", "1", "--corpus", "mitsuba")
    assert "1600" in capsys.readouterr().out


def test_sbrdf_sizes_runs(monkeypatch, capsys):
    run("sbrdf_sizes", monkeypatch, "--counts", "16", "--materials", DEMO)
    assert "|" in capsys.readouterr().out


def test_encode_memory_runs(monkeypatch, capsys):
    run("encode_memory", monkeypatch, "--n", "1", "--repeats", "1", "--corpus", "mitsuba",
        "--settings", "plain", "--", "--coeffs", "16")
    assert "plain" in capsys.readouterr().out


def test_acquisition_table_runs(monkeypatch, capsys):
    from sparse_brdf.acquisition import defaults
    from sparse_brdf.sources.corpora import get_corpus

    # the trained defaults (atom prior, PCA basis) from two training materials, not 50
    two = get_corpus(defaults.TRAINING_CORPUS).split("train")[:2]
    monkeypatch.setattr(defaults, "training_materials", lambda: two)
    run("acquisition_table", monkeypatch, "--materials", "blue-metallic-paint2", "--n", "100",
        "--placements", "bins")
    assert "blue-metallic-paint2" in capsys.readouterr().out


# Speed: Dr.Jit evaluators and the plugins' lookups, few pairs.

def test_bench_eval_runs(monkeypatch, capsys):
    run("bench_eval", monkeypatch, "--material", MATERIAL, "--corpus", "mitsuba", "--n", "1024",
        "--repeats", "1", "--rounds", "1", "--pca-train", "2")
    assert "vs tabulated" in capsys.readouterr().out


def test_bench_lookup_call_runs(monkeypatch, capsys):
    run("bench_lookup_call", monkeypatch, "--material", MATERIAL, "--pairs", "20",
        "--rounds", "1")
    assert "tabulated_brdf" in capsys.readouterr().out


# Renders: a few pixels at one sample each.

@pytest.mark.render
def test_bench_render_runs(monkeypatch, capsys):
    run("bench_render", monkeypatch, "--material", MATERIAL, "--res", "8", "--spp", "1",
        "--repeats", "1", "--counts", "32")
    assert "tabulated_brdf" in capsys.readouterr().out


@pytest.mark.render
def test_bench_variants_runs(monkeypatch, capsys):
    # scalar_rgb too: its render threads reach an auto-decoded material's first lookup
    # while another thread builds it (a material once read as built before it was)
    run("bench_variants", monkeypatch, "--material", MATERIAL, "--variants",
        "scalar_rgb,llvm_ad_rgb", "--no-neural", "--res", "8", "--spp", "1", "--repeats", "1")
    out = capsys.readouterr().out
    assert "scalar_rgb" in out and "llvm_ad_rgb" in out


@pytest.mark.render
def test_blend_sweep_runs(monkeypatch, tmp_path):
    run("blend_sweep", monkeypatch, "--alphas", "0", "1", "--spp", "1", "--res", "8",
        "--out", str(tmp_path / "blend.png"))
    assert (tmp_path / "blend.png").stat().st_size > 0


@pytest.mark.render
def test_sampling_noise_runs(monkeypatch, capsys):
    run("sampling_noise", monkeypatch, "--spp", "1", "--seeds", "1", "--ref-spp", "1",
        "--ref-renders", "1", "--res", "8", "--materials", MATERIAL, "--scenes", "sphere")
    assert "cosine" in capsys.readouterr().out


@pytest.mark.render
def test_one_light_runs(monkeypatch, tmp_path):
    out = tmp_path / "one_light.json"
    assert run("one_light", monkeypatch, "--corpus", "mitsuba", "--materials", "au-ggx-0.25",
               "--angles", "40", "--res", "8", "--spp", "1", "-o", str(out)) == 0
    assert "flip" in out.read_text()


@pytest.mark.render
def test_nbrdf_refit_runs(monkeypatch, capsys):
    run("nbrdf_refit", monkeypatch, "--epochs", "1", "--materials", "blue-metallic-paint2",
        "--scenes", "sphere", "--res", "8", "--spp", "1")
    assert "blue-metallic-paint2" in capsys.readouterr().out


@pytest.mark.render
def test_fit_images_study_runs(monkeypatch, capsys):
    run("fit_images_study", monkeypatch, "--materials", "silver-paint", "--fit-views",
        "envrot=0", "--held-out", "envrot=45", "--iterations", "1", "--res", "8", "--spp", "1")
    assert "silver-paint" in capsys.readouterr().out


@pytest.mark.render
def test_fit_images_identify_runs(monkeypatch, capsys):
    run("fit_images_identify", monkeypatch, "--references", "encoding", "--fit-views",
        "envrot=0", "--rate", "envrot=45", "--iterations", "1", "--res", "8", "--spp", "1",
        "--rate-spp", "1")
    assert "h20-90" in capsys.readouterr().out  # the BRDF regions of the held-out error
