"""Hostile input never crashes, never destroys, always explains.

Every CLI error path: the exit status, exactly one line on stderr, and the
file or option it names; inputs are never overwritten, outputs never left partial;
valid-but-unusual materials work. Small grids and a random orthonormal ensemble keep it
fast; the few renders are marked ``render``.
"""

from __future__ import annotations

import errno
import functools
import hashlib
import os
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from conftest import SMALL, cli_fails, random_orthonormal, run_cli
from sparse_brdf.brdf import BRDF
from sparse_brdf.cli import EXIT_BUG, main
from sparse_brdf.coding.coefficients import SparseBRDF
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.coords import MERL_SHAPE, geometric_valid
from sparse_brdf.errors import (
    BRDFFileError,
    ImageFileError,
    InputFileError,
    OutputError,
    SparseBRDFError,
    one_line,
)
from sparse_brdf.evaluation.images import read_exr, write_exr, write_image
from sparse_brdf.fileio import atomic_write, cleanup_on_signals, output_name, staged
from sparse_brdf.sources.merl import read_merl, write_merl
from sparse_brdf.sources.nbrdf import tabulate_nbrdf

ROOT = Path(__file__).resolve().parents[1]
SPHERE = ROOT / "scenes" / "sphere.xml"
H5 = ROOT / "sparse_brdf" / "data" / "materials" / "blue-fabric.h5"


# ------------------------------------------------------------------------------ helpers


run = run_cli
fails = cli_fails


def digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def leftovers(folder: Path, keep=()) -> list[str]:
    """Files in ``folder`` other than ``keep`` (hidden temporaries included)."""
    return sorted(p.name for p in Path(folder).iterdir() if p.name not in set(keep))


def constant_brdf(rgb, shape=SMALL, name="test") -> BRDF:
    values = np.broadcast_to(np.asarray(rgb, np.float32), (*shape, 3)).copy()
    return BRDF(values, geometric_valid(shape), name=name)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("reliability")


@pytest.fixture(scope="module")
def ens_file(work) -> Path:
    """A random orthonormal ensemble of two dictionaries on the small grid."""
    rng = np.random.default_rng(7)
    u = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    return Ensemble(*u, taus=np.array([16, 16])).save(work / "small.npz")


@pytest.fixture(scope="module")
def merl(work) -> Path:
    return write_merl(work / "m.binary", constant_brdf((0.2, 0.1, 0.05)))


@pytest.fixture(scope="module")
def sbrdf(work, merl, ens_file) -> Path:
    out = work / "m.sbrdf"
    assert main(["encode", str(merl), "-o", str(out), "--coeffs", "20",
                 "--ensemble", str(ens_file)]) == 0
    return out


def with_values(model: SparseBRDF, path: Path, **changes) -> Path:
    """``model`` with some fields changed, saved at ``path``."""
    fields = dict(transform=model.transform, shape=model.shape,
                  ensemble_id=model.ensemble_id, dict_index=model.dict_index,
                  locations=model.locations, values=model.values, name=model.name,
                  basis=model.basis)
    fields.update(changes)
    return save_sbrdf(path, SparseBRDF(**fields))


def odd_grid(model: SparseBRDF, path: Path, **changes) -> Path:
    """``model`` on an 18 x 18 x 18 grid (its coefficients that fit), saved at ``path``."""
    size = 18 * 18 * 18
    keep = [loc < size for loc in model.locations]
    return with_values(model, path, shape=(18, 18, 18),
                       locations=[loc[k] for loc, k in zip(model.locations, keep, strict=True)],
                       values=[v[k] for v, k in zip(model.values, keep, strict=True)],
                       **changes)


# ----------------------------------------------------------- 2. inputs never destroyed


def test_encode_refuses_to_overwrite_its_input(capsys, tmp_path, merl, ens_file):
    src = tmp_path / "c.binary"
    src.write_bytes(merl.read_bytes())
    before = digest(src)
    fails(capsys, "encode", src, "-o", src, "--ensemble", ens_file, names=["c.binary"])
    assert digest(src) == before
    link = tmp_path / "link.binary"
    link.symlink_to(src)
    fails(capsys, "encode", src, "-o", link, "--ensemble", ens_file, names=["link.binary"])
    os.link(src, tmp_path / "hard.binary")
    fails(capsys, "encode", src, "-o", tmp_path / "hard.binary", "--ensemble", ens_file,
          names=["hard.binary"])
    assert digest(src) == before


def test_decode_blend_convert_refuse_their_inputs(capsys, tmp_path, sbrdf, merl, ens_file):
    x = tmp_path / "x.sbrdf"
    x.write_bytes(sbrdf.read_bytes())
    before = digest(x)
    fails(capsys, "decode", x, "-o", x, "--ensemble", ens_file, names=["x.sbrdf"])
    fails(capsys, "blend", x, sbrdf, "--alpha", "0.5", "-o", x, "--ensemble", ens_file,
          names=["x.sbrdf"])
    fails(capsys, "decode", x, "-o", ens_file, "--ensemble", ens_file, names=["small.npz"])
    assert digest(x) == before
    m = tmp_path / "m.binary"
    m.write_bytes(merl.read_bytes())
    fails(capsys, "convert", m, m, names=["m.binary"])


def test_render_refuses_its_scene_materials_and_mask(capsys, tmp_path, merl):
    scene = tmp_path / "s.xml"
    scene.write_text(SPHERE.read_text())
    before = digest(scene)
    fails(capsys, "render", scene, "-o", scene, names=["s.xml"])
    fails(capsys, "render", scene, "-o", merl, "--material", f"material={merl}",
          names=["m.binary"])
    fails(capsys, "render", scene, "-o", tmp_path / "a.exr", "--mask", tmp_path / "a.exr",
          "--material", f"material={merl}", names=["a.exr"])
    assert digest(scene) == before


