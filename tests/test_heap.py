"""A batch command keeps freed memory in its heap (imudiag.commands.heap, issue 14): the same
pages are not faulted in again each time arrays of a few MiB are allocated and freed."""

from __future__ import annotations

import subprocess
import sys

import pytest

from imudiag.commands.heap import keep_freed_memory

#: five arrays of 1 MiB at once, freed together, 100 times: glibc's defaults give the
#: heap's top back each time (more than twice the mapping threshold free there)
WORKLOAD = """
import resource, sys
import numpy as np
from imudiag.commands.heap import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(100):
    arrays = [np.ones(1 << 17) for _ in range(5)]
    del arrays
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    out = subprocess.run(
        [sys.executable, "-c", WORKLOAD, mode], capture_output=True, text=True, check=True
    )
    return int(out.stdout.strip())


def test_freed_memory_is_kept_in_the_heap() -> None:
    if not keep_freed_memory():  # this process only; the workload runs in children
        pytest.skip("the C library has no mallopt (not Linux/glibc)")
    default, kept = _faults("default"), _faults("keep")
    # 500 MiB allocated in all: about 128 000 pages faulted in with the defaults
    assert default > 50_000, default
    assert kept < default / 10, (kept, default)
