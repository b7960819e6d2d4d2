"""Batch commands keep their heap (``imudiag.cli.keep_heap``, issue 14).

``imudiag diagnose`` allocates and frees arrays of megabytes block after block; with
glibc's default (dynamic) thresholds much of that went back to the kernel and came back
as page faults: 0.5-0.6 s of system time on 10^6 frames. Checked here in real
subprocesses: after ``keep_heap`` a freed 32 MiB array stays in the process (resident
memory does not fall), without it the memory is returned; the daemon is not a batch
command.
"""

from __future__ import annotations

import platform
import subprocess
import sys
from pathlib import Path

import pytest

from imudiag.cli import BATCH_COMMANDS, build_parser

ROOT = Path(__file__).resolve().parent.parent

_FREE_AND_MEASURE = """
import sys
import numpy as np
from imudiag.cli import keep_heap
applied = keep_heap() if sys.argv[1] == "keep" else None
def resident_mib():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096 / 2**20
before = resident_mib()
a = np.ones(32 << 17)  # 32 MiB of float64, every page touched
a = None
print(applied, resident_mib() - before)
"""


def _freed(mode: str) -> tuple[str, float]:
    r = subprocess.run(
        [sys.executable, "-c", _FREE_AND_MEASURE, mode],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
    )
    applied, grown = r.stdout.split()
    return applied, float(grown)


def test_batch_commands_are_commands_and_not_the_daemon():
    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    assert set(BATCH_COMMANDS) <= set(sub.choices)
    assert "run" not in BATCH_COMMANDS and "bench" not in BATCH_COMMANDS


@pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
    reason="mallopt thresholds are glibc's (elsewhere keep_heap changes nothing)",
)
def test_freed_blocks_stay_in_the_process():
    applied, kept = _freed("keep")
    assert applied == "True"
    assert kept > 30.0, f"{kept:.1f} MiB still resident after the free"
    applied, returned = _freed("default")
    assert applied == "None"
    assert returned < 2.0, f"{returned:.1f} MiB still resident after the free"