def test_fit_scene_refuses_a_file_as_folder_and_its_inputs(capsys, tmp_path, sbrdf):
    out = tmp_path / "out"
    out.write_text("not a folder")
    fails(capsys, "fit-scene", SPHERE, "--target-snr", "20", "--material",
          f"material={sbrdf}", "-o", out, names=["out"])
    folder = tmp_path / "fs"
    folder.mkdir()
    inside = folder / "material.sbrdf"
    inside.write_bytes(sbrdf.read_bytes())
    fails(capsys, "fit-scene", SPHERE, "--target-snr", "20", "--material",
          f"material={inside}", "-o", folder, names=["material.sbrdf"])
    fails(capsys, "fit-scene", SPHERE, "--target-snr", "20", "--material",
          f"../x={sbrdf}", "-o", folder, names=["../x"])


# ------------------------------------------------------------- 1. OS errors, one line


def test_output_is_a_folder_or_a_device(capsys, tmp_path, sbrdf, ens_file):
    (tmp_path / "d.binary").mkdir()
    fails(capsys, "decode", sbrdf, "-o", tmp_path / "d.binary", "--ensemble", ens_file,
          names=["d.binary", "folder"])
    os.mkfifo(tmp_path / "p.binary")
    fails(capsys, "decode", sbrdf, "-o", tmp_path / "p.binary", "--ensemble", ens_file,
          names=["p.binary"])
    assert (tmp_path / "p.binary").is_fifo()


def test_unwritable_folder(capsys, tmp_path, sbrdf, ens_file, monkeypatch):
    import sparse_brdf.fileio as fileio

    def refuse(path, suffix, output):  # what creating a file in a read-only folder raises
        raise PermissionError(errno.EACCES, "Permission denied", str(path.parent))

    monkeypatch.setattr(fileio, "_create_temporary", refuse)
    line = fails(capsys, "decode", sbrdf, "-o", tmp_path / "ro" / "x.binary", "--ensemble",
                 ens_file, names=["x.binary", "Permission denied"])
    assert "cannot write" in line


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder(capsys, tmp_path, sbrdf, ens_file):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        fails(capsys, "decode", sbrdf, "-o", ro / "x.binary", "--ensemble", ens_file,
              names=["x.binary"])
    finally:
        ro.chmod(0o755)


def test_disk_full_keeps_the_old_output(capsys, tmp_path, sbrdf, ens_file, monkeypatch):
    out = tmp_path / "x.binary"
    out.write_bytes(b"the previous output")

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    fails(capsys, "decode", sbrdf, "-o", out, "--ensemble", ens_file,
          names=["x.binary", "No space left"])
    assert out.read_bytes() == b"the previous output"
    assert leftovers(tmp_path) == ["x.binary"]


