"""The one validator of configuration values: type and range checks that name the key.

Every reader of settings (a diagnosis configuration, the daemon's YAML file, a
bench scenario, a simulator scenario's parameters, a certificate) checks a value
with these functions. ``where`` is the key path (``"diagnosis.prior_factor"``):
the error is :class:`~imudiag.errors.BadInput` reading ``"<key>: <reason>"``; or
a callable that turns the reason into the reader's own error (one that also
names the file and line, e.g. ``ConfigError``).

Numbers accept any real (``int``, ``float``, numpy scalars), never ``bool``;
integers any integral value, never ``bool`` nor ``2.0``.

This module imports nothing from imudiag but :mod:`imudiag.errors` and
:mod:`imudiag.argtypes` (ground floor).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from typing import Any

from .argtypes import rate_problem
from .errors import BadInput

#: Turns a reason into the exception to raise.
Fail = Callable[[str], Exception]


def failing(where: str | Fail) -> Fail:
    """The error maker of ``where``: a key path gives ``BadInput("<key>: <reason>")``."""
    if callable(where):
        return where
    return lambda reason: BadInput(f"{where}: {reason}")


def is_number(value: Any) -> bool:
    """True for a real number that is not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def range_text(lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> str:
    """The interval ``[lo, hi]`` written with open ends as ``(`` / ``)``."""
    return f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def number(
    value: Any,
    where: str | Fail,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    unit: str = "",
) -> float:
    """``value`` as a finite float within ``lo`` .. ``hi`` (ends closed unless open), in
    ``unit`` (named in the reason)."""
    fail = failing(where)
    if not is_number(value):
        raise fail(f"expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:  # an integer beyond the float range
        raise fail("not a finite number: integer beyond the float range") from None
    if not math.isfinite(v):
        raise fail(f"not a finite number: {v!r}")
    if v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
        within = range_text(lo, hi, lo_open, hi_open)
        raise fail(f"{v!r} is out of range {within} {unit}".rstrip())
    return v


def sample_rate(value: Any, where: str | Fail) -> float:
    """``value`` as an IMU's sample rate, Hz (:func:`imudiag.argtypes.rate_problem`)."""
    rate = number(value, where)
    problem = rate_problem(rate)
    if problem:
        raise failing(where)(problem)
    return rate


def integer(value: Any, where: str | Fail, lo: int = 0, hi: int | None = None) -> int:
    """``value`` as an int within ``lo`` .. ``hi`` (no upper end when ``hi`` is None)."""
    fail = failing(where)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise fail(f"expected an integer, got {value!r}")
    v = int(value)
    if v < lo or (hi is not None and v > hi):
        top = "inf" if hi is None else str(hi)
        raise fail(f"{v!r} is out of range [{lo}, {top}]")
    return v


def boolean(value: Any, where: str | Fail) -> bool:
    """``value`` when it is ``True`` or ``False``."""
    if not isinstance(value, bool):
        raise failing(where)(f"expected true or false, got {value!r}")
    return value


def text(value: Any, where: str | Fail, choices: Sequence[str] = ()) -> str:
    """``value`` as a non-empty stripped string, one of ``choices`` when given."""
    fail = failing(where)
    if not isinstance(value, str) or not value.strip():
        raise fail(f"expected a non-empty string, got {value!r}")
    v = value.strip()
    if choices and v not in choices:
        raise fail(f"expected one of {', '.join(choices)}, got {v!r}")
    return v


def unknown_keys(keys: Any, known: Sequence[str], where: Callable[[str], Fail]) -> None:
    """Refuse the first of ``keys`` not in ``known``; ``where(key)`` makes its error."""
    for k in keys:
        if k not in known:
            raise where(str(k))(f"unknown key; known: {', '.join(known)}")


__all__ = [
    "Fail",
    "boolean",
    "failing",
    "integer",
    "is_number",
    "number",
    "range_text",
    "sample_rate",
    "text",
    "unknown_keys",
]
