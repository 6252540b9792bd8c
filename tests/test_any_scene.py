"""Any Mitsuba 3 scene, any output name: the command line on a scene written as Mitsuba's
own examples are (``tests/data/still_life.xml``: no ``$``-parameters, a 96 x 64 film, a
ground plane, two shapes sharing the material ``paint``), and outputs that follow their
names (image previews, refused suffixes, nothing partial)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import cli_fails, run_cli
from sparse_brdf.cli import main
from sparse_brdf.coding.fileformat import load_sbrdf
from sparse_brdf.errors import MissingDataError, UsageError
from sparse_brdf.evaluation.images import preview, read_exr, read_mask
from sparse_brdf.evaluation.render import film_size, load_scene, object_mask, render_scene
from sparse_brdf.evaluation.scenes import check_scene_data, scene_xml
from sparse_brdf.mitsuba_env import CPU_VARIANTS

SCENE = Path(__file__).resolve().parent / "data" / "still_life.xml"
PAINT = "mitsuba:plastic-red-ggx-0.3"


run = run_cli
fails = cli_fails


@pytest.mark.render
def test_render_scene_keeps_the_film_and_sets_what_the_scene_does_not_declare():
    img = render_scene(SCENE, {"paint": PAINT}, spp=2, seed=0)
    assert img.shape == (64, 96, 3) and np.isfinite(img).all() and img.mean() > 0
    assert film_size(SCENE) == (96, 64) and film_size(SCENE, 48) == (48, 32)
    small = render_scene(SCENE, {"paint": PAINT}, spp=2, res=48)
    assert small.shape == (32, 48, 3)  # the longer side, the aspect ratio kept
    assert render_scene(SCENE, None, spp=1, res=(30, 10)).shape == (10, 30, 3)
    # the seed and spp reach the sampler: the same seed repeats, another one differs
    again = render_scene(SCENE, {"paint": PAINT}, spp=2, seed=0)
    other = render_scene(SCENE, {"paint": PAINT}, spp=2, seed=5)
    assert np.array_equal(img, again) and not np.array_equal(img, other)
    more = render_scene(SCENE, {"paint": PAINT}, spp=16, seed=0)
    assert np.abs(more - img).mean() > 0
    # a scene that declares $res still takes it as the square side
    assert render_scene("sphere", None, spp=1, res=12).shape == (12, 12, 3)
    assert render_scene("sphere", None, spp=1, res=(20, 10)).shape == (10, 20, 3)
    with pytest.raises(ValueError, match="envrot"):
        render_scene(SCENE, None, spp=1, params={"envrot": 90})


def test_object_is_the_shapes_of_the_replaced_materials():
    every = object_mask(SCENE)
    paint = object_mask(SCENE, materials=["paint"])
    floor = object_mask(SCENE, materials=["floor"])
    assert paint.shape == (64, 96)
    # the ground plane covers most of the image: it is geometry, not the object
    assert every.mean() > 0.7 and 0.1 < paint.mean() < 0.4
    # edge pixels see both (any of their subsamples counts); no interior pixel does
    assert (paint & floor).sum() < 0.3 * paint.sum() and np.all(paint <= every)
    # both shapes carry the material: a blob left (cube) and one right (sphere)
    cols = np.flatnonzero(paint.any(0))
    assert cols.min() < 48 < cols.max() and not paint[:, 46:50].any()
    with pytest.raises(KeyError, match="nothere"):
        object_mask(SCENE, materials=["nothere"])


def _scene_with_ids(tmp_path: Path) -> Path:
    """still_life.xml with ids on a shape, an emitter, the sensor and a texture."""
    text = SCENE.read_text()
    for old, new in (('<shape type="sphere">', '<shape type="sphere" id="shape-ball">'),
                     ('<emitter type="constant">',
                      '<emitter type="constant" id="emitter-envmap">'),
                     ('<sensor type="perspective">', '<sensor type="perspective" id="cam">'),
                     ('<bsdf type="diffuse" id="floor">',
                      '<texture type="checkerboard" id="tex-check"/>\n'
                      '    <bsdf type="diffuse" id="floor">')):
        assert old in text
        text = text.replace(old, new)
    scene = tmp_path / "ids.xml"
    scene.write_text(text)
    return scene


def test_material_ids_must_name_bsdfs(tmp_path, capsys):
    """``--material ID=FILE`` with the id of a shape, an emitter, a sensor or a texture,
    an unknown id, or one id twice: one line naming the option and the id, before any
    work (no output), in render, snr --scene and render_scene alike."""
    scene = _scene_with_ids(tmp_path)
    out = tmp_path / "x.exr"
    for mid, kind in (("shape-ball", "a shape"), ("emitter-envmap", "an emitter"),
                      ("cam", "a sensor"), ("tex-check", "a texture")):
        line = fails(capsys, "render", scene, "-o", out, "--material", f"{mid}={PAINT}",
                     names=[f"--material {mid}: that id is {kind}, not a BSDF"])
        assert "floor, paint" in line  # the ids it could have meant
        fails(capsys, "snr", out, out, "--scene", scene, "--material", mid,
              names=[f"--material {mid}: that id is {kind}, not a BSDF"])
        with pytest.raises(UsageError, match=f"{mid}.*{kind}, not a BSDF"):
            render_scene(scene, {mid: PAINT}, spp=1)
        with pytest.raises(UsageError, match=f"{mid}.*{kind}, not a BSDF"):
            object_mask(scene, materials=[mid])
    fails(capsys, "render", scene, "-o", out, "--material", f"nothere={PAINT}",
          names=["--material nothere", "no element", "floor, paint"])
    fails(capsys, "render", scene, "-o", out, "--material", f"paint={PAINT}",
          "--material", "paint=other.sbrdf", names=["--material paint", "given twice",
                                                    PAINT, "other.sbrdf"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ids.xml"]


def test_scene_mistakes_are_one_line_naming_the_file(tmp_path, capsys, monkeypatch):
    """A parameter the scene does not use, a copied scene without its data file, and a
    folder given as the scene: one line each, naming what is wrong."""
    text = SCENE.read_text()
    out = tmp_path / "x.exr"
    # declared as a <default> but never used as $width: Mitsuba would refuse the value
    declared = tmp_path / "declared.xml"
    declared.write_text(text.replace('<scene version="3.0.0">', '<scene version="3.0.0">\n'
                                     '    <default name="width" value="96"/>'))
    fails(capsys, "render", declared, "-o", out, "-D", "width=200", "-D", "envrot=1",
          names=["-D width, envrot: not a parameter of declared.xml", "$width",
                 "its parameters: none"])
    with pytest.raises(UsageError, match=r"declared.xml: width is not a parameter"):
        render_scene(declared, None, spp=1, params={"width": 200})
    # used as $width: the value reaches the film
    used = tmp_path / "used.xml"
    used.write_text(text.replace('name="width" value="96"', 'name="width" value="$width"')
                    .replace('<scene version="3.0.0">', '<scene version="3.0.0">\n'
                             '    <default name="width" value="96"/>'))
    sensor = load_scene(used, None, spp=1, params={"width": 20}).sensors()[0]
    assert [int(v) for v in sensor.film().size()] == [20, 64]
    # used as $width without a <default>: the value must be given
    undeclared = tmp_path / "undeclared.xml"
    undeclared.write_text(text.replace('name="width" value="96"', 'name="width" '
                                       'value="$width"'))
    with pytest.raises(UsageError, match=r"uses \$width but declares no <default>"):
        load_scene(undeclared, None, spp=1)
    # a copied scene whose environment map stayed behind: the map and the scene, no advice
    # about the paper's map
    copy = tmp_path / "copy.xml"
    copy.write_text(text.replace('<emitter type="constant">\n        <rgb name="radiance" '
                                 'value="0.2"/>', '<emitter type="envmap">\n        '
                                 '<string name="filename" value="envmaps/sky.exr"/>'))
    line = fails(capsys, "render", copy, "-o", out, names=["envmaps/sky.exr", str(copy)])
    assert "Grace" not in line and "SPARSE_BRDF_DATA" not in line
    # ... but the paper's scene without its map says where the shared data goes
    monkeypatch.setattr("sparse_brdf.evaluation.scenes.shared_envmaps_dir", lambda: None)
    paper = tmp_path / "paper_sphere.xml"
    paper.write_text((Path(__file__).resolve().parents[1] / "scenes" / "paper_sphere.xml")
                     .read_text())
    fails(capsys, "render", paper, "-o", out, names=["grace_latlong.exr", "Grace",
                                                    "SPARSE_BRDF_DATA"])
    # a file of a BSDF being replaced is not needed
    textured = tmp_path / "textured.xml"
    textured.write_text(text.replace(
        '<rgb name="diffuse_reflectance" value="0.6, 0.2, 0.1"/>',
        '<texture type="bitmap" name="diffuse_reflectance">\n'
        '            <string name="filename" value="paint.png"/>\n        </texture>'))
    with pytest.raises(MissingDataError, match="textured.xml: refers to paint.png"):
        check_scene_data(textured)
    check_scene_data(textured, replaced=["paint"])
    # a folder is a folder, not a missing scene; its scene files are named
    line = fails(capsys, "render", tmp_path, "-o", out, names=[str(tmp_path), "a folder",
                                                                 "copy.xml"])
    assert "no such" not in line
    assert not out.exists()


@pytest.mark.render
def test_a_twosided_bsdf_stays_twosided(tmp_path):
    """Replacing the id of a ``twosided`` wrapper (as Mitsuba's two-sided Cornell box
    names its walls) keeps the wrapper: the quad, seen from behind, is lit."""
    import xml.etree.ElementTree as ET

    scene = SCENE.parent / "back_face.xml"
    root = ET.fromstring(scene_xml(scene, {"red": PAINT}))
    outer = next(e for e in root.iter("bsdf") if e.get("id") == "red")
    assert outer.get("type") == "twosided"
    assert [(e.get("type"), e.get("id")) for e in outer] == [("tabulated_brdf", None)]
    original = render_scene(scene, None, spp=4)
    img = render_scene(scene, {"red": PAINT}, spp=4)
    assert img.shape == (16, 16, 3) and original.mean() > 0.02
    assert img.mean() > 0.02 and (img.sum(-1) > 0).all()  # every pixel sees the back face
    assert img[..., 0].mean() > 2 * img[..., 2].mean()  # and it is the red plastic


@pytest.mark.render
def test_render_snr_and_masks_on_any_scene(tmp_path, capsys):
    a, b, mask = tmp_path / "a.exr", tmp_path / "b.exr", tmp_path / "m.exr"
    common = ["--material", f"paint={PAINT}", "--spp", 2, "--sampling", "cosine"]
    code, out, err = run(capsys, "render", SCENE, "-o", a, "--mask", mask, *common)
    assert code == 0, err
    assert read_exr(a).shape == (64, 96, 3) and "96x64" in out
    assert np.array_equal(read_mask(mask), object_mask(SCENE, materials=["paint"]))
    assert run(capsys, "render", SCENE, "-o", b, "--seed", 1, *common)[0] == 0
    code, out, err = run(capsys, "snr", a, b, "--scene", SCENE, "--material", "paint",
                         "--json")
    assert code == 0, err
    by_scene = json.loads(out)
    code, out, _ = run(capsys, "snr", a, b, "--mask", mask, "--json")
    assert code == 0 and json.loads(out) == by_scene  # the written mask is the scene's
    assert by_scene["object_pixels"] == int(read_mask(mask).sum()) < 0.4 * 96 * 64
    assert np.isfinite(by_scene["snr_object_db"]) and np.isfinite(by_scene["snr_whole_db"])
    # a scene without the shipped scenes' `material` needs to be told the object
    fails(capsys, "snr", a, b, "--scene", SCENE, names=["--material", "paint"])
    # without a mask: the whole-image form, and why the object-only one is missing
    code, out, _ = run(capsys, "snr", a, b)
    assert code == 0 and f"whole-image {by_scene['snr_whole_db']:.2f} dB" in out
    assert "object-only not computed" in out
    # the resolution option keeps the aspect ratio; an undeclared -D is refused
    code, out, err = run(capsys, "render", SCENE, "-o", a, "--res", 48, *common)
    assert code == 0 and read_exr(a).shape == (32, 48, 3), err
    fails(capsys, "render", SCENE, "-o", tmp_path / "x.exr", "-D", "envrot=9",
          names=["envrot", "not a parameter"])


@pytest.mark.render
def test_fit_scene_and_fit_images_on_any_scene(tmp_path, capsys):
    out = tmp_path / "fs"
    code, text, err = run(capsys, "fit-scene", SCENE, "--material", f"paint={PAINT}",
                          "--target-snr", 12, "--spp", 2, "--res", 32, "-o", out)
    assert code == 0, err
    rep = json.loads((out / "fit-scene.json").read_text())
    assert rep["size"] == [32, 21] and (out / "paint.sbrdf").is_file()
    assert "32x21" in (out / "fit-scene.md").read_text()
    ref = tmp_path / "ref.exr"
    assert run(capsys, "render", SCENE, "-o", ref, "--material", f"paint={PAINT}", "--spp", 2,
               "--res", 32, "--sampling", "cosine")[0] == 0
    fitted = tmp_path / "fit.sbrdf"
    code, text, err = run(capsys, "fit-images", SCENE, "--view", ref, "--start",
                          out / "paint.sbrdf", "--material", "paint", "-o", fitted,
                          "--iterations", 2, "--spp", 2)
    assert code == 0, err
    start = load_sbrdf(out / "paint.sbrdf")
    assert load_sbrdf(fitted).n_coeffs.tolist() == start.n_coeffs.tolist()  # support kept


@pytest.mark.render
def test_outputs_follow_their_names(tmp_path, capsys):
    png, jpg = tmp_path / "a.png", tmp_path / "a.jpg"
    common = ["--material", f"paint={PAINT}", "--spp", 2]
    assert run(capsys, "render", SCENE, "-o", png, *common)[0] == 0
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size == (96, 64) and im.mode == "RGB"
        dark = np.asarray(im)
    assert run(capsys, "render", SCENE, "-o", jpg, "--exposure", 2, *common)[0] == 0
    with Image.open(jpg) as im:
        assert im.format == "JPEG" and np.asarray(im).mean() > dark.mean() + 20
    exr = tmp_path / "a.exr"
    assert run(capsys, "render", SCENE, "-o", exr, "--exposure", 2, *common)[0] == 0
    img = read_exr(exr)  # linear HDR, as rendered: the exposure is the preview's alone
    assert np.array_equal(preview(img), dark) and img.max() > 1.0
    assert np.array_equal(preview(np.array([[[0.0, 1.0, 0.5]]])), [[[0, 255, 188]]])
    # a suffix that is not what the command writes: one line, before any work
    before = sorted(p.name for p in tmp_path.iterdir())
    fails(capsys, "render", SCENE, "-o", tmp_path / "x.sbrdf", names=["x.sbrdf", ".exr"])
    fails(capsys, "render", SCENE, "-o", exr, "--material", f"paint={PAINT}", "--mask",
          tmp_path / "m.png", names=["m.png", ".npy"])
    fails(capsys, "encode", PAINT, "-o", tmp_path / "x.binary", names=["x.binary", ".sbrdf"])
    fails(capsys, "decode", tmp_path / "in.sbrdf", "-o", tmp_path / "x.sbrdf",
          names=["x.sbrdf", ".binary"])
    fails(capsys, "plan-samples", 10, "-o", tmp_path / "x.sbrdf", names=[".csv"])
    fails(capsys, "train", "-o", tmp_path / "x.sbrdf", names=[".npz"])
    # -o DIR/ names a folder: refused, saying the file name it wants
    err = fails(capsys, "decode", tmp_path / "in.sbrdf", "-o", f"{tmp_path}/out/",
                names=["folder", "NAME.binary"])
    assert "out" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_no_partial_output_when_one_output_fails(tmp_path, capsys):
    """``render -o x.exr --mask BAD/m.exr``: refused before the render, and x.exr is not
    written (also an existing x.exr is left as it was)."""
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    out = tmp_path / "x.exr"
    fails(capsys, "render", SCENE, "-o", out, "--material", f"paint={PAINT}", "--mask",
          blocker / "m.exr", names=["m.exr", "not a folder"])
    assert not out.exists()
    out.write_bytes(b"old")
    fails(capsys, "render", SCENE, "-o", out, "--material", f"paint={PAINT}", "--mask",
          blocker / "m.exr")
    assert out.read_bytes() == b"old"
    # --mask needs the object: the shapes of a replaced material
    fails(capsys, "render", SCENE, "-o", out, "--mask", tmp_path / "m.exr",
          names=["--material"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "x.exr"]


def test_staged_outputs_are_written_together(tmp_path):
    from sparse_brdf.fileio import staged

    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    with pytest.raises(RuntimeError), staged([a, b]) as (ta, tb):
        ta.write_text("a")
        raise RuntimeError("the second output failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    with staged([a, b]) as (ta, tb):
        ta.write_text("a")
        tb.write_text("b")
    assert a.read_text() == "a" and b.read_text() == "b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]


@pytest.mark.render
def test_readme_own_scene_example_runs(tmp_path, monkeypatch):
    """The README's block that swaps a material into an existing scene and wraps the
    plugin in twosided for open meshes runs as printed (from the checkout's root)."""
    import re

    import mitsuba as mi

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, re.S)
    code = next(b for b in blocks if "twosided" in b and "render_scene" in b)
    assert len(code.strip().splitlines()) <= 14  # about ten lines
    assert main(["encode", PAINT, "-o", str(tmp_path / "gold.sbrdf"), "--coeffs", "16"]) == 0
    monkeypatch.chdir(tmp_path)
    env: dict = {}
    exec(compile(code.replace("tests/data/still_life.xml", str(SCENE)), "README.md",
                 "exec"), env)
    with Image.open(tmp_path / "still_life.png") as im:
        assert im.size == (96, 64)
    assert env["img"].shape == (64, 96, 3)
    flags = env["leaf"].bsdf().flags()
    assert mi.has_flag(flags, mi.BSDFFlags.BackSide) and mi.has_flag(flags,
                                                                     mi.BSDFFlags.FrontSide)


