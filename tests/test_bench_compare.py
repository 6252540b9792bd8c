"""The regression gate: ``sparse-brdf bench-compare OLD NEW --fail-if-worse DB``."""

from __future__ import annotations

import copy
import json
import math

import pytest

from sparse_brdf.benchmark.compare import compare_results
from sparse_brdf.benchmark.results_file import SCHEMA
from sparse_brdf.cli import main
from sparse_brdf.fileio import strict_json


def _results(renders: dict | None = None) -> dict:
    """Results of two materials x two models, each rendered in ``sphere``; ``renders``:
    cell key -> the figures that differ."""
    cells = {}
    for mat in ("m/a", "m/b"):
        for model in ("sparse-64", "tabulated"):
            r = {"snr_object": 30.0, "snr_whole": 40.0, "flip": 0.05}
            if model == "tabulated":
                r = {"snr_object": math.inf, "snr_whole": math.inf, "flip": 0.0}
            cells[f"{mat}|{model}"] = {"material": mat, "model": model, "status": "finished",
                                       "cos_snr": 25.0, "renders": {"sphere": r}}
    for key, r in (renders or {}).items():
        cells[key]["renders"]["sphere"].update(r)
    return {"schema": SCHEMA, "config": {"corpora": ["m"], "split": "test", "spp": 8,
                                         "res": 48, "seed": 0, "scenes": ["sphere.xml"]},
            "provenance": {}, "cells": cells, "noise_floor": {}, "speed": {}}


def _write(path, data) -> str:
    path.write_text(strict_json(data))
    return str(path)


@pytest.fixture
def old(tmp_path):
    return _write(tmp_path / "old.json", _results())


def _gate(capsys, *args) -> tuple[int, str, str]:
    rc = main(["bench-compare", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_unchanged_results_pass(tmp_path, old, capsys):
    new = _write(tmp_path / "new.json", _results())
    rc, out, _ = _gate(capsys, old, new, "--fail-if-worse", 0, "--fail-if-flip-rises", 0)
    assert rc == 0 and "4 shared cells, 12 figures, none worse" in out


def test_a_drop_beyond_the_tolerance_fails_and_names_the_cell(tmp_path, old, capsys):
    new = _write(tmp_path / "new.json", _results({"m/a|sparse-64": {"snr_object": 28.5}}))
    rc, out, _ = _gate(capsys, old, new, "--fail-if-worse", 1)
    assert rc == 1
    assert "m/a|sparse-64 in sphere: snr_object 30.00 -> 28.50 dB (-1.50 dB)" in out
    assert "1 of 12 figures of 4 shared cells are worse" in out
    rc, out, _ = _gate(capsys, old, new, "--fail-if-worse", 2)  # within 2 dB
    assert rc == 0
    better = _write(tmp_path / "better.json", _results({"m/a|sparse-64": {"snr_object": 50}}))
    assert _gate(capsys, old, better, "--fail-if-worse", 0)[0] == 0


def test_flip_rises_fail_only_when_gated(tmp_path, old, capsys):
    new = _write(tmp_path / "new.json", _results({"m/b|sparse-64": {"flip": 0.08}}))
    assert _gate(capsys, old, new, "--fail-if-worse", 1)[0] == 0
    rc, out, _ = _gate(capsys, old, new, "--fail-if-worse", 1, "--fail-if-flip-rises", 0.02)
    assert rc == 1 and "m/b|sparse-64 in sphere: flip 0.0500 -> 0.0800 (+0.0300)" in out
    assert _gate(capsys, old, new, "--fail-if-worse", 1, "--fail-if-flip-rises", 0.05)[0] == 0


def test_an_identical_render_that_is_no_longer_identical_fails(tmp_path, old, capsys):
    new = _write(tmp_path / "new.json", _results({"m/a|tabulated": {"snr_object": 80.0}}))
    rc, out, _ = _gate(capsys, old, new, "--fail-if-worse", 5)
    assert rc == 1 and "m/a|tabulated in sphere: snr_object inf -> 80.00 dB" in out


def test_a_cell_that_fails_now_fails_the_gate(tmp_path, old, capsys):
    data = _results()
    data["cells"]["m/b|tabulated"] = {"material": "m/b", "model": "tabulated",
                                      "status": "failed", "error": "ValueError: boom"}
    rc, out, _ = _gate(capsys, old, _write(tmp_path / "new.json", data), "--fail-if-worse", 9)
    assert rc == 1 and "m/b|tabulated: finished -> failed: ValueError: boom" in out


def test_without_renders_the_cosine_weighted_snr_is_compared(tmp_path, capsys):
    data = _results()
    for c in data["cells"].values():
        del c["renders"]
    old = _write(tmp_path / "old.json", data)
    worse = copy.deepcopy(data)
    worse["cells"]["m/a|sparse-64"]["cos_snr"] = 20.0
    rc, out, _ = _gate(capsys, old, _write(tmp_path / "new.json", worse), "--fail-if-worse", 1)
    assert rc == 1 and "m/a|sparse-64: cos_snr 25.00 -> 20.00 dB" in out
    assert compare_results(old, old, 0)["figures"] == 4


@pytest.mark.parametrize("change, args, message", [
    (None, ["--fail-if-worse", "-1"], "--fail-if-worse: must be"),
    (None, ["--fail-if-worse", "x"], "--fail-if-worse: expected a number"),
    (None, ["--fail-if-worse", "1", "--fail-if-flip-rises", "2"], "--fail-if-flip-rises"),
    (None, [], "the following arguments are required: --fail-if-worse"),
    ({"spp": 16}, ["--fail-if-worse", "1"], "new.json: measured with spp = 16"),
    ("cells", ["--fail-if-worse", "1"], "no cell finished in"),
    ("missing", ["--fail-if-worse", "1"], "nowhere.json"),
    ("garbage", ["--fail-if-worse", "1"], "not a JSON file"),
])
def test_bad_inputs_are_one_line_and_exit_2(tmp_path, old, capsys, change, args, message):
    data = _results()
    new = tmp_path / "new.json"
    if isinstance(change, dict):
        data["config"].update(change)
    elif change == "cells":
        data["cells"] = {f"x/{k}": v for k, v in data["cells"].items()}
    new.write_text(strict_json(data))
    if change == "missing":
        new = tmp_path / "nowhere.json"
    elif change == "garbage":
        new.write_text("{not json")
    try:
        code = main(["bench-compare", old, str(new), *args])
    except SystemExit as exc:  # argparse's own usage errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_results_round_trip_through_json(tmp_path):
    """The baseline files are strict JSON: infinite SNRs come back as inf."""
    p = tmp_path / "r.json"
    p.write_text(strict_json(_results()))
    assert json.loads(p.read_text())["non_finite"]
    assert compare_results(p, p, 0)["worse"] == []
