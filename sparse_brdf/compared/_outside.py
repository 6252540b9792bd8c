"""Models from outside the package: a ``module:Class[:KEY=VALUE,...]`` spec, imported.

The module is imported as Python imports it (``PYTHONPATH``, installed packages), with
the current directory searched last, so that ``sparse-brdf bench`` run beside a
``mymodels.py`` finds it; the class is built with the spec's options as keyword
arguments and must follow the compared-model protocol
(:class:`~sparse_brdf.compared.protocol.ComparedModel`). Every failure (no such module, a
module that raises on import, no such class, a constructor that refuses the options, an
object that does not follow the protocol) is a :class:`~sparse_brdf.errors.UsageError`
of one line naming the spec. A bench that runs on a Dask cluster needs the module
importable on the workers too.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
from collections.abc import Iterator

from ..errors import UsageError, one_line
from .protocol import check_model

__all__ = ["load_outside_model", "parse_value"]


def parse_value(text: str):
    """An option's value as the spec writes it: an integer, a float, ``true``/``false``,
    else the text itself (a string)."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        with contextlib.suppress(ValueError):
            return kind(text)
    return text.strip()


@contextlib.contextmanager
def _current_directory_on_path() -> Iterator[None]:
    """The current directory searched last while importing (as ``python -m`` would search
    it, but after the installed packages, so that it shadows none)."""
    cwd = os.getcwd()
    added = cwd not in sys.path
    if added:
        sys.path.append(cwd)
    try:
        yield
    finally:
        if added:
            with contextlib.suppress(ValueError):
                sys.path.remove(cwd)


def load_outside_model(module: str, cls: str, options: dict, spec: str):
    """Import ``module``, build ``cls(**options)`` and check it follows the protocol.

    Parameters
    ----------
    module, cls : str
        A dotted module name and a class name in it.
    options : dict
        Keyword arguments of the constructor.
    spec : str
        The spec as written, for messages.

    Returns
    -------
    ComparedModel
        The unfitted model.

    Raises
    ------
    UsageError
        One line naming ``spec`` and the problem.
    """
    where = f"model {spec!r}"
    with _current_directory_on_path():
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
                raise UsageError(f"{where}: no module named {exc.name!r} on the Python path "
                                 "or in the current directory") from None
            raise UsageError(f"{where}: importing {module} failed: {one_line(exc)}") from None
        except Exception as exc:  # noqa: BLE001 - the user's module: any error is reported
            raise UsageError(f"{where}: importing {module} failed: {type(exc).__name__}: "
                             f"{one_line(exc)}") from None
    obj = getattr(mod, cls, None)
    if obj is None:
        raise UsageError(f"{where}: module {module} has no class {cls}")
    if not isinstance(obj, type):
        raise UsageError(f"{where}: {module}.{cls} is a {type(obj).__name__}, not a class")
    try:
        model = obj(**options)
    except Exception as exc:  # noqa: BLE001 - the user's constructor: any error is reported
        args = ", ".join(f"{k}={v!r}" for k, v in options.items())
        raise UsageError(f"{where}: {cls}({args}) failed: {type(exc).__name__}: "
                         f"{one_line(exc)}") from None
    problem = check_model(model)
    if problem:
        raise UsageError(f"{where}: {module}.{cls} does not follow the compared-model "
                         f"protocol (docs/bench-guide.md): {problem}")
    return model
