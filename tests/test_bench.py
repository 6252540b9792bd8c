"""The CI-sized bench (sparse_brdf/data/configs/ci.toml) end to end: cells, report, resume."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from other_cpu import pinned_cpu
from sparse_brdf.benchmark.acquisition_bench import KIND as ACQUISITION
from sparse_brdf.benchmark.acquisition_bench import (
    AcquisitionConfig,
    check_acquisition_config,
)
from sparse_brdf.benchmark.bench import Bench
from sparse_brdf.benchmark.bench_config import (
    BenchConfig,
    check_config,
    config_kind,
    evaluated_materials,
    find_config,
    learners_training_set,
)
from sparse_brdf.benchmark.charts import pareto
from sparse_brdf.benchmark.compare import compare_results, format_worse
from sparse_brdf.benchmark.provenance import environment_provenance
from sparse_brdf.benchmark.results_file import read_results
from sparse_brdf.coding.spec import ENCODE_OPTIONS
from sparse_brdf.compared.specs import make_model
from sparse_brdf.errors import MissingDataError
from sparse_brdf.evaluation.scenes import parse_scene_spec
from sparse_brdf.fileio import parse_strict_json

ROOT = Path(__file__).resolve().parent.parent
#: The CI bench's results as the project last stored them (sparse-brdf bench ci under the
#: pinned kernels of other_cpu.pinned_cpu, cut down by benchmark.compare.quality_of), and
#: the gate's tolerances against them. Under pinned kernels every x86-64 CPU with AVX2
#: rounds alike: two runs gave identical figures. Without them a last bit can tip one
#: of the encoder's choices: on an AVX-512 machine one cell moved by 0.49 dB of SNR
#: (2026-12-08), so a CPU that cannot be pinned gets the wider tolerances.
CI_BASELINE = ROOT / "tests" / "data" / "ci_bench_baseline.json"
CI_WORSE_DB, CI_FLIP_RISE = 0.1, 0.001
UNPINNED_WORSE_DB, UNPINNED_FLIP_RISE = 1.0, 0.01


def test_pareto_front():
    pts = [(1.0, 10.0), (2.0, 20.0), (3.0, 15.0), (0.5, 5.0)]
    assert pareto(pts) == [0, 1, 3]


def test_pareto_front_faster_is_better():
    pts = [(1e6, 10.0), (1e7, 20.0), (1e5, 30.0), (1e7, 5.0)]
    assert pareto(pts, higher_x=True) == [1, 2]


@pytest.mark.bench
def test_learned_models_never_train_on_evaluated_materials(tmp_path):
    """PCA trains on the training split minus every evaluated material, and a config that
    leaves no disjoint training set is refused (it used to train on its test materials)."""
    cfg = BenchConfig(corpora=["mitsuba"], split="all", models=["pca:4"], render=False,
                      stability=False, speed=False, out=str(tmp_path / "b"))
    bench = Bench(cfg, progress=False)
    with pytest.raises(ValueError, match="disjoint|does not evaluate"):
        bench.run()
    cfg = BenchConfig(corpora=["mitsuba"], split="test", max_materials=1, models=["pca:4"],
                      render=False, stability=False, speed=False, out=str(tmp_path / "c"),
                      pca_train_max=3)
    bench = Bench(cfg, progress=False)
    evaluated = bench.materials()
    train = bench.training_materials(evaluated)
    assert len(train) == 3
    assert not {(m.corpus, m.name) for m in train} & {(m.corpus, m.name) for m in evaluated}
    # even when the evaluated set includes training-split materials, they are left out
    cfg.split = "train"
    cfg.max_materials = 2
    evaluated = bench.materials()
    assert not {m.name for m in bench.training_materials(evaluated)} & {
        m.name for m in evaluated}


def test_old_one_scene_configs_still_load(tmp_path):
    old = tmp_path / "old.toml"
    old.write_text('scene = "sphere.xml"\nspp = 4\n')
    assert BenchConfig.load(old).scenes == ["sphere.xml"]
    broken = tmp_path / "broken.toml"
    broken.write_text("spp = \n")
    with pytest.raises(ValueError, match="broken.toml"):
        BenchConfig.load(broken)


def test_unknown_model_and_setting(tmp_path):
    with pytest.raises(ValueError, match="unknown model 'svd'"):
        make_model("svd")
    bad = tmp_path / "bad.toml"
    bad.write_text('spp = 4\ncolour = "red"\n')
    with pytest.raises(ValueError, match="unknown bench settings"):
        BenchConfig.load(bad)


@pytest.mark.bench
@pytest.mark.render
def test_ci_bench_report(tmp_path):
    cfg = BenchConfig.load("ci")
    cfg.out = str(tmp_path / "bench")
    out = Path(cfg.out)
    # a fresh process, so that numpy, OpenBLAS and Dr.Jit start on the pinned kernels
    pinned = pinned_cpu()
    run = subprocess.run([sys.executable, "-m", "sparse_brdf.cli", "bench", "ci", "--out",
                          str(out)], env={**os.environ, **(pinned or {})},
                         capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stderr[-3000:]
    results = read_results(out)
    cells = results["cells"]
    assert len(cells) == 2 * len(cfg.models)
    assert all(c["status"] == "finished" for c in cells.values()), cells
    scenes = ["sphere"] + (["paper_sphere"] if "paper_sphere" not in
                           results["skipped_scenes"] else [])
    for name in ("report.md", "results.csv", "results.json", "error_vs_coeffs.png",
                 *(f"speed_accuracy-{s}.png" for s in scenes)):
        assert (out / name).is_file(), name
    assert "flip@sphere" in (out / "results.csv").read_text()
    assert (out / "work" / "sphere" / "mitsuba__{}__naive.flip.npy".format(
        cells[next(iter(cells))]["material"].split("/")[1])).is_file()
    report = (out / "report.md").read_text()
    for heading in ("Table 3", "Table 4", "Table 2", "Fig. 2", "Stability", "Noise floor",
                    "object-only", "whole-image", "FLIP mean", "HDR-FLIP", *scenes):
        assert heading in report, heading
    # every model has its own evaluation speed
    assert set(results["speed"]) == {c["model"] for c in cells.values()}
    assert all(v > 0 for v in results["speed"].values())
    for scene in scenes:
        # the tabulated model renders exactly like the reference (same seed, same table)
        tab = [c["renders"][scene] for c in cells.values() if c["model"] == "tabulated"]
        assert all(t[f] == float("inf") or t[f] > 100 for t in tab
                   for f in ("snr_whole", "snr_object"))
        assert all(t["flip"] < 1e-6 for t in tab)  # HDR-FLIP: identical renders score 0
        flips = [c["renders"][scene]["flip"] for c in cells.values()]
        assert all(0 <= f <= 1 for f in flips) and max(flips) > 0
        for mat in {c["material"] for c in cells.values()}:
            r262, r64 = (cells[f"{mat}|sparse-{n}"]["renders"][scene] for n in (262, 64))
            # more coefficients, better renders; the background adds signal, never error
            assert r262["snr_object"] > r64["snr_object"] - 0.5
            assert r262["snr_whole"] >= r262["snr_object"] - 0.1
    # no figure worse than in the project's stored results of this config
    worse_db, flip_rise = ((CI_WORSE_DB, CI_FLIP_RISE) if pinned else
                           (UNPINNED_WORSE_DB, UNPINNED_FLIP_RISE))
    found = compare_results(CI_BASELINE, out, worse_db, flip_rise)
    assert found["cells"] == len(cells), found
    assert found["worse"] == [], [format_worse(w) for w in found["worse"]]
    # and the gate is tight enough to see a model lose accuracy (64 against 262 coefficients)
    base = parse_strict_json(CI_BASELINE.read_text())["cells"]
    r64, r262 = (base[f"mitsuba/al-ggx-0.3|sparse-{n}"]["renders"]["sphere"] for n in (64, 262))
    assert r262["snr_object"] - r64["snr_object"] > 5 * worse_db
    # a re-run skips every finished cell
    before = parse_strict_json((out / "results.json").read_text())  # inf SNRs put back
    again = Bench(cfg, progress=False)
    again.run()
    assert again.results["cells"] == before["cells"]


def test_bench_renders_coefficient_files_with_its_own_ensemble(tmp_path, monkeypatch,
                                                               small_ensemble):
    """A bench configured with an ensemble file hands it to the sparse plugin (the plugin
    would otherwise decode with the shipped ensemble and refuse the files); both plugins
    sample cosine-weighted whatever their default, and the scene's parameters are set."""
    import sparse_brdf.benchmark.cells as cells_mod

    seen = []

    def fake_render(scene, materials, spp, seed, res, params, sparse_options=None,
                    sampling=None):
        assert sampling == "cosine"  # the bench's renders share their sample paths
        seen.append((materials["material"], params, sparse_options))
        return np.zeros((2, 2, 3), np.float32)

    monkeypatch.setattr(cells_mod, "render_scene", fake_render)
    monkeypatch.setattr(cells_mod, "write_exr", lambda path, img: None)
    ens = small_ensemble.save(tmp_path / "ens.npz")
    cfg = BenchConfig(out=str(tmp_path / "out"), ensemble=str(ens))
    b = Bench(cfg, progress=False)
    spec = parse_scene_spec("sphere_light.xml:lightangle=40")
    assert spec.key == "sphere_light-lightangle=40"
    b.cells.scenes = {spec.key: spec}
    (b.work / spec.key).mkdir(parents=True)
    b.cells.render(spec.key, "merl/x", str(tmp_path / "x.sbrdf"), 0, "m")
    b.cells.render(spec.key, "merl/x", str(tmp_path / "x.binary"), 0, "ref")
    assert seen == [(str(tmp_path / "x.sbrdf"), {"lightangle": "40"},
                     {"ensemble": str(ens.resolve())}),
                    (str(tmp_path / "x.binary"), {"lightangle": "40"}, None)]


