"""CPU time and resident memory of a process, read from Linux ``/proc``.

Used by the live-daemon benchmark (a subprocess) and by the memory checks.
"""

from __future__ import annotations

import os

_TICKS_PER_S = os.sysconf("SC_CLK_TCK")
_PAGE_BYTES = os.sysconf("SC_PAGE_SIZE")


def cpu_seconds(pid: int | str = "self") -> float:
    """User + system CPU time consumed so far by process ``pid``, seconds."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
        text = fh.read()
    # the command name (field 2) may hold spaces: split after its closing parenthesis
    fields = text[text.rindex(")") + 2 :].split()
    utime, stime = int(fields[11]), int(fields[12])
    return (utime + stime) / _TICKS_PER_S


def rss_bytes(pid: int | str = "self") -> int:
    """Resident set size of process ``pid`` now, bytes (``/proc/PID/statm``)."""
    with open(f"/proc/{pid}/statm", encoding="ascii") as fh:
        return int(fh.read().split()[1]) * _PAGE_BYTES


def peak_rss_bytes(pid: int | str = "self") -> int:
    """Peak resident set size (VmHWM) of process ``pid`` so far, bytes."""
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    raise OSError(f"/proc/{pid}/status has no VmHWM line")


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        return os.cpu_count() or 1
