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
    exists, so that a moved guide leaves no pointer behind."""
    missing = []
    for md in _markdown():
        for name in NAMED.findall(md.read_text()):
            if any(c in name for c in "*<>{}") or "NAME" in name:  # a pattern, a placeholder
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
