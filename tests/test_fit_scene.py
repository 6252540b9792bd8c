"""fit-scene on a small grid: budgets reach the target in the scene, files and report."""

import json

import pytest

from conftest import SMALL
from sparse_brdf.cli import main
from sparse_brdf.coding.fileformat import load_sbrdf
from sparse_brdf.fitting.fit_scene import scene_materials
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    d = tmp_path_factory.mktemp("mats")
    out = {}
    for mid, name in (("material", "plastic-green-ggx-0.1"), ("material2", "diffuse-orange"),
                      ("material3", "au-ggx-0.25")):
        out[mid] = str(write_merl(d / f"{name}.binary", load_brdf(f"mitsuba:{name}",
                                                                  shape=SMALL)))
    return out


def test_scene_materials_finds_overrides_and_xml(tmp_path, materials):
    scene = tmp_path / "s.xml"
    scene.write_text('<scene version="3.0.0"><bsdf type="tabulated_brdf" id="m1">'
                     '<string name="filename" value="a.binary"/></bsdf>'
                     '<bsdf type="diffuse" id="m2"/></scene>')
    found = scene_materials(scene, {"m2": "b.binary"})
    assert found == {"m1": str(tmp_path / "a.binary"), "m2": "b.binary"}
    with pytest.raises(ValueError, match="no measured materials"):
        scene_materials(_empty(tmp_path), {})


def _empty(tmp_path):
    p = tmp_path / "empty.xml"
    p.write_text('<scene version="3.0.0"><bsdf type="diffuse" id="m"/></scene>')
    return p


def test_fit_scene_reaches_target(tmp_path, materials, small_ensemble):
    ens = small_ensemble.save(tmp_path / "ens.npz")
    out = tmp_path / "fit"
    args = ["fit-scene", "spheres.xml", "--target-snr", "30", "-o", str(out), "--ensemble",
            str(ens), "--spp", "4", "--res", "32"]
    for mid, path in materials.items():
        args += ["--material", f"{mid}={path}"]
    assert main(args) == 0
    rep = json.loads((out / "fit-scene.json").read_text())
    assert {r["id"] for r in rep["materials"]} == set(materials)
    assert rep["scene_snr_all_sparse"] >= 30  # the target holds for the whole scene
    for r in rep["materials"]:
        assert r["verified_snr"] >= 30
        m = load_sbrdf(r["file"], small_ensemble)
        assert m.n_coeffs.sum() == r["coefficients_total"] <= 3 * r["coefficients"]
        assert r["memory_strict"] < r["memory_tabulated"]
    assert rep["bytes_total"] == sum((out / f"{m}.sbrdf").stat().st_size for m in materials)
    assert "verified SNR" in (out / "fit-scene.md").read_text()
    assert not list(out.glob("*.candidate.sbrdf"))
