"""Shared fixtures: the bundled certificate, the test data folders, the CLI; the two tiers.

Two tiers (README "Tests"). A test is **deterministic** unless it is marked ``realtime``:
no wall-clock bound, no real-time process, so it runs in parallel (``-n 2``) and gives the
same verdict on a loaded machine. A test that runs real-time processes is marked
``realtime`` (a module-level ``pytestmark = pytest.mark.realtime``, or
``@pytest.mark.realtime`` on the test in a mixed module): ptys, daemon subprocesses
(``imudiag run`` that runs), signals sent to processes, the bench, gpsd, paced sources
(``speed`` > 0) and threads timed on the wall clock. Its timing is still judged on sample
time or events; a wall-clock figure goes to ``benchmarks/`` (printed, never asserted).

The rule is enforced: in a test without the marker, opening a pty, sending a signal to a
process or starting gpsd/gpsfake fails the test with a message saying to mark it.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import pytest

from imudiag.certificate import Certificate, load_default

DATA_DIR = Path(__file__).parent / "data"
REAL_DATA_DIR = DATA_DIR / "real"
PROJECT_DIR = Path(__file__).parent.parent


@pytest.fixture
def default_certificate() -> Certificate:
    """A fresh copy of the simulated board's certificate (safe to modify)."""
    return load_default()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """tests/data: files the tests read (never write here)."""
    return DATA_DIR


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """tests/data/real: copies of real IMU recordings, one folder each with SOURCE.md."""
    return REAL_DATA_DIR


def run_imudiag(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """Run ``python -m imudiag ARGS`` in a real subprocess; returns its exit code and output."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run(
        [sys.executable, "-m", "imudiag", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=PROJECT_DIR,
        env=env,
        check=False,
    )


def run_imudiag_in_process(*args: str) -> subprocess.CompletedProcess[str]:
    """``imudiag ARGS`` as :func:`run_imudiag` reports it, run by the command's own entry
    point (:func:`imudiag.cli.main`) in this process, from the project directory: exit
    status, stdout and stderr as text (argparse's exit as its status). For a parametrized
    check of what a command writes or refuses, beside one real subprocess run per
    behaviour (the CLI is the contract): a subprocess costs an interpreter start and the
    command's imports (about 0.3 s on the 2-core machine). The signal handlers the command
    installs are put back; the compiled kernels are on or off as a new process would have
    them (``IMUDIAG_KERNELS``), whatever an earlier test in this worker chose."""
    from imudiag import kernels
    from imudiag.cli import main

    out, err = io.StringIO(), io.StringIO()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    fresh = os.environ.get("IMUDIAG_KERNELS", "").strip().lower() == "numba"
    try:
        with (
            contextlib.chdir(PROJECT_DIR),
            redirect_stdout(out),
            redirect_stderr(err),
            kernels.switched(fresh),
        ):
            try:
                code = main(list(args))
            except SystemExit as exc:  # argparse: --help, --version, a bad option
                code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    return subprocess.CompletedProcess(["imudiag", *args], code, out.getvalue(), err.getvalue())


_WITHOUT = """
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name == {module!r} or name.startswith({module!r} + "."):
            raise ImportError("blocked for the test: " + name)
sys.meta_path.insert(0, Block())
sys.argv = ["imudiag", *{args!r}]
from imudiag.cli import main
sys.exit(main())
"""


def run_imudiag_without(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``imudiag ARGS`` in a real subprocess in which ``module`` cannot be imported (an
    optional extra that is not installed)."""
    code = _WITHOUT.format(module=module, args=list(args))
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )


@pytest.fixture
def imudiag_cli():
    """The :func:`run_imudiag` helper: ``imudiag_cli("convert", a, b).returncode``."""
    return run_imudiag


@pytest.fixture
def imudiag_in_process():
    """The :func:`run_imudiag_in_process` helper, for the cases of a behaviour that one real
    subprocess run already covers."""
    return run_imudiag_in_process


#: programs that are real-time processes whatever their arguments
_REALTIME_PROGRAMS = ("gpsd", "gpsfake")


def _refuse(what: str) -> None:
    pytest.fail(
        f"{what} in a deterministic test: a real-time process; mark the test (or its module) "
        "with pytest.mark.realtime (tests/conftest.py states the rule)",
        pytrace=False,
    )


@pytest.fixture(autouse=True)
def _deterministic_tier_guard(request: pytest.FixtureRequest) -> Iterator[None]:
    """Keep the tiers honest: a test without the ``realtime`` marker may not open a pty,
    send a signal to a process or start gpsd (the deterministic tier runs in parallel and
    must give the same verdict however loaded the machine is)."""
    if request.node.get_closest_marker("realtime") is not None:
        yield
        return
    mp = pytest.MonkeyPatch()
    popen_init = subprocess.Popen.__init__

    def openpty() -> tuple[int, int]:
        _refuse("os.openpty()")
        raise AssertionError  # not reached

    def kill(pid: int, sig: int) -> None:
        _refuse(f"os.kill({pid}, {sig})")

    def killpg(pgid: int, sig: int) -> None:
        _refuse(f"os.killpg({pgid}, {sig})")

    def popen(self: subprocess.Popen[Any], args: Any, *a: Any, **kw: Any) -> None:
        argv = [args] if isinstance(args, str | bytes | os.PathLike) else list(args)
        program = os.path.basename(os.fsdecode(argv[0])) if argv else ""
        if program in _REALTIME_PROGRAMS:
            _refuse(f"starting {program}")
        popen_init(self, args, *a, **kw)

    mp.setattr(os, "openpty", openpty)
    mp.setattr(os, "kill", kill)
    mp.setattr(os, "killpg", killpg)
    mp.setattr(subprocess.Popen, "__init__", popen)
    try:
        yield
    finally:
        mp.undo()
