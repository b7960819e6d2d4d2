"""The whole test suite in three steps (README "Quick start", what ``.ci/run`` runs):

1. style: ``ruff check``, ``ruff format --check``, ``mypy -p imudiag`` (``.ci/style.py``);
2. deterministic tier: every test not marked ``realtime``, on 2 workers, each test file on
   one worker so its module fixtures are made once (``pytest -m "not realtime" -n 2
   --dist loadfile``; tests/conftest.py states the rule);
3. real-time tier: the tests marked ``realtime`` (ptys, daemon processes, signals, the
   bench, gpsd), serially, after the deterministic tier.

Bytecode: the steps run without ``PYTHONDONTWRITEBYTECODE`` (removed from their
environment where it is set), so each module is compiled once and its ``__pycache__``
(git-ignored) reused: the tests start hundreds of ``python -m imudiag`` processes, and each
compiled imudiag's sources again (about 0.3-0.5 s a start on the 2-core machine), pytest
rewrote every test module's asserts in every worker (12 s of each tier's collection), and
``.ci/run`` installs the venv with ``pip --no-compile`` (70 s less install) because the
modules the tests import are compiled on first use here.

BLAS threads: the steps run with one BLAS/OpenMP thread per process (``OPENBLAS_NUM_THREADS``,
``OMP_NUM_THREADS``, ``MKL_NUM_THREADS`` = 1 unless already set): the deterministic tier
already runs one worker per core, and numpy's OpenBLAS started its own thread per core
in each, whose spinning doubled the cost of a dot product of 7 10^4 samples on the
loaded 2-core machine (the model check's Allan curves: 43 s against 60 s for two of its
tests). Results are those of a single-threaded BLAS (the frozen reports hold to 1e-9).

Warm-up beside the style gates: mypy runs on one core, so while it runs a
``pytest --collect-only`` of the deterministic tier (output discarded, its exit status
ignored: the tier reports its own collection errors) imports every test module once on the
other core, which writes the rewritten test modules and imudiag's bytecode. In a fresh
clone each of the tier's two workers otherwise rewrote and compiled all of them itself
(about 12 s of collection each on the 2-core machine, against 3.5 s warm). Beside it the
optional compiled kernels (numba, :mod:`imudiag.kernels`) are compiled once into numba's
cache (``imudiag/__pycache__``, git-ignored), the exact fit's kernels and the others in two
processes: in a fresh clone the first test of each tier worker that used them compiled
them itself (48 s of CPU, and both workers at once), where a developer's later runs load
them from the cache (about 1.4 s). Each warm-up process's end is printed after the style
step (the tiers wait for all of them). mypy checks with two worker processes
(``num_workers`` in pyproject.toml).

Every step runs, whatever the one before gave; the exit status is 0 only when all three
passed. Each step's wall time is printed (a figure, not a bound). Extra arguments are
passed to both pytest runs (e.g. ``-x``, ``-k bench``).

Usage: ``python .ci/suite.py [PYTEST ARGS]`` with the interpreter of the venv that has the
[test] extra; ``--workers N`` changes the deterministic tier's 2 workers.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WORKERS = 2  #: pytest-xdist workers of the deterministic tier (the CI machine has 2 cores)
#: the steps' environment: this one without PYTHONDONTWRITEBYTECODE, one BLAS thread a
#: process unless set (module docstring)
ENV = {
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    **{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"},
}


#: the warm-up beside the style gates (module docstring): its processes' arguments after the
#: interpreter, their output discarded and their exit status ignored (the tiers report their
#: own errors)
WARM_UP = {
    # every test module imported once: rewritten test modules and imudiag's bytecode written
    "collection": [
        "-m",
        "pytest",
        "-q",
        "--collect-only",
        "-m",
        "not realtime",
        "-p",
        "no:cacheprovider",
    ],
    # the compiled kernels (numba's cache in imudiag/__pycache__): a fresh clone compiles
    # them once here instead of in each tier worker whose tests use them, in two processes
    # side by side of about the same compile time (numba compiles on one core): the exact
    # fit's chain, 23 s, and the rest, 25 s (it was the fits' 30 s against the streams' 12)
    "kernels (exact fit)": ["-c", "from imudiag import numba_kernels as k; k.warm_up(0)"],
    "kernels (the rest)": ["-c", "from imudiag import numba_kernels as k; k.warm_up(1)"],
}


def _step(name: str, argv: list[str]) -> tuple[str, int, float]:
    print(f"== {name}: {' '.join(argv[1:])}", flush=True)
    start = time.monotonic()
    code = subprocess.run(argv, cwd=ROOT, env=ENV).returncode
    took = time.monotonic() - start
    print(f"== {name}: {'passed' if code == 0 else f'FAILED (exit {code})'} in {took:.0f} s")
    return name, code, took


def main(argv: list[str]) -> int:
    workers = WORKERS
    if "--workers" in argv:
        i = argv.index("--workers")
        workers = int(argv[i + 1])
        del argv[i : i + 2]
    py = sys.executable
    # the warm-up (module docstring): started before the style gates, awaited after them
    started = time.monotonic()
    warm = {
        name: subprocess.Popen(
            [py, *args], cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        for name, args in WARM_UP.items()
    }
    style = _step("style", [py, str(ROOT / ".ci" / "style.py")])
    for name, proc in warm.items():
        proc.wait()
        print(f"== warm-up: {name} done {time.monotonic() - started:.0f} s after the start")
    steps = [
        style,
        _step(
            "deterministic tier",
            [
                py,
                "-m",
                "pytest",
                "-q",
                "-m",
                "not realtime",
                "-n",
                str(workers),
                "--dist",
                "loadfile",
                *argv,
            ],
        ),
        _step(
            "real-time tier", [py, "-m", "pytest", "-q", "-m", "realtime", "-p", "no:xdist", *argv]
        ),
    ]
    print(
        "== suite: "
        + ", ".join(f"{n} {'ok' if c == 0 else 'FAILED'} ({t:.0f} s)" for n, c, t in steps)
    )
    return 0 if all(c == 0 for _, c, _ in steps) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
