"""benchmarks/harness.py: the options, the machine header and the JSON record every
benchmark script shares; and the scripts import no sibling script but the shared modules."""

from __future__ import annotations

import ast
import importlib.util
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
# the modules benchmark scripts share; any other sibling import couples two scripts
SHARED = {"harness", "render_timing"}


def _harness():
    spec = importlib.util.spec_from_file_location("harness", BENCH / "harness.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_parser_keeps_the_docstring_and_adds_json(tmp_path):
    h = _harness()
    doc = "Title.\n\n    .venv/bin/python benchmarks/x.py --n 3\n"
    p = h.parser(doc)
    assert p.description == doc
    assert p.parse_args(["--json", str(tmp_path / "r.json")]).json == tmp_path / "r.json"
    assert p.parse_args([]).json is None
    assert "--json" not in h.parser(doc, json_option=False).format_help()


def test_header_names_machine_load_date_and_commit():
    h = _harness()
    info = {"host": "box", "cpu": "Some CPU", "cores": 2, "load_average": [1.5, 2.25, 3.0],
            "date": "2026-12-02 07:40 UTC", "commit": "abc1234", "python": "3.12.0"}
    assert h.header(info) == ("box, Some CPU, 2 cores, load average 1.50 / 2.25 / 3.00 "
                              "(1 / 5 / 15 min), 2026-12-02 07:40 UTC, commit abc1234")
    live = h.machine()
    assert set(live) == set(info)
    assert len(live["load_average"]) == 3 and live["cores"] >= 1
    assert live["date"].endswith("UTC") and live["commit"]


def test_write_json_records_provenance(tmp_path, monkeypatch):
    h = _harness()
    monkeypatch.setattr(sys, "argv", ["/x/benchmarks/bench_x.py", "--n", "3"])
    args = h.parser("doc").parse_args(["--json", str(tmp_path / "sub" / "r.json")])
    path = h.write_json(args.json, [{"a": 1.5}], args)
    record = json.loads(path.read_text())
    assert set(record) == {"machine", "command", "args", "results"}
    assert record["command"] == "bench_x.py --n 3"
    assert record["args"] == {"json": str(tmp_path / "sub" / "r.json")}
    assert record["results"] == [{"a": 1.5}]
    assert "load_average" in record["machine"]
    assert list((tmp_path / "sub").iterdir()) == [path]  # written atomically, nothing left


def test_scripts_import_no_sibling_script():
    scripts = {p.stem for p in BENCH.rglob("*.py")}
    bad = []
    for p in BENCH.rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{p.relative_to(ROOT)}: {n}" for n in names
                    if n.split(".")[0] in scripts - SHARED]
    assert bad == []


def test_every_live_script_has_a_readme_row():
    readme = (BENCH / "README.md").read_text()
    live = sorted(p.name for p in BENCH.glob("*.py"))
    missing = [n for n in live if n not in {f"{m}.py" for m in SHARED}
               and f"| `{n}` |" not in readme]
    assert live and missing == []
