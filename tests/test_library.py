"""The ``sparse_library`` BSDF: many sparse materials in one BSDF, each shape picking its
material by an attribute (mitsuba_plugin.library, sparse_brdf.decoders.library)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import LOBE, SMALL, random_orthonormal
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.decoders.library import (
    HEADER_F,
    HEADER_U,
    PairLookup,
    material_pairs,
    pair_buffers,
    pair_counts,
    pair_header,
)
from sparse_brdf.decoders.lookups import model_x
from sparse_brdf.decoders.scene import ensemble_rows
from sparse_brdf.errors import PluginError
from sparse_brdf.metrics import render_snr
from sparse_brdf.mitsuba_env import set_variant
from sparse_brdf.transforms import has_floor, has_lobe, per_material

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")
from test_many_materials import PER_MATERIAL_BYTES, random_models  # noqa: E402
from test_variants import CPU_VARIANTS  # noqa: E402

import mitsuba_plugin  # noqa: E402

pytestmark = pytest.mark.numerics

N_MATERIALS = 50


def _ensemble(seed: int = 3) -> Ensemble:
    rng = np.random.default_rng(seed)
    return Ensemble(*(np.stack([random_orthonormal(n, rng) for _ in range(3)])
                      for n in SMALL), taus=np.zeros(3))


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """50 distinct materials on the small grid over one random ensemble: both colour
    bases and every kind of transform weight (plain, cosine; scale 1 and 300, the level
    transforms' own gains, the lobe transforms' lobes, the floor transforms' floors)."""
    folder = tmp_path_factory.mktemp("library")
    ens = _ensemble()
    models = random_models(ens, N_MATERIALS, 60)
    kinds = [("log-relative", "rgb"), ("log-relative-cosine", "opponent"),
             ("log-plus", "opponent"), ("log-plus-cosine", "rgb"),
             ("log-level", "rgb"), ("log-level-cosine", "opponent"),
             ("log-lobe", "opponent"), ("log-lobe-cosine", "rgb"),
             ("log-lobe-floor", "rgb"), ("log-lobe-floor-cosine", "opponent")]
    k = len(kinds)
    models = [SparseBRDF(kinds[i % k][0], m.shape, m.ensemble_id, m.dict_index,
                         m.locations, m.values, name=m.name, basis=kinds[i % k][1],
                         gain=0.25 * (1 + i % 5) if per_material(kinds[i % k][0]) else 1.0,
                         lobe=(LOBE[0] * (1 + i % 3), *LOBE[1:]) if has_lobe(kinds[i % k][0])
                         else None, floor=0.5 if has_floor(kinds[i % k][0]) else 0.0)
              for i, m in enumerate(models)]
    files = [str(save_sbrdf(folder / f"m{i}.sbrdf", m)) for i, m in enumerate(models)]
    return {"ensemble": str(ens.save(folder / "ens.npz")), "ens": ens, "files": files,
            "folder": folder}


def scene(bsdfs, index=None, res: int = 32, spp: int = 8) -> dict:
    """Spheres in rows of 8 under a directional light and a constant sky, sphere i
    holding ``bsdfs[i]`` (or the one library ``bsdfs[0]`` with ``sbrdf_index`` =
    ``index[i]``)."""
    d = {"type": "scene", "integrator": {"type": "direct"},
         "sensor": {"type": "perspective", "fov": 45, "to_world":
                    mi.ScalarTransform4f().look_at(origin=[0, 0, 9], target=[0, 0, 0],
                                                   up=[0, 1, 0]),
                    "sampler": {"type": "independent", "sample_count": spp},
                    "film": {"type": "hdrfilm", "width": res, "height": res}},
         "light": {"type": "directional", "direction": [0.2, -0.3, -1.0], "irradiance": 2.0},
         "env": {"type": "constant", "radiance": 0.3}}
    n = len(bsdfs) if index is None else len(index)
    for i in range(n):
        r, c = divmod(i, 8)
        d[f"s{i}"] = {"type": "sphere", "center": [c - 3.5, r - 3.0, 0.0], "radius": 0.45,
                      "bsdf": bsdfs[i] if index is None else bsdfs[0]}
        if index is not None:
            d[f"s{i}"]["sbrdf_index"] = {"type": "uniform", "value": float(index[i])}
    return d


def render(d: dict, spp: int = 8) -> np.ndarray:
    return np.array(mi.render(mi.load_dict(d), spp=spp, seed=1), np.float64)


def _library(lib, files=None, **opts) -> dict:
    return {"type": "sparse_library", "filenames": ",".join(files or lib["files"]),
            "ensemble": lib["ensemble"], **opts}


@pytest.fixture
def llvm():
    set_variant("llvm_ad_rgb")
    mitsuba_plugin.register()


def test01_pair_lookup_decodes_every_material(library):
    """The pair decoder's numpy twin gives each material's transformed R, G, B at every
    bin, as the strict decoder does."""
    ens = library["ens"]
    models = [load_sbrdf(f, ens) for f in library["files"][:8]]
    rows = ensemble_rows(ens)
    pairs = [material_pairs(m, ens, rows) for m in models]
    header = pair_header(models, rows)
    assert header.n_pairs == sum(p.packed.size for p in pairs)
    tables, packed = pair_buffers(models, ens, rows, header.n_pairs)
    look = PairLookup(tables, packed, header, rows.rows, SMALL)
    bins = tuple(a.ravel() for a in np.indices(SMALL))
    for i, model in enumerate(models):
        np.testing.assert_allclose(look.eval(i, bins), model_x(model, ens, bins, "strict"),
                                   atol=3e-5)
        assert look.point(i, 3, 4, 5) == pytest.approx(look.eval(i, ([3], [4], [5]))[:, 0])


@pytest.mark.render
@pytest.mark.parametrize("opts", [
    {"sampling": "cosine"}, {"sampling": "lobe"}, {"sampling": "cosine", "interpolate": True},
    {"sampling": "cosine", "memory_budget": 1.5},
    {"sampling": "lobe", "interpolate": True, "memory_budget": 1.5}])
def test02_library_renders_what_each_material_renders(library, llvm, opts):
    """50 materials at 32 x 32: one library renders what 50 ``sparse_brdf`` render (the
    same sample paths: each material's own lobe), to >= 100 dB, in any order of the
    shapes' indices."""
    files = library["files"]
    per_opts = {k: v for k, v in opts.items() if k != "memory_budget"}
    per = [mi.load_dict({"type": "sparse_brdf", "filename": f, "decoder": "strict",
                         "ensemble": library["ensemble"], **per_opts}) for f in files]
    ref = render(scene(per))
    lib = mi.load_dict(_library(library, **opts))
    assert lib.n_materials == N_MATERIALS
    if "memory_budget" in opts:  # some materials on the grouped decoder, the others pairs
        assert 0 < lib.n_grouped < N_MATERIALS
        assert lib.memory_bytes <= opts["memory_budget"] * 2**20
    img = render(scene([lib], index=range(N_MATERIALS)))
    assert ref.mean() > 1e-3 and render_snr(ref, img) >= 100.0
    # read by shape id once the scene is checked (no virtual call over the shapes)
    checked = mi.load_dict(scene([lib], index=range(N_MATERIALS)))
    assert mitsuba_plugin.check_scene(checked) == N_MATERIALS and lib._ids is not None
    img_ids = np.array(mi.render(checked, spp=8, seed=1), np.float64)
    assert render_snr(ref, img_ids) >= 100.0
    order = np.random.default_rng(0).permutation(N_MATERIALS)
    lib2 = mi.load_dict(_library(library, files=[files[i] for i in order], **opts))
    img2 = render(scene([lib2], index=np.argsort(order)))
    assert render_snr(ref, img2) >= 100.0


def test03_memory_per_material_on_the_merl_grid(llvm, tmp_path):
    """50 materials of 262 coefficients per channel over the shipped ensemble, their
    terms on 40 (b, c) pairs of atoms per channel (encoded materials have 80-120 pairs
    in all): the library holds under 100 kB a material, 4 (n1 + 1) bytes a pair (the
    atom rows are the ensemble's, shared)."""
    ens = Ensemble.default()
    models = random_models(ens, N_MATERIALS, 262, atoms=(60, 8, 5), seed=5)
    files = [str(save_sbrdf(tmp_path / f"m{i}.sbrdf", m)) for i, m in enumerate(models)]
    lib = mi.load_dict({"type": "sparse_library", "filenames": ",".join(files),
                        "sampling": "cosine"})
    pairs = sum(sum(pair_counts(m)) for m in models)
    assert lib.memory_bytes == 4 * 91 * pairs + 4 * (HEADER_U + HEADER_F) * N_MATERIALS
    assert lib.memory_bytes <= N_MATERIALS * PER_MATERIAL_BYTES
    assert lib.shared_bytes == ensemble_rows(ens).nbytes


@pytest.mark.render
@pytest.mark.parametrize("variant", CPU_VARIANTS)
def test04_every_variant(library, variant):
    """In each CPU variant a library of 4 materials (one on the grouped decoder, three
    on pairs) renders what they render alone."""
    set_variant(variant)
    mitsuba_plugin.register()
    files = library["files"][:4]
    res, spp = (8, 2) if variant.startswith("scalar") else (16, 4)
    per = [{"type": "sparse_brdf", "filename": f, "decoder": "strict",
            "ensemble": library["ensemble"], "sampling": "lobe"} for f in files]
    ref = render(scene(per, res=res, spp=spp), spp)
    lib = _library(library, files=files, sampling="lobe", memory_budget=0.1)
    assert mi.load_dict(lib).n_grouped == 1
    img = render(scene([lib], index=[0, 1, 2, 3], res=res, spp=spp), spp)
    assert np.isfinite(img).all() and ref.mean() > 1e-4
    assert render_snr(ref, img) >= 100.0, variant


def test05_errors_name_the_file_or_property(library, llvm, tmp_path):
    files = library["files"]

    def load(**opts):
        return mi.load_dict({"type": "sparse_library", "ensemble": library["ensemble"],
                             **opts})

    with pytest.raises(Exception, match="'filenames' names no file"):
        load(filenames=" , ")
    with pytest.raises(Exception, match="missing.sbrdf"):
        load(filenames=f"{files[0]},{tmp_path / 'missing.sbrdf'}")
    with pytest.raises(Exception, match="sampling="):
        load(filenames=files[0], sampling="mirror")
    # a file of another ensemble (the shipped one's id)
    other = random_models(Ensemble.default(), 1, 20, seed=2)[0]
    path = save_sbrdf(tmp_path / "other.sbrdf", other)
    with pytest.raises(Exception, match="m0.sbrdf' was encoded with ensemble"):
        mi.load_dict({"type": "sparse_library", "filenames": f"{path},{files[0]}"})


@pytest.mark.render
def test06_shapes_must_name_a_material(library, llvm):
    lib = mi.load_dict(_library(library, files=library["files"][:3], sampling="cosine"))
    ok = mi.load_dict(scene([lib], index=[0, 2, 1]))
    assert mitsuba_plugin.check_scene(ok) == 3
    for bad, what in (([0, 3, 1], "s1.*sbrdf_index=3.*0 to 2"),
                      ([0, 1.5, 1], "s1.*sbrdf_index=1.5")):
        with pytest.raises(PluginError, match=what):
            mitsuba_plugin.check_scene(mi.load_dict(scene([lib], index=bad)))
    d = scene([lib], index=[0, 1])
    del d["s1"]["sbrdf_index"]
    with pytest.raises(PluginError, match="s1.*no attribute"):
        mitsuba_plugin.check_scene(mi.load_dict(d))
    # out of range in a render: that shape is black, the others unchanged
    img = render(scene([lib], index=[0, 7, 1]), 4)
    assert np.isfinite(img).all()


def _scene_xml(folder, files, ensemble, wrap_first: bool = False) -> str:
    """A scene file of ``len(files)`` spheres, sphere i with its own ``sparse_brdf`` of
    ``files[i]`` (the first, if ``wrap_first``, a ``<ref>`` inside a ``twosided``)."""
    shapes = []
    for i, f in enumerate(files):
        r, c = divmod(i, 8)
        bsdf = (f'<bsdf type="sparse_brdf"><string name="filename" value="{f}"/>'
                f'<string name="ensemble" value="{ensemble}"/>'
                f'<string name="sampling" value="cosine"/></bsdf>')
        if wrap_first and i == 0:
            bsdf = '<bsdf type="twosided"><ref id="first"/></bsdf>'
        shapes.append(f'<shape type="sphere" id="s{i}"><point name="center" x="{c - 3.5}" '
                      f'y="{r - 3.0}" z="0"/><float name="radius" value="0.45"/>{bsdf}'
                      f'</shape>')
    first = (f'<bsdf type="sparse_brdf" id="first"><string name="filename" '
             f'value="{files[0]}"/><string name="ensemble" value="{ensemble}"/></bsdf>'
             if wrap_first else "")
    path = folder / f"scene-{len(files)}-{int(wrap_first)}.xml"
    path.write_text(
        '<scene version="3.0.0"><integrator type="direct"/>'
        '<sensor type="perspective"><float name="fov" value="45"/>'
        '<transform name="to_world"><lookat origin="0, 0, 9" target="0, 0, 0" up="0, 1, 0"/>'
        '</transform><sampler type="independent"><integer name="sample_count" value="8"/>'
        '</sampler><film type="hdrfilm"><integer name="width" value="32"/>'
        '<integer name="height" value="32"/></film></sensor>'
        '<emitter type="directional"><vector name="direction" x="0.2" y="-0.3" z="-1"/>'
        '<rgb name="irradiance" value="2"/></emitter>'
        f'<emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>{first}'
        + "".join(shapes) + "</scene>")
    return str(path)


@pytest.mark.render
def test07_render_scene_serves_many_materials_from_a_library(library, monkeypatch):
    """``render_scene`` writes a scene's 50 own ``sparse_brdf`` materials as one library
    (the same image, >= 100 dB); a material inside a wrapper keeps its own BSDF."""
    import xml.etree.ElementTree as ET

    from mitsuba_plugin.loading import library_key
    from sparse_brdf.evaluation import libraries
    from sparse_brdf.evaluation.libraries import to_libraries
    from sparse_brdf.evaluation.render import load_scene, render_scene

    files, ens = library["files"], library["ensemble"]
    path = _scene_xml(library["folder"], files, ens)
    assert {type(s.bsdf()).__name__ for s in load_scene(path).shapes()} == {"SparseBSDF"}
    monkeypatch.setattr(libraries, "LIBRARY_MIN_MATERIALS", 40)
    scene = load_scene(path)
    assert {type(s.bsdf()).__name__ for s in scene.shapes()} == {"SparseLibrary"}
    assert scene.shapes()[0].bsdf().n_grouped == 0
    budgeted = load_scene(path, memory_budget=1.5)  # the render's budget: the library's
    assert 0 < budgeted.shapes()[0].bsdf().n_grouped < len(files)
    img = render_scene(path, spp=8, seed=1)
    ref = render_scene(path, spp=8, seed=1, libraries=False)
    assert ref.mean() > 1e-3 and render_snr(ref, img) >= 100.0
    wrapped = ET.parse(_scene_xml(library["folder"], files, ens, wrap_first=True)).getroot()
    lines = to_libraries(wrapped, library["folder"], library_key, min_materials=40)
    assert len(lines) == 1 and "49 materials on 49 shapes" in lines[0]
    assert sorted(el.get("id") for el in wrapped if el.tag == "bsdf") == [
        "__sparse_library_0", "first"]
    few = ET.parse(_scene_xml(library["folder"], files[:10], ens)).getroot()
    assert to_libraries(few, library["folder"], library_key) == []


@pytest.mark.render
def test08_meshes_sharing_a_library_stay_apart(library, tmp_path, monkeypatch):
    """Mitsuba merges meshes that share a BSDF (and drops their attributes) unless the
    scene loads with optimize=False, as ``render_scene`` does once it writes a library:
    two cubes keep their own materials."""
    from sparse_brdf.evaluation import libraries
    from sparse_brdf.evaluation.render import render_scene

    files, ens = library["files"][:2], library["ensemble"]

    def cube(x, f):
        return (f'<shape type="cube"><transform name="to_world"><scale value="0.4"/>'
                f'<rotate y="1" angle="30"/><translate x="{x}"/></transform>'
                f'<bsdf type="sparse_brdf"><string name="filename" value="{f}"/>'
                f'<string name="ensemble" value="{ens}"/></bsdf></shape>')

    path = tmp_path / "cubes.xml"
    path.write_text(
        '<scene version="3.0.0"><integrator type="direct"/>'
        '<sensor type="perspective"><float name="fov" value="40"/><transform name="to_world">'
        '<lookat origin="0, 1, 5" target="0, 0, 0" up="0, 1, 0"/></transform>'
        '<film type="hdrfilm"><integer name="width" value="32"/>'
        '<integer name="height" value="16"/></film></sensor>'
        '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>'
        f'{cube(-0.6, files[0])}{cube(0.6, files[1])}</scene>')
    ref = render_scene(path, spp=4, seed=1, libraries=False)
    monkeypatch.setattr(libraries, "LIBRARY_MIN_MATERIALS", 2)
    img = render_scene(path, spp=4, seed=1)
    assert ref.mean() > 1e-3 and render_snr(ref, img) >= 100.0
    # loaded as written (optimize=True), the two cubes become one mesh without attribute
    lib = (f'<bsdf type="sparse_library" id="lib"><string name="filenames" '
           f'value="{",".join(files)}"/><string name="ensemble" value="{ens}"/></bsdf>')
    shapes = "".join(
        f'<shape type="cube"><transform name="to_world"><translate x="{x}"/></transform>'
        f'<ref id="lib"/><texture name="sbrdf_index" type="uniform">'
        f'<float name="value" value="{i}"/></texture></shape>'
        for i, x in enumerate((-1.5, 1.5)))
    xml = f'<scene version="3.0.0">{lib}{shapes}</scene>'
    with pytest.raises(PluginError, match="optimize=False"):
        mitsuba_plugin.check_scene(mi.load_string(xml))
    assert mitsuba_plugin.check_scene(mi.load_string(xml, optimize=False)) == 2


@pytest.mark.render
def test09_instances_keep_reading_the_attribute(library, llvm):
    """Shapes inside an ``instance`` are not among the scene's shapes: a scene with one
    keeps reading the attribute (no table of shape ids), and renders the same."""
    files = library["files"][:2]
    lib = mi.load_dict(_library(library, files=files, sampling="cosine"))
    per = [mi.load_dict({"type": "sparse_brdf", "filename": f, "decoder": "strict",
                         "ensemble": library["ensemble"], "sampling": "cosine"})
           for f in files]

    def with_instance(d, inner, index=None):
        d["group"] = {"type": "shapegroup", "inner": {
            "type": "sphere", "center": [0.0, 2.5, 0.0], "radius": 0.45, "bsdf": inner}}
        if index is not None:
            d["group"]["inner"]["sbrdf_index"] = {"type": "uniform", "value": index}
        d["inst"] = {"type": "instance", "shape": {"type": "ref", "id": "group"}}
        return d

    ref = render(with_instance(scene(per), per[1]), 4)
    d = with_instance(scene([lib], index=[0, 1]), lib, 1.0)
    checked = mi.load_dict(d)
    assert mitsuba_plugin.check_scene(checked) == 2 and lib._ids is None
    img = np.array(mi.render(checked, spp=4, seed=1), np.float64)
    assert render_snr(ref, img) >= 100.0
