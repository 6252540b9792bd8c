"""Every test can fail: read with ``ast``, each test function asserts something.

A test counts as able to fail when its body (nested functions included) holds an
``assert`` statement, uses ``pytest.raises``, ``pytest.warns`` or ``pytest.fail``, calls a
name that starts with ``assert`` (``np.testing.assert_allclose``, ``self.assertEqual``,
a mock's ``assert_called_once``), or calls or hands on a helper that does one of these,
directly or through other helpers: functions of the test's own module, of
``tests/conftest.py`` and of the other modules of ``tests/`` it imports from. A test that
sleeps and may skip (``time.sleep`` and ``pytest.skip`` in one function) is flagged too:
on a fast or slow machine it skips, and tests nothing.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass, field
from pathlib import Path

TESTS = Path(__file__).resolve().parent

#: The calls of pytest that fail a test by themselves.
FAILING_CALLS = {"pytest.raises", "pytest.warns", "pytest.fail", "pytest.deprecated_call"}


def _dotted(node: ast.AST) -> str | None:
    """``a.b.c`` for a name or an attribute chain, else None."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        head = _dotted(node.value)
        return None if head is None else f"{head}.{node.attr}"
    return None


@dataclass
class _Module:
    """A module's functions (``name`` or ``Class.name``), its imports and aliases."""

    name: str
    functions: dict[str, ast.AST] = field(default_factory=dict)
    imports: dict[str, str] = field(default_factory=dict)  # local name -> full name
    aliases: dict[str, str] = field(default_factory=dict)  # ``fails = cli_fails``
    tests: list[str] = field(default_factory=list)

    @classmethod
    def parse(cls, source: str, name: str) -> _Module:
        mod = cls(name)
        tree = ast.parse(source)
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                mod.functions[node.name] = node
                if node.name.startswith("test"):
                    mod.tests.append(node.name)
            elif isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        mod.functions[f"{node.name}.{item.name}"] = item
                        if node.name.startswith("Test") and item.name.startswith("test"):
                            mod.tests.append(f"{node.name}.{item.name}")
            elif (isinstance(node, ast.Assign) and len(node.targets) == 1
                  and isinstance(node.targets[0], ast.Name)
                  and isinstance(node.value, (ast.Name, ast.Attribute))):
                mod.aliases[node.targets[0].id] = _dotted(node.value) or ""
        for node in ast.walk(tree):  # imports anywhere (tests import inside functions)
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.asname:
                        mod.imports[a.asname] = a.name
                    else:
                        top = a.name.split(".")[0]
                        mod.imports[top] = top
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                for a in node.names:
                    mod.imports[a.asname or a.name] = f"{node.module}.{a.name}"
        return mod

    def full_name(self, dotted: str) -> str:
        """``dotted`` with its first name resolved through the module's aliases and
        imports: ``np.testing.assert_allclose`` -> ``numpy.testing.assert_allclose``."""
        head, _, rest = dotted.partition(".")
        for _ in range(10):  # alias chains
            if head in self.aliases and self.aliases[head] and head not in self.functions:
                target = self.aliases[head]
                head, _, more = target.partition(".")
                rest = ".".join(p for p in (more, rest) if p)
            else:
                break
        if head in self.imports and head not in self.functions:
            head = self.imports[head]
        return ".".join(p for p in (head, rest) if p)


