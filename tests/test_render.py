"""Rendering with the plugins: scenes, material overrides, EXR files, the noise floor."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from sparse_brdf.errors import RenderError
from sparse_brdf.evaluation.images import read_exr, write_exr
from sparse_brdf.evaluation.render import noise_floor, noise_floor_snr, object_mask, render_scene
from sparse_brdf.evaluation.scenes import parse_overrides, plugin_for, scene_xml
from sparse_brdf.metrics import render_snr

pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from test_plugin import make_exact_material  # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / "scenes"
SPHERE = SCENES / "sphere.xml"
SPHERES = SCENES / "spheres.xml"
RES, SPP = 32, 4

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def exact_material(tmp_path_factory):
    """A glossy material, its exact sparse code and the code's decoded table."""
    return make_exact_material(tmp_path_factory.mktemp("render"))


def _sparse(mat, **kw):
    return {"ensemble": mat["ensemble"], **kw}


def test_scenes_and_envmap_are_shipped():
    assert (SCENES / "envmaps" / "studio.exr").is_file()
    assert "CC0" in (SCENES / "envmaps" / "ATTRIBUTION.md").read_text()
    for scene in (SPHERE, SPHERES):
        text = scene.read_text()
        assert 'id="material"' in text and "$spp" in text and "$res" in text
    assert 'id="material3"' in SPHERES.read_text()


def test_overrides_and_plugin_choice(exact_material):
    assert parse_overrides(["material=a.sbrdf", "material2=b.binary"]) == {
        "material": "a.sbrdf", "material2": "b.binary"}
    assert parse_overrides(["c.h5"]) == {"material": "c.h5"}  # a bare file: id "material"
    with pytest.raises(ValueError):
        parse_overrides(["material="])
    # an id given twice (a bare file is id "material"): refused, neither wins
    with pytest.raises(ValueError, match="--material material: given twice"):
        parse_overrides(["material=a.sbrdf", "c.h5"])
    assert plugin_for("x.SBRDF") == "sparse_brdf"
    assert plugin_for("mitsuba:cu-ggx-0.12") == "tabulated_brdf"
    xml = scene_xml(SPHERE, {"material": exact_material["sbrdf"]},
                    sparse_options=_sparse(exact_material, decoder="strict", interpolate=True))
    assert 'type="sparse_brdf"' in xml and 'value="strict"' in xml
    assert '<boolean name="interpolate" value="true"' in xml
    with pytest.raises(KeyError, match="nothere"):
        scene_xml(SPHERE, {"nothere": exact_material["binary"]})


def test_renders_are_finite_and_the_exact_model_matches_its_table(exact_material):
    native = render_scene(SPHERE, None, spp=SPP, seed=0, res=RES)
    assert native.shape == (RES, RES, 3) and native.dtype == np.float32
    assert np.all(np.isfinite(native)) and native.mean() > 0
    ref = render_scene(SPHERE, {"material": exact_material["binary"]}, spp=SPP, seed=0,
                       res=RES, sampling="cosine")
    assert np.all(np.isfinite(ref)) and ref.mean() > 0
    for decoder in ("grouped", "strict"):
        img = render_scene(SPHERE, {"material": exact_material["sbrdf"]}, spp=SPP, seed=0,
                           res=RES, sparse_options=_sparse(exact_material, decoder=decoder),
                           sampling="cosine")
        assert np.all(np.isfinite(img))
        # same seed and cosine sampling: the Monte Carlo noise cancels, so the exact
        # model differs from its own table by float rounding only
        assert render_snr(ref, img) > 60, decoder
    # the model against the original (not sparse) material: close, but not exact
    orig = render_scene(SPHERE, {"material": exact_material["original"]}, spp=SPP, seed=0,
                        res=RES, sampling="cosine")
    assert 15 < render_snr(orig, img) < 200


def test_lobe_sampling_and_interpolation_render(exact_material):
    ref = render_scene(SPHERE, {"material": exact_material["binary"]}, spp=SPP, seed=0,
                       res=RES, tabulated_options={"sampling": "lobe", "interpolate": True})
    img = render_scene(SPHERE, {"material": exact_material["sbrdf"]}, spp=SPP, seed=0,
                       res=RES, sparse_options=_sparse(exact_material, sampling="lobe",
                                                       interpolate=True))
    assert np.all(np.isfinite(ref)) and np.all(np.isfinite(img))
    # both converge to nearly the same image (interpolation of X vs of rho differs a bit)
    assert render_snr(ref, img) > 20


def test_swapping_materials_does_not_recompile(exact_material, tmp_path):
    second = make_exact_material(tmp_path, "principled-clearcoat-red-0.4", 200)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        hashes = []
        # the second material also uses the other grouped layout: same kernel
        for mat, layout in ((exact_material, "union"), (second, "slots")):
            dr.kernel_history()  # clear
            render_scene(SPHERE, {"material": mat["sbrdf"]}, spp=2, seed=0, res=16,
                         sparse_options=_sparse(mat, decoder="grouped", layout=layout))
            hist = dr.kernel_history()
            hashes.append({k["hash"] for k in hist
                           if k["type"] == dr.KernelType.JIT and k["operation_count"] > 200})
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert hashes[0] and hashes[1] <= hashes[0], "a second material compiled a new kernel"


def test_three_spheres_scene(exact_material):
    img = render_scene(SPHERES, {"material": exact_material["sbrdf"],
                                 "material2": exact_material["binary"],
                                 "material3": "mitsuba:diffuse-white"},
                       spp=2, seed=0, res=24, sparse_options=_sparse(exact_material))
    assert img.shape == (24, 24, 3) and np.all(np.isfinite(img)) and img.mean() > 0


