"""Declared parameters and the one check of a value against its declaration.

Every choice and range a user can set (transforms, selectors, fills, bases, decoders,
layouts, sampling, taus, dictionary counts, grid sides, render settings) is declared once,
beside the code that uses it, as a :class:`Choice` or an :class:`Interval` (the spirit of
scikit-learn's ``_parameter_constraints``): e.g. ``encode.PARAMETERS``,
``train.PARAMETERS``, ``render.RENDER_PARAMETERS``. The library checks its inputs with
:func:`check` (or :func:`check_choice`, :func:`check_range`), which raises
:class:`~sparse_brdf.errors.UsageError` naming the parameter, the value and what is
allowed; the command line builds its choices, argument types and defaults from the same
declarations and from the library functions' signatures.

>>> check("fill", "missing", Choice(("missing", "invalid")))
'missing'
>>> check("tau", 0, Interval(int, 1))
Traceback (most recent call last):
...
sparse_brdf.errors.UsageError: tau must be an integer >= 1, got 0
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Integral, Real

from .errors import SparseBRDFError, UsageError

__all__ = ["SEED", "Choice", "Interval", "check", "check_all", "check_choice", "check_range"]


@dataclass(frozen=True)
class Choice:
    """One of a fixed tuple of ``values`` (strings or numbers), compared with ``==``."""

    values: tuple

    def __contains__(self, value: object) -> bool:
        if isinstance(value, bool) or not isinstance(value, (str, Real)):
            return False  # an array, a list, None: never a choice
        return value in self.values

    def describe(self) -> str:
        """``one of a, b, c``."""
        return "one of " + ", ".join(map(str, self.values))


def _number(x: float | None) -> str:
    """A bound as written: integers in full (1458000, not 1.458e+06), others with %g."""
    if x is not None and float(x).is_integer() and abs(x) < 1e16:
        return str(int(x))
    return f"{x:g}" if x is not None else ""


#: Which ends of an :class:`Interval` belong to it: (lo, hi).
_CLOSED = {"both": (True, True), "left": (True, False), "right": (False, True),
           "neither": (False, False)}


@dataclass(frozen=True)
class Interval:
    """A finite number of type ``kind`` (``int`` or ``float``) between ``lo`` and ``hi``
    (None: unbounded); ``closed`` says which ends belong to it: "both" [lo, hi], "left"
    [lo, hi), "right" (lo, hi], "neither" (lo, hi). Booleans are refused; an ``int``
    interval takes integral floats (``3.0``) too, as numpy gives them."""

    kind: type
    lo: float | None = None
    hi: float | None = None
    closed: str = "both"

    def __post_init__(self) -> None:
        if self.kind not in (int, float) or self.closed not in _CLOSED:
            raise TypeError(f"Interval({self.kind!r}, closed={self.closed!r}): kind must be "
                            f"int or float, closed one of {', '.join(_CLOSED)}")

    def __contains__(self, value: object) -> bool:
        if isinstance(value, bool) or not isinstance(value, Real):
            return False
        if not math.isfinite(float(value)):
            return False
        if self.kind is int and not (isinstance(value, Integral) or float(value).is_integer()):
            return False
        lo_in, hi_in = _CLOSED[self.closed]
        if self.lo is not None and (value < self.lo or (not lo_in and value == self.lo)):
            return False
        if self.hi is not None and (value > self.hi or (not hi_in and value == self.hi)):
            return False
        return True

    def describe(self) -> str:
        """``an integer >= 1``, ``in [0, 1)``, ``> 0``, ...: what follows "must be"."""
        lo_in, hi_in = _CLOSED[self.closed]
        what = "an integer " if self.kind is int else ""
        lo, hi = _number(self.lo), _number(self.hi)
        if self.lo is None and self.hi is None:
            return "an integer" if self.kind is int else "a finite number"
        if self.hi is None:
            return f"{what}{'>=' if lo_in else '>'} {lo}"
        if self.lo is None:
            return f"{what}{'<=' if hi_in else '<'} {hi}"
        return f"{what}in {'[' if lo_in else '('}{lo}, {hi}{']' if hi_in else ')'}"

    def capped(self, hi: float) -> Interval:
        """This interval with its upper end lowered to ``hi`` (e.g. a grid's entries)."""
        return Interval(self.kind, self.lo, hi if self.hi is None else min(self.hi, hi),
                        self.closed)

    def parse(self, text: str, name: str = "value") -> int | float:
        """``text`` (a command-line word) as a checked number of this interval."""
        try:
            value = int(text) if self.kind is int else float(text)
        except ValueError:
            raise UsageError(f"{name}: expected {'an integer' if self.kind is int else 'a number'}"
                             f", got {text!r}") from None
        return check(name, value, self)


#: Every seed a user gives (trainer, renders, bench): 32 bits, as Mitsuba's samplers take.
SEED = Interval(int, 0, (1 << 32) - 1)

#: What a parameter may be declared as: a :class:`Choice`, an :class:`Interval`, or a plain
#: tuple (read as a Choice).
Constraint = Choice | Interval | tuple


def _as_constraint(constraint: Constraint) -> Choice | Interval:
    return Choice(tuple(constraint)) if isinstance(constraint, tuple) else constraint


def check(name: str, value, constraint: Constraint,
          error: type[SparseBRDFError] = UsageError):
    """``value`` if it satisfies ``constraint``, else ``error`` (default
    :class:`~sparse_brdf.errors.UsageError`) naming ``name``, the value and what is allowed.

    Parameters
    ----------
    name : str
        The parameter as the user wrote it (``"transform"``, ``"--taus"``,
        ``"sparse_brdf: decoder"``); it starts the message.
    value : object
        The value given.
    constraint : Choice, Interval or tuple
        The declaration (a tuple is a :class:`Choice`).
    error : subclass of SparseBRDFError
        The exception raised (e.g. :class:`~sparse_brdf.errors.PluginError` in the plugin,
        :class:`~sparse_brdf.errors.ConfigError` for a bench config).

    Returns
    -------
    object
        ``value`` unchanged; an ``int`` interval returns it as an ``int``.
    """
    c = _as_constraint(constraint)
    if value in c:
        return int(value) if isinstance(c, Interval) and c.kind is int else value
    if isinstance(c, Choice):
        raise error(f"unknown {name} {value!r}: expected {c.describe()}")
    raise error(f"{name} must be {c.describe()}, got {value!r}")


def check_choice(name: str, value, choices: tuple | Choice,
                 error: type[SparseBRDFError] = UsageError):
    """``value`` if it is one of ``choices``, else ``error`` ("unknown NAME VALUE:
    expected one of ...")."""
    return check(name, value, choices if isinstance(choices, Choice) else Choice(choices), error)


def check_range(name: str, value, lo: float | None = None, hi: float | None = None,
                integer: bool = False, closed: str = "both",
                error: type[SparseBRDFError] = UsageError):
    """``value`` if it is a finite number (an integer with ``integer``) in [lo, hi]
    (``closed``: see :class:`Interval`), else ``error`` ("NAME must be ..., got VALUE")."""
    return check(name, value, Interval(int if integer else float, lo, hi, closed), error)


def check_all(constraints: Mapping[str, Constraint], values: Mapping[str, object],
              error: type[SparseBRDFError] = UsageError) -> None:
    """Check each of ``values`` whose name has a declaration in ``constraints`` (None
    values are skipped: they stand for a default resolved elsewhere)."""
    for name, value in values.items():
        if name in constraints and value is not None:
            check(name, value, constraints[name], error)
