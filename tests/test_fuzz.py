"""Property-based fuzzing (hypothesis): the readers get random truncations, byte flips and
header mutations, and the command line random bad arguments; only the documented error
types come out, and the command line answers with status 0 or 2 and at most one line.

Bounded: a fixed number of examples each, no deadline, no example database (nothing is
written into the checkout). The ``.sbrdf`` reader is fuzzed with its format's own tests.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import SMALL, run_cli
from sparse_brdf.benchmark.bench_config import BenchConfig
from sparse_brdf.brdf import BRDF
from sparse_brdf.cli import main
from sparse_brdf.coords import geometric_valid
from sparse_brdf.errors import BRDFFileError, ConfigError, ImageFileError, InputFileError
from sparse_brdf.evaluation.images import read_exr, write_exr
from sparse_brdf.sources.merl import read_merl, write_merl
from sparse_brdf.sources.nbrdf import read_nbrdf_weights, tabulate_nbrdf

ROOT = Path(__file__).resolve().parents[1]
H5 = ROOT / "sparse_brdf" / "data" / "materials" / "violet-rubber.h5"

FUZZ = settings(max_examples=40, deadline=None, database=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def mutated(draw, base: bytes, header: int) -> bytes:
    """``base`` truncated, with bytes flipped, with its first ``header`` bytes rewritten,
    or with bytes appended."""
    data = bytearray(base)
    kind = draw(st.sampled_from(["truncate", "flip", "header", "append"]))
    if kind == "truncate":
        return bytes(data[:draw(st.integers(0, len(data) - 1))])
    if kind == "append":
        return bytes(data + draw(st.binary(min_size=1, max_size=64)))
    hi = header if kind == "header" else len(data)
    for _ in range(draw(st.integers(1, 8))):
        i = draw(st.integers(0, hi - 1))
        data[i] = draw(st.integers(0, 255)) if kind == "header" else data[i] ^ draw(
            st.integers(1, 255))
    return bytes(data)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


# ------------------------------------------------------------------------------ MERL

_MERL = None


def merl_base(work: Path) -> bytes:
    global _MERL
    if _MERL is None:
        values = np.random.default_rng(3).random((*SMALL, 3)).astype(np.float32)
        _MERL = write_merl(work / "base.binary",
                           BRDF(values, geometric_valid(SMALL))).read_bytes()
    return _MERL


def _check_merl(path: Path) -> None:
    try:
        brdf = read_merl(path)
    except BRDFFileError as exc:
        assert str(path) in str(exc)
        return
    assert np.all(np.isfinite(brdf.values)) and brdf.valid.any()


@FUZZ
@given(data=st.data())
def test_merl_reader_mutations(work, data):
    path = work / "fuzz.binary"
    path.write_bytes(data.draw(mutated(merl_base(work), 12)))
    _check_merl(path)


@FUZZ
@given(dims=st.tuples(*[st.integers(-2**31, 2**31 - 1)] * 3), tail=st.binary(max_size=96))
def test_merl_reader_headers(work, dims, tail):
    path = work / "head.binary"
    path.write_bytes(struct.pack("<3i", *dims) + tail)
    _check_merl(path)


# ------------------------------------------------------------------------------- .h5


def _check_h5(path: Path, read=read_nbrdf_weights) -> None:
    """``read(path)`` succeeds or raises BRDFFileError naming the file."""
    try:
        read(path)
    except BRDFFileError as exc:
        assert str(path) in str(exc)


@FUZZ
@given(data=st.data())
def test_h5_reader_mutations(work, data):
    path = work / "fuzz.h5"
    path.write_bytes(data.draw(mutated(H5.read_bytes(), 512)))
    _check_h5(path)


_ARRAYS = st.one_of(
    st.tuples(st.sampled_from(["f4", "f8", "i2", "u1"]),
              st.lists(st.integers(0, 30), min_size=0, max_size=3)),
    st.just(("S3", [4])))


@FUZZ
@given(layers=st.lists(st.tuples(_ARRAYS, _ARRAYS, st.booleans()), min_size=0, max_size=4),
       scale=st.sampled_from([0.0, 1.0, 1e3, np.nan]))
def test_h5_reader_structures(work, layers, scale):
    """Well-formed HDF5 files with missing, extra, misshapen or mistyped layers."""
    import h5py

    path = work / "struct.h5"
    with h5py.File(path, "w") as f:
        for i, ((kd, ks), (bd, bs), as_group) in enumerate(layers, 1):
            name = f"dense_{i}"
            g = f.create_group(name)
            if as_group:
                g = g.create_group(name)
            for key, (dtype, shape) in (("kernel:0", (kd, ks)), ("bias:0", (bd, bs))):
                if dtype == "S3":
                    g[key] = np.array([b"abc"] * shape[0])
                else:
                    with np.errstate(invalid="ignore"):  # NaN as an integer: anything
                        g[key] = (np.ones(shape) * scale).astype(dtype)
    _check_h5(path, lambda p: tabulate_nbrdf(p, SMALL))


# ------------------------------------------------------------------------------- EXR


@FUZZ
@given(data=st.data())
def test_exr_reader_mutations(work, data):
    base = work / "base.exr"
    if not base.exists():
        write_exr(base, np.random.default_rng(4).random((8, 8, 3)).astype(np.float32))
    path = work / "fuzz.exr"
    path.write_bytes(data.draw(mutated(base.read_bytes(), 320)))
    try:
        img = read_exr(path)
    except ImageFileError as exc:
        assert str(path) in str(exc)
        return
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32


# ------------------------------------------------------------------------ bench config

_FIELDS = sorted(BenchConfig.__dataclass_fields__)
_SCALARS = st.one_of(st.integers(-2**70, 2**70), st.floats(allow_nan=True),
                     st.booleans(), st.text(max_size=12))
_VALUES = st.one_of(_SCALARS, st.lists(_SCALARS, max_size=4),
                    st.lists(st.sampled_from(["sparse:262", "sparse:0", "tucker:1x2",
                                              "pca:-1", "naive", "sparse:262:zz=1",
                                              "cpd:3:x", "tabulated", "sparse:x"]),
                             max_size=3))


def _toml(value) -> str:
    """A TOML literal (floats' nan/inf as TOML spells them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if value != value else ("inf" if value > 0 else "-inf") \
            if abs(value) == float("inf") else repr(value)
    if isinstance(value, str):
        return '"' + "".join(c if c.isprintable() and c not in '"\\' else
                             f"\\u{ord(c):04x}" for c in value) + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)