INCLUDE = SCENE.parent / "include" / "main.xml"


@pytest.mark.render
def test_included_files_are_read_as_mitsuba_reads_them(tmp_path, capsys):
    """``tests/data/include/main.xml`` takes its shapes, BSDFs and the parameters res and
    max_depth from included files (an include inside an include, relative to its own
    file): the ids, ``$``-parameters and data files found there are the scene's, and the
    scene rendered with nothing replaced is Mitsuba's own render of the file."""
    import mitsuba as mi

    from sparse_brdf.mitsuba_env import set_variant

    out = tmp_path / "x.exr"
    code, text, err = run(capsys, "render", INCLUDE, "-o", out, "--material",
                          f"paint={PAINT}", "--res", 8, "--spp", 1, "-D", "max_depth=2")
    assert code == 0, err
    assert read_exr(out).shape == (8, 8, 3) and "8x8" in text  # $res of parts/shapes.xml
    # the scene as it is: exactly what Mitsuba renders from the file itself
    set_variant("llvm_ad_rgb")
    theirs = mi.render(mi.load_file(str(INCLUDE), res=8, max_depth=2, spp=2), spp=2)
    theirs = np.array(theirs, dtype=np.float32)
    ours = render_scene(INCLUDE, None, spp=2, res=8, params={"max_depth": 2})
    assert np.array_equal(ours, theirs) and ours.mean() > 0.01
    # -D max_depth reaches the integrator that an included default sets: one bounce
    # less is darker where the wall lights the ball
    deeper = render_scene(INCLUDE, None, spp=2, res=8, params={"max_depth": 3})
    assert deeper.sum() > ours.sum()
    # the replaced BSDF is the included one: the ball turns from diffuse to plastic
    swapped = render_scene(INCLUDE, {"paint": PAINT}, spp=2, res=8,
                           params={"max_depth": 2})
    assert not np.array_equal(swapped, ours)
    ball = object_mask(INCLUDE, res=8, materials=["paint"])
    change = np.abs(swapped - ours).sum(-1)
    assert 0 < ball.sum() < 64 and change[ball].mean() > 3 * change[~ball].mean()
    # the ids of every file are listed; a parameter of none is refused naming them
    fails(capsys, "render", INCLUDE, "-o", out, "--material", f"nothere={PAINT}",
          names=["--material nothere", "paint, wall"])
    fails(capsys, "render", INCLUDE, "-o", out, "-D", "width=3",
          names=["-D width", "max_depth, res, spp"])


