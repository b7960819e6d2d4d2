"""The ``imudiag`` command line: one subcommand per module of ``imudiag.commands``.

Each command module defines ``register(subparsers)`` that adds its parser and
sets ``func`` to a callable ``(args) -> int``. Exit status (spec/reports.md):
0 done whatever the verdict, 2 bad input (the message names file, line or
key, and the reason), 1 anything else; an error of the
:class:`~imudiag.errors.ImudiagError` family maps to its status through
:func:`imudiag.errors.exit_code`, here and nowhere else. Every module listed
in :data:`COMMANDS` must import: a command that fails to load is an error,
never a silently missing subcommand. ``imudiag COMMAND ...`` imports that command's
module only (start-up of ``imudiag diagnose``: issue 14); ``imudiag --help`` and an
unknown command build the parser of them all.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence
from typing import NoReturn, cast

from . import __version__
from .errors import EXIT_BAD_INPUT, EXIT_ERROR, EXIT_OK, ImudiagError, exit_code

#: Subcommand modules in ``imudiag.commands``, in the order ``--help`` lists them.
COMMANDS = (
    "run",
    "diagnose",
    "calibrate",
    "model_check",
    "simulate",
    "allan",
    "bench",
    "convert",
    "certificate",
    "fleet",
)

__all__ = ["COMMANDS", "EXIT_BAD_INPUT", "EXIT_ERROR", "EXIT_OK", "build_parser", "main"]
EXIT_SIGINT = 130  #: 128 + SIGINT, as a shell reports Ctrl-C
EXIT_SIGTERM = 143  #: 128 + SIGTERM


#: environment variables that size the BLAS thread pools numpy starts on import
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """One BLAS thread for this process unless the environment says otherwise (before numpy
    is imported; no effect after). imudiag's matrices are small ((N, 3) by (3, 3)), where
    a pool of threads only spins: ``imudiag diagnose`` on 10^6 frames took 10.2-10.9 s
    with OpenBLAS's default threads on a loaded 2-core machine against 6.4-6.6 s with one
    (docs/benchmarks.md)."""
    if "numpy" in sys.modules:
        return
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


#: commands that read a recording through and exit: their heap is kept (:func:`keep_heap`)
BATCH_COMMANDS = ("diagnose", "calibrate", "model-check", "allan", "convert", "simulate")
#: glibc ``mallopt`` parameters (malloc.h) and the values :func:`keep_heap` sets, bytes
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
BATCH_MMAP_THRESHOLD = 64 << 20
BATCH_TRIM_THRESHOLD = 512 << 20


def keep_heap() -> bool:
    """For a batch command on glibc: blocks of up to 64 MiB come from the heap and freed
    memory stays in the process until it exits (``mallopt``), so the arrays of each block
    of samples (megabytes, freed and allocated again block after block) stop costing a
    ``mmap``, a ``munmap`` and a page fault per 4 KiB every time. ``imudiag diagnose`` on
    10^6 frames: 0.5-0.6 s of system time -> 0.1 s, the same peak resident memory
    (docs/benchmarks.md). Not for the daemon, which must give memory back. True when set;
    False where the C library has no ``mallopt`` (musl, macOS): nothing changes there."""
    import ctypes

    try:
        # the process's own symbols, libc's among them: ctypes.util.find_library("c") would
        # import subprocess and run ldconfig -p for the same handle (issue 14: start-up)
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(
        mallopt(M_MMAP_THRESHOLD, BATCH_MMAP_THRESHOLD)
        and mallopt(M_TRIM_THRESHOLD, BATCH_TRIM_THRESHOLD)
    )


class Terminated(KeyboardInterrupt):
    """SIGTERM during a command: unwinds like Ctrl-C (temporary files removed), exit 143."""


def _on_signal(signum: int, frame: object) -> None:
    # one signal ends the command: a second must not cut its clean-up short
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if signum == signal.SIGTERM:
        raise Terminated()
    raise KeyboardInterrupt()


class OneLineErrorParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line naming the option, exit 2 (bad input)."""

    def error(self, message: str) -> NoReturn:
        """Print ``PROG: error: MESSAGE (see PROG --help)`` and exit 2."""
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def command_module(argv: Sequence[str]) -> str | None:
    """The module in :data:`COMMANDS` of the subcommand ``argv`` names (its first word, as
    ``imudiag COMMAND ...`` takes no option before the command but --help/--version), or None
    (no such command: the full parser lists them)."""
    names = {module.replace("_", "-"): module for module in COMMANDS}
    return names.get(argv[0]) if argv else None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser with every available subcommand, or with the one of module
    ``only`` (imports nothing of the others: ``imudiag diagnose`` starts without the
    daemon's, the simulator's or the model check's modules). Subparsers are of the same
    class: a bad option value is one line, exit 2, before any command runs."""
    parser = OneLineErrorParser(
        prog="imudiag",
        description="Onboard IMU monitor and scalar diagnosis (Avrutov 2015).",
    )
    parser.add_argument("--version", action="version", version=f"imudiag {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS if only is None else (only,):
        # every command is part of the build: one that fails to import is an error to see,
        # never a command silently missing from --help
        importlib.import_module(f"imudiag.commands.{name}").register(sub)
    return parser


def _subparser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The parser of subcommand ``command`` (the top one when there is none)."""
    for action in parser._actions:  # argparse keeps its subparsers only there
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return cast(argparse.ArgumentParser, action.choices[command])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``imudiag`` console script."""
    single_threaded_blas()
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(command_module(args_list))
    args, extra = parser.parse_known_args(args_list)
    if extra:  # named by the command's own parser: "imudiag COMMAND: error: ... (see ...)"
        sub = _subparser(parser, getattr(args, "command", None))
        sub.error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    from .argtypes import named_paths, output_dests
    from .atomic import refuse_overwrite

    if args.command in BATCH_COMMANDS:
        keep_heap()
    if args.command != "run":  # the daemon handles its own signals (exit 0 on SIGTERM)
        signal.signal(signal.SIGTERM, _on_signal)
        signal.signal(signal.SIGINT, _on_signal)

    # the words naming the command in messages: a command with actions sets ``command_name``
    name = getattr(args, "command_name", None) or args.command
    # every file option of the command: those it declares and each of type writable_output_path
    declared = tuple(getattr(args, "outputs", ()))
    outputs = declared + tuple(d for d in output_dests(parser, args) if d not in declared)
    try:
        refuse_overwrite(named_paths(args, getattr(args, "inputs", ())), named_paths(args, outputs))
        return int(args.func(args) or 0)
    except ImudiagError as exc:
        print(f"imudiag {name}: error: {exc}", file=sys.stderr)
        return exit_code(exc)
    except Terminated:
        print(
            f"imudiag {name}: terminated (SIGTERM); nothing half-written left",
            file=sys.stderr,
        )
        return EXIT_SIGTERM
    except KeyboardInterrupt:
        if args.command == "run":
            return EXIT_OK
        print(f"imudiag {name}: interrupted; nothing half-written left", file=sys.stderr)
        return EXIT_SIGINT
    except BrokenPipeError:
        return EXIT_OK