def test_scene_with_a_syntax_error(capsys, tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0"><bsdf')
    fails(capsys, "render", bad, "-o", tmp_path / "x.exr", names=["bad.xml", "XML"])
    fails(capsys, "fit-scene", bad, "--target-snr", "20", "-o", tmp_path / "o",
          names=["bad.xml"])
    bad.write_bytes(b"\xff\xfe<scene/>")
    fails(capsys, "render", bad, "-o", tmp_path / "x.exr", names=["bad.xml"])


def test_sbrdf_whose_grid_disagrees_with_its_ensemble(capsys, tmp_path, sbrdf, ens_file):
    odd = odd_grid(load_sbrdf(sbrdf), tmp_path / "grid.sbrdf")
    fails(capsys, "decode", odd, "-o", tmp_path / "g.binary", "--ensemble", ens_file,
          names=["grid.sbrdf", "grid"])
    assert leftovers(tmp_path) == ["grid.sbrdf"]


def test_malformed_h5_layers(capsys, tmp_path):
    import h5py

    for name, layer, data in [("width.h5", "dense_2", np.zeros((21, 22), np.float32)),
                              ("flat.h5", "dense_2", np.zeros(21, np.float32)),
                              ("text.h5", "dense_1", np.array([b"x"] * 6))]:
        path = tmp_path / name
        path.write_bytes(H5.read_bytes())
        with h5py.File(path, "r+") as f:
            del f[layer][layer]["kernel:0"]
            f[layer][layer]["kernel:0"] = data
        fails(capsys, "info", path, names=[name])
    nan = tmp_path / "nan.h5"
    nan.write_bytes(H5.read_bytes())
    with h5py.File(nan, "r+") as f:
        f["dense_3"]["dense_3"]["bias:0"][0] = np.nan
    fails(capsys, "info", nan, names=["nan.h5", "NaN"])
    big = tmp_path / "big.h5"
    big.write_bytes(H5.read_bytes())
    with h5py.File(big, "r+") as f:
        f["dense_3"]["dense_3"]["bias:0"][:] = 1e4  # exp overflows: the values are inf
    with pytest.raises(BRDFFileError, match="big.h5"):  # on the small grid: faster
        tabulate_nbrdf(big, SMALL)


def test_merl_header_dimensions_that_overflow(capsys, tmp_path):
    for name, dims in [("ovf.binary", (2**31 - 1, 2**31 - 1, 2**31 - 2)),
                       ("neg.binary", (-90, -90, 180)), ("big.binary", (1 << 20, 1 << 10, 2))]:
        (tmp_path / name).write_bytes(struct.pack("<3i", *dims) + bytes(64))
        fails(capsys, "info", tmp_path / name, names=[name])
    huge = tmp_path / "huge.binary"
    header = struct.pack("<3i", 2, 2, 2)
    huge.write_bytes(header + np.full(24, 1e300, "<f8").tobytes())
    fails(capsys, "info", huge, names=["huge.binary"])


def test_bench_config_errors_name_the_file(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    for body in (b"spp = [\n", b"\xff\xfe", b"spp = 0\n", b'models = ["sparse:x"]\n',
                 b"bogus = 1\n"):
        bad.write_bytes(body)
        fails(capsys, "bench", bad, names=["bad.toml"])


def test_bench_on_a_fifo_does_not_hang(capsys, tmp_path):
    fifo = tmp_path / "cfg.toml"
    os.mkfifo(fifo)
    result = {}
    t = threading.Thread(target=lambda: result.update(r=run(capsys, "bench", fifo)),
                         daemon=True)
    t.start()
    t.join(20)
    assert not t.is_alive(), "bench blocked reading a FIFO"
    code, _, err = result["r"]
    assert code == 2 and len(err.splitlines()) == 1 and "cfg.toml" in err


# ------------------------------------------------------------- wrong successes, bounds


@pytest.mark.parametrize("argv, option", [
    (["render", "sphere.xml", "-o", "x.exr", "--spp", "0"], "--spp"),
    (["render", "sphere.xml", "-o", "x.exr", "--res", "-1"], "--res"),
    (["render", "sphere.xml", "-o", "x.exr", "--seed", "-1"], "--seed"),
    (["encode", "x.binary", "-o", "x.sbrdf", "--coeffs", "99999999999"], "--coeffs"),
    (["encode", "x.binary", "-o", "x.sbrdf", "--coeffs", "0"], "--coeffs"),
    (["encode", "x.binary", "-o", "x.sbrdf", "--max-error", "nan"], "--max-error"),
    (["encode", "x.binary", "-o", "x.sbrdf", "--fill-iters", "-1"], "--fill-iters"),
    (["blend", "a.sbrdf", "b.sbrdf", "--alpha", "0.5", "--coeffs", "0", "-o", "c.sbrdf"],
     "--coeffs"),
    (["blend", "a.sbrdf", "b.sbrdf", "--alpha", "0.5", "--coeffs", "-5", "-o", "c.sbrdf"],
     "--coeffs"),
    (["blend", "a.sbrdf", "b.sbrdf", "--alpha", "inf", "-o", "c.sbrdf"], "--alpha"),
    (["fit-scene", "sphere", "--target-snr", "nan"], "--target-snr"),
    (["train", "-o", "e.npz", "--taus", "0"], "--taus"),
    (["train", "--corpus", "mitsuba", "-o", "e.npz", "--grid", "1000", "1000", "1000"],
     "--grid"),
    (["encode"], "required"),
    ([], "required"),
])
def test_bad_options_are_one_line(capsys, tmp_path, monkeypatch, argv, option):
    monkeypatch.chdir(tmp_path)
    fails(capsys, *argv, names=[option])


def test_blend_coeffs_beyond_the_grid(capsys, tmp_path, sbrdf, ens_file):
    """--coeffs is a maximum here too: capped at a channel's entries, with a note."""
    code, out, err = run(capsys, "blend", sbrdf, sbrdf, "--alpha", "0.5", "--coeffs",
                         "20000", "-o", tmp_path / "b.sbrdf", "--ensemble", ens_file)
    assert code == 0 and "wrote" in out, err
    assert err.count("\n") == 1 and "--coeffs 20000" in err and "11664" in err
    code, _, err = run(capsys, "blend", sbrdf, sbrdf, "--alpha", "0.5", "-o",
                       tmp_path / "c.sbrdf", "--ensemble", ens_file)
    assert code == 0 and err == ""


def huge_file(sbrdf: Path, path: Path, value: float, all_of_them: bool = False) -> Path:
    """``sbrdf`` with its first coefficient (or all of channel 0's) set to ``value``,
    written without the model's checks (as a corrupt or hostile file would hold it)."""
    m = load_sbrdf(sbrdf)
    m.values[0] = m.values[0].copy()
    m.values[0][slice(None) if all_of_them else 0] = value
    return save_sbrdf(path, m)


def test_huge_coefficient_is_refused_at_load(capsys, tmp_path, sbrdf, ens_file):
    huge = huge_file(sbrdf, tmp_path / "huge.sbrdf", 3e38)
    fails(capsys, "decode", huge, "-o", tmp_path / "h.binary", "--ensemble", ens_file,
          names=["huge.sbrdf"])
    fails(capsys, "info", huge, names=["huge.sbrdf"])
    assert leftovers(tmp_path) == ["huge.sbrdf"]


# ------------------------------------------------------------ 3. unusual materials work


@pytest.mark.parametrize("rgb", [(0.3, 0.0, 0.0), (0.0, 0.0, 0.0), (1e-30, 2e-30, 0.0),
                                 (1e-6, 1e-6, 1e-6), (1e30, 1.0, 0.5)])
@pytest.mark.parametrize("paper", [False, True])
def test_unusual_materials_encode_and_decode(capsys, tmp_path, ens_file, rgb, paper):
    src = write_merl(tmp_path / "u.binary", constant_brdf(rgb))
    out, dec = tmp_path / "u.sbrdf", tmp_path / "d.binary"
    code, _, err = run(capsys, "encode", src, "-o", out, "--coeffs", "16", "--ensemble",
                       ens_file, *(["--paper"] if paper else []))
    assert code == 0 and err == ""  # no numpy warning leaks
    model = load_sbrdf(out)
    if paper:  # rgb basis: a channel without signal has no coefficient
        for c, value in enumerate(rgb):
            if value == 0:
                assert model.n_coeffs[c] == 0
    code, _, err = run(capsys, "decode", out, "-o", dec, "--ensemble", ens_file)
    assert code == 0 and err == ""
    back = read_merl(dec)
    assert np.all(np.isfinite(back.values))
    for c, value in enumerate(rgb):
        if value == 0:  # exact in the rgb basis; the opponent mix's quantisation (half
            # a step, at most 1/512 of a channel's largest value; measured 1.4e-4 of max)
            assert np.abs(back.values[..., c]).max() <= (0 if paper
                                                         else 2e-3 * max(rgb) + 1e-30)


def test_file_without_coefficients_decodes(capsys, tmp_path, sbrdf, ens_file):
    m = load_sbrdf(sbrdf)
    empty = with_values(m, tmp_path / "zero.sbrdf", locations=[np.zeros(0)] * 3,
                        values=[np.zeros(0)] * 3)
    code, _, err = run(capsys, "decode", empty, "-o", tmp_path / "z.binary", "--ensemble",
                       ens_file)
    assert code == 0, err
    assert np.all(read_merl(tmp_path / "z.binary").values == 0)


# --------------------------------------------------------------------- 4. renders


@pytest.mark.render
def test_render_refuses_nan_pixels_and_corrupt_materials(capsys, tmp_path, sbrdf, ens_file):
    pytest.importorskip("mitsuba")
    common = ["--spp", "1", "--res", "8", "--ensemble", ens_file]
    huge = huge_file(sbrdf, tmp_path / "huge.sbrdf", 3e38)  # refused as it loads
    line = fails(capsys, "render", SPHERE, "-o", tmp_path / "h.exr", "--material",
                 f"material={huge}", *common, names=["huge.sbrdf"])
    assert "File " not in line
    # plausible coefficients whose values overflow: decoded and clamped to float32's
    # largest value, and the render that would hold inf pixels is refused
    big = huge_file(sbrdf, tmp_path / "big.sbrdf", 2e3, all_of_them=True)
    assert run(capsys, "decode", big, "-o", tmp_path / "b.binary", "--ensemble",
               ens_file)[0] == 0
    assert np.isfinite(read_merl(tmp_path / "b.binary").values).all()
    (tmp_path / "b.binary").unlink()
    line = fails(capsys, "render", SPHERE, "-o", tmp_path / "h.exr", "--material",
                 f"material={big}", *common, names=["big.sbrdf"])
    assert "NaN" in line
    corrupt = tmp_path / "corrupt.sbrdf"
    data = bytearray(sbrdf.read_bytes())
    data[60] ^= 0xFF
    corrupt.write_bytes(bytes(data))
    line = fails(capsys, "render", SPHERE, "-o", tmp_path / "c.exr", "--material",
                 f"material={corrupt}", *common, names=["corrupt.sbrdf"])
    assert "File " not in line and "line " not in line  # no Mitsuba traceback inside
    assert leftovers(tmp_path) == ["big.sbrdf", "corrupt.sbrdf", "huge.sbrdf"]


@pytest.mark.render
@pytest.mark.parametrize("decoder", ["strict", "grouped"])
def test_render_a_material_without_coefficients(capsys, tmp_path, sbrdf, ens_file, decoder):
    pytest.importorskip("mitsuba")
    m = load_sbrdf(sbrdf)
    empty = with_values(m, tmp_path / "zero.sbrdf", locations=[np.zeros(0)] * 3,
                        values=[np.zeros(0)] * 3)
    code, _, err = run(capsys, "render", SPHERE, "-o", tmp_path / "z.exr", "--material",
                       f"material={empty}", "--spp", "1", "--res", "8", "--ensemble",
                       ens_file, "--decoder", decoder)
    assert code == 0, err
    assert np.all(np.isfinite(read_exr(tmp_path / "z.exr")))


# ------------------------------------------------------------------------ snr images


def _exr(path: Path, channels: dict) -> Path:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    return path


def test_snr_reads_rgba_and_names_nan_images(capsys, tmp_path):
    rng = np.random.default_rng(1)
    a = rng.random((8, 8, 4)).astype(np.float32)
    rgba = _exr(tmp_path / "rgba.exr", {"RGBA": a})
    rgb = write_exr(tmp_path / "rgb.exr", a[..., :3])
    np.save(tmp_path / "mask.npy", np.ones((8, 8), bool))
    code, out, err = run(capsys, "snr", rgba, rgb, "--mask", tmp_path / "mask.npy")
    assert code == 0 and "inf dB" in out, err
    split = _exr(tmp_path / "split.exr", {c: a[..., i].copy() for i, c in enumerate("RGBA")})
    np.testing.assert_array_equal(read_exr(split), a[..., :3])
    nan = a[..., :3].copy()
    nan[2, 3, 1] = np.nan
    write_exr(tmp_path / "nan.exr", nan)
    fails(capsys, "snr", rgb, tmp_path / "nan.exr", "--mask", tmp_path / "mask.npy",
          names=["nan.exr", "NaN"])
    write_exr(tmp_path / "small.exr", a[:4, :4, :3])
    fails(capsys, "snr", rgb, tmp_path / "small.exr", "--mask", tmp_path / "mask.npy",
          names=["small.exr"])
    np.save(tmp_path / "none.npy", np.zeros((8, 8), bool))
    fails(capsys, "snr", rgb, rgba, "--mask", tmp_path / "none.npy", names=["none.npy"])
    _exr(tmp_path / "y.exr", {"Y": a[..., 0].copy()})
    fails(capsys, "snr", tmp_path / "y.exr", rgb, "--mask", tmp_path / "mask.npy",
          names=["y.exr"])
    with pytest.raises(ImageFileError, match="y.exr"):
        read_exr(tmp_path / "y.exr")


# ------------------------------------------------------------------- messages, names


def test_control_characters_never_reach_the_terminal(capsys, tmp_path, sbrdf, ens_file):
    m = load_sbrdf(sbrdf)
    evil = "evil\x1b[31mRED\x07\nsecond line\u202e"
    odd = odd_grid(m, tmp_path / "odd.sbrdf", name=evil)
    line = fails(capsys, "decode", odd, "-o", tmp_path / "o.binary", "--ensemble", ens_file,
                 names=["odd.sbrdf", "\\x1b", "\\x07", "\\u202e"])
    assert "\x1b" not in line and "\x07" not in line and "\u202e" not in line
    assert one_line("a\r\nb\tc\x9b") == "a | b c\\x9b"


def test_info_escapes_the_stored_name(capsys, tmp_path):
    src = write_merl(tmp_path / "n.binary", constant_brdf((0.1, 0.1, 0.1)))
    # a MERL file's name is its file name: put the control character there
    evil = tmp_path / "a\x1bb.binary"
    evil.write_bytes(src.read_bytes())
    code, out, err = run(capsys, "info", evil)
    assert code == 0 and "\x1b" not in out and "\\x1b" in out


def test_missing_and_non_regular_inputs(capsys, tmp_path, ens_file):
    fails(capsys, "info", tmp_path / "missing.binary", names=["missing.binary"])
    (tmp_path / "dir.binary").mkdir()
    fails(capsys, "info", tmp_path / "dir.binary", names=["dir.binary", "regular"])
    fails(capsys, "decode", tmp_path / "dir.sbrdf", "-o", tmp_path / "x.binary",
          names=["dir.sbrdf"])
    os.mkfifo(tmp_path / "f.sbrdf")
    fails(capsys, "decode", tmp_path / "f.sbrdf", "-o", tmp_path / "x.binary", "--ensemble",
          ens_file, names=["f.sbrdf"])
    fails(capsys, "info", "mitsuba:no-such-thing", names=["mitsuba:no-such-thing"])
    fails(capsys, "corpus", "list", "no-such-corpus", names=["no-such-corpus"])


def test_errors_form_one_hierarchy():
    from sparse_brdf import errors

    classes = [c for c in vars(errors).values() if isinstance(c, type)
               and issubclass(c, Exception) and c.__module__ == errors.__name__]
    assert len(classes) >= 10
    assert all(issubclass(c, SparseBRDFError) for c in classes)
    assert issubclass(OutputError, OSError) and issubclass(InputFileError, OSError)
    assert issubclass(BRDFFileError, ValueError)
    from mitsuba_plugin import PluginError
    from sparse_brdf.errors import RenderError
    from sparse_brdf.mitsuba_env import MitsubaSetupError

    assert {PluginError, RenderError, MitsubaSetupError} <= set(classes)


# -------------------------------------------------------------- bugs are called bugs


def test_an_internal_error_says_it_is_a_bug(capsys, monkeypatch, tmp_path):
    from sparse_brdf.cli import _data  # where `info` looks its reader up

    def broken(*args, **kwargs):
        return np.zeros(3).reshape(2, 2)  # a genuine numpy error, not a user's

    monkeypatch.setattr(_data, "load_brdf", broken)
    code, _, err = run(capsys, "info", tmp_path / "x.binary")
    assert code == EXIT_BUG and len(err.splitlines()) == 1
    assert "internal error" in err and "bug" in err and "--debug" in err
    assert "Traceback" not in err
    code, _, err = run(capsys, "info", tmp_path / "x.binary", "--debug")
    assert code == EXIT_BUG and "Traceback" in err and "reshape" in err
    assert err.splitlines()[-1].startswith("sparse-brdf: internal error")
    monkeypatch.setenv("SPARSE_BRDF_DEBUG", "1")
    code, _, err = run(capsys, "info", tmp_path / "x.binary")
    assert code == EXIT_BUG and "Traceback" in err


def test_debug_shows_the_traceback_of_a_user_error(capsys, tmp_path):
    code, _, err = run(capsys, "--debug", "info", tmp_path / "missing.binary")
    assert code == 2 and "Traceback" in err and "missing.binary" in err.splitlines()[-1]


# ------------------------------------------------------ interrupts leave nothing behind


def test_sigterm_while_writing_leaves_no_temporary(capsys, tmp_path, sbrdf, ens_file,
                                                   monkeypatch):
    from sparse_brdf.cli import _codec  # where `decode` looks its writer up

    def write_then_killed(path, brdf):
        with atomic_write(path) as f:
            f.write(b"x" * 4096)
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # the handler runs at the next bytecode
                f.write(b"y")
        raise AssertionError("not interrupted")

    monkeypatch.setattr(_codec, "write_merl", write_then_killed)
    out = tmp_path / "out"
    out.mkdir()
    code, _, err = run(capsys, "decode", sbrdf, "-o", out / "x.binary", "--ensemble",
                       ens_file)
    assert code == 128 + signal.SIGTERM
    assert len(err.splitlines()) == 1 and "SIGTERM" in err
    assert leftovers(out) == []
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # restored


def test_cleanup_on_signals_restores_handlers(tmp_path):
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), cleanup_on_signals():
        with atomic_write(tmp_path / "a.bin") as f:
            f.write(b"partial")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.5)
    assert leftovers(tmp_path) == []
    assert signal.getsignal(signal.SIGTERM) == before