def test_scalar_variant_renders(exact_material):
    img = render_scene(SPHERE, {"material": exact_material["sbrdf"]}, spp=1, seed=0, res=4,
                       variant="scalar_rgb", sparse_options=_sparse(exact_material))
    assert img.shape == (4, 4, 3) and np.all(np.isfinite(img))


def test_errors_name_the_file(exact_material, tmp_path):
    missing = tmp_path / "missing.sbrdf"
    with pytest.raises(RenderError, match="missing.sbrdf"):
        render_scene(SPHERE, {"material": str(missing)}, spp=1, res=4,
                     sparse_options=_sparse(exact_material))
    with pytest.raises(FileNotFoundError, match="nope.xml"):
        render_scene(tmp_path / "nope.xml", None, spp=1, res=4)


def test_noise_floor_and_seeds(exact_material):
    mats = {"material": exact_material["binary"]}
    a = render_scene(SPHERE, mats, spp=2, seed=3, res=16)
    b = render_scene(SPHERE, mats, spp=2, seed=3, res=16)
    assert render_snr(a, b) == float("inf")  # deterministic for a given seed
    floor = noise_floor(SPHERE, mats, spp=2, seeds=(0, 1), res=16)
    # both forms, finite and noise-limited; the background adds signal and no noise
    assert 0 < floor.object <= floor.whole < 60
    mask = np.ones(a.shape[:2], bool)
    assert noise_floor_snr(a, b, mask) == (float("inf"), float("inf"))


def test_exr_roundtrip_is_exact_and_atomic(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.random((7, 5, 3)).astype(np.float32) * 10
    path = write_exr(tmp_path / "sub" / "img.exr", img)
    np.testing.assert_array_equal(read_exr(path), img)
    assert sorted(p.name for p in path.parent.iterdir()) == ["img.exr"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask  # not mkstemp's 0600
    with pytest.raises(ValueError):
        write_exr(tmp_path / "bad.exr", img[..., :2])
    assert not (tmp_path / "bad.exr").exists()
    (tmp_path / "junk.exr").write_bytes(b"not an exr")
    with pytest.raises(ValueError, match="junk.exr"):
        read_exr(tmp_path / "junk.exr")


@pytest.mark.shared
def test_measured_material_renders(shared_data):
    h5 = sorted((shared_data / "nbrdf" / "merl").glob("*.h5"))
    if not h5:
        pytest.skip("no Neural-BRDF materials in the shared data")
    img = render_scene(SPHERE, {"material": str(h5[0])}, spp=2, seed=0, res=16)
    assert np.all(np.isfinite(img)) and img.mean() > 0


def test_point_light_scene_lights_the_side_the_light_turns_to():
    # the scene's own material: diffuse, reflectance 0.5, under irradiance 3 (W/m^2)
    scene = SCENES / "sphere_light.xml"
    mask = object_mask(scene, res=32)
    lit = {}
    for angle in (0, 90, 150):
        img = render_scene(scene, None, spp=4, seed=0, res=32,
                           params={"lightangle": angle}).mean(axis=2)
        lit[angle] = (img > 1e-4) & mask
        if angle == 0:
            # a flash: every object pixel lit, the brightest where the normal faces the
            # camera and the light, radiance 0.5 / pi * 3
            assert lit[0].sum() >= 0.97 * mask.sum()
            assert img.max() == pytest.approx(0.5 / np.pi * 3.0, rel=0.02)
    frac = {a: lit[a].sum() / mask.sum() for a in lit}
    assert 0.35 < frac[90] < 0.65 and frac[150] < 0.2 < frac[90]
    # the light turns towards the image's +x or -x: the lit crescent is on one side
    cols = np.nonzero(lit[150])[1]
    assert cols.size > 0 and (cols.max() < 16 or cols.min() >= 16)
    assert 'id="material"' in scene.read_text()


def test_closeups_aim_at_the_highlight(tmp_path, monkeypatch):
    # the identify benchmark's close-ups: the brightest pixel of a glossy material is at
    # the image's centre, where the normal is the half-vector of light and camera
    import importlib.util

    from sparse_brdf import load_brdf
    from sparse_brdf.paths import DEMO_MATERIALS_DIR
    from sparse_brdf.sources.merl import write_merl

    bench = Path(__file__).resolve().parents[1] / "benchmarks"
    monkeypatch.syspath_prepend(str(bench))  # the script imports its harness
    path = bench / "fit_images_identify.py"
    spec = importlib.util.spec_from_file_location("fit_images_identify", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    n, theta_d = mod.highlight(0.0, 0.0)
    assert theta_d == pytest.approx(0.0, abs=1e-6)
    assert n == pytest.approx(np.array([0.0, 0.9, 4.0]) / np.hypot(0.9, 4.0))
    table = write_merl(tmp_path / "m.binary",
                       load_brdf(DEMO_MATERIALS_DIR / "blue-metallic-paint2.h5"))
    for spec_ in mod.closeup_views(["90:0:4", "135:90:1"]):
        params = dict(kv.split("=") for kv in spec_.split(","))
        img = render_scene(SCENES / "sphere_light.xml", {"material": str(table)}, spp=16,
                           seed=0, res=16, params=params).mean(axis=2)
        row, col = np.unravel_index(img.argmax(), img.shape)
        assert abs(row - 7.5) <= 1.5 and abs(col - 7.5) <= 1.5, spec_
    # with the light 160 degrees away the highlight is behind the sphere's rim
    with pytest.raises(ValueError, match="160:0:1"):
        mod.closeup_views(["160:0:1"])
