"""The command line: help, corpus listing, info, convert, train, encode, decode, errors."""

import json

import numpy as np
import pytest

from sparse_brdf.cli import main
from sparse_brdf.sources.merl import read_merl


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for cmd in ("corpus", "info", "convert", "train", "encode", "decode"):
        assert cmd in out


def test_corpus_list(capsys):
    assert main(["corpus", "list"]) == 0
    assert "mitsuba" in capsys.readouterr().out
    assert main(["corpus", "list", "mitsuba"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) >= 40 and any(" test " in ln for ln in lines)


def test_info_json(capsys):
    assert main(["info", "mitsuba:diffuse-white", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["shape"] == [90, 90, 180]
    assert info["albedo"] == pytest.approx([0.8, 0.8, 0.78], rel=0.03)
    assert info["valid_bins"] < info["total_bins"]


def test_convert_then_read(tmp_path, capsys):
    out = tmp_path / "w.binary"
    assert main(["convert", "mitsuba:diffuse-red", str(out)]) == 0
    b = read_merl(out)
    np.testing.assert_allclose(b.values[b.valid][:, 0], 0.6 / np.pi, rtol=1e-3)
    assert main(["convert", "mitsuba:diffuse-red", str(tmp_path / "w.png")]) != 0


def test_errors_are_one_line_and_name_the_file(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing.binary")]) == 2
    err = capsys.readouterr().err
    assert "missing.binary" in err and "Traceback" not in err
    bad = tmp_path / "bad.binary"
    bad.write_bytes(b"\x5a\0\0\0" * 3 + b"\0" * 100)
    assert main(["info", str(bad)]) == 2
    assert "truncated" in capsys.readouterr().err


def test_encode_in_the_lobe_pair_and_info(tmp_path, capsys):
    """``encode --transform lobe`` writes a file in one of the lobe pair (their floor
    form), 20 bytes of gain, lobe and floor beside the coefficients; ``info`` states the
    lobe and the floor, in text and JSON."""
    from sparse_brdf.coding.fileformat import load_sbrdf
    from sparse_brdf.transforms import LOBE_TRANSFORMS

    sb = tmp_path / "cu.sbrdf"
    assert main(["encode", "mitsuba:cu-ggx-0.12", "-o", str(sb), "--coeffs", "40",
                 "--transform", "lobe"]) == 0
    assert "wrote" in capsys.readouterr().out
    model = load_sbrdf(sb)
    assert model.transform in LOBE_TRANSFORMS and model.lobe[0] > 0
    assert main(["info", str(sb), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["lobe"] == {"alpha": model.lobe[0], "kd": list(model.lobe[1:4]),
                            "ks": list(model.lobe[4:])}
    assert info["floor"] == model.floor
    assert main(["info", str(sb)]) == 0
    out = capsys.readouterr().out
    assert f"base lobe alpha {model.lobe[0]:.4g}" in out
    assert f"floor {model.floor:.4g} L (values below decode as 0)" in out
    # the transform's choices name the pair
    with pytest.raises(SystemExit) as exc:  # argparse's usage error
        main(["encode", "mitsuba:cu-ggx-0.12", "-o", str(tmp_path / "x.sbrdf"),
              "--transform", "lobes"])
    assert exc.value.code == 2 and "'lobe', " in capsys.readouterr().err


def test_info_on_a_sbrdf_shows_what_the_file_holds(tmp_path, capsys):
    """``info FILE.sbrdf``: the file's version, ensemble, transform, colour basis,
    coefficients per channel and in all, bytes and dictionaries, beside the decoded
    statistics; ``--json`` has the same keys."""
    from sparse_brdf.coding.fileformat import file_size, load_sbrdf, save_sbrdf
    from sparse_brdf.paths import DEFAULT_ENSEMBLE_ID

    sb = tmp_path / "cu.sbrdf"
    assert main(["encode", "mitsuba:cu-ggx-0.12", "-o", str(sb), "--coeffs", "40"]) == 0
    capsys.readouterr()
    model = load_sbrdf(sb)
    assert main(["info", str(sb), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["version"], info["bytes"]) == (2, sb.stat().st_size)
    assert info["codec"] in ("stored", "deflate", "lzma")
    assert info["ensemble"] == model.ensemble_id == DEFAULT_ENSEMBLE_ID
    assert info["ensemble_shipped"] is True
    assert info["transform"] == model.transform and info["grid"] == [90, 90, 180]
    assert info["basis"] == "opponent" and info["channels"][0] == "luminance"
    assert info["coefficients"] == model.n_coeffs.tolist()
    assert info["coefficients_total"] == sum(info["coefficients"]) > 0
    assert info["dictionaries"] == model.dict_index.tolist()
    assert info["valid_bins"] < info["total_bins"] and len(info["albedo"]) == 3  # decoded
    # the text names the same keys, with the same values
    assert main(["info", str(sb)]) == 0
    lines = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines()}
    assert lines["version"].split()[1] == "2" and info["codec"] in lines["version"]
    assert lines["bytes"].split()[1] == str(info["bytes"])
    assert info["ensemble"] in lines["ensemble"] and "shipped" in lines["ensemble"]
    assert info["transform"] in lines["transform"] and "opponent" in lines["basis"]
    assert lines["coefficients"].split()[1] == str(info["coefficients_total"])
    assert all(f"{ch} {n}" in lines["coefficients"]
               for ch, n in zip(info["channels"], info["coefficients"], strict=True))
    assert all(f"{ch} {d}" in lines["dictionaries"]
               for ch, d in zip(info["channels"], info["dictionaries"], strict=True))
    assert "valid" in lines and "R" in lines
    # a version-1 file: no payload codec, 8 bytes per coefficient
    old = save_sbrdf(tmp_path / "v1.sbrdf", model, version=1)
    assert main(["info", str(old), "--json"]) == 0
    v1 = json.loads(capsys.readouterr().out)
    assert (v1["version"], v1["codec"]) == (1, None)
    assert v1["bytes"] == old.stat().st_size == file_size(
        info["coefficients_total"], len(model.name.encode()), model.transform)
    assert v1["coefficients"] == info["coefficients"]
    # a material that is not a file of coefficients has none of these keys
    assert main(["info", "mitsuba:cu-ggx-0.12", "--json"]) == 0
    assert "version" not in json.loads(capsys.readouterr().out)


@pytest.mark.train
def test_train_encode_decode_round_trip(tmp_path, capsys):
    ens = tmp_path / "e.npz"
    assert main(["train", "--corpus", "mitsuba", "--grid", "18", "18", "36", "--taus", "16",
                 "--dicts", "2", "--iterations", "2", "-o", str(ens),
                 "--checkpoint-dir", str(tmp_path / "ck")]) == 0
    assert (tmp_path / "ck" / "tau-16.npz").is_file()
    src = tmp_path / "src.binary"
    from sparse_brdf.sources.load import load_brdf
    from sparse_brdf.sources.merl import write_merl

    write_merl(src, load_brdf("mitsuba:cu-ggx-0.35", shape=(18, 18, 36)))
    sb = tmp_path / "m.sbrdf"
    capsys.readouterr()
    assert main(["encode", str(src), "-o", str(sb), "--coeffs", "30", "--ensemble", str(ens),
                 "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    # the default encoder: one budget of 3 x 30 over the opponent channels
    assert sum(info["coefficients"]) == 90 and info["bytes"] == sb.stat().st_size
    assert info["options"]["basis"] == "opponent"
    paper = tmp_path / "p.sbrdf"
    assert main(["encode", str(src), "-o", str(paper), "--coeffs", "30", "--ensemble",
                 str(ens), "--paper", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["coefficients"] == [30, 30, 30] and info["options"]["basis"] == "rgb"
    out = tmp_path / "d.binary"
    assert main(["decode", str(sb), "-o", str(out), "--ensemble", str(ens)]) == 0
    assert read_merl(out).shape == (18, 18, 36)


@pytest.mark.render
def test_render_and_snr(tmp_path, capsys):
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    common = ["--material", "material=mitsuba:plastic-red-ggx-0.3", "--spp", "4", "--res", "24"]
    assert main(["render", "sphere.xml", "-o", str(a), *common]) == 0
    assert main(["render", "sphere.xml", "-o", str(b), "--seed", "3", *common]) == 0
    mask = tmp_path / "mask.exr"
    assert main(["render", "sphere.xml", "-o", str(a), "--mask", str(mask), *common]) == 0
    capsys.readouterr()
    assert main(["snr", str(a), str(a), "--json", "--scene", "sphere"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["snr_whole_db"] == out["snr_object_db"] == float("inf")
    assert out["flip_object"] == 0.0
    assert 0 < out["object_pixels"] < out["pixels"] == 24 * 24
    assert main(["snr", str(a), str(b), "--mask", str(mask), "--json"]) == 0
    by_mask = json.loads(capsys.readouterr().out)
    assert main(["snr", str(a), str(b), "--scene", "sphere.xml", "--json"]) == 0
    by_scene = json.loads(capsys.readouterr().out)
    assert by_mask == by_scene  # the written mask is the scene's
    # different seeds: finite, noise-limited; the background adds signal and no error
    assert 0 < by_scene["snr_object_db"] <= by_scene["snr_whole_db"] < 60
    assert 0 < by_scene["flip_object"] < 0.5  # noise only
    assert main(["snr", str(a), str(b), "--scene", "sphere"]) == 0
    line = capsys.readouterr().out
    assert "whole-image" in line and "object-only" in line and "HDR-FLIP" in line
    # no way to tell the object's pixels: the whole-image form, and why the other is missing
    assert main(["snr", str(a), str(b)]) == 0
    line = capsys.readouterr().out
    assert f"whole-image {by_scene['snr_whole_db']:.2f} dB" in line
    assert "object-only not computed" in line and "--scene" in line and "--mask" in line
    assert main(["snr", str(a), str(b), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["snr_whole_db"] == by_scene["snr_whole_db"] and out["snr_object_db"] is None
    assert out["flip_object"] is None and 0 < out["flip_whole"] < 0.5
    assert "--mask" in out["object_missing"]
    assert main(["render", "sphere.xml", "-o", str(a), "--material",
                 f"material={tmp_path / 'missing.sbrdf'}"]) == 2
    assert "missing.sbrdf" in capsys.readouterr().err


@pytest.mark.parametrize("env", [None, "1"])
def test_commands_leave_huge_pages_to_the_user(monkeypatch, env):
    """The command line turns off numpy's madvised huge pages (first touches of fresh
    memory stalled on compaction: docs/benchmarks.md), unless NUMPY_MADVISE_HUGEPAGE is
    set, which is numpy's own switch and wins."""
    setter = np._core.multiarray._set_madvise_hugepage
    if env is None:
        monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    else:
        monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", env)
    before = setter(True)
    try:
        with pytest.raises(SystemExit):
            main(["--help"])
        assert setter(True) is (env is not None)  # the flag main() left
    finally:
        setter(before)


def test_commands_tune_malloc_unless_the_user_does():
    """The command line keeps freed arrays in the heap (glibc mallopt: docs/benchmarks.md),
    each setting skipped where its MALLOC_* variable is set, all of them where
    GLIBC_TUNABLES tunes malloc; glibc accepts every one."""
    import ctypes
    import sys

    from sparse_brdf.cli import MALLOC_SETTINGS
    from sparse_brdf.cli._process import malloc_settings

    every = [(p, v) for p, v, _ in MALLOC_SETTINGS]
    assert malloc_settings({}) == every
    assert malloc_settings({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}) == []
    assert malloc_settings({"GLIBC_TUNABLES": "glibc.pthread.rseq=0"}) == every
    var = MALLOC_SETTINGS[0][2]
    assert malloc_settings({var: "1"}) == every[1:]
    if sys.platform.startswith("linux"):
        mallopt = ctypes.CDLL(None).mallopt
        assert all(mallopt(ctypes.c_int(p), ctypes.c_int(v)) == 1 for p, v in every)


def test_every_option_has_help_and_says_its_default(capsys):
    """Each option of each command explains itself and its default (required ones have
    none, flags are off); examples use built-in materials and shipped scenes only."""
    import argparse

    from sparse_brdf.cli import EPILOG, build_parser, parsers

    missing = []
    for p in parsers(build_parser()):
        fmt = p._get_formatter()
        for a in p._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            text = fmt._get_help_string(a) if a.help else ""
            flag = a.default is False
            if not text or (a.option_strings and not a.required and not flag
                            and not any(w in text for w in ("(default", "default:",
                                                            "default per"))):
                missing.append(f"{p.prog} {'/'.join(a.option_strings) or a.dest}")
    assert missing == []
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    out = capsys.readouterr().out
    assert "(default: 64)" in out and "(default: 0)" in out and "(default: auto)" in out
    assert "(default: lobe)" in out
    with pytest.raises(SystemExit):
        main(["encode", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "3 x N coefficients shared over the three coded channels" in out
    assert "../shared" not in EPILOG and "mitsuba:" in EPILOG


def test_a_copy_keeps_its_own_name(tmp_path, capsys):
    """The cache is keyed by content, but a byte-identical copy is reported and encoded
    under its own name and path."""
    import shutil

    from sparse_brdf.paths import DEMO_MATERIALS_DIR

    first = tmp_path / "blue-fabric.h5"
    copy = tmp_path / "copy.h5"
    shutil.copy(DEMO_MATERIALS_DIR / "blue-fabric.h5", first)
    shutil.copy(first, copy)
    for path, name in ((first, "blue-fabric"), (copy, "copy")):
        assert main(["info", str(path), "--json"]) == 0
        info = json.loads(capsys.readouterr().out)
        assert (info["name"], info["source"]) == (name, str(path))
    from sparse_brdf.coding.fileformat import load_sbrdf

    out = tmp_path / "copy.sbrdf"
    assert main(["encode", str(copy), "-o", str(out), "--coeffs", "8"]) == 0
    assert load_sbrdf(out).name == "copy"


def test_snr_refuses_a_tone_mapped_preview(tmp_path, capsys):
    """A .png preview is not the linear image the SNR and HDR-FLIP compare: one line
    naming the file and the .exr to give instead, exit 2."""
    png = tmp_path / "look.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n")
    assert main(["snr", str(png), str(png)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "look.png" in err and ".exr" in err


def test_snr_refusals_name_the_file(tmp_path, capsys):
    """Images snr cannot score get one line naming the file as given: an all-black
    reference, an image with negative values, a mask that selects no pixel. A black
    image against a lit reference is no error: it scores 0 dB."""
    from conftest import cli_fails
    from sparse_brdf.evaluation.images import write_exr, write_mask

    lit = np.random.default_rng(0).random((8, 8, 3), np.float32) + 0.1
    ref, black, negative = tmp_path / "ref.exr", tmp_path / "black.exr", tmp_path / "neg.exr"
    write_exr(ref, lit)
    write_exr(black, np.zeros((8, 8, 3), np.float32))
    write_exr(negative, lit - 1.0)
    empty = write_mask(tmp_path / "empty.npy", np.zeros((8, 8), bool))
    line = cli_fails(capsys, "snr", black, ref, names=[black, "black"])
    assert line.split("error: ")[1].startswith(f"{black}: ")
    for argv, named in (([ref, negative], negative), ([negative, ref], negative),
                        ([ref, ref, "--mask", empty], empty)):
        line = cli_fails(capsys, "snr", *argv, names=[named])
        assert line.split("error: ")[1].startswith(f"{named}: "), line
    assert main(["snr", str(ref), str(black), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["snr_whole_db"] == pytest.approx(0.0)
