"""``imudiag COMMAND`` imports only that command's module (issue 14: start-up of `diagnose`).

Checked in real subprocesses running the console entry point, which list ``sys.modules`` at
exit on standard error (``-X importtime`` does not see ``importlib.import_module``):
``imudiag diagnose`` imports no other command module and none of the daemon's, simulator's,
model check's or GNSS aiding's packages; every command still has its full parser
(``--help``), ``imudiag --help`` lists them all, and an unknown command is still one line,
exit 2.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from imudiag.certificate import load_default
from imudiag.cli import BLAS_THREAD_VARIABLES, COMMANDS
from imudiag.logs import open_writer
from imudiag.sim import simulate, still

ROOT = Path(__file__).resolve().parent.parent
#: packages `imudiag diagnose` (no --gnss, no --plots) has no use for
NOT_FOR_DIAGNOSE = (
    "imudiag.service",
    "imudiag.sim",
    "imudiag.modelcheck",
    "imudiag.aiding",
    "imudiag.bench",
    "imudiag.interop",
    "imudiag.diagnosis.calibrate",  # calibrate_recording imports it
    "imudiag.diagnosis.holdout",
)
#: standard modules `imudiag diagnose` (no --gnss, no --plots) has no use for: secrets (the
#: temporary name of an atomic write is os.urandom's), ctypes.util and the subprocess it
#: imports and runs (keep_heap finds mallopt among the process's own symbols)
STDLIB_NOT_FOR_DIAGNOSE = frozenset({"secrets", "hmac", "ctypes.util", "subprocess"})
#: what importing the diagnose command alone leaves out (importlib.resources: only for the
#: bundled certificate; a run still imports it through importlib.metadata, for log plug-ins)
NOT_ON_IMPORT = (*NOT_FOR_DIAGNOSE, "importlib.resources", *STDLIB_NOT_FOR_DIAGNOSE)


_LIST_AT_EXIT = """
import atexit, sys
import os
atexit.register(lambda: sys.stderr.write("MODULES " + " ".join(sorted(sys.modules)) + "\\n"))
blas = lambda: os.environ.get("OPENBLAS_NUM_THREADS", "-")  # noqa: E731
atexit.register(lambda: sys.stderr.write("BLAS " + blas() + "\\n"))
sys.argv = ["imudiag", *{args!r}]
from imudiag.cli import main
sys.exit(main())
"""


def imported_modules(
    *args: str, blas_threads: str | None = None
) -> tuple[subprocess.CompletedProcess[str], set[str]]:
    """Run ``imudiag ARGS`` in a subprocess (``OPENBLAS_NUM_THREADS``: ``blas_threads``, or
    unset); (the process, the modules loaded at its exit)."""
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    if blas_threads is not None:
        env["OPENBLAS_NUM_THREADS"] = blas_threads
    proc = subprocess.run(
        [sys.executable, "-c", _LIST_AT_EXIT.format(args=list(args))],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=120,
        check=False,
    )
    listed = [line for line in proc.stderr.splitlines() if line.startswith("MODULES ")]
    assert len(listed) == 1, proc.stderr[-2000:]
    return proc, set(listed[0].split()[1:])


@pytest.fixture(scope="module")
def still_log(tmp_path_factory) -> Path:
    """20 s of the default board lying still (200 Hz, seeded) as .npz."""
    sim = simulate(load_default(), still(20.0, rate_hz=200.0), seed=4)
    path = tmp_path_factory.mktemp("lazy") / "still.npz"
    with open_writer(path, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(sim.samples)
    return path


def test_diagnose_imports_no_other_command(still_log, tmp_path):
    out = tmp_path / "report.json"
    proc, names = imported_modules("diagnose", str(still_log), "--json", str(out), "-q")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert out.exists()
    assert "imudiag.commands.diagnose" in names and "imudiag.diagnosis.session" in names
    others = {f"imudiag.commands.{m}" for m in COMMANDS if m not in ("diagnose",)}
    # diagnose shares its --gnss and --certificate-noise options with helper modules
    assert not (names & others), sorted(names & others)
    heavy = sorted(n for n in names if n.startswith(NOT_FOR_DIAGNOSE))
    assert not heavy, heavy
    assert not (names & STDLIB_NOT_FOR_DIAGNOSE), sorted(names & STDLIB_NOT_FOR_DIAGNOSE)


def test_importing_diagnose_leaves_out_what_it_does_not_use():
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, imudiag.commands.diagnose; print(' '.join(sorted(sys.modules)))",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        check=True,
    )
    names = set(proc.stdout.split())
    assert "imudiag.diagnosis.session" in names and "yaml" in names
    unused = sorted(n for n in names if n.startswith(NOT_ON_IMPORT))
    assert not unused, unused


@pytest.mark.parametrize("module", COMMANDS)
def test_every_command_has_its_parser(module):
    name = module.replace("_", "-")
    proc, names = imported_modules(name, "--help")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith(f"usage: imudiag {name} ")
    assert f"imudiag.commands.{module}" in names


def test_help_lists_every_command_and_a_bad_one_is_one_line():
    proc, names = imported_modules("--help")
    assert proc.returncode == 0
    for module in COMMANDS:
        assert module.replace("_", "-") in proc.stdout
        assert f"imudiag.commands.{module}" in names
    proc, _ = imported_modules("model_check", "--help")  # the module's name is not a command
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if not line.startswith(("MODULES", "BLAS"))]
    assert len(errors) == 1 and "invalid choice: 'model_check'" in errors[0]
    assert "model-check" in errors[0]  # the full list of commands


def blas_threads_at_exit(proc: subprocess.CompletedProcess[str]) -> str:
    """The ``OPENBLAS_NUM_THREADS`` the process had at its exit ('-': unset)."""
    return [ln for ln in proc.stderr.splitlines() if ln.startswith("BLAS ")][0].split()[1]


def test_one_blas_thread_unless_the_environment_says(still_log):
    """numpy's BLAS pool only spins on imudiag's (N, 3) by (3, 3) products: the command line
    asks for one thread before numpy is imported, and keeps what the user set."""
    proc, names = imported_modules("diagnose", str(still_log), "-q")
    assert proc.returncode == 0 and "numpy" in names
    assert blas_threads_at_exit(proc) == "1"
    proc, _ = imported_modules("diagnose", str(still_log), "-q", blas_threads="2")
    assert proc.returncode == 0
    assert blas_threads_at_exit(proc) == "2"