def test_sigint_during_encode(tmp_path):
    """A real process: Ctrl-C while encoding a full-size material. The child says on
    stdout when it is inside the encoder (the material loaded, the imports done) and
    encodes again and again until the interrupt comes, so the SIGINT always lands in the
    encoding, however fast the machine: exit 128 + SIGINT, one line, nothing left."""
    src = write_merl(tmp_path / "c.binary", constant_brdf((0.3, 0.2, 0.1), MERL_SHAPE))
    out = tmp_path / "out"
    out.mkdir()
    code = (
        "import faulthandler, signal, sys\n"
        "faulthandler.register(signal.SIGUSR1)\n"  # the stacks, should it hang
        # Ctrl-C's handler even where this test runs in the background (a shell starts
        # `cmd &` with SIGINT ignored, and Python then leaves it ignored)
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "import sparse_brdf.cli as cli\n"
        "from sparse_brdf.cli import files\n"  # where encode_file looks the encoder up
        "real = files.encode_with\n"
        "def encode_until_interrupted(*a, **k):\n"
        "    print('encoding', flush=True)\n"
        "    while True:\n"
        "        real(*a, **k)\n"
        "files.encode_with = encode_until_interrupted\n"
        f"sys.exit(cli.main(['encode', {str(src)!r}, '-o', {str(out / 'c.sbrdf')!r}, "
        "'--fill-iters', '2']))\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        ready, _, _ = select.select([p.stdout], [], [], 300)
        said = p.stdout.readline() if ready else ""
        assert said == "encoding\n", (said, p.poll())
        p.send_signal(signal.SIGINT)
        try:
            _, err = p.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGUSR1)
            time.sleep(2)
            p.kill()
            _, err = p.communicate()
            pytest.fail(f"the interrupted encode did not end; its stacks:\n{err}")
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 128 + signal.SIGINT, err
    assert len(err.splitlines()) == 1 and "SIGINT" in err and "Traceback" not in err, err
    assert leftovers(out) == []


