"""The package's structure: no import cycles, layers that only look down, lazy imports
that say why, and a non-editable install that finds its own scenes and configs."""

from __future__ import annotations

import ast
import importlib
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from sparse_brdf.coding.ensemble import shipped_ids

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sparse_brdf", "mitsuba_plugin")
# Modules of sparse_brdf allowed to import the Mitsuba plugin: the render helpers.
PLUGIN_USERS = {"sparse_brdf.evaluation.render", "sparse_brdf.benchmark.speed"}
# Imports that may sit inside a function, with a comment saying why (heavy or optional).
LAZY_OK = ("mitsuba", "drjit", "mitsuba_plugin", "matplotlib", "tqdm", "dask", "distributed",
           "OpenEXR", "Imath", "h5py", "scipy", "tensorly", "threadpoolctl", "flip_evaluator",
           "PIL")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _resolve(mod: str, node: ast.ImportFrom, is_pkg: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(path: Path) -> list[tuple[str, bool, int]]:
    """(imported module, at top level?, line) for every import in a file."""
    mod = _module_name(path)
    tree = ast.parse(path.read_text(), filename=str(path))
    top = {id(n) for n in tree.body}
    for n in tree.body:  # `if TYPE_CHECKING:` / try blocks at module level count as top
        if isinstance(n, (ast.If, ast.Try)):
            top |= {id(c) for c in ast.walk(n)}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, id(node) in top, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(mod, node, path.name == "__init__.py")
            names = [f"{target}.{a.name}" for a in node.names]
            out += [(n, id(node) in top, node.lineno) for n in names]
    return out


def _graph() -> dict[str, set[str]]:
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    mods = {_module_name(p): p for p in files}
    graph: dict[str, set[str]] = {}
    for m, p in mods.items():
        deps = set()
        for name, _, _ in _imports(p):
            while name and name not in mods:  # "pkg.mod.attr" -> "pkg.mod"
                name = name.rpartition(".")[0]
            if name and name != m and not m.startswith(name + "."):
                deps.add(name)
        graph[m] = deps
    return graph


def test_no_import_cycles():
    graph = _graph()
    assert len(graph) > 30
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if d.endswith("__init__") or graph.get(d) is None:
                continue
            if state.get(d) == 1:
                cycle = stack[stack.index(d):] + [d]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state and m not in PACKAGES:
            visit(m)


# The subpackages of sparse_brdf, each a family (docs/architecture.md, "The package"), and
# which groups each group may import ("Rules"). "core" is the top-level modules; "top" the
# command line and the demo (and the package's __init__); "batch" the batch encoder, a
# top-level module above coding/ and sources/ (it loads materials and encodes them).
SUBPACKAGES = ("coding", "training", "acquisition", "compared", "decoders", "fitting",
               "sources", "evaluation", "benchmark")
# Top-level modules that are a layer of their own rather than core.
LAYER_MODULES = ("batch",)
ALLOWED = {
    "core": {"core"},
    "coding": {"core", "coding"},
    "decoders": {"core", "decoders"},
    "training": {"core", "coding", "training"},
    "sources": {"core", "sources", "coding"},
    "compared": {"core", "coding", "compared"},
    "acquisition": {"core", "coding", "compared", "sources", "acquisition"},
    "evaluation": {"core", "decoders", "evaluation", "mitsuba_plugin"},
    "benchmark": {"core", "coding", "decoders", "sources", "compared", "acquisition",
                  "training", "evaluation", "benchmark", "mitsuba_plugin"},
    "fitting": {"core", "coding", "decoders", "sources", "evaluation", "fitting"},
    "batch": {"core", "coding", "sources", "batch"},
    "top": {"core", "coding", "decoders", "training", "sources", "compared", "acquisition",
            "evaluation", "benchmark", "fitting", "batch", "top"},
    "mitsuba_plugin": {"core", "coding", "decoders", "sources", "mitsuba_plugin"},
}


def _group(m: str) -> str:
    parts = m.split(".")
    if parts[0] != "sparse_brdf" or len(parts) < 2:
        return parts[0]
    if parts[1] in SUBPACKAGES or parts[1] in LAYER_MODULES:
        return parts[1]
    return "top" if parts[1] in ("cli", "demo", "__init__") else "core"


def test_the_subpackages_are_the_declared_families():
    found = {p.parent.name for p in (ROOT / "sparse_brdf").glob("*/__init__.py")}
    assert found - {"cli"} == set(SUBPACKAGES)  # cli/: the command line, the "top" group
    assert set(ALLOWED) == {*SUBPACKAGES, *LAYER_MODULES, "core", "top", "mitsuba_plugin"}
    assert all((ROOT / "sparse_brdf" / f"{m}.py").is_file() for m in LAYER_MODULES)


def test_groups_import_one_way():
    bad = []
    for m, deps in _graph().items():
        for d in deps:
            if m == "sparse_brdf" or d == "sparse_brdf":
                continue
            if _group(d) not in ALLOWED[_group(m)]:
                bad.append(f"{m} -> {d}")
    # sources may read .sbrdf files through the coding package, nothing else of it
    bad += [f"{m} -> {d}" for m, deps in _graph().items() if _group(m) == "sources"
            for d in deps if _group(d) == "coding"
            and (m, d) != ("sparse_brdf.sources.load", "sparse_brdf.coding.fileformat")]
    assert bad == []


def test_no_module_answers_names_it_does_not_hold():
    """No module-level ``__getattr__`` (a name is imported from the module that defines it)
    and no import hook: ``import sparse_brdf`` leaves ``sys.meta_path`` as it was."""
    bad = [f"{p.relative_to(ROOT)}:{node.lineno}" for pkg in PACKAGES
           for p in (ROOT / pkg).rglob("*.py")
           for node in ast.parse(p.read_text()).body
           if isinstance(node, ast.FunctionDef) and node.name == "__getattr__"
           or isinstance(node, ast.Assign)
           and any(isinstance(t, ast.Name) and t.id == "__getattr__" for t in node.targets)]
    assert bad == []
    code = ("import sys; before = list(sys.meta_path); import sparse_brdf, sparse_brdf.cli; "
            "print(sys.meta_path == before)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout.strip()
    assert out == "True"


# Private names imported across modules, allowed with a reason; each entry is
# "importing module: imported module.name" (the test fails on an entry that no longer
# occurs, so the list only shrinks).
PRIVATE_IMPORTS_ALLOWED: set[str] = set()


def _is_module(dotted: str) -> bool:
    p = ROOT.joinpath(*dotted.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _private_imports(path: Path, mod: str | None = None) -> list[str]:
    """``module: target.name`` for each name starting with one underscore that ``path``
    (the module ``mod``) imports from another module (a private module itself,
    ``from . import _pools``, is a module of the package, not a name)."""
    mod = mod or _module_name(path)
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            target = _resolve(mod, node, path.name == "__init__.py")
            out += [f"{mod}: {target}.{a.name}" for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                    and not _is_module(f"{target}.{a.name}")]
    return out


def test_no_private_name_crosses_a_module_seam():
    """A name that starts with an underscore is private to its module: no other module
    imports it (scikit-learn keeps a family's helpers private to its module). What several
    modules share is public in the module that defines it, which may itself be private
    (``from ._steps import Monitor``)."""
    found = {hit for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
             for hit in _private_imports(p)}
    assert sorted(found - PRIVATE_IMPORTS_ALLOWED) == []
    assert sorted(PRIVATE_IMPORTS_ALLOWED - found) == []  # the list only shrinks


def test_private_import_check_can_fail(tmp_path):
    sample = tmp_path / "probe.py"
    sample.write_text("from .recovery import encode_samples as _e\nfrom .sensing import "
                      "_hidden\nfrom . import _pools\n")
    assert _private_imports(sample, "sparse_brdf.acquisition.probe") == [
        "sparse_brdf.acquisition.probe: sparse_brdf.acquisition.sensing._hidden"]


# Size bounds: a folder a newcomer can read in a sitting, modules with one job.
MAX_MODULES, MAX_FOLDER_LINES, MAX_MODULE_LINES = 14, 4000, 600


def _lines(p: Path) -> int:
    return len(p.read_text().splitlines())


def test_folders_and_modules_stay_small():
    folders = {p.parent for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    big = []
    for f in sorted(folders):
        mods = [p for p in f.glob("*.py") if p.name != "__init__.py"]
        lines = sum(_lines(p) for p in f.glob("*.py"))
        if len(mods) > MAX_MODULES or lines > MAX_FOLDER_LINES:
            big.append(f"{f.relative_to(ROOT)}: {len(mods)} modules, {lines} lines")
    big += [f"{p.relative_to(ROOT)}: {_lines(p)} lines" for pkg in PACKAGES
            for p in (ROOT / pkg).rglob("*.py")
            if _lines(p) > MAX_MODULE_LINES]
    assert big == []


def test_subpackages_say_what_they_hold():
    """Each subpackage's __init__ has a docstring and ``__all__``, and binds no name that
    is also one of its modules (``from pkg import mod`` must give the module)."""
    bad = []
    for init in (ROOT / "sparse_brdf").glob("*/__init__.py"):
        tree = ast.parse(init.read_text())
        names = {t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets
                 if isinstance(t, ast.Name)}
        if not ast.get_docstring(tree) or "__all__" not in names:
            bad.append(f"{init.relative_to(ROOT)}: no docstring or no __all__")
        bound = {a.asname or a.name for n in tree.body if isinstance(n, ast.ImportFrom)
                 for a in n.names}
        modules = {p.stem for p in init.parent.glob("*.py")} | {
            p.parent.name for p in init.parent.glob("*/__init__.py")}
        bad += [f"{init.relative_to(ROOT)}: binds {n}, a module's name" for n in bound & modules]
    assert bad == []


def test_library_does_not_import_the_plugin():
    graph = _graph()
    offenders = sorted(m for m, deps in graph.items() if m.startswith("sparse_brdf")
                       and any(d.startswith("mitsuba_plugin") for d in deps)
                       and m not in PLUGIN_USERS)
    assert offenders == []


def test_plugin_holds_no_numpy_layouts():
    """mitsuba_plugin is Dr.Jit and Mitsuba code; numpy layouts live in sparse_brdf."""
    for p in (ROOT / "mitsuba_plugin").rglob("*.py"):
        names = {n.split(".")[0] for n, _, _ in _imports(p)}
        # evaluators.py only checks and converts each baseline's numpy parameters on upload
        assert "numpy" not in names or p.name == "evaluators.py", p


def test_lazy_imports_are_deliberate_and_explained():
    bad = []
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            lines = p.read_text().splitlines()
            for name, at_top, line in _imports(p):
                if at_top or name == "__future__.annotations":
                    continue
                root = name.split(".")[0]
                if root not in LAZY_OK:
                    bad.append(f"{p.relative_to(ROOT)}:{line}: {name} imported inside a function")
                    continue
                near = " ".join(lines[max(0, line - 6): line])
                if "#" not in near:
                    bad.append(f"{p.relative_to(ROOT)}:{line}: lazy {name} without a reason")
    assert bad == []


# The one module that starts threads, thread or process pools, Dask clients or BLAS
# thread limits (docs/architecture.md, "Rules").
PARALLEL = "sparse_brdf.parallel"
POOL_MODULES = ("concurrent.futures", "multiprocessing", "threadpoolctl", "dask",
                "distributed", "joblib")
POOL_NAMES = {"Thread", "Timer", "ThreadPoolExecutor", "ProcessPoolExecutor", "Pool",
              "ThreadpoolController", "threadpool_limits", "LocalCluster", "Client"}


def _pool_makers(path: Path) -> list[str]:
    """Where a file imports a pool module, or names a thread or pool class."""
    tree = ast.parse(path.read_text(), filename=str(path))
    hits = [f"{line}: imports {name}" for name, _, line in _imports(path)
            if any(name == m or name.startswith(m + ".") for m in POOL_MODULES)]
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in POOL_NAMES:
            hits.append(f"{node.lineno}: uses .{node.attr}")
        elif isinstance(node, ast.ImportFrom) and node.module == "threading":
            hits += [f"{node.lineno}: imports threading.{a.name}" for a in node.names
                     if a.name in POOL_NAMES]
    return hits


def test_only_parallel_creates_threads_and_pools():
    """Thread pools, threads, process pools, Dask clusters and BLAS thread limits are made
    in ``sparse_brdf/parallel.py`` alone; everything else maps through it."""
    bad = [f"{p.relative_to(ROOT)}:{hit}" for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
           if _module_name(p) != PARALLEL for hit in _pool_makers(p)]
    assert bad == []
    # and the check can fail: parallel.py itself makes a pool and limits BLAS
    assert any("ThreadPoolExecutor" in h for h in _pool_makers(ROOT / "sparse_brdf/parallel.py"))
    assert any("threadpoolctl" in h for h in _pool_makers(ROOT / "sparse_brdf/parallel.py"))


def test_functions_stay_short():
    """No function over 80 lines, its docstring not counted (numpydoc sections of a
    function with many options are long by design), in the packages and in benchmarks/,
    unless its first line carries a ``# long:`` reason."""
    long = []
    files = [p for d in (*PACKAGES, "benchmarks") for p in (ROOT / d).rglob("*.py")]
    for p in files:
        lines = p.read_text().splitlines()
        for node in ast.walk(ast.parse("\n".join(lines))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                doc = node.body[0]
                if (isinstance(doc, ast.Expr) and isinstance(doc.value, ast.Constant)
                        and isinstance(doc.value.value, str)):
                    n -= doc.end_lineno - doc.lineno + 1
                if n > 80 and "# long:" not in lines[node.lineno - 1]:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name}: {n} lines")
    assert long == []


# Classes stay under MAX_CLASS_LINES lines (docstrings and all) unless their docstring gives
# the reason in a sentence starting with LONG_BECAUSE (docs/architecture.md, "Rules").
MAX_CLASS_LINES, LONG_BECAUSE = 200, "Long because"
# Classes over the bound without a reason yet, each with why (the list only shrinks).
LONG_CLASSES_ALLOWED: set[str] = set()


def _long_classes(path: Path, root: Path = ROOT) -> list[str]:
    """``file:Class`` of each class of ``path`` over the bound whose docstring gives no
    reason."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ClassDef):
            doc = ast.get_docstring(node) or ""
            reason = re.search(rf"(^|[.\n]\s*){LONG_BECAUSE}\b", doc)
            if node.end_lineno - node.lineno + 1 > MAX_CLASS_LINES and not reason:
                out.append(f"{path.relative_to(root).as_posix()}:{node.name}")
    return out


def test_classes_stay_small_or_say_why():
    """No class over 200 lines in the packages unless its docstring says why ("Long
    because ..."), as no function is over 80 lines unless its first line says why."""
    found = {hit for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
             for hit in _long_classes(p)}
    assert sorted(found - LONG_CLASSES_ALLOWED) == []
    assert sorted(LONG_CLASSES_ALLOWED - found) == []  # the list only shrinks


def test_long_class_check_can_fail(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_CLASS_LINES))
    quiet, told = tmp_path / "quiet.py", tmp_path / "told.py"
    quiet.write_text(f'class Big:\n    """Many."""\n{body}\n')
    told.write_text(f'class Big:\n    """Many.\n\n    Long because of x.\n    """\n{body}\n')
    assert _long_classes(quiet, tmp_path) == ["quiet.py:Big"]
    assert _long_classes(told, tmp_path) == []


# A pointer to a text the reader does not have: a SPEC section, an issue number ("issue 14",
# "issue #14", "#14"). Cite the paper or docs/ instead. A quoted "SPEC" is a byte string
# (a file's magic number), not a pointer.
POINTER = re.compile(r"(?<!\")\bSPEC\b|\bSPEC\b(?!\")|\b[Ii]ssues?\s+#?\d+|(?<![\w&#/])#\d{1,4}\b")


def _texts_for_readers() -> list[Path]:
    """Code, tests, benchmarks, scenes, the README and docs/: everything a reader opens."""
    files = [p for d in (*PACKAGES, "tests", "benchmarks") for p in (ROOT / d).rglob("*.py")]
    files += [p for d in (*PACKAGES, "scenes") for ext in ("toml", "xml", "json")
              for p in (ROOT / d).rglob(f"*.{ext}")]
    files += [ROOT / "README.md", ROOT / "Makefile", ROOT / "pyproject.toml",
              *(ROOT / "docs").rglob("*.md"), *(ROOT / "benchmarks").rglob("*.md")]
    return [p for p in files if p.is_file() and p != Path(__file__).resolve()]


def test_no_pointer_to_files_outside_the_repository():
    files = _texts_for_readers()
    assert ROOT / "README.md" in files and any(p.parent.name == "docs" for p in files)
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()[:80]}" for p in files
            for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
            if POINTER.search(line)]
    assert hits == []


def test_pointer_pattern_catches_what_it_should():
    for text in ("SPEC section 7", '"SPEC section 7"', "(issue 14)", "issue #13", "see #13.",
                 "Issues 3 and 4"):
        assert POINTER.search(text), text
    for text in ('raw[:4] != b"SPEC"', "a SPECTRUM", "spec = 8.0", "issues about 800 gathers",
                 "colour #1f77b4",
                 "# long: why", "## Heading", "&#10;", "the paper's section 6"):
        assert not POINTER.search(text), text


def test_import_stays_light():
    """`import sparse_brdf` (and the CLI module) must not pull in Mitsuba, matplotlib or
    Dask (an optional dependency, loaded only when a cluster is asked for)."""
    code = ("import sys, sparse_brdf, sparse_brdf.cli; "
            "print(sorted(m for m in ('mitsuba', 'drjit', 'matplotlib', 'mitsuba_plugin', "
            "'dask', 'distributed') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout.strip()
    assert out == "[]"


@pytest.mark.render
def test_wheel_ships_scenes_and_configs(tmp_path):
    """A non-editable install renders a shipped scene by name and finds its configs."""
    # build from a copy of what a source distribution holds, so the checkout stays clean
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("sparse_brdf", "mitsuba_plugin", "scenes"):
        shutil.copytree(ROOT / name, src / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    wheel_dir = tmp_path / "wheel"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "-w", str(wheel_dir), str(src)], capture_output=True, text=True)
    if build.returncode != 0:
        pytest.fail(f"building the wheel failed:\n{build.stderr[-2000:]}")
    (wheel,) = wheel_dir.glob("*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for need in ("sparse_brdf/scenes/sphere.xml", "sparse_brdf/scenes/paper_sphere.xml",
                 "sparse_brdf/scenes/envmaps/studio.exr", "sparse_brdf/data/configs/ci.toml",
                 "mitsuba_plugin/__init__.py",
                 *(f"sparse_brdf/data/ensembles/{i}.npz" for i in shipped_ids())):
        assert need in names, need
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                    str(site), str(wheel)], check=True, capture_output=True)
    work = tmp_path / "work"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    code = ("import sparse_brdf, sparse_brdf.paths as p, sparse_brdf.cli as c; "
            "print(sparse_brdf.__file__); print(p.SCENES_DIR); "
            "c.main(['render', 'sphere.xml', '-o', 'out.exr', '--spp', '1', '--res', '16'])")
    run = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    first, second = run.stdout.splitlines()[:2]
    assert first.startswith(str(site)) and second.startswith(str(site))
    assert (work / "out.exr").stat().st_size > 0
    assert not (work / "scenes").exists()
    shutil.rmtree(site)


# Entry points of scripts: `python -m sparse_brdf.demo` runs demo.main, not the public one.
SCRIPT_ENTRIES = {("main", "sparse_brdf/demo.py")}


def test_every_public_name_is_defined_once():
    """A function or class that the package or a subpackage exports (``__all__``) has one
    definition in the package: no second copy, no wrapper of the same name elsewhere."""
    defined: dict[str, list[str]] = {}
    for p in (ROOT / "sparse_brdf").rglob("*.py"):
        for node in ast.parse(p.read_text()).body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                where = p.relative_to(ROOT).as_posix()
                if (node.name, where) not in SCRIPT_ENTRIES:
                    defined.setdefault(node.name, []).append(where)
    packages = ["sparse_brdf"] + [f"sparse_brdf.{s}" for s in (*SUBPACKAGES, "cli")]
    public = {n for pkg in packages for n in importlib.import_module(pkg).__all__}
    assert len(public) > 80
    twice = {n: defined[n] for n in sorted(public) if len(defined.get(n, [])) > 1}
    assert twice == {}