@pytest.mark.parametrize("text, message", [
    ("sphere_light.xml:lightangle", "expected KEY=VALUE"),
    ("sphere_light.xml:colour=red", "declares no parameter colour"),
    ("sphere_light.xml:spp=4", "spp is set for every scene"),
    ("nowhere.xml:lightangle=3", "no such scene file"),
])
def test_bad_scene_specs_name_the_config(tmp_path, text, message):
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'scenes = ["{text}"]\n')
    with pytest.raises(ValueError, match=f"c.toml: setting scenes: .*{message}"):
        BenchConfig.load(cfg)


def test_results_of_another_ensemble_or_encoder_are_not_reused(tmp_path, small_ensemble):
    """A resumed bench keeps its results only when the config, the ensemble and the
    encoder's defaults are unchanged; otherwise results and cached renders go."""
    ens = small_ensemble.save(tmp_path / "ens.npz")
    cfg = BenchConfig(out=str(tmp_path / "out"), ensemble=str(ens))
    b = Bench(cfg, progress=False)
    b.results["cells"]["merl/x|sparse-262"] = {"status": "finished"}
    b.out.mkdir()
    b._save()
    (b.work / "sphere").mkdir(parents=True)
    (b.work / "sphere" / "old.exr").write_bytes(b"x")
    assert Bench(cfg, progress=False).results["cells"]  # same everything: resumed
    data = json.loads((b.out / "results.json").read_text())
    data["provenance"]["ensemble"] = "0" * 32  # written with another ensemble
    (b.out / "results.json").write_text(json.dumps(data))
    again = Bench(cfg, progress=False)
    assert again.results["cells"] == {} and not b.work.exists()
    assert again.results["provenance"] == {"ensemble": small_ensemble.id,
                                           "encoder_defaults": dict(ENCODE_OPTIONS),
                                           "sbrdf_version": 2,
                                           "environment": environment_provenance()}
    # another Mitsuba (or Dr.Jit, or machine) renders the references anew
    again._save()
    data = json.loads((b.out / "results.json").read_text())
    data["cells"] = {"merl/x|sparse-262": {"status": "finished"}}
    data["provenance"]["environment"]["mitsuba"] = "0.0.1"
    (b.out / "results.json").write_text(json.dumps(data))
    assert Bench(cfg, progress=False).results["cells"] == {}