# ------------------------------------------------- user situations, not bugs; paths named


def test_bench_whose_pca_would_train_on_its_test_materials(capsys, tmp_path, merl):
    """split = "all" over a folder leaves PCA no material it is not scored on: one line
    naming the config, exit 2, from the check and from a run, and nothing written."""
    folder = tmp_path / "mats"
    folder.mkdir()
    for name in ("a", "b", "c"):
        (folder / f"{name}.binary").write_bytes(merl.read_bytes())
    cfg = tmp_path / "fair.toml"
    cfg.write_text(f'corpora = ["{folder}"]\nsplit = "all"\nmodels = ["naive", "pca:2"]\n'
                   'stability = false\nspeed = false\n')
    for extra in (["--check"], ["--out", tmp_path / "out", "--no-render"]):
        line = fails(capsys, "bench", cfg, *extra, names=["fair.toml", "pca-2", "split"])
        assert "bug" not in line
    assert not (tmp_path / "out").exists()
    cfg.write_text(f'corpora = ["{folder}"]\nsplit = "all"\nmodels = ["naive"]\n')
    # the stability suite's default models hold a PCA model too
    fails(capsys, "bench", cfg, "--check", names=["fair.toml", "pca-40"])
    cfg.write_text(f'corpora = ["{folder}"]\nsplit = "all"\nmodels = ["naive"]\n'
                   'stability_models = ["naive"]\n')
    code, out, _ = run(capsys, "bench", cfg, "--check")
    assert code == 0 and "3 materials x 1 models" in out


