"""The public API (``sparse_brdf.__all__``) documents itself the numpydoc way: every
function and public method that takes arguments has a Parameters section naming each of
them, every one that returns something has a Returns section, and every class says what
it holds."""

from __future__ import annotations

import inspect
import re

import sparse_brdf as sb

SECTION = re.compile(r"^(\w[\w ]*)\n-{3,}\n", re.MULTILINE)


def _sections(doc: str) -> dict[str, str]:
    """Section title -> body of a numpydoc docstring."""
    marks = list(SECTION.finditer(doc))
    return {m.group(1): doc[m.end(): marks[i + 1].start() if i + 1 < len(marks) else None]
            for i, m in enumerate(marks)}


def _documented_names(body: str) -> set[str]:
    """Names an entry line of a Parameters section declares (``a, b : type``, ``**kw``)."""
    names = set()
    for line in body.splitlines():
        if line and not line[0].isspace():
            head = line.split(" : ")[0]
            names |= {n.strip().lstrip("*") for n in head.split(",")}
    return names


def _public_callables():
    for name in sb.__all__:
        obj = getattr(sb, name)
        if inspect.isclass(obj):
            for attr, value in vars(obj).items():
                if attr.startswith("_"):
                    continue
                func = value.__func__ if isinstance(value, (classmethod, staticmethod)) else value
                if inspect.isfunction(func):
                    yield f"{name}.{attr}", func
        elif inspect.isfunction(obj):
            yield name, obj


def test_the_api_is_large_enough_to_check():
    assert len(list(_public_callables())) > 30


def test_public_callables_have_numpydoc_sections():
    bad = []
    for name, func in _public_callables():
        doc = inspect.getdoc(func) or ""
        sections = _sections(doc)
        sig = inspect.signature(func)
        params = [p for p in sig.parameters if p not in ("self", "cls")]
        if params:
            missing = set(params) - _documented_names(sections.get("Parameters", ""))
            if "Parameters" not in sections:
                bad.append(f"{name}: no Parameters section")
            elif missing:
                bad.append(f"{name}: Parameters does not name {sorted(missing)}")
        returns = sig.return_annotation
        if returns not in (None, "None", inspect.Signature.empty) and "Returns" not in sections:
            bad.append(f"{name}: no Returns section")
    assert bad == []


def test_public_classes_say_what_they_hold():
    bad = []
    for name in sb.__all__:
        obj = getattr(sb, name)
        if inspect.isclass(obj):
            doc = inspect.getdoc(obj) or ""
            if not doc or doc == inspect.getdoc(obj.__mro__[1]):
                bad.append(f"{name}: no docstring of its own")
            elif not issubclass(obj, BaseException) and "Attributes" not in _sections(doc):
                bad.append(f"{name}: no Attributes section")
    assert bad == []
