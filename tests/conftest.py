"""Shared fixtures: the bundled certificate, the test data folders, the CLI."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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