def test_render_to_a_full_disk_names_the_output(tmp_path):
    """The EXR writer fails for real (a file-size limit stands for a full disk: the
    write returns EFBIG): one line naming the output, exit 2, nothing left behind."""
    out = tmp_path / "img.exr"
    code = (
        "import functools, resource, signal, sys\n"
        "import numpy as np\n"
        "import sparse_brdf.cli as cli\n"
        "from sparse_brdf.cli import _render\n"  # where `render` looks the renderer up
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "_render.render_scene = functools.wraps(_render.render_scene)(lambda *a, **k: "
        "np.random.default_rng(0).random((64, 64, 3), np.float32))\n"  # ~40 kB, no Mitsuba
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
        f"sys.exit(cli.main(['render', 'sphere.xml', '-o', {str(out)!r}]))\n")
    run_ = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    lines = run_.stderr.splitlines()
    assert run_.returncode == 2, run_.stderr
    assert len(lines) == 1 and f"{out}: cannot write" in lines[0], lines
    assert ".img.exr." not in lines[0] and "File too large" in lines[0], lines
    assert leftovers(tmp_path) == []


def test_exr_writer_errors_are_output_errors(tmp_path, monkeypatch):
    class Full(_FullDiskEXR):
        error = "runtime"

    monkeypatch.setattr(OpenEXR, "File", Full)
    with pytest.raises(OutputError, match="x.exr.*No space left"):
        write_exr(tmp_path / "x.exr", np.zeros((4, 4, 3), np.float32))
    assert leftovers(tmp_path) == []


class _FullDiskEXR:
    """OpenEXR.File whose write fails as on a full disk: ``OSError`` (ENOSPC) or, as
    OpenEXR itself reports it, a RuntimeError naming the file it was given."""

    error = "oserror"

    def __init__(self, *a):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False

    def write(self, name):
        if self.error == "oserror":
            raise OSError(errno.ENOSPC, "No space left on device")
        raise RuntimeError(f'Failed to write pixel data to image file "{name}". No space '
                           'left on device.')


@pytest.mark.parametrize("name, fault", [("s7.exr", "oserror"), ("s7.exr", "runtime"),
                                         ("s7.png", "fsync")])
def test_render_onto_a_full_disk_names_the_output(capsys, tmp_path, monkeypatch, name,
                                                  fault):
    """render stages its outputs and hands the writers staging files: a full disk is one
    line naming the output the user gave (never the hidden staging file), exit 2, the old
    output kept and no staging file left."""
    from sparse_brdf.cli import _render

    monkeypatch.setattr(_render, "render_scene", functools.wraps(_render.render_scene)(
        lambda *a, **k: np.random.default_rng(0).random((16, 16, 3), np.float32)))
    if fault == "fsync":
        def full(fd):
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(os, "fsync", full)
    else:
        monkeypatch.setattr(_FullDiskEXR, "error", fault)
        monkeypatch.setattr(OpenEXR, "File", _FullDiskEXR)
    folder = tmp_path / "full"
    folder.mkdir()
    out = folder / name
    out.write_bytes(b"the previous image")
    line = fails(capsys, "render", SPHERE, "-o", out, names=[out, "No space left"])
    assert line == f"sparse-brdf: error: {out}: cannot write" + (
        " the EXR image" if fault == "runtime" else "") + ": No space left on device"
    assert f".{name}." not in line
    assert out.read_bytes() == b"the previous image"
    assert leftovers(folder) == [name]


