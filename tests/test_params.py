"""Declared parameters (sparse_brdf.params): one check, one message form, and a command
line whose choices, bounds and defaults are the library's."""

from __future__ import annotations

import argparse
import inspect
import math
import re
from pathlib import Path

import numpy as np
import pytest

from sparse_brdf import cli
from sparse_brdf.acquisition.planning import plan
from sparse_brdf.acquisition.recovery import encode_samples
from sparse_brdf.benchmark.ranking import merge_results
from sparse_brdf.cli.files import encode_samples_file
from sparse_brdf.coding import spec as encode_module
from sparse_brdf.coding.budget import check_budget, encode_to_bytes
from sparse_brdf.coding.encode import encode
from sparse_brdf.coding.fileformat import check_version
from sparse_brdf.coding.interpolate import interpolate
from sparse_brdf.compared.sparse_model import SparseModel
from sparse_brdf.coords import GRID_SIDE, MERL_SHAPE, check_grid
from sparse_brdf.decoders.layouts import DECODERS, LOBES, PLUGIN_DEFAULTS
from sparse_brdf.errors import ConfigError, UsageError
from sparse_brdf.evaluation.render import render_scene
from sparse_brdf.evaluation.scenes import RENDER_PARAMETERS
from sparse_brdf.fitting.fit_images import fit_images
from sparse_brdf.fitting.fit_scene import fit_scene
from sparse_brdf.mitsuba_env import VARIANTS
from sparse_brdf.params import SEED, Choice, Interval, check, check_choice, check_range
from sparse_brdf.sources.corpora import SPLITS, TRAINING_CORPORA
from sparse_brdf.sources.dataset import training_data
from sparse_brdf.training import train as train_module
from sparse_brdf.training.train import train_dictionaries, train_ensemble
from sparse_brdf.transforms import COLOUR_BASES, TRANSFORMS, check_basis, check_transform

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------ the check itself
def test_choice_message_names_parameter_value_and_choices():
    assert check_choice("fill", "missing", ("missing", "invalid")) == "missing"
    with pytest.raises(UsageError) as err:
        check_choice("fill", "all", ("missing", "invalid"))
    assert str(err.value) == "unknown fill 'all': expected one of missing, invalid"
    for odd in (None, 1, ["missing"], np.array(["missing"]), True):
        with pytest.raises(UsageError):
            check("fill", odd, Choice(("missing", "invalid")))


@pytest.mark.parametrize("c,good,bad,text", [
    (Interval(int, 1), [1, 7, 3.0, np.int64(5)], [0, -1, 1.5, True, "3", None, math.nan],
     "an integer >= 1"),
    (Interval(float, 0.0, 1.0, "left"), [0, 0.5, 0.999], [1, 1.0, -0.1, math.inf, math.nan],
     "in [0, 1)"),
    (Interval(float, 0.0, closed="right"), [1e-300, 3], [0, -1], "> 0"),
    (Interval(int, 0, 1000), [0, 1000], [1001, -1], "an integer in [0, 1000]"),
    (SEED, [0, 2**32 - 1], [2**32, -1], "an integer in [0, 4294967295]"),
])
def test_interval_membership_and_message(c, good, bad, text):
    for v in good:
        assert check("x", v, c) == v
    for v in bad:
        with pytest.raises(UsageError, match=re.escape(f"x must be {text}, got")):
            check("x", v, c)
    assert c.describe() == text


def test_int_interval_returns_an_int_and_capped_lowers_the_top():
    assert type(check("n", 3.0, Interval(int, 1))) is int
    assert Interval(int, 1).capped(10) == Interval(int, 1, 10)
    assert Interval(int, 1, 5).capped(10) == Interval(int, 1, 5)
    assert check_range("q", 0.5, 0, 1) == 0.5
    with pytest.raises(ConfigError, match="q must be in"):
        check_range("q", 2, 0, 1, error=ConfigError)


