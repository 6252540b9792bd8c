"""The documentation's shape: a README and guides a newcomer can finish, dated runs kept
apart in docs/records/, and every pointer to a file of the repository still resolving."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RECORDS = DOCS / "records"
README_MAX = 320
GUIDE_MAX = 320
LONGER_GUIDES = {"results.md": 450}  # current figures, one table per question

# [text](target) and ![alt](target), with an optional "title"
LINK = re.compile(r"!?\[[^\]]*\]\(<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\)")
# a path of the repository named in the text: `docs/method.md`, docs/results.md, ...
NAMED = re.compile(r"(?<![\w/.-])((?:docs|benchmarks|scenes|examples|tests)/[\w./*<>{}-]*[\w/*>}])")


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines())


def _markdown() -> list[Path]:
    """Everything a reader opens as prose: the README, docs/ and the benchmarks' README."""
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md")),
            *sorted((ROOT / "benchmarks").rglob("*.md"))]


def test_readme_fits_its_bound():
    assert _lines(ROOT / "README.md") <= README_MAX


def test_each_guide_fits_its_bound():
    guides = sorted(DOCS.glob("*.md"))
    assert {"method.md", "results.md", "benchmarks.md", "fit-images.md"} <= {
        p.name for p in guides}
    long = [f"{p.name}: {_lines(p)} lines" for p in guides
            if _lines(p) > LONGER_GUIDES.get(p.name, GUIDE_MAX)]
    assert long == []


def test_records_live_in_their_own_folder():
    """Guides say what holds now; dated runs and lab notebooks sit in docs/records/."""
    assert (RECORDS / "history.md").is_file()
    records = [p for p in RECORDS.glob("*.md")]
    assert len(records) >= 3
    dated = re.compile(r"\d{4}-\d{2}|history|runs|notebook", re.I)
    assert [p.name for p in DOCS.glob("*.md") if dated.search(p.stem)] == []
    # a guide holds no run-by-run notebook: no heading names a numbered run
    run = re.compile(r"^#+ .*\bRuns? \d", re.M)
    assert [p.name for p in DOCS.glob("*.md") if run.search(p.read_text())] == []


def test_every_relative_link_resolves():
    broken = []
    for md in _markdown():
        for target in LINK.findall(md.read_text()):
            if re.match(r"[a-z][a-z0-9+.-]*:|#", target):  # a web address or an anchor
                continue
            path = target.split("#", 1)[0]
            if path and not (md.parent / path).exists():
                broken.append(f"{md.relative_to(ROOT)}: ({target})")
    assert broken == []


def test_every_named_repository_file_exists():
    """A file of the repository named in prose (`docs/results.md`, `scenes/sphere.xml`)
    exists, so that a moved guide leaves no pointer behind. A record (docs/records/) is
    dated history: a benchmark script it names may since have gone (git keeps it)."""
    missing = []
    for md in _markdown():
        for name in NAMED.findall(md.read_text()):
            if any(c in name for c in "*<>{}") or "NAME" in name:  # a pattern, a placeholder
                continue
            if RECORDS in md.parents and name.startswith("benchmarks/"):
                continue
            if not (ROOT / name).exists():
                missing.append(f"{md.relative_to(ROOT)}: {name}")
    assert sorted(set(missing)) == []


def test_readme_names_the_two_commands_and_ci_runs_its_test_command():
    readme = (ROOT / "README.md").read_text()
    assert "make demo" in readme and "make test" in readme
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_the_link_patterns_catch_what_they_should():
    assert LINK.findall("see [the guide](docs/method.md#grid) and ![f](figures/a.png)") == [
        "docs/method.md#grid", "figures/a.png"]
    assert NAMED.findall("in `docs/results.md`, and docs/records/history.md.") == [
        "docs/results.md", "docs/records/history.md"]
    assert NAMED.findall("sparse_brdf/docs/x and mydocs/y") == []


# Python names in code: `sparse_brdf.a.b`, `sb.name` (after `import sparse_brdf as sb`),
# `from sparse_brdf.a import b, c`
DOTTED = re.compile(r"(?<![\w.])((?:sparse_brdf|mitsuba_plugin|sb)(?:\.[A-Za-z_]\w*)+)")
FROM_IMPORT = re.compile(r"from\s+((?:sparse_brdf|mitsuba_plugin)(?:\.\w+)*)\s+import\s+"
                         r"\(?\s*([\w ,\n]+)")
