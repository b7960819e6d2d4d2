"""A fleet worker's malloc (issue 28, :mod:`imudiag.fleet.allocator`): under Dask's nanny
setting (``MALLOC_TRIM_THRESHOLD_=65536``) every large array a diagnosis frees is given back
and the next faults its pages in again; after the worker's warm-up they are reused, and a
worker holding more than its mark gives them back after a log. Real processes (the
environment variable is read by glibc at start), page faults counted by ``getrusage``."""

from __future__ import annotations

import json
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    platform.libc_ver()[0] != "glibc", reason="glibc's malloc only (this C library is not glibc)"
)

PROBE = r"""
import json, resource, sys
import numpy as np
from imudiag.fleet import allocator

kept = allocator.keep_freed_memory() if sys.argv[1] == "keep" else None
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
np.ones(10)  # numpy's own first allocations
before = faults()
for _ in range(100):  # a block's largest array, 65536 x 13 floats, made and freed
    a = np.ones((65536, 13))
    del a
during = faults() - before
big = allocator.resident_bytes()
gave = allocator.release_freed_memory(above_bytes=0)
after = allocator.resident_bytes()
print(json.dumps({"kept": kept, "faults": during, "gave": gave, "rss": [big, after]}))
"""


def probe(mode: str) -> dict:
    env = {"MALLOC_TRIM_THRESHOLD_": "65536", "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20)}
    out = subprocess.run(
        [sys.executable, "-c", PROBE, mode], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(out.stdout)


def test_freed_arrays_are_reused_after_the_warm_up_and_given_back_past_the_mark():
    dask_like = probe("dask")
    kept = probe("keep")
    pages = 65536 * 13 * 8 // 4096
    # under the workers' environment (Dask's trimming) the arrays fault their pages in again
    # and again (about a third of each, in runs of this probe: 4 000 to 61 000 faults)
    assert dask_like["faults"] >= 2 * pages, dask_like
    # kept: part of the first array's pages, then none
    assert kept["kept"] is True
    assert kept["faults"] <= pages, kept
    assert dask_like["faults"] >= 5 * kept["faults"]
    # past the mark (0 here) the free heap goes back to the system
    assert kept["gave"] is True
    assert kept["rss"][1] < kept["rss"][0]


def test_below_the_mark_nothing_is_given_back():
    from imudiag.fleet.allocator import release_freed_memory

    assert release_freed_memory(above_bytes=1 << 60) is False
