"""The style gates, a CI step of their own (before the tests): ``ruff check``, ``ruff format
--check`` and ``mypy -p imudiag``, each run plainly from the repository root, as a developer
runs them. Exit 0 when all three pass, else 1 after running all three.

``mypy -p imudiag`` finds ``imudiag.drivers`` and ``imudiag.config`` (installed from the
top-level ``drivers/`` and ``config/``, pyproject's package-dir) through the symbolic links
``imudiag/drivers`` and ``imudiag/config``, so it works on an editable install too.

Usage: ``python .ci/style.py`` (the interpreter of the venv that has the [test] extra).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

GATES: list[tuple[str, list[str]]] = [
    ("ruff check", ["-m", "ruff", "check", "--no-cache", "."]),
    ("ruff format --check", ["-m", "ruff", "format", "--check", "--no-cache", "."]),
    ("mypy -p imudiag", ["-m", "mypy", "-p", "imudiag"]),
]


def main() -> int:
    failed = []
    for name, args in GATES:
        start = time.monotonic()
        r = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True)
        took = time.monotonic() - start
        verdict = "ok" if r.returncode == 0 else f"FAILED (exit {r.returncode})"
        print(f"style: {name}: {verdict} ({took:.1f} s wall)", flush=True)
        if r.returncode != 0:
            failed.append(name)
            sys.stdout.write(r.stdout[-20000:])
            sys.stderr.write(r.stderr[-5000:])
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
