"""Allowed ranges of configuration values, declared beside each config dataclass.

Each config class lists its numeric fields' limits in `LIMITS` and its flag prefix in
`FLAG_PREFIX`, is decorated `@validated` (under `@dataclass`) and calls `check_limits(self)`
from its `validate`, so a value from a preset or a checkpoint's saved config is checked where
it enters. The command line parses with the checks deferred (`deferred_checks`) and then runs
`validate_tree` itself, so a bad flag is one line naming it, not a traceback or a tyro box:

    LIMITS: ClassVar[dict[str, Limit]] = {"lr": above(0), "gamma": between(0, 1, lo_open=True)}

A violation raises ValueError naming the flag, the value and what is allowed:
`--ppo.lr = -0.001 is not allowed: give a finite number > 0`. NaN and infinities are refused
for every limited field, and so is an integer too large for a float. Tuples are checked element
by element; None is refused unless the field is optional. Strings, booleans and Literals are
not limited here: tyro checks them on the command line and `learner.config._from_dict` in a saved
file. `tests/learner/test_config_errors.py` holds every numeric field of `RunConfig` to having one.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import math
import types
import typing
from dataclasses import dataclass


@dataclass(frozen=True)
class Limit:
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    """Only used in the message: "an integer" instead of "a finite number"."""

    def allows(self, x: float) -> bool:
        if not math.isfinite(x):
            return False
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            return False
        return not (self.hi is not None and (x >= self.hi if self.hi_open else x > self.hi))

    def describe(self) -> str:
        kind = "an integer" if self.integer else "a finite number"
        lo, hi = _bound(self.lo), _bound(self.hi)
        if self.lo is not None and self.hi is not None:
            return f"{kind} in {'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"
        if self.lo is not None:
            return f"{kind} {'>' if self.lo_open else '>='} {lo}"
        if self.hi is not None:
            return f"{kind} {'<' if self.hi_open else '<='} {hi}"
        return kind


def _bound(x: float | None) -> str:
    """A limit's bound as written: whole numbers in full (4294967295, not 4.29497e+09)."""
    if x is None:
        return ""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def at_least(lo: float, integer: bool = True) -> Limit:
    return Limit(lo=lo, integer=integer)


def above(lo: float) -> Limit:
    return Limit(lo=lo, lo_open=True)


def between(lo: float, hi: float, lo_open: bool = False, hi_open: bool = False, integer: bool = False) -> Limit:
    return Limit(lo, hi, lo_open, hi_open, integer)


FINITE = Limit()
SEED = between(0, 2**32 - 1, integer=True)
"""A random seed: numpy's generators refuse negative seeds, torch's manual_seed overflows past 2^64."""
PORT = between(0, 65535, integer=True)
"""A TCP/UDP port (0: the system picks a free one)."""


def flag(prefix: str, name: str) -> str:
    """The command-line flag of a field: `--ppo.kl-stop`."""
    return "--" + (prefix + "." if prefix else "") + name.replace("_", "-")


@functools.cache
def _tuple_fields(cls: type) -> frozenset[str]:
    """Fields of a config class declared as tuples (the others take one value)."""
    hints = typing.get_type_hints(cls)
    return frozenset(f.name for f in dataclasses.fields(cls) if typing.get_origin(hints[f.name]) is tuple)


@functools.cache
def _int_fields(cls: type) -> frozenset[str]:
    """Fields of a config class declared int (alone, optional or in a tuple): a saved config or
    a `--set` may hold 2.5 there, which no flag parser would have let through."""
    hints = typing.get_type_hints(cls)

    def ints(h) -> bool:
        args = [a for a in typing.get_args(h) if a is not type(None) and a is not Ellipsis]
        return h is int or (bool(args) and all(ints(a) for a in args))

    return frozenset(f.name for f in dataclasses.fields(cls) if ints(hints[f.name]))


@functools.cache
def _optional_fields(cls: type) -> frozenset[str]:
    """Fields of a config class that may hold None (`X | None`)."""
    hints = typing.get_type_hints(cls)
    return frozenset(f.name for f in dataclasses.fields(cls) if type(None) in typing.get_args(hints[f.name]))


def check_limits(obj) -> None:
    """ValueError naming the first field of `obj` outside its `LIMITS` entry (or holding a list
    where one value belongs, or one value where a list does)."""
    prefix = getattr(obj, "FLAG_PREFIX", "")
    tuples, ints = _tuple_fields(type(obj)), _int_fields(type(obj))
    for name, limit in obj.LIMITS.items():
        if name in ints:
            limit = dataclasses.replace(limit, integer=True)
        value = getattr(obj, name)
        if value is None and name in _optional_fields(type(obj)):
            continue
        many = name in tuples
        if isinstance(value, (tuple, list)) != many:
            raise ValueError(f"{flag(prefix, name)} = {value!r} is not allowed: give "
                             f"{'a list of values, each ' if many else 'one value, '}{limit.describe()}")
        for x in value if many else (value,):
            if (isinstance(x, bool) or not isinstance(x, int if name in ints else (int, float))
                    or not limit.allows(_as_float(x))):
                each = " each" if many else ""
                raise ValueError(f"{flag(prefix, name)} = {value!r} is not allowed: give{each} {limit.describe()}")


def _as_float(x: int | float) -> float:
    """`float(x)`, or NaN (refused by every limit) for an integer too large for a float."""
    try:
        return float(x)
    except OverflowError:
        return math.nan


def _numeric(hint) -> bool:
    """int or float (not bool), an optional one, or a tuple of them."""
    args = [a for a in typing.get_args(hint) if a is not type(None) and a is not Ellipsis]
    if typing.get_origin(hint) in (tuple, typing.Union, types.UnionType):
        return bool(args) and all(_numeric(a) for a in args)
    return hint in (int, float)


def unlimited_numeric_fields(cls: type) -> list[str]:
    """Numeric fields of a config class (int, float, optional or tuples of them) without a
    LIMITS entry."""
    hints = typing.get_type_hints(cls)
    limits = getattr(cls, "LIMITS", {})
    return [f.name for f in dataclasses.fields(cls) if _numeric(hints[f.name]) and f.name not in limits]


_DEFERRED = contextvars.ContextVar("morphmimic_deferred_config_checks", default=False)


def validated(cls: type) -> type:
    """Class decorator (place it under `@dataclass`): construction runs `cls.validate` unless
    inside `deferred_checks()`."""

    def __post_init__(self) -> None:
        if not _DEFERRED.get():
            self.validate()

    cls.__post_init__ = __post_init__
    return cls


@contextlib.contextmanager
def deferred_checks():
    """Build configs without validating them (a parser building nested dataclasses)."""
    token = _DEFERRED.set(True)
    try:
        yield
    finally:
        _DEFERRED.reset(token)


def validate_tree(cfg) -> None:
    """Validate a config and every config nested in it, innermost first (the ValueError of the
    first bad value)."""
    for f in dataclasses.fields(cfg):
        child = getattr(cfg, f.name)
        if dataclasses.is_dataclass(child) and not isinstance(child, type):
            validate_tree(child)
    if hasattr(cfg, "validate"):
        cfg.validate()
