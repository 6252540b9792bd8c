"""EncodeSpec: an encoding request resolved and checked once, at each public boundary
(encode, encode_to_bytes, encode_file, encode_batch, encode_samples, blend), and
trusted below it. The ensemble is resolved once and each parameter checked once per
call (the calls are counted)."""

from __future__ import annotations

import collections
import dataclasses
import sys

import numpy as np
import pytest

from conftest import SMALL, random_orthonormal
from sparse_brdf import (
    EncodeSpec,
    encode,
    encode_samples,
    encode_to_bytes,
    interpolate,
    save_sbrdf,
)
from sparse_brdf.acquisition.planning import measure_table, plan
from sparse_brdf.batch import encode_batch
from sparse_brdf.cli import main
from sparse_brdf.cli.files import encode_file
from sparse_brdf.coding.ensemble import Ensemble
from sparse_brdf.coding.interpolate import blend_files
from sparse_brdf.errors import UsageError
from sparse_brdf.sources.load import load_brdf
from sparse_brdf.sources.merl import write_merl

#: The functions that resolve or check what an EncodeSpec holds, or the output, counted
#: wherever the package's modules bound them.
COUNTED = ("resolve_ensemble", "encoder_ensemble", "check_options", "check_new_output",
           "check_output", "check_budget")
#: check_choice names that are data checks of the transforms and the file format, run by
#: the numerics on every call (not parameters a spec holds).
DATA_CHECKS = {"transform", "colour basis", ".sbrdf version"}


@pytest.fixture(scope="module")
def ens(tmp_path_factory):
    rng = np.random.default_rng(3)
    u = [np.stack([random_orthonormal(n, rng) for _ in range(2)]) for n in SMALL]
    e = Ensemble(*u, taus=np.array([16, 16]))
    return e, e.save(tmp_path_factory.mktemp("ens") / "small.npz")


@pytest.fixture(scope="module")
def brdf():
    return load_brdf("mitsuba:plastic-red-ggx-0.3", shape=SMALL)


@pytest.fixture
def calls(monkeypatch):
    """Counts of the COUNTED functions and of params.check / check_choice by parameter."""
    count: collections.Counter = collections.Counter()

    def counting(name, fn, by_param=False):
        def wrapper(*args, **kwargs):
            if not by_param:
                count[name] += 1
            elif args[0] not in DATA_CHECKS:
                count[f"{name}:{args[0]}"] += 1
            return fn(*args, **kwargs)
        return wrapper

    wrapped: dict[int, object] = {}
    for modname, module in list(sys.modules.items()):
        if not modname.startswith("sparse_brdf") or module is None:
            continue
        for name in (*COUNTED, "check", "check_choice"):
            fn = vars(module).get(name)
            home = getattr(fn, "__module__", "") or ""
            by_param = name in ("check", "check_choice")  # the declared parameters' checks
            if callable(fn) and (home == "sparse_brdf.params" if by_param
                                 else home.startswith("sparse_brdf")):
                if id(fn) not in wrapped:
                    wrapped[id(fn)] = counting(name, fn, by_param)
                monkeypatch.setattr(module, name, wrapped[id(fn)])
    return count


def _once(count):
    """Every counted check ran at most once, and the ensemble was resolved once."""
    assert count["resolve_ensemble"] == 1, count
    assert {k: v for k, v in count.items() if v > 1} == {}


def test_build_resolves_every_default(ens):
    spec = EncodeSpec.build(ens[0], 10**6, basis="rgb", fill="missing")
    assert spec.ensemble is ens[0] and spec.n_coeffs == int(np.prod(SMALL))  # capped
    assert (spec.budget, spec.fill_iters, spec.joint) == ("channel", 3, False)
    assert spec.transforms == ens[0].transforms and spec.transform == "auto"
    assert spec.options == {"selector": "render-albedo", "fill": "missing",
                            "fill_iters": 3, "basis": "rgb", "budget": "channel"}
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.n_coeffs = 3
    assert "EncodeSpec(" in repr(spec) and len(repr(spec)) < 300


@pytest.mark.parametrize("kwargs, match", [
    ({"n_coeffs": 0}, "n_coeffs"), ({"max_error": 1.0}, "max_error"),
    ({"selector": "best"}, "selector"), ({"transform": "log"}, "transform"),
    ({"n_bytes": 0}, "n_bytes"), ({"colour": "rgb"}, "unknown encoding option")])
def test_build_refuses_bad_requests(ens, kwargs, match):
    with pytest.raises(UsageError, match=match):
        EncodeSpec.build(ens[0], **kwargs)


def test_encode_and_encode_to_bytes_check_once(ens, brdf, calls):
    encode(brdf, ens[1], 20, max_error=1e-3)
    _once(calls)
    assert calls["check:n_coeffs"] == calls["check:max_error"] == calls["check_options"] == 1
    calls.clear()
    encode_to_bytes(brdf, ens[1], n_bytes=400)
    _once(calls)
    assert calls["check:n_bytes"] == 1


@pytest.mark.parametrize("n_bytes", [None, 400])
def test_encode_file_checks_once(ens, brdf, tmp_path, calls, n_bytes):
    src = write_merl(tmp_path / "m.binary", brdf)
    encode_file(src, tmp_path / "m.sbrdf", ens[1], None if n_bytes else 20, n_bytes)
    _once(calls)
    assert calls["check_new_output"] == 1 and calls["check_output"] == 1


def test_encode_command_checks_once(ens, brdf, tmp_path, calls, capsys):
    src = write_merl(tmp_path / "m.binary", brdf)
    assert main(["encode", str(src), "-o", str(tmp_path / "m.sbrdf"), "--coeffs", "20",
                 "--ensemble", str(ens[1])]) == 0
    _once(calls)
    assert calls["check_output"] == 1


def test_encode_batch_checks_once(ens, brdf, tmp_path, calls):
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("a", "b"):
        write_merl(folder / f"{name}.binary", dataclasses.replace(brdf, name=name))
    summary = encode_batch(folder, tmp_path / "out", ens[1], {"n_coeffs": 20}, progress=False)
    assert summary["encoded"] == 2
    _once(calls)


def test_encode_samples_checks_once(ens, brdf, calls):
    wi, wo = plan(400, "stratified", 0)
    encode_samples(measure_table(brdf, wi, wo), ens[0], 10, prior=None)
    assert calls["check:n_coeffs"] == calls["check:folds"] == 1
    assert calls["resolve_ensemble"] == 1 and {k: v for k, v in calls.items() if v > 1} == {}


def test_blend_checks_once(ens, brdf, tmp_path, calls):
    a = encode(brdf, ens[0], 20)
    b = encode(dataclasses.replace(brdf, values=brdf.values * 0.5), ens[0], 20)
    calls.clear()
    interpolate(a, b, 0.3, ens[0], 10)
    _once(calls)
    pa, pb = save_sbrdf(tmp_path / "a.sbrdf", a), save_sbrdf(tmp_path / "b.sbrdf", b)
    calls.clear()
    blend_files(pa, pb, tmp_path / "ab.sbrdf", 0.3, ens[1], 10)
    _once(calls)
    assert calls["check:alpha"] == calls["check:--coeffs"] == calls["check_output"] == 1