def _check_config(path: Path) -> None:
    try:
        BenchConfig.load(path)
    except (ConfigError, InputFileError) as exc:
        assert str(path) in str(exc)


@FUZZ
@given(settings_=st.dictionaries(st.one_of(st.sampled_from(_FIELDS), st.just("scene"),
                                           st.text("abcxyz_", min_size=1, max_size=6)),
                                 _VALUES, max_size=5))
def test_bench_config_settings(work, settings_):
    path = work / "settings.toml"
    path.write_text("".join(f"{k} = {_toml(v)}\n" for k, v in settings_.items()))
    _check_config(path)


@FUZZ
@given(data=st.data())
def test_bench_config_mutations(work, data):
    base = (ROOT / "sparse_brdf" / "data" / "configs" / "ci.toml").read_bytes()
    path = work / "mutated.toml"
    path.write_bytes(data.draw(mutated(base, 64)))
    _check_config(path)


# ---------------------------------------------------------------------- command line


@pytest.fixture(scope="module")
def bad_inputs(work) -> list[str]:
    """Paths a hostile user passes: missing, empty, truncated, corrupt, of another kind,
    a folder, a FIFO, names with control characters."""
    d = work / "bad"
    d.mkdir()
    (d / "empty.binary").write_bytes(b"")
    (d / "short.binary").write_bytes(merl_base(work)[:1000])
    (d / "text.sbrdf").write_text("not a coefficient file\n")
    (d / "magic.sbrdf").write_bytes(b"SBRDF\r\n\x1a" + bytes(60))
    (d / "bad.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    (d / "bad.xml").write_text('<scene version="3.0.0"><bsdf')
    (d / "bad.toml").write_text("spp = [")
    (d / "bad.exr").write_bytes(b"v/1\x01" + bytes(40))
    (d / "bad.npz").write_bytes(b"PK\x03\x04" + bytes(30))
    (d / "a\x1b[31m.binary").write_bytes(b"\x00" * 20)
    (d / "folder.sbrdf").mkdir()
    os.mkfifo(d / "fifo.binary")
    names = sorted(str(p) for p in d.iterdir())
    return names + [str(d / "missing.binary"), "mitsuba:no-such", "", "-"]


_COMMANDS = {
    # command: (number of positional inputs, options taking a value)
    "info": (1, []),
    "convert": (1, []),
    "encode": (1, ["--coeffs", "--max-error", "--fill-iters", "--transform", "--ensemble"]),
    "decode": (1, ["--ensemble"]),
    "blend": (2, ["--alpha", "--coeffs", "--ensemble"]),
    "render": (1, ["--spp", "--res", "--seed", "--material", "--decoder", "--ensemble"]),
    "snr": (2, ["--mask", "--scene", "--reference2"]),
    "fit-scene": (1, ["--target-snr", "--spp", "--res", "--material", "--ensemble"]),
    "bench": (1, ["--out"]),
    "train": (0, ["--taus", "--dicts", "--grid", "--extend"]),
}
_WORDS = st.one_of(st.integers(-10**12, 10**12).map(str),
                   st.sampled_from(["nan", "inf", "-inf", "1e308", "-0", "0", "0x10", "",
                                    "material=", "=x", "auto", "strict"]),
                   st.text(st.characters(codec="utf-8", exclude_characters="\x00"),
                           max_size=8))


@st.composite
def bad_argv(draw, inputs: list[str]) -> list[str]:
    cmd = draw(st.sampled_from(sorted(_COMMANDS)))
    n_inputs, options = _COMMANDS[cmd]
    # an empty TOML file is a valid bench config (every default): a full bench
    usable = [p for p in inputs if cmd != "bench" or not p.endswith("empty.binary")]
    argv = [cmd] + [draw(st.sampled_from(usable)) for _ in range(n_inputs)]
    if cmd == "train":  # only bad corpora (never ".", say): training would take minutes
        argv += ["--corpus", *draw(st.lists(st.sampled_from(inputs), min_size=1, max_size=2))]
    for opt in draw(st.lists(st.sampled_from(options), max_size=3)) if options else []:
        value = draw(st.one_of(_WORDS, st.sampled_from(inputs)))
        argv += [opt, value] if opt != "--material" else [opt, f"material={value}"]
    output = draw(st.sampled_from(inputs + ["out.x"]))
    if cmd == "convert":
        argv.insert(2, output)
    elif cmd in ("encode", "decode", "blend", "render"):
        argv += ["-o", output]
    return argv


@FUZZ
@given(data=st.data())
def test_cli_bad_arguments(work, bad_inputs, capsys, monkeypatch, data):
    cwd = work / "cwd"  # empty: a relative name never finds a material by chance
    cwd.mkdir(exist_ok=True)
    monkeypatch.chdir(cwd)
    argv = data.draw(bad_argv(bad_inputs))
    before = {p: os.stat(p).st_mtime_ns for p in bad_inputs if os.path.isfile(p)}
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    out, err = capsys.readouterr()
    assert code in (0, 2), (argv, err)
    if code:
        assert len(err.splitlines()) == 1, (argv, err)
        assert "Traceback" not in err and "\x1b" not in err
    for p, mtime in before.items():  # no input was rewritten
        assert os.stat(p).st_mtime_ns == mtime, (argv, p)
    leftovers = [p.name for p in work.rglob(".*") if p.is_file()]
    assert leftovers == [], (argv, leftovers)


# ------------------------------------------------ bench configs: every combination, exit 0/2

#: Model specs of every kind, good and odd (the grammar's own tests: tests/test_specs.py).
_SPEC_PARTS = {
    "sparse": st.one_of(
        st.sampled_from(["", "262", "16", "b900", "b0", "bx", "0", "-3", "1e3", "99999999"]),
        st.integers(1, 2000).map(str), st.integers(1, 5000).map(lambda n: f"b{n}")),
    "transform": st.sampled_from(["", "auto", "log-plus", "log-plus-cosine", "log", "paper"]),
    "option": st.sampled_from(["selector=render", "selector=gamma-mse", "selector=x",
                               "fill=missing", "fill=invalid", "fill=all", "fill_iters=0",
                               "fill_iters=7", "fill_iters=x", "fill_iters=2000",
                               "basis=rgb", "basis=opponent", "basis=xyz", "budget=joint",
                               "budget=channel", "version=1", "version=2", "version=3",
                               "colour=rgb", "fill", "=", ""]),
    "size": st.one_of(st.integers(-2, 400).map(str), st.sampled_from(["", "x", "1.5", "²"])),
}


def _either(odd: bool, good, bad):
    """``good``, or (when this axis is the odd one) ``good`` or ``bad``."""
    return st.one_of(good, bad) if odd else good


@st.composite
def model_spec(draw, odd: bool = False) -> str:
    """A model spec of any kind: well-formed, or (``odd``) possibly not."""
    kind = draw(_either(odd, st.sampled_from(["sparse", "naive", "cpd", "tucker", "pca",
                                              "tabulated"]),
                        st.sampled_from(["svd", "", "PCA"])))
    size = _either(odd, st.integers(1, 60).map(str), _SPEC_PARTS["size"])
    if kind == "sparse":
        parts = [draw(_either(odd, st.sampled_from(["", "16", "262", "b900", "b3000"]),
                              _SPEC_PARTS["sparse"]))]
        good_opts = st.sampled_from(["selector=render", "fill=missing", "fill_iters=2",
                                     "basis=rgb", "budget=channel", "version=1"])
        if draw(st.booleans()):
            parts.append(draw(_either(odd, st.sampled_from(["", "auto", "log-plus", "paper"]),
                                      _SPEC_PARTS["transform"])))
        if draw(st.booleans()):
            opts = draw(st.lists(_either(odd, good_opts, _SPEC_PARTS["option"]), max_size=3,
                                 unique=True))
            parts.append(",".join(opts))
        return "sparse:" + ":".join(parts)
    if kind == "tucker":
        ranks = draw(st.lists(size, min_size=3, max_size=3) if not odd
                     else st.lists(size, max_size=4))
        return "tucker" + draw(st.sampled_from(["", ":" + "x".join(ranks)]))
    if kind in ("naive", "tabulated"):
        return kind + draw(_either(odd, st.just(""), size.map(lambda s: ":" + s)))
    return kind + draw(st.one_of(st.just(""), size.map(lambda s: ":" + s)))


@pytest.fixture(scope="module")
def bench_world(work) -> dict[str, str]:
    """Corpora, scenes and ensembles a config may name: a folder of three small-grid
    materials, an empty folder, a folder of a corrupt file, a small ensemble, a corrupt
    one, a scene with a syntax error."""
    from conftest import random_orthonormal
    from sparse_brdf.coding.ensemble import Ensemble

    d = work / "bench_world"
    (d / "mats").mkdir(parents=True)
    (d / "empty").mkdir()
    (d / "corrupt").mkdir()
    for i, rgb in enumerate(((0.2, 0.1, 0.05), (0.5, 0.5, 0.5), (0.01, 0.2, 0.3))):
        values = np.broadcast_to(np.asarray(rgb, np.float32), (*SMALL, 3)).copy()
        write_merl(d / "mats" / f"m{i}.binary", BRDF(values, geometric_valid(SMALL), f"m{i}"))
    (d / "corrupt" / "x.binary").write_bytes(b"\x01" * 30)
    (d / "mixed").mkdir()  # two grids: the small one, and a 4 x 4 x 8 one
    for name in ("m0", "m1"):
        (d / "mixed" / f"{name}.binary").write_bytes((d / "mats" / f"{name}.binary").read_bytes())
    tiny = np.full((4, 4, 8, 3), 0.1, np.float32)
    write_merl(d / "mixed" / "tiny.binary", BRDF(tiny, geometric_valid((4, 4, 8)), "tiny"))
    rng = np.random.default_rng(5)
    u = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    Ensemble(*u, taus=np.array([16, 16])).save(d / "small.npz")
    (d / "bad.npz").write_bytes(b"PK\x03\x04" + bytes(30))
    (d / "bad.xml").write_text('<scene version="3.0.0"><bsdf')
    return {k: str(v) for k, v in {"mats": d / "mats", "mixed": d / "mixed",
                                    "empty": d / "empty",
                                    "corrupt": d / "corrupt", "small": d / "small.npz",
                                    "bad_npz": d / "bad.npz", "bad_xml": d / "bad.xml",
                                    "missing": d / "no-such"}.items()}


#: Usable values of the numeric and boolean settings, and odd ones.
_GOOD_SETTINGS = {"spp": st.integers(1, 64), "res": st.integers(1, 256),
                  "seed": st.integers(0, 4).map(lambda i: 2 * i),  # never the noise_seed
                  "noise_seed": st.integers(0, 4).map(lambda i: 2 * i + 1),
                  "max_materials": st.integers(1, 9), "pca_train_max": st.integers(2, 50),
                  "speed_evals": st.integers(1, 1 << 20),
                  "curve_coeffs": st.lists(st.integers(1, 2000), max_size=3),
                  "render": st.booleans(), "stability": st.booleans(), "speed": st.booleans()}
_ODD = st.one_of(st.integers(-3, 0), st.sampled_from([2**31, 2**70]),
                 st.floats(allow_nan=True), st.booleans(), st.text(max_size=3),
                 st.lists(st.integers(-1, 3), max_size=2))


_AXES = ("corpora", "split", "models", "scenes", "ensemble", "settings")


@st.composite
def bench_config(draw, world: dict[str, str]) -> dict:
    """A bench config: every corpus and split combination, model specs of every kind,
    scenes and ensembles, usable settings; in most examples one axis (``_AXES``) is given
    odd values too."""
    odd = draw(st.sampled_from([None, None, *_AXES]))
    good_corpora = ["mitsuba", "merl", "rgl", "merl-demo", world["mats"]]
    odd_corpora = [world["empty"], world["corrupt"], world["missing"], "", "no-such"]
    cfg: dict = {
        "corpora": draw(st.lists(_either(odd == "corpora", st.sampled_from(good_corpora),
                                         st.sampled_from(odd_corpora)), max_size=3)),
        "split": draw(_either(odd == "split", st.sampled_from(["train", "test", "all"]),
                              st.sampled_from(["", "Test", 3]))),
        "models": draw(st.lists(model_spec(odd == "models"), max_size=4)),
        "stability_models": draw(st.lists(model_spec(odd == "models"), max_size=2)),
        "scenes": draw(st.lists(_either(odd == "scenes", st.sampled_from(
            ["sphere.xml", "paper_sphere", "spheres.xml"]), st.sampled_from(
            ["nope.xml", world["bad_xml"], ""])), max_size=3)),
        "ensemble": draw(_either(odd == "ensemble", st.sampled_from([None, world["small"]]),
                                 st.sampled_from([world["bad_npz"], world["missing"],
                                                  "0" * 32, ""]))),
    }
    for key, good in _GOOD_SETTINGS.items():
        if draw(st.integers(0, 2)) == 0:
            cfg[key] = draw(_either(odd == "settings", good, _ODD))
    return {k: v for k, v in cfg.items() if v is not None}


def _write_config(path: Path, cfg: dict) -> Path:
    path.write_text("".join(f"{k} = {_toml(v)}\n" for k, v in cfg.items()))
    return path


def _bench(capsys, argv) -> tuple[int, str, str]:
    return run_cli(capsys, *argv)


@settings(max_examples=120, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_bench_configs_check_with_exit_0_or_2(work, bench_world, capsys, monkeypatch, data):
    """``bench CONFIG --check`` over generated configs: status 0, or 2 with one line
    naming what is wrong; never an internal error (70)."""
    monkeypatch.chdir(work)
    cfg = data.draw(bench_config(bench_world))
    path = _write_config(work / "generated.toml", cfg)
    code, out, err = _bench(capsys, ["bench", path, "--check"])
    assert code in (0, 2), (cfg, err)
    if code == 2:
        assert len(err.splitlines()) == 1 and "Traceback" not in err, (cfg, err)
    else:
        assert "ok:" in out and err.count("\n") <= 0, (cfg, out, err)


@settings(max_examples=12, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(models=st.lists(st.sampled_from(["sparse:16", "sparse:b700:basis=rgb", "naive",
                                        "tabulated", "pca:2", "tucker:2x1x1", "sparse:0",
                                        "cpd:1"]), min_size=1, max_size=3),
       split=st.sampled_from(["train", "test", "all"]),
       curve=st.lists(st.integers(1, 20000), max_size=2),
       corpus=st.sampled_from(["mats", "mixed"]))
@pytest.mark.bench
def test_bench_runs_with_exit_0_or_2(work, bench_world, capsys, models, split, curve,
                                     corpus):
    """Small real runs (BRDF-space metrics, small grids, one folder of mixed grids):
    status 0 or 2 with one line, never 70; a config the check refuses, the run refuses
    with the same line."""
    cfg = {"corpora": [bench_world[corpus]], "split": split, "models": models,
           "ensemble": bench_world["small"], "render": False, "speed": False,
           "stability": False, "curve_coeffs": curve}
    path = _write_config(work / "run.toml", cfg)
    checked = _bench(capsys, ["bench", path, "--check"])
    ran = _bench(capsys, ["bench", path, "--out", work / "run_out"])
    assert checked[0] in (0, 2) and ran[0] in (0, 2), (cfg, checked, ran)
    for code, _, err in (checked, ran):  # progress-bar lines aside, one line
        lines = [ln for ln in err.splitlines() if ln.strip() and "bench:" not in ln[:12]]
        assert code == 0 or len(lines) == 1, (cfg, err)
        assert code == 0 or lines[0].startswith("sparse-brdf: error: "), (cfg, err)
    if checked[0] == 2:
        assert ran == checked, (cfg, checked, ran)