def test_encode_onto_a_full_disk_names_the_output(capsys, tmp_path, merl, ens_file,
                                                   monkeypatch):
    """The same for encode (one output written by atomic_write): the message names the
    .sbrdf the user gave, and nothing is left."""
    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    out = tmp_path / "full" / "c.sbrdf"
    line = fails(capsys, "encode", merl, "-o", out, "--coeffs", "20", "--ensemble",
                 ens_file, names=[out, "No space left"])
    assert line == f"sparse-brdf: error: {out}: cannot write: No space left on device"
    assert leftovers(tmp_path / "full") == []


def test_writers_given_a_staging_file_name_the_output(tmp_path):
    """A writer that is itself atomic, given a staging file of staged(), names the
    staged output in its errors: the system's (ENOSPC) and the package's own."""
    out = tmp_path / "a.exr"
    with pytest.raises(ImageFileError) as caught, staged([out]) as tmp:
        assert output_name(tmp[0]) == out and tmp[0] != out
        write_image(tmp[0], np.zeros((4, 4), np.float32))  # not an (H, W, 3) image
    assert str(caught.value).startswith(f"{out}: expected an image")
    with pytest.raises(OutputError) as caught, staged([out]) as tmp:
        with atomic_write(tmp[0]):
            raise OSError(errno.ENOSPC, "No space left on device")
    assert str(caught.value) == f"{out}: cannot write: No space left on device"
    assert leftovers(tmp_path) == []
    assert output_name(out) == out


def test_encode_on_another_grid_names_the_file(capsys, tmp_path, ens_file):
    src = write_merl(tmp_path / "smallgrid.binary",
                     constant_brdf((0.2, 0.1, 0.05), shape=(4, 4, 8), name="smallgrid"))
    line = fails(capsys, "encode", src, "-o", tmp_path / "x.sbrdf", "--ensemble", ens_file,
                 names=[src, "(4, 4, 8)"])
    assert line.split("error: ")[1].startswith(str(src))
    assert leftovers(tmp_path) == ["smallgrid.binary"]


def test_blend_errors_name_the_files(capsys, tmp_path, merl, ens_file):
    a, b = tmp_path / "good.sbrdf", tmp_path / "other.sbrdf"
    for out, t in ((a, "log-plus"), (b, "log-plus-cosine")):
        assert main(["encode", str(merl), "-o", str(out), "--coeffs", "20", "--transform", t,
                     "--ensemble", str(ens_file)]) == 0
    capsys.readouterr()
    fails(capsys, "blend", a, b, "--alpha", "0.5", "-o", tmp_path / "c.sbrdf", "--ensemble",
          ens_file, names=[a, b, "log-plus-cosine"])
    # without --ensemble: A names an ensemble that is not shipped
    line = fails(capsys, "blend", a, b, "--alpha", "0.5", "-o", tmp_path / "c.sbrdf",
                 names=[a, load_sbrdf(a).ensemble_id, "--ensemble"])
    assert "not shipped" in line
    assert not (tmp_path / "c.sbrdf").exists()


def test_encode_caps_coeffs_to_a_small_grid(capsys, tmp_path):
    """The default --coeffs (262) is a maximum: on a 4 x 4 x 8 grid (128 per channel) it
    is capped silently; a number the user gave is capped with a note on stderr."""
    rng = np.random.default_rng(3)
    shape = (4, 4, 8)
    ens = Ensemble(*[np.stack([random_orthonormal(n, rng)]) for n in shape],
                   taus=np.array([8])).save(tmp_path / "tiny.npz")
    src = write_merl(tmp_path / "tiny.binary", constant_brdf((0.3, 0.2, 0.1), shape=shape))
    code, out, err = run(capsys, "encode", src, "-o", tmp_path / "d.sbrdf", "--ensemble", ens)
    assert code == 0 and err == "" and "wrote" in out
    code, out, err = run(capsys, "encode", src, "-o", tmp_path / "g.sbrdf", "--ensemble", ens,
                         "--coeffs", "300")
    assert code == 0 and err.count("\n") == 1 and "--coeffs 300" in err and "128" in err
    at_most = tmp_path / "m.sbrdf"
    assert main(["encode", str(src), "-o", str(at_most), "--ensemble", str(ens),
                 "--coeffs", "128"]) == 0
    assert (tmp_path / "d.sbrdf").read_bytes() == at_most.read_bytes() == \
        (tmp_path / "g.sbrdf").read_bytes()