def test_include_mistakes_are_one_line_naming_the_including_file(tmp_path, capsys):
    """A missing included file, an included file that is not XML, and includes in a
    cycle: one line naming the including file, before any work."""
    out = tmp_path / "x.exr"
    main_xml = tmp_path / "main.xml"
    main_xml.write_text('<scene version="3.0.0"><include filename="parts/a.xml"/></scene>')
    fails(capsys, "render", main_xml, "-o", out, names=[str(main_xml), "parts/a.xml",
                                                        "not there"])
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "a.xml").write_text('<scene><include filename="b.xml"/></scene>')
    (tmp_path / "parts" / "b.xml").write_text("<scene><bsdf")
    fails(capsys, "render", main_xml, "-o", out, names=["b.xml", "not a valid scene XML"])
    (tmp_path / "parts" / "b.xml").write_text('<scene><include filename="a.xml"/></scene>')
    fails(capsys, "render", main_xml, "-o", out, names=["b.xml", "a.xml", "cycle"])
    assert not out.exists()


TWO_BOXES = SCENE.parent / "two_boxes.xml"


@pytest.mark.render
def test_one_bsdf_on_many_meshes_is_the_object(tmp_path, capsys):
    """``tests/data/two_boxes.xml``: two cubes share the BSDF ``box`` and carry no ids, so
    Mitsuba merges them into one mesh; the object is still both boxes, in ``object_mask``,
    ``render --mask`` and ``snr --scene --material box``."""
    mask = object_mask(TWO_BOXES, materials=["box"])
    assert mask.shape == (16, 16) and 20 < mask.sum() < 0.4 * mask.size
    cols = np.flatnonzero(mask.any(0))  # a box left of the centre and one right of it
    assert cols.min() < 8 and cols.max() >= 8 and mask[:, :8].any() and mask[:, 8:].any()
    # one ray per pixel: every hit is a box or a wall, never both
    boxes, walls = (object_mask(TWO_BOXES, materials=m, subsamples=1)
                    for m in (["box"], ["white", "red"]))
    assert boxes.any() and not (boxes & walls).any()
    assert np.array_equal(boxes | walls, object_mask(TWO_BOXES, subsamples=1))
    a, b, m = tmp_path / "a.exr", tmp_path / "b.exr", tmp_path / "m.exr"
    common = ["--material", f"box={PAINT}", "--spp", 2, "--sampling", "cosine"]
    code, out, err = run(capsys, "render", TWO_BOXES, "-o", a, "--mask", m, *common)
    assert code == 0, err
    assert np.array_equal(read_mask(m), mask) and f"{int(mask.sum())} of 256" in out
    assert run(capsys, "render", TWO_BOXES, "-o", b, "--seed", 1, *common)[0] == 0
    code, out, err = run(capsys, "snr", a, b, "--scene", TWO_BOXES, "--material", "box",
                         "--json")
    assert code == 0, err
    assert json.loads(out)["object_pixels"] == int(mask.sum())
    # one box's BSDF a wrapper without an id around the shared one: still both boxes
    text = TWO_BOXES.read_text()
    last = text.rindex('<ref id="box"/>')
    wrapped = tmp_path / "wrapped.xml"
    wrapped.write_text(text[:last] + '<bsdf type="twosided"><ref id="box"/></bsdf>'
                       + text[last + len('<ref id="box"/>'):])
    assert np.array_equal(object_mask(wrapped, materials=["box"]), mask)
    # a wrapper with the id (as the two-sided Cornell box's walls): its shapes
    assert object_mask(SCENE.parent / "back_face.xml", materials=["red"]).all()