CODE = re.compile(r"```.*?```|`[^`\n]+`", re.S)


def _python_names(text: str) -> set[str]:
    """The package's dotted names that the code spans and blocks of ``text`` mention."""
    code = "\n".join(CODE.findall(text))
    found = {n.replace("sb.", "sparse_brdf.", 1) if n.startswith("sb.") else n
             for n in DOTTED.findall(code)}
    for module, items in FROM_IMPORT.findall(code):
        found |= {f"{module}.{item.split()[0]}" for item in items.split(",") if item.strip()}
    return found


def _row_pointers(text: str) -> set[str]:
    """In the table rows that start with a module's name (`sparse_brdf.a.b.f(...)`), the
    bare names of later code spans (`g`), as the reader takes them: ``sparse_brdf.a.b.g``,
    or of the module of the latest dotted name before them."""
    found = set()
    for row in text.splitlines():
        if not row.startswith("| `sparse_brdf."):
            continue
        module = None
        for span in re.findall(r"`([^`]+)`", row):
            if dotted := DOTTED.match(span):
                module = dotted.group(1).rsplit(".", 1)[0]
            elif module and re.fullmatch(r"[A-Za-z_]\w*", span):
                found.add(f"{module}.{span}")
    return found


def _resolve(name: str) -> str | None:
    """None when ``name`` (a module, or attributes of one) imports without a warning;
    else why not: a missing module or name, or the warnings it gives."""
    import importlib
    import warnings

    parts = name.split(".")
    prefixes = [".".join(parts[:i]) for i in range(1, len(parts) + 1)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obj = importlib.import_module(parts[0])
        for i, attr in enumerate(parts[1:], 2):
            try:
                obj = (importlib.import_module(prefixes[i - 1]) if hasattr(obj, "__path__")
                       and not hasattr(obj, attr) else getattr(obj, attr))
            except (ImportError, AttributeError):
                return f"no {attr} in {prefixes[i - 2]}"
    warned = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]
    return "; ".join(warned) or None


def test_the_readme_names_only_current_python_names():
    """Every `sparse_brdf.x.y` and `from sparse_brdf.x import y` of the README imports
    without a DeprecationWarning: no pointer to a name that moved."""
    readme = (ROOT / "README.md").read_text()
    names = _python_names(readme) | _row_pointers(readme)
    assert {"sparse_brdf.evaluation.render.render_scene", "sparse_brdf.evaluation.images.read_exr",
            "sparse_brdf.evaluation.images.write_image", "sparse_brdf.load_brdf"} <= names
    assert {n: why for n in sorted(names) if (why := _resolve(n))} == {}


def test_the_guides_name_only_current_python_names():
    """In docs/, every Python name a code span mentions imports from where it says (old
    paths are listed in CHANGELOG.md, not in the guides)."""
    stale = []
    for md in sorted(DOCS.glob("*.md")):
        for para in md.read_text().split("\n\n"):
            stale += [f"{md.name}: {n}: {why}" for n in sorted(_python_names(para))
                      if (why := _resolve(n))]
    assert stale == []


def test_the_name_check_catches_moved_and_missing_names():
    assert _python_names("`sb.encode(b)` and ```\nfrom sparse_brdf.evaluation.render "
                         "import (write_exr,\n    render_scene as r)\n```") == {
        "sparse_brdf.encode", "sparse_brdf.evaluation.render",
        "sparse_brdf.evaluation.render.write_exr", "sparse_brdf.evaluation.render.render_scene"}
    assert _python_names("prose sparse_brdf.encode, not code") == set()
    assert _row_pointers("| `sparse_brdf.evaluation.render.render_scene(s)` | renders; "
                         "`write_exr`/`read_exr`, `sparse_brdf.coords.MERL_SHAPE`, `x=1` |\n"
                         "| `load(x)` | `y` |") == {
        "sparse_brdf.evaluation.render.write_exr", "sparse_brdf.evaluation.render.read_exr"}
    assert _resolve("sparse_brdf.evaluation.render.write_exr") == (
        "no write_exr in sparse_brdf.evaluation.render")  # moved to evaluation.images
    assert _resolve("sparse_brdf.model.encode") == "no model in sparse_brdf"  # an old path
    assert _resolve("sparse_brdf.no_such_name") == "no no_such_name in sparse_brdf"
    assert _resolve("sparse_brdf.coding.ensemble.Ensemble.default") is None
