"""Argument types of the command line: every option value is checked when it is parsed.

Each factory returns an ``argparse`` ``type=`` callable that converts the text
or raises :class:`argparse.ArgumentTypeError`; argparse then names the option,
and :mod:`imudiag.cli` prints that as one line and exits 2 (bad input) before
the command runs. The same rules hold for every command: a rate of 0, -5, nan
or inf, a negative duration, a seed that is not an integer >= 0, an output in
a directory that does not exist or cannot be written are all refused here.

This module imports nothing from imudiag (ground floor).
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path

#: Largest seed accepted (numpy's generators take any integer >= 0; this keeps it a uint64).
MAX_SEED = 2**64 - 1
#: The sample rates an IMU log can have, Hz: from 0.5 Hz (below the 1 Hz at which PX4
#: logs its raw sensor topics by default) to 100 kHz (above the fastest MEMS output data
#: rates, 32 kHz). A stated rate, a log's ``sample_rate`` and the rate its time stamps
#: show are refused outside it: 1e9 Hz is a typing slip, and each buffer sized in seconds
#: of samples (the still detector's windows) grows with it; 0.2 Hz is a t column in ms
#: read as seconds (a 200 Hz log).
MIN_RATE_HZ = 0.5
MAX_RATE_HZ = 100_000.0


def rate_problem(rate_hz: float) -> str | None:
    """Why ``rate_hz`` cannot be an IMU's sample rate (outside :data:`MIN_RATE_HZ` ..
    :data:`MAX_RATE_HZ`, or not a finite number), or None when it can."""
    if not (math.isfinite(rate_hz) and MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ):
        return (
            f"{rate_hz:g} Hz is not an IMU's sample rate "
            f"(expected {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz)"
        )
    return None


def _number(text: str, unit: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number ({unit}), got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number ({unit}), got {text!r}")
    return value


def _named(func: Callable, name: str) -> Callable:
    func.__name__ = name  # argparse's own messages name the type by it
    return func


def finite_float(unit: str) -> Callable[[str], float]:
    """A finite number in ``unit`` (nan and inf refused)."""
    return _named(lambda text: _number(text, unit), "finite_float")


def positive_float(unit: str, above: float = 0.0) -> Callable[[str], float]:
    """A finite number in ``unit`` greater than ``above`` (default 0)."""

    def convert(text: str) -> float:
        value = _number(text, unit)
        if not value > above:
            raise argparse.ArgumentTypeError(f"must be > {above:g} {unit}, got {text!r}")
        return value

    return _named(convert, "positive_float")


def sample_rate(text: str) -> float:
    """An IMU's sample rate in Hz: :data:`MIN_RATE_HZ` to :data:`MAX_RATE_HZ`."""
    value = _number(text, "Hz")
    problem = rate_problem(value)
    if problem:
        raise argparse.ArgumentTypeError(f"got {text!r}: {problem}")
    return value


def nonnegative_float(unit: str) -> Callable[[str], float]:
    """A finite number in ``unit``, 0 or more."""

    def convert(text: str) -> float:
        value = _number(text, unit)
        if value < 0:
            raise argparse.ArgumentTypeError(f"must be >= 0 {unit}, got {text!r}")
        return value

    return _named(convert, "nonnegative_float")


def _integer(text: str, what: str) -> int:
    try:
        return int(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer ({what}), got {text!r}") from None


def positive_int(what: str, minimum: int = 1) -> Callable[[str], int]:
    """An integer count of ``what``, at least ``minimum`` (default 1)."""

    def convert(text: str) -> int:
        value = _integer(text, what)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum} ({what}), got {text!r}")
        return value

    return _named(convert, "positive_int")


def nonnegative_int(what: str) -> Callable[[str], int]:
    """An integer ``what`` (an index, a number), 0 or more."""
    return _named(positive_int(what, minimum=0), "nonnegative_int")


def seed(text: str) -> int:
    """A random seed: an integer from 0 to 2**64 - 1."""
    value = _integer(text, "a random seed")
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer from 0 to 2**64-1, got {text!r}")
    return value


def _check_directory(directory: Path, what: str) -> None:
    """ArgumentTypeError ``cannot write WHAT: REASON`` unless files can be made in it."""
    reason = None
    if not directory.exists():
        reason = f"directory {str(directory)!r} does not exist"
    elif not directory.is_dir():
        reason = f"{str(directory)!r} is not a directory"
    elif not os.access(directory, os.W_OK | os.X_OK):
        reason = f"directory {str(directory)!r} is not writable"
    if reason:
        raise argparse.ArgumentTypeError(f"cannot write {what}: {reason}")


def writable_output_path(stdout: bool = False) -> Callable[[str], str]:
    """A file to write: its directory exists and is writable, and it is not a directory.

    ``-`` (standard output) is accepted when ``stdout`` is true.
    """

    def convert(text: str) -> str:
        if text == "-" and stdout:
            return text
        if not text:
            raise argparse.ArgumentTypeError("empty file name")
        path = Path(text).expanduser()
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"cannot write {text!r}: a directory, not a file")
        _check_directory(path.parent, repr(text))
        return text

    convert.writes_file = True  # type: ignore[attr-defined]  # found by output_dests
    return _named(convert, "writable_output_path")


def writable_directory(text: str) -> str:
    """A directory to write files into: an existing writable one, or a new one (made with its
    parents) below an existing writable directory."""
    if not text:
        raise argparse.ArgumentTypeError("empty directory name")
    path = Path(text).expanduser().absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    _check_directory(path, f"into {text!r}")
    return text


def named_paths(args: argparse.Namespace, keys: tuple[str, ...]) -> list[tuple[str, str | None]]:
    """The paths a command was given under ``keys`` (argparse dests), each with the name the
    user typed it as (``LOG``, ``--like``, ...), for :func:`imudiag.atomic.refuse_overwrite`."""
    return [
        (
            k.upper()
            if k in ("log", "input", "output")
            else {"scenario_file": "--scenario"}.get(k, "--" + k.replace("_", "-")),
            getattr(args, k, None),
        )
        for k in keys
    ]


def output_dests(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[str, ...]:
    """The dests of every option of the command ``args`` ran (its subcommand, and the action
    of a command with actions) whose type is :func:`writable_output_path`: each file a
    command writes, found from its parser so that none can be left out of the check that no
    two outputs, and no output and input, name one file
    (:func:`imudiag.atomic.refuse_overwrite`)."""
    found: list[str] = []
    stack = [parser]
    while stack:
        p = stack.pop()
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                chosen = action.choices.get(getattr(args, action.dest, None) or "")
                if chosen is not None:
                    stack.append(chosen)
            elif getattr(action.type, "writes_file", False) and action.dest not in found:
                found.append(action.dest)
    return tuple(found)


__all__ = [
    "MAX_RATE_HZ",
    "MAX_SEED",
    "MIN_RATE_HZ",
    "finite_float",
    "named_paths",
    "nonnegative_float",
    "output_dests",
    "nonnegative_int",
    "positive_float",
    "positive_int",
    "rate_problem",
    "sample_rate",
    "seed",
    "writable_directory",
    "writable_output_path",
]