@pytest.mark.render
@pytest.mark.parametrize("variant", CPU_VARIANTS)
def test_every_cpu_variant_renders_from_the_command_line_and_python(variant, tmp_path,
                                                                     capsys):
    """``render --variant V`` and ``render_scene(variant=V)``: a spectral variant's image
    is RGB (Mitsuba's film converts it), a mono variant's one channel (Y in an EXR, a
    greyscale PNG)."""
    import OpenEXR

    scene = SCENE.parent / "back_face.xml"
    mono = "mono" in variant
    img = render_scene(scene, {"red": PAINT}, spp=1, res=8, variant=variant)
    assert img.shape == (8, 8, 1 if mono else 3) and np.isfinite(img).all()
    assert img.mean() > 0.01 and (mono or img[..., 0].mean() > 2 * img[..., 2].mean())
    exr, png = tmp_path / "a.exr", tmp_path / "a.png"
    for out in (exr, png):
        code, text, err = run(capsys, "render", scene, "-o", out, "--variant", variant,
                              "--material", f"red={PAINT}", "--res", 8, "--spp", 1)
        assert code == 0 and variant in text, err
    with OpenEXR.File(str(exr)) as f:
        assert sorted(f.channels()) == (["Y"] if mono else ["RGB"])
        written = np.asarray(f.channels()["Y" if mono else "RGB"].pixels)
    # the same render (scalar polarized ones vary in the last bit from run to run)
    np.testing.assert_allclose(written, img[..., 0] if mono else img, rtol=1e-5, atol=1e-7)
    with Image.open(png) as im:
        assert im.mode == ("L" if mono else "RGB") and im.size == (8, 8)


