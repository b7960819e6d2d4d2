"""The switch of the optional compiled kernels (numba, the ``fleet`` extra; issue 28).

The kernels themselves are in :mod:`imudiag.numba_kernels` (module-level, so numba's disk
cache serves every later process: about 1 s of CPU to load them against 11-20 s to compile):
the window fits (the exact fit after its set-up in one call, :mod:`imudiag.diagnosis.
scalar_fit`; the rotation fit's products, wrapped by :mod:`imudiag.diagnosis.kernels`), the
GNSS epoch cut of the moving-base diagnosis
(:meth:`imudiag.aiding.specific_force.ImuSeries.epochs`), the still detector's rows, rate
band, variance, jump and drift tests and trailing spreads (:mod:`imudiag.quasistatic`), the
prefix sums of :class:`imudiag.trailing.PrefixSums` (the detector's and the monitor's), the
vibration meter's high-pass, the stuck check's scan and the noise judge's second
differences (bit for bit); with them on, the CSV reader reads numbers with pyarrow's
parser where pyarrow is installed (:mod:`imudiag.logs.arrow_csv`, bit for bit). This
switch sits on the ground floor (tests/test_layout.py) so that every floor that has a kernel
can ask it.

The plain numpy paths stay the reference and the default. :func:`enable` switches the
kernels on in this process where numba is installed, :func:`switched` in one thread for a
block: a fleet task runs its diagnosis inside ``switched(True)`` (the JIT compile, or the
load of numba's on-disk cache, paid once by the worker's first task in its warm-up, outside
that log's CPU figure, :func:`load`), so a process that calls the task itself keeps its own
choice; ``imudiag diagnose`` and the daemon keep the plain loops unless
``IMUDIAG_KERNELS=numba`` is set in the environment.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from typing import Any

#: "on": None until the first :func:`enabled` reads ``IMUDIAG_KERNELS``; "error": why the
#: kernels could not be loaded (None: not tried, or loaded)
_STATE: dict[str, Any] = {"on": None, "loaded": False, "error": None}
#: the compiled functions by name (:func:`imudiag.numba_kernels.warm_up`)
_KERNELS: dict[str, Callable[..., Any]] = {}


def available() -> bool:
    """Whether numba can be imported here (the ``fleet`` extra installs it)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def load() -> bool:
    """Compile the kernels (or load them from numba's cache) and run each once, without
    switching them on; whether they can be used (without numba, or when that failed,
    :func:`status` says why). Cheap after the first call."""
    if not _STATE["loaded"] and _STATE["error"] is None:
        try:
            from . import numba_kernels

            _KERNELS.update(numba_kernels.warm_up())
            _STATE["loaded"] = True
        except Exception as exc:  # noqa: BLE001 - no numba, or a failed compile: plain loops
            _STATE["error"] = f"{type(exc).__name__}: {exc}"
    return bool(_STATE["loaded"])


def enable(on: bool = True) -> bool:
    """Use the compiled kernels in this process from now on (``on``, after :func:`load`), or
    the plain loops; returns whether the kernels are in use."""
    _STATE["on"] = bool(on) and load()
    return bool(_STATE["on"])


#: a thread's own choice (:func:`switched`), over the process's
_LOCAL = threading.local()


@contextlib.contextmanager
def switched(on: bool) -> Iterator[bool]:
    """The kernels on (where :func:`load` can) or off in this thread for the ``with`` block,
    whatever the process's choice, restored after (a fleet task: the caller's process and
    other tasks' threads keep theirs); yields whether they are on."""
    before = getattr(_LOCAL, "on", None)
    _LOCAL.on = bool(on) and load()
    try:
        yield _LOCAL.on
    finally:
        _LOCAL.on = before


def enabled() -> bool:
    """Whether the compiled kernels are in use in this thread: its :func:`switched` block,
    else the process's :func:`enable` (the first call switches them on when
    ``IMUDIAG_KERNELS=numba`` is set in the environment)."""
    local = getattr(_LOCAL, "on", None)
    if local is not None:
        return bool(local)
    if _STATE["on"] is None:
        _STATE["on"] = False
        if os.environ.get("IMUDIAG_KERNELS", "").strip().lower() == "numba":
            enable(True)
    return bool(_STATE["on"])


def kernel(name: str) -> Callable[..., Any] | None:
    """The compiled function ``name`` (:func:`imudiag.numba_kernels.warm_up`) when the
    kernels are in use in this thread, else None (the caller runs its plain path)."""
    return _KERNELS.get(name) if enabled() else None


def status() -> str:
    """``numba`` when the kernels are in use, else ``plain`` and why."""
    if enabled():
        return "numba"
    return "plain" + (f" ({_STATE['error']})" if _STATE["error"] else "")


__all__ = ["available", "enable", "enabled", "kernel", "load", "status", "switched"]