class Checker:
    """The test modules and the helpers they reach, and which of their functions assert."""

    def __init__(self, modules: dict[str, _Module]) -> None:
        self.modules = modules
        self.asserting = self._asserting()

    @classmethod
    def from_sources(cls, sources: dict[str, str]) -> Checker:
        """A checker of ``sources``: module name (``conftest``, ``test_x``) -> source."""
        return cls({name: _Module.parse(src, name) for name, src in sources.items()})

    @classmethod
    def from_folder(cls, folder: Path = TESTS) -> Checker:
        """A checker of every module of ``folder`` (``tests/``)."""
        return cls.from_sources({p.stem: p.read_text() for p in sorted(folder.glob("*.py"))})

    def _references(self, mod: _Module, qualname: str) -> tuple[set[str], set[tuple]]:
        """The full names a function calls, and the known functions it calls or hands on
        (``(module, qualname)``)."""
        node = mod.functions[qualname]
        cls = qualname.rpartition(".")[0]
        calls, helpers = set(), set()
        for sub in ast.walk(node):
            if isinstance(sub, ast.Call):
                dotted = _dotted(sub.func)
                if dotted:
                    calls.add(mod.full_name(dotted))
            dotted = _dotted(sub) if isinstance(sub, (ast.Name, ast.Attribute)) else None
            if dotted is None:
                continue
            if cls and dotted.startswith("self.") and f"{cls}.{dotted[5:]}" in mod.functions:
                helpers.add((mod.name, f"{cls}.{dotted[5:]}"))
                continue
            if dotted in mod.functions and dotted != qualname:
                helpers.add((mod.name, dotted))
                continue
            full = mod.full_name(dotted)
            if full in mod.functions and full != qualname:
                helpers.add((mod.name, full))
                continue
            found = self._function(full)
            if found:
                helpers.add(found)
        return calls, helpers

    def _function(self, full: str) -> tuple[str, str] | None:
        """The known function ``module.name`` stands for, following the names a test
        module imports or aliases from another (``from test_reliability import fails``,
        where ``fails = cli_fails``); None if it is none of them."""
        for _ in range(10):
            owner, _, name = full.rpartition(".")
            mod = self.modules.get(owner)
            if mod is None:
                return None
            if name in mod.functions:
                return owner, name
            if name not in mod.aliases and name not in mod.imports:
                return None
            full = mod.full_name(name)
        return None

    def _asserting(self) -> set[tuple[str, str]]:
        """Every function (``(module, qualname)``) that asserts, itself or through the
        helpers it reaches (a fixed point)."""
        asserting, reaches = set(), {}
        for mod in self.modules.values():
            for qualname, node in mod.functions.items():
                calls, helpers = self._references(mod, qualname)
                key = (mod.name, qualname)
                if (any(isinstance(n, ast.Assert) for n in ast.walk(node))
                        or calls & FAILING_CALLS
                        or any(c.rpartition(".")[2].startswith("assert") for c in calls)):
                    asserting.add(key)
                reaches[key] = helpers
        grew = True
        while grew:
            grew = False
            for key, helpers in reaches.items():
                if key not in asserting and helpers & asserting:
                    asserting.add(key)
                    grew = True
        return asserting

    def tests_that_cannot_fail(self) -> list[str]:
        """``module::test`` (``module::Class::test``) of each test that asserts nothing."""
        return [f"{m.name}.py::{t.replace('.', '::')}" for m in self.modules.values()
                for t in m.tests if (m.name, t) not in self.asserting]

    def tests_that_sleep_and_skip(self) -> list[str]:
        """``module::test`` of each test that calls ``time.sleep`` and ``pytest.skip``:
        a skip that depends on timing."""
        out = []
        for m in self.modules.values():
            for t in m.tests:
                calls, _ = self._references(m, t)
                if "time.sleep" in calls and "pytest.skip" in calls:
                    out.append(f"{m.name}.py::{t.replace('.', '::')}")
        return out


def _checker() -> Checker:
    return Checker.from_folder()


def test_every_test_can_fail():
    checker = _checker()
    assert sum(len(m.tests) for m in checker.modules.values()) > 400  # it finds them
    bad = checker.tests_that_cannot_fail()
    assert not bad, "these tests assert nothing (add the assertion they mean):\n" + \
        "\n".join(bad)


def test_no_test_skips_on_timing():
    bad = _checker().tests_that_sleep_and_skip()
    assert not bad, "these tests sleep and may skip, so on some machines they test " \
        "nothing (synchronise instead):\n" + "\n".join(bad)


def test_the_checker_on_a_synthetic_module():
    conftest = (
        "import pytest\n"
        "def cli_fails(x):\n"
        "    assert x == 2\n"
        "    return x\n")
    source = (
        "import time\n"
        "import numpy as np\n"
        "import pytest\n"
        "from conftest import cli_fails\n"
        "fails = cli_fails\n"
        "def helper(x):\n"
        "    return check(x)\n"
        "def check(x):\n"
        "    np.testing.assert_allclose(x, 1)\n"
        "def quiet(x):\n"
        "    return x + 1\n"
        "def test_nothing():\n"
        "    quiet(1)\n"
        "def test_assert():\n"
        "    assert quiet(1) == 2\n"
        "def test_through_helpers():\n"
        "    helper(1)\n"
        "def test_through_conftest():\n"
        "    fails(2)\n"
        "def test_raises():\n"
        "    with pytest.raises(ValueError):\n"
        "        int('x')\n"
        "def test_sleeps_then_skips():\n"
        "    time.sleep(1)\n"
        "    if quiet(1):\n"
        "        pytest.skip('too fast')\n"
        "    assert True\n"
        "class TestThings:\n"
        "    def _ok(self):\n"
        "        self.assertEqual(1, 1)\n"
        "    def test_method(self):\n"
        "        self._ok()\n"
        "    def test_quiet_method(self):\n"
        "        quiet(2)\n")
    other = (  # a helper imported from another test module, under that module's alias
        "from test_x import fails\n"
        "from test_x import quiet as q\n"
        "def test_through_another_module():\n"
        "    fails(2)\n"
        "def test_quiet_import():\n"
        "    q(2)\n")
    checker = Checker.from_sources({"conftest": conftest, "test_x": source, "test_y": other})
    assert checker.tests_that_cannot_fail() == ["test_x.py::test_nothing",
                                                "test_x.py::TestThings::test_quiet_method",
                                                "test_y.py::test_quiet_import"]
    assert checker.tests_that_sleep_and_skip() == ["test_x.py::test_sleeps_then_skips"]