def test_an_unknown_variant_is_refused(tmp_path, capsys):
    fails(capsys, "render", SCENE, "-o", tmp_path / "a.exr", "--variant", "scalar_mono",
          names=["--variant", "scalar_mono"])
    with pytest.raises(UsageError, match="variant.*rgb_ad_llvm"):
        render_scene(SCENE, None, spp=1, variant="rgb_ad_llvm")
    assert list(tmp_path.iterdir()) == []


def _scene_with_the_plugin(folder: Path, name: str = "scene.xml") -> Path:
    """still_life.xml in ``folder`` with its paint a ``sparse_brdf`` BSDF reading
    gold.sbrdf beside it (written once per folder)."""
    if not (folder / "gold.sbrdf").exists():
        assert main(["encode", PAINT, "-o", str(folder / "gold.sbrdf"), "--coeffs", "16"]) == 0
    old = '<bsdf type="roughplastic" id="paint">'
    text = SCENE.read_text()
    assert old in text
    scene = folder / name
    scene.write_text(text.replace(old, '<bsdf type="sparse_brdf" id="paint">\n'
                                  '        <string name="filename" value="gold.sbrdf"/>\n'
                                  '    </bsdf>\n    <bsdf type="roughplastic" id="unused">'))
    return scene


@pytest.mark.render
def test_render_takes_mitsubas_command_line(tmp_path, capsys, monkeypatch):
    """``sparse-brdf render`` in place of ``mitsuba``: the scenes first, several in one
    call, each written beside its scene or into the ``-o`` folder as SCENE.exr; ``-D
    spp=N`` as Mitsuba takes it; ``-m VARIANT``; a scene whose BSDF is ``sparse_brdf``,
    which Mitsuba's own command cannot load."""
    import shutil
    import subprocess
    import sys

    a = _scene_with_the_plugin(tmp_path, "a.xml")
    (tmp_path / "sub").mkdir()
    b = _scene_with_the_plugin(tmp_path / "sub", "b.xml")
    mitsuba = shutil.which("mitsuba", path=str(Path(sys.executable).parent))
    if mitsuba:  # Mitsuba's own command knows no sparse_brdf
        done = subprocess.run([mitsuba, str(a)], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path)
        said = done.stdout + done.stderr
        assert done.returncode != 0 and "sparse_brdf" in said and "not found" in said
    code, out, err = run(capsys, "render", a, b, "-D", "spp=1", "--res", 24, "-m",
                         "scalar_rgb")
    assert code == 0, err
    for image in (tmp_path / "a.exr", tmp_path / "sub" / "b.exr"):
        assert read_exr(image).shape == (16, 24, 3) and f"wrote {image}" in out
    assert "1 spp" in out and "scalar_rgb" in out
    code, out, err = run(capsys, "render", a, b, "-o", f"{tmp_path}/out/", "--spp", 1,
                         "--res", 24)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.exr", "b.exr"]
    # the image is the scene's as the plugin renders it (-D spp=1 is --spp 1)
    one = render_scene(a, None, spp=1, res=24)
    assert np.array_equal(read_exr(tmp_path / "out" / "a.exr"), one) and one.mean() > 0
    # a shipped scene given by name is written to the current folder
    monkeypatch.chdir(tmp_path / "out")
    assert run(capsys, "render", "sphere", "--spp", 1, "--res", 8)[0] == 0
    assert (tmp_path / "out" / "sphere.exr").is_file()
    # mistakes: one line, before any work
    before = sorted(p.name for p in tmp_path.rglob("*"))
    fails(capsys, "render", a, b, "-o", tmp_path / "one.exr",
          names=["-o", "one.exr", "2 scenes", "folder"])
    fails(capsys, "render", a, "-D", "spp=2", "--spp", 3, names=["-D spp=2", "--spp 3"])
    fails(capsys, "render", a, "-D", "spp=0", names=["-D spp"])
    fails(capsys, "render", a, a, "-o", f"{tmp_path}/out2/", names=["a.exr", "two scenes"])
    fails(capsys, "render", a, b, "--material", f"paint={PAINT}", "--mask",
          tmp_path / "m.exr", names=["--mask", "2 scenes"])
    fails(capsys, "render", a, SCENE.parent / "back_face.xml", "--material",
          f"paint={PAINT}", names=["--material paint", "back_face.xml"])
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