def test_library_checks_use_it():
    for call, match in ((lambda: check_transform("log"), "unknown transform 'log': expected "
                         "one of log-plus, log-plus-cosine"),
                        (lambda: check_basis("xyz"), "unknown colour basis 'xyz'"),
                        (lambda: check_grid((1, 90, 180), "--grid"), "--grid side must be"),
                        (lambda: check_grid((900, 900, 1800)), "at most 1458000")):
        with pytest.raises(UsageError, match=re.escape(match)):
            call()
    assert check_grid([90, 90, 180]) == MERL_SHAPE


def test_one_sbrdf_version_check(small_ensemble):
    """The writer, the byte budget and the bench's sparse model refuse an unknown .sbrdf
    version with one error type and one message."""
    from sparse_brdf.coding.coefficients import SparseBRDF
    from sparse_brdf.coding.fileformat import to_bytes

    m = SparseBRDF("log-plus", small_ensemble.shape, small_ensemble.id, [0, 0, 0],
                   [[0]] * 3, [[1.0]] * 3)
    messages = set()
    for call in (lambda: check_version(3), lambda: to_bytes(m, 3),
                 lambda: check_budget("x", 1000, 3),
                 lambda: SparseModel(small_ensemble, version=3)):
        with pytest.raises(UsageError) as err:
            call()
        messages.add(str(err.value))
    assert messages == {"unknown .sbrdf version 3: expected one of 1, 2"}


def test_no_hand_written_choice_checks_remain():
    """"expected one of" is written once, in params.py (the plugin's checks are its own)."""
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in (ROOT / "sparse_brdf").rglob("*.py")
            if p.name != "params.py"
            for i, line in enumerate(p.read_text().splitlines(), 1)
            if "expected one of" in line and "raise" in line]
    # the reader's list of BRDF file formats (a file error, not a parameter)
    assert all("sources/load.py" in h for h in hits), hits


# ------------------------------------------------------------------ the command line
def _options(command: str) -> dict[str, argparse.Action]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a for a in sub.choices[command]._actions if a.dest != "help"}


def _lib_default(func, name):
    d = inspect.signature(func).parameters[name].default
    return list(d) if isinstance(d, tuple) else d


#: Each CLI option that stands for a library parameter: (command, dest) -> (function,
#: parameter). Their defaults must agree.
MIRRORS = {
    ("train", "transform"): (training_data, "transforms"),
    ("train", "basis"): (training_data, "basis"),
    ("train", "grid"): (training_data, "shape"),
    ("train", "taus"): (train_ensemble, "taus"),
    ("train", "dicts"): (train_ensemble, "n_dicts"),
    ("train", "iterations"): (train_ensemble, "n_iter"),
    ("train", "seed"): (train_ensemble, "seed"),
    ("train", "warm_start"): (train_ensemble, "warm_start"),
    ("train", "reassign_every"): (train_dictionaries, "reassign_every"),
    ("train", "tol"): (train_dictionaries, "tol"),
    ("train", "max_moved"): (train_dictionaries, "max_moved"),
    ("train", "shard_tensors"): (train_dictionaries, "shard_tensors"),
    ("train", "masked"): (train_dictionaries, "masked"),
    ("train", "init"): (train_dictionaries, "init"),
    ("encode", "coeffs"): (encode, "n_coeffs"),
    ("encode", "bytes"): (encode_to_bytes, "n_bytes"),
    ("encode", "max_error"): (encode, "max_error"),
    ("encode", "transform"): (encode, "transform"),
    ("encode", "selector"): (encode, "selector"),
    ("encode", "fill"): (encode, "fill"),
    ("encode", "fill_iters"): (encode, "fill_iters"),
    ("encode", "basis"): (encode, "basis"),
    ("encode", "budget"): (encode, "budget"),
    ("encode-samples", "coeffs"): (encode_samples, "n_coeffs"),
    ("encode-samples", "bytes"): (encode_samples, "n_bytes"),
    ("encode-samples", "seed"): (encode_samples, "seed"),
    ("encode-samples", "prior"): (encode_samples_file, "prior"),
    ("plan-samples", "placement"): (plan, "placement"),
    ("plan-samples", "seed"): (plan, "seed"),
    ("render", "spp"): (render_scene, "spp"),
    ("render", "seed"): (render_scene, "seed"),
    ("render", "res"): (render_scene, "res"),
    ("render", "variant"): (render_scene, "variant"),
    ("fit-scene", "output"): (fit_scene, "out"),
    ("fit-scene", "spp"): (fit_scene, "spp"),
    ("fit-scene", "res"): (fit_scene, "res"),
    ("fit-scene", "seed"): (fit_scene, "seed"),
    ("fit-scene", "bytes"): (fit_scene, "max_bytes"),
    ("blend", "coeffs"): (interpolate, "n_coeffs"),
    ("bench-merge", "by"): (merge_results, "by"),
    **{("fit-images", o): (fit_images, o) for o in ("material", "iterations", "lr", "lr_end",
                                                    "spp", "seed", "decoder", "variant",
                                                    "optimizer", "loss", "prior_weight",
                                                    "validate_every")},
}
#: Options with a default of the command line's own (no library parameter stands behind
#: them): the corpora and split the trainer reads, and the plugins' render choices.
OWN = {("train", "corpus"): list(TRAINING_CORPORA), ("train", "split"): "train",
       ("render", "sampling"): PLUGIN_DEFAULTS["sampling"],
       ("render", "decoder"): PLUGIN_DEFAULTS["decoder"]}


