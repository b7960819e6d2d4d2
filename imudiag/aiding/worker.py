"""One batch at a time, off the caller's thread: the daemon's aiding batches.

:class:`BatchWorker` runs ``fn(job)`` for the jobs handed to :meth:`BatchWorker.submit`
in a single thread it owns (``threaded=True``), or inline in the caller
(``threaded=False``: offline and deterministic use; the same results for the same jobs).
A job is refused while the previous one is still running (the caller keeps its data
and tries again later): nothing queues behind a slow batch. Each result is published
by one reference assignment (:attr:`BatchWorker.result`), so a reader never sees a
half-made result and no lock is held while ``fn`` computes. An exception in ``fn`` is
logged, counted and kept (:attr:`BatchWorker.last_error`) and the worker carries on
with the next job: it neither kills the caller nor disappears silently.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

log = logging.getLogger(__name__)

J = TypeVar("J")
R = TypeVar("R")

#: how long :meth:`BatchWorker.close` waits for a running batch to end, s
JOIN_TIMEOUT_S = 5.0


class BatchWorker(Generic[J, R]):
    """Runs ``fn`` on submitted jobs, one at a time (module doc)."""

    def __init__(self, fn: Callable[[J], R], threaded: bool = True, name: str = "batch") -> None:
        self.fn = fn
        self.threaded = threaded
        self.name = name
        self.result: R | None = None  #: the last published result (one reference)
        self.submitted = 0  #: jobs accepted
        self.done = 0  #: jobs finished (published or failed)
        self.errors = 0  #: jobs whose ``fn`` raised
        self.last_error = ""  #: "ExceptionType: message" of the last failure ("" if none)
        self._cond = threading.Condition()
        self._job: J | None = None
        self._running = False
        self._stop = False
        self._thread: threading.Thread | None = None

    @property
    def busy(self) -> bool:
        """True while a job is waiting or running."""
        return self._job is not None or self._running

    def submit(self, job: J) -> bool:
        """Hand over ``job``; False (refused) while the previous one is not done."""
        if not self.threaded:
            self.submitted += 1
            self._run(job)
            return True
        with self._cond:
            if self._stop or self.busy:
                return False
            self._job = job
            self.submitted += 1
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._loop, name=f"imudiag-{self.name}", daemon=True
                )
                self._thread.start()
            self._cond.notify_all()
        return True

    def wait(self, count: int, timeout_s: float | None = None) -> bool:
        """Wait until ``count`` jobs are done (published or failed); False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self.done >= count, timeout_s)

    def close(self, timeout_s: float = JOIN_TIMEOUT_S) -> bool:
        """Stop the thread after the running job; False when it did not end in ``timeout_s``."""
        with self._cond:
            self._stop = True
            self._job = None
            self._cond.notify_all()
            thread = self._thread
        if thread is None:
            return True
        thread.join(timeout_s)
        if thread.is_alive():
            log.warning(
                "%s worker still busy after %.1f s at close; left behind", self.name, timeout_s
            )
            return False
        return True

    def _loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stop or self._job is not None)
                if self._stop:
                    return
                job, self._job = self._job, None
                self._running = True
            assert job is not None
            self._run(job)

    def _run(self, job: J) -> None:
        try:
            out = self.fn(job)
        except Exception as exc:  # reported in the status, the worker carries on
            log.exception("%s failed", self.name)
            with self._cond:
                self.errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
                self._finish()
            return
        with self._cond:
            self.result = out
            self._finish()

    def _finish(self) -> None:
        self._running = False
        self.done += 1
        self._cond.notify_all()


__all__ = ["JOIN_TIMEOUT_S", "BatchWorker"]
