"""Freed memory kept in the process's heap for a batch command (glibc's ``mallopt``).

By default glibc's malloc maps an allocation above a moving threshold (128 KiB at the
start) fresh from the kernel and unmaps it when freed, and gives the top of its heap
back once more than twice that threshold is free there. A diagnosis allocates and frees
arrays of a few hundred KiB to a few MiB thousands of times (every window fit, every
block of the monitor), so the same pages are faulted in again and again: on the
benchmark's 10^6-frame capture ``imudiag diagnose`` took 214 000 minor page faults and
0.6-1.3 s of system time on the development machine (a virtual machine, where a fault
costs several microseconds), against 27 000 faults and 0.1 s with the freed memory
kept; the peak RSS grew by 4 MB (148 -> 152 MB), the report is byte for byte the same.

For the batch commands only: a daemon that runs for months should give memory back.
"""

from __future__ import annotations

import ctypes
import sys

#: glibc's ``mallopt`` parameter numbers (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: allocations up to this size (bytes) come from the heap, not a fresh mapping: glibc's
#: largest mapping threshold on 64-bit (32 MiB; above it ``mallopt`` refuses)
MMAP_THRESHOLD_BYTES = 32 << 20
#: free memory (bytes) at the top of the heap kept before it is given back
TRIM_THRESHOLD_BYTES = 64 << 20


def keep_freed_memory() -> bool:
    """Make malloc keep freed memory in the heap (thresholds above); True when set.

    False, and nothing changed, where the C library has no ``mallopt`` or refuses the
    values (not Linux, not glibc).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(
        mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
        and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )


__all__ = ["MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "keep_freed_memory"]