@pytest.mark.parametrize("key", sorted(MIRRORS))
def test_cli_default_is_the_library_default(key):
    action = _options(key[0])[key[1]]
    assert action.default == _lib_default(*MIRRORS[key]), key


def test_every_cli_default_is_accounted_for():
    """An option whose default is not None/False/[] mirrors a library parameter (above) or
    is one of the command line's own; a new option with a retyped default fails here."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    loose = []
    for command in sub.choices:  # every subcommand, those added later too
        for dest, a in _options(command).items():
            if a.default in (None, False, [], argparse.SUPPRESS) or dest in ("command", "func"):
                continue
            if (command, dest) in MIRRORS:
                continue
            if OWN.get((command, dest), object()) != a.default:
                loose.append((command, dest, a.default))
    assert loose == []


def test_cli_choices_are_the_declarations():
    enc, tr, rn = _options("encode"), _options("train"), _options("render")
    params = encode_module.PARAMETERS
    for dest in ("transform", "selector", "fill", "basis", "budget"):
        assert tuple(enc[dest].choices) == tuple(params[dest]), dest
    assert tuple(tr["transform"].choices) == TRANSFORMS
    assert tuple(tr["basis"].choices) == COLOUR_BASES
    assert tuple(tr["split"].choices) == SPLITS
    assert tuple(tr["init"].choices) == train_module.PARAMETERS["init"]
    assert tuple(rn["sampling"].choices) == LOBES
    assert tuple(rn["decoder"].choices) == DECODERS
    assert tuple(rn["variant"].choices) == VARIANTS


@pytest.mark.parametrize("command,dest,declared", [
    ("train", "taus", train_module.PARAMETERS["tau"].capped(math.prod(MERL_SHAPE))),
    ("train", "dicts", train_module.PARAMETERS["n_dicts"]),
    ("train", "max_moved", train_module.PARAMETERS["max_moved"]),
    ("train", "shard_tensors", train_module.PARAMETERS["shard_tensors"]),
    ("train", "grid", GRID_SIDE),
    ("encode", "coeffs", cli.COEFFS),
    ("encode", "max_error", encode_module.PARAMETERS["max_error"]),
    ("encode", "fill_iters", encode_module.PARAMETERS["fill_iters"]),
    ("render", "spp", RENDER_PARAMETERS["spp"]),
    ("render", "seed", RENDER_PARAMETERS["seed"]),
    ("render", "res", RENDER_PARAMETERS["res"]),
])
def test_cli_bounds_are_the_declarations(command, dest, declared):
    parse = _options(command)[dest].type
    inside = [declared.lo, declared.hi if declared.closed == "both" else None]
    for v in (v for v in inside if v is not None):
        assert parse(str(v)) == v
    outside = [] if declared.lo is None else [declared.lo - 1]
    if declared.hi is not None:
        outside.append(declared.hi + (1 if declared.closed == "both" else 0))
    for v in outside:
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(declared.describe())):
            parse(str(v))