def test_a_closed_stdout_is_not_an_error():
    """``sparse-brdf corpus list | head``: the reader goes away; no message, status 141."""
    p = subprocess.Popen([sys.executable, "-m", "sparse_brdf.cli", "corpus", "list",
                          "mitsuba"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()
    err = p.stderr.read()
    p.stderr.close()
    assert p.wait(timeout=60) == 128 + signal.SIGPIPE and err == b""


# ------------------------------------------------- hostile input: one line, exit 2, nothing


def _samples_csv(path: Path, rgb) -> Path:
    """A samples CSV of 40 uniform direction pairs, every row the value ``rgb`` except the
    first, which holds ``rgb`` times the first row's factor given by ``rgb`` itself."""
    from sparse_brdf.acquisition.files import write_samples
    from sparse_brdf.acquisition.measurements import Samples
    from sparse_brdf.acquisition.planning import plan

    wi, wo = plan(40, "uniform", 0)
    values = np.broadcast_to(np.asarray(rgb, np.float64), (40, 3)).copy()
    return write_samples(path, Samples(wi, wo, values))


def test_an_unbounded_size_is_a_usage_error_not_a_bug(tmp_path, capsys, monkeypatch):
    fails(capsys, "plan-samples", 10**15, "-o", tmp_path / "p.csv",
          names=["n", "1000000000000000"])
    from sparse_brdf.cli import _samples  # where `plan-samples` looks its writer up

    def too_big(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(_samples, "plan_samples_file", too_big)
    line = fails(capsys, "plan-samples", 4000000, "-o", tmp_path / "p.csv",
                 names=["not enough memory"])
    assert "internal error" not in line
    assert leftovers(tmp_path) == []


def test_absurd_sample_values_never_make_a_file_of_infinities(tmp_path, capsys, ens_file):
    big = _samples_csv(tmp_path / "big.csv", (0.1, 0.1, 0.1))
    text = big.read_text().splitlines()
    row = text[1].split(",")
    row[6] = "1e300"
    big.write_text("\n".join([text[0], ",".join(row), *text[2:]]) + "\n")
    fails(capsys, "encode-samples", big, "-o", tmp_path / "m.sbrdf", "--prior", "none",
          "--ensemble", ens_file, names=["big.csv", "row 1", "out of range"])
    assert leftovers(tmp_path) == ["big.csv"]


def test_zero_samples_are_refused_and_constant_ones_warned_of(tmp_path, capsys, ens_file):
    zero = _samples_csv(tmp_path / "zero.csv", 0.0)
    fails(capsys, "encode-samples", zero, "-o", tmp_path / "z.sbrdf", "--prior", "none",
          "--ensemble", ens_file, names=["zero.csv", "every sample value is 0"])
    grey = _samples_csv(tmp_path / "grey.csv", 0.2)
    code, out, err = run(capsys, "encode-samples", grey, "-o", tmp_path / "g.sbrdf",
                         "--prior", "none", "--ensemble", ens_file, "--coeffs", 4)
    assert code == 0 and "warning" in err and "same value" in err, err
    assert (tmp_path / "g.sbrdf").is_file() and not (tmp_path / "z.sbrdf").exists()


def test_no_command_overwrites_a_file_of_another_kind(tmp_path, capsys, sbrdf, merl):
    target = tmp_path / "keep.sbrdf"
    target.write_bytes(sbrdf.read_bytes())
    before = digest(target)
    for argv in (["plan-samples", 10, "-o", target],
                 ["convert", merl, target],
                 ["decode", sbrdf, "-o", target],
                 ["render", "sphere", "-o", target],
                 ["train", "-o", target]):
        fails(capsys, *argv, names=["keep.sbrdf", "."])
    assert digest(target) == before and leftovers(tmp_path) == ["keep.sbrdf"]


def test_bench_check_refuses_budgets_and_model_lists_that_cannot_run(tmp_path, capsys):
    tiny = tmp_path / "tiny.toml"
    tiny.write_text('corpora = ["mitsuba"]\nmodels = ["sparse:b20"]\nrender = false\n')
    fails(capsys, "bench", tiny, "--check", names=["tiny.toml", "sparse-b20", "20 bytes"])
    empty = tmp_path / "empty.toml"
    empty.write_text('corpora = ["mitsuba"]\nmodels = []\nrender = false\n')
    fails(capsys, "bench", empty, "--check", names=["empty.toml", "no model"])
    fine = tmp_path / "fine.toml"
    fine.write_text('corpora = ["mitsuba"]\nmodels = ["sparse:b400"]\nrender = false\n')
    code, out, err = run(capsys, "bench", fine, "--check")
    assert code == 0 and "ok" in out, err


def test_fit_images_refuses_an_unwritable_output_before_the_fit(tmp_path, capsys, sbrdf,
                                                                 monkeypatch):
    from sparse_brdf.cli import _fit  # where `fit-images` looks its reader up

    def never(*args, **kwargs):
        raise AssertionError("the fit ran before its output was checked")

    monkeypatch.setattr(_fit, "load_views", never)
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    fails(capsys, "fit-images", "sphere", "--view", tmp_path / "ref.exr", "--start", sbrdf,
          "-o", blocker / "fit.sbrdf", names=["fit.sbrdf", "not a folder"])
    assert leftovers(tmp_path) == ["file"]


def test_a_blend_across_ensembles_says_how_to_re_encode(tmp_path, capsys, sbrdf, merl,
                                                        ens_file):
    rng = np.random.default_rng(8)
    u = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    other = Ensemble(*u, taus=np.array([16, 16])).save(tmp_path / "other.npz")
    b = tmp_path / "b.sbrdf"
    assert main(["encode", str(merl), "-o", str(b), "--coeffs", "8",
                 "--ensemble", str(other)]) == 0
    capsys.readouterr()
    fails(capsys, "blend", sbrdf, b, "--alpha", 0.5, "-o", tmp_path / "ab.sbrdf",
          "--ensemble", ens_file, names=["b.sbrdf", "re-encode", "sparse-brdf encode",
                                         "--ensemble"])
    assert not (tmp_path / "ab.sbrdf").exists()


def test_encode_samples_checks_its_output_before_reading_or_fitting(tmp_path, capsys,
                                                                    monkeypatch):
    from sparse_brdf.acquisition import defaults as acquisition

    def never(*args, **kwargs):
        raise AssertionError("the prior was built before the output was checked")

    monkeypatch.setattr(acquisition, "prior_of", never)
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    samples = _samples_csv(tmp_path / "s.csv", 0.1)
    fails(capsys, "encode-samples", samples, "-o", blocker / "x.sbrdf",
          names=["x.sbrdf", "not a folder"])
    fails(capsys, "encode-samples", samples, "-o", tmp_path / "x.binary",
          names=["x.binary", ".sbrdf"])
    assert leftovers(tmp_path) == ["file", "s.csv"]