@pytest.mark.parametrize("name", sorted(p.stem for p in
                                        (ROOT / "sparse_brdf" / "data" / "configs").glob("*.toml")))
def test_every_shipped_config_checks(name):
    """Every shipped config loads and passes ``bench NAME --check`` (models, corpora,
    training materials, scenes); one that needs ../shared/data skips where it is absent."""
    if config_kind(name) == ACQUISITION:  # encoding from samples: its own bench
        acq = AcquisitionConfig.load(name)
        try:
            plan = check_acquisition_config(acq)
        except MissingDataError as exc:
            pytest.skip(f"{name}: {exc}")
        assert plan["materials"] > 0 and plan["cells"] > 0 and plan["scenes"]
        return
    cfg = BenchConfig.load(find_config(name))
    try:
        plan = check_config(cfg)
    except MissingDataError as exc:
        pytest.skip(f"{name}: {exc}")
    assert plan["materials"] > 0 and plan["models"]
    if any(m.startswith("pca") for m in plan["models"]):  # never trained on what is scored
        evaluated = evaluated_materials(cfg)
        keys = {(m.corpus, m.name) for m in evaluated}
        train = learners_training_set(cfg, evaluated)
        assert len(train) == plan["training"] >= 2
        assert not keys & {(m.corpus, m.name) for m in train}


def test_scene_specs_name_their_scenes():
    assert parse_scene_spec("sphere.xml").key == "sphere"
    spec = parse_scene_spec("sphere_light:lightangle=70, lightroll=90")
    assert spec.params == {"lightangle": "70", "lightroll": "90"}
    assert spec.key == "sphere_light-lightangle=70-lightroll=90"
    # a key names folders and files: no path separator in it
    assert parse_scene_spec("sphere.xml:envmap=envmaps/studio.exr").key == \
        "sphere-envmap=envmaps_studio.exr"
