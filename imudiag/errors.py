"""The one exception family of imudiag, and the exit status of each member.

Every error imudiag raises on purpose derives from :class:`ImudiagError`; the
command line maps an error to its exit status with :func:`exit_code` and
nowhere else (spec/reports.md: 0 done whatever the verdict, 2 bad input,
1 anything else). Members also derive from the built-in class callers caught
before the family existed (``ValueError``, ``OSError``, ``RuntimeError``), so
existing ``except ValueError`` clauses keep working.

This module imports nothing from imudiag: any layer, the wire codec
included, may raise these.
"""

from __future__ import annotations

EXIT_OK = 0  #: done, whatever the verdict
EXIT_ERROR = 1  #: anything else (a bench that could not run, an internal error)
EXIT_BAD_INPUT = 2  #: bad input: the message names file, line or key, and why


class ImudiagError(Exception):
    """Base of every error imudiag raises on purpose."""

    exit_code: int = EXIT_ERROR


class BadInput(ImudiagError, ValueError):
    """Bad input given to a command: the message names the file, line or key, and why."""

    exit_code = EXIT_BAD_INPUT


class CertificateError(BadInput):
    """A calibration certificate that breaks a rule (see :mod:`imudiag.certificate`)."""


class SourceError(ImudiagError, OSError):
    """A sample source cannot be opened or has gone away (bad URL, device unplugged)."""

    exit_code = EXIT_BAD_INPUT


class DeviceError(SourceError):
    """The device behind a source failed: missing, permission denied, unplugged."""


class SinkError(ImudiagError, OSError):
    """A status output (file, serial or socket link) cannot be opened or written."""


class BenchError(ImudiagError, RuntimeError):
    """A bench run that could not be carried out (daemon died, board stalled)."""

    exit_code = EXIT_ERROR


def exit_code(exc: BaseException) -> int:
    """The exit status of the command line for ``exc`` (1 for anything outside the family)."""
    if isinstance(exc, ImudiagError):
        return exc.exit_code
    return EXIT_ERROR


__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_ERROR",
    "EXIT_OK",
    "BadInput",
    "BenchError",
    "CertificateError",
    "DeviceError",
    "ImudiagError",
    "SinkError",
    "SourceError",
    "exit_code",
]