@pytest.mark.render
def test_rendering_guide_own_scene_commands_run(tmp_path, capsys, monkeypatch):
    """Every command of docs/rendering.md's "Your own scene" runs as printed (the scenes
    of ``tests/data/`` from the checkout's root, the outputs in a temporary folder) and
    writes what it says: an image per ``-o``, a mask that selects both boxes, one channel
    in a mono variant."""
    import re
    import shlex

    import OpenEXR

    root = Path(__file__).resolve().parents[1]
    guide = (root / "docs" / "rendering.md").read_text()
    section = guide.split("\n## Your own scene\n", 1)[1].split("\n## ", 1)[0]
    commands = [ln for block in re.findall(r"```sh\n(.*?)```", section, re.S)
                for ln in block.splitlines() if ln.strip()]
    assert len(commands) == 5 and all(c.startswith("sparse-brdf render ") for c in commands)
    monkeypatch.chdir(tmp_path)
    for command in commands:
        argv = [a.replace("tests/data/", f"{root}/tests/data/") for a in shlex.split(command)]
        code, _, err = run(capsys, *argv[1:])
        assert code == 0, (command, err)
        assert (tmp_path / argv[argv.index("-o") + 1]).is_file(), command
    boxes = read_mask(tmp_path / "boxes-mask.exr")
    assert boxes[:, :8].any() and boxes[:, 8:].any()
    with OpenEXR.File(str(tmp_path / "mono.exr")) as f:
        assert list(f.channels()) == ["Y"]
    assert read_exr(tmp_path / "back.exr").mean() > 0.02
