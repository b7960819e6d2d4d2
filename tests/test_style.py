"""Style gates of issue 12 item 16, run by the suite (and so by .ci/run): the whole tree is
`ruff check` clean and `ruff format` clean (ruff is in the [test] extra)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _ruff(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ruff", *args, "."],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_ruff_check_is_clean():
    r = _ruff("check", "--no-cache")
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_format_is_clean():
    r = _ruff("format", "--check", "--no-cache")
    assert r.returncode == 0, "ruff format would change:\n" + r.stdout + r.stderr


def test_mypy_is_clean(tmp_path):
    """`mypy -p imudiag` on the package as it is installed: drivers/ is imudiag.drivers and
    config/ is imudiag.config (pyproject's package-dir), staged here with symbolic links."""
    stage = tmp_path / "stage" / "imudiag"
    stage.mkdir(parents=True)
    for entry in (ROOT / "imudiag").iterdir():
        if entry.name != "__pycache__":
            (stage / entry.name).symlink_to(entry)
    (stage / "drivers").symlink_to(ROOT / "drivers")
    (stage / "config").symlink_to(ROOT / "config")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "-p",
            "imudiag",
            "--config-file",
            str(ROOT / "pyproject.toml"),
            "--cache-dir",
            str(tmp_path / "cache"),
        ],
        cwd=stage.parent,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout[-5000:] + r.stderr[-2000:]
    assert "no issues found" in r.stdout
