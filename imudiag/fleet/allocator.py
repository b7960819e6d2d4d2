"""glibc's malloc in a fleet worker (issue 28): arrays reused, not mapped anew, during a log;
freed memory given back between logs.

A diagnosis allocates and frees arrays of 0.1-7 MB per block of 65536 samples, a few hundred
per block. Under glibc's defaults, or Dask's nanny setting ``MALLOC_TRIM_THRESHOLD_=65536``
(so that a worker gives freed memory back), each such array is mapped anew or its pages
returned to the system when it is freed, and the next one faults its pages in again (zeroed
by the kernel): on a 10^6-sample board log about 1.5x10^5 page faults and a fifth of the
task's CPU (docs/benchmarks.md). :func:`keep_freed_memory` (a worker's warm-up) keeps freed
memory in the heap for the next array; :func:`release_freed_memory` (the end of each log)
gives it back where the worker holds more than :data:`RELEASE_ABOVE_BYTES` (below that,
the next log reuses it without faulting it in again), so a worker's memory limit sees no more
than a log's own peak.

Both act through glibc's ``mallopt`` and ``malloc_trim`` (ctypes); on another C library they
do nothing and say so (False).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import platform
import resource
from typing import Any

#: The largest allocation taken from the heap rather than mapped on its own, bytes: glibc's
#: own ceiling for its sliding threshold (32 MiB; a block's largest array is about 7 MB).
MMAP_THRESHOLD_BYTES = 32 * 2**20
#: Free memory at the heap's top kept for the next allocation during a log, bytes (the
#: worker's memory limit, 2 GiB by default, bounds a log's peak anyway).
TRIM_THRESHOLD_BYTES = 2**30
#: Resident memory above which a worker gives its free heap back after a log, bytes: a
#: diagnosis reads its log in blocks, so what one keeps (about 0.1-0.2 GB) is reused by the
#: next; only a worker grown beyond this (a log read whole, a large GNSS track) trims.
RELEASE_ABOVE_BYTES = 512 * 2**20
#: ``mallopt`` parameters (glibc's malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3


@functools.lru_cache(maxsize=1)
def _glibc() -> Any | None:
    """glibc as a ctypes library, or None (another C library, or none found)."""
    if platform.libc_ver()[0] != "glibc":
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None
    if not (hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim")):
        return None
    libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    libc.mallopt.restype = ctypes.c_int
    libc.malloc_trim.argtypes = [ctypes.c_size_t]
    libc.malloc_trim.restype = ctypes.c_int
    return libc


def keep_freed_memory() -> bool:
    """Keep freed memory in this process's heap for the next allocation (arrays up to
    :data:`MMAP_THRESHOLD_BYTES` from the heap, its top trimmed only beyond
    :data:`TRIM_THRESHOLD_BYTES`); whether glibc took both settings."""
    libc = _glibc()
    if libc is None:
        return False
    mmap_ok = libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
    trim_ok = libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
    return mmap_ok and trim_ok


def resident_bytes() -> int | None:
    """This process's resident memory now, bytes (``/proc/self/statm``; None where absent)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            pages = int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return pages * resource.getpagesize()


def release_freed_memory(above_bytes: int = RELEASE_ABOVE_BYTES) -> bool:
    """Give the heap's free memory back to the system (``malloc_trim(0)``: its top and the
    free pages within it) when this process holds more than ``above_bytes`` resident (the
    next log reuses what it keeps below that, without faulting it in again); whether glibc
    gave any back (False: below the mark, nothing to give, or not glibc)."""
    libc = _glibc()
    if libc is None:
        return False
    rss = resident_bytes()
    if rss is not None and rss <= above_bytes:
        return False
    return bool(libc.malloc_trim(0))


__all__ = [
    "MMAP_THRESHOLD_BYTES",
    "RELEASE_ABOVE_BYTES",
    "TRIM_THRESHOLD_BYTES",
    "keep_freed_memory",
    "release_freed_memory",
    "resident_bytes",
]
