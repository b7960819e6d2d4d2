"""One batch at a time, off the caller's thread: the daemon's aiding batches.

:class:`BatchWorker` runs ``fn(job)`` for the jobs handed to :meth:`BatchWorker.submit`,
``fn`` made by ``factory()``, in one of three modes:

- ``"process"``: a child process (spawned, niced by :data:`PROCESS_NICE`) makes ``fn``
  and runs the jobs; a reader thread receives each result. No GIL is shared with the
  caller: with a thread, a batch of seconds of CPU still delayed a 1 kHz sampling loop
  by up to 0.3 s (it waits for the GIL each time it wakes; docs/moving-base.md);
- ``"thread"``: one thread of this process runs them;
- ``"inline"``: :meth:`submit` runs the job at once in the caller (offline and
  deterministic use).

The same jobs give the same results in every mode. A job is refused while the previous
one is still running (the caller keeps its data and tries again later): nothing queues
behind a slow batch. Each result is published by one reference assignment
(:attr:`BatchWorker.result`), so a reader never sees a half-made result and no lock is
held while ``fn`` computes. An exception in ``fn`` is logged, counted and kept
(:attr:`BatchWorker.last_error`) and the worker carries on with the next job; a child
process that dies is reported the same way and started again (with a new ``fn``) at
the next job.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

log = logging.getLogger(__name__)

J = TypeVar("J")
R = TypeVar("R")

#: how long :meth:`BatchWorker.close` waits for a running batch to end, s
JOIN_TIMEOUT_S = 5.0
#: niceness added to a worker process: the sampling loop goes first when CPU is short
PROCESS_NICE = 10
MODES = ("process", "thread", "inline")


def _serve(factory: Callable[[], Callable[[Any], Any]], conn: Any, nice: int) -> None:
    """The worker process: ``fn = factory()``, then one result (or error) per job. It
    ignores SIGINT and SIGTERM (a Ctrl-C or systemd's stop reaches the whole group): the
    parent ends it at close, and it ends by itself when the parent's end of the pipe
    closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if nice:
        try:
            os.nice(nice)
        except OSError:  # not allowed: run at the caller's priority
            pass
    fn = factory()
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        try:
            out = fn(job)
        except Exception as exc:
            log.exception("batch failed")
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
        else:
            conn.send(("ok", out))


class BatchWorker(Generic[J, R]):
    """Runs ``factory()``'s function on submitted jobs, one at a time (module doc)."""

    def __init__(
        self, factory: Callable[[], Callable[[J], R]], mode: str = "thread", name: str = "batch"
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"batch worker mode {mode!r}: expected one of {', '.join(MODES)}")
        self.factory = factory
        self.mode = mode
        self.name = name
        self.result: R | None = None  #: the last published result (one reference)
        self.submitted = 0  #: jobs accepted
        self.done = 0  #: jobs finished (published or failed)
        self.errors = 0  #: jobs that failed
        self.last_error = ""  #: "ExceptionType: message" of the last failure ("" if none)
        self._cond = threading.Condition()
        self._job: J | None = None
        self._running = False
        self._stop = False
        self._thread: threading.Thread | None = None
        self._fn: Callable[[J], R] | None = None if mode == "process" else factory()
        self._proc: Any = None  # multiprocessing process (mode "process")
        self._conn: Any = None
        self._reader: threading.Thread | None = None  # receives the process's results

    @property
    def busy(self) -> bool:
        """True while a job is waiting or running."""
        return self._job is not None or self._running

    def submit(self, job: J) -> bool:
        """Hand over ``job``; False (refused) while the previous one is not done."""
        if self.mode == "inline":
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
        """Stop after the running job; False when it did not end within ``timeout_s`` (a
        worker process is then terminated)."""
        with self._cond:
            self._stop = True
            self._job = None
            self._cond.notify_all()
            thread = self._thread
        ok = True
        if thread is not None:  # the worker (thread) or the sender (process)
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning(
                    "%s worker still busy after %.1f s at close; left behind", self.name, timeout_s
                )
                ok = False
        if self._proc is not None and self._conn is not None:
            try:
                self._conn.send(None)
            except (OSError, ValueError):
                pass
            self._proc.join(timeout_s)
            if self._proc.is_alive():
                log.warning(
                    "%s process still busy after %.1f s at close; terminated", self.name, timeout_s
                )
                self._proc.terminate()
                self._proc.join(timeout_s)
                ok = False
            self._conn.close()
            if self._reader is not None:
                self._reader.join(timeout_s)
        return ok

    # -- thread and inline ---------------------------------------------------

    def _loop(self) -> None:
        """The worker thread: runs each job (mode "thread"), or sends it to the worker
        process (mode "process": a write that waits for the niced child to read never
        holds up the caller)."""
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stop or self._job is not None)
                if self._stop:
                    return
                job, self._job = self._job, None
                self._running = True
            assert job is not None
            if self.mode == "process":
                self._send(job)
            else:
                self._run(job)

    def _run(self, job: J) -> None:
        assert self._fn is not None
        try:
            out = self._fn(job)
        except Exception as exc:  # reported in the status, the worker carries on
            log.exception("%s failed", self.name)
            self._failed(f"{type(exc).__name__}: {exc}")
            return
        self._publish(out)

    def _publish(self, out: R) -> None:
        with self._cond:
            self.result = out
            self._finish()

    def _failed(self, message: str) -> None:
        with self._cond:
            self.errors += 1
            self.last_error = message
            self._finish()

    def _finish(self) -> None:
        self._running = False
        self.done += 1
        self._cond.notify_all()

    # -- process ----------------------------------------------------------------

    def _send(self, job: J) -> None:
        """Hand ``job`` to the process (started first if it is not running); a process
        that cannot start (no fork under a task limit, a factory that cannot be sent) or
        a job that cannot be sent fails this job only: counted, kept in ``last_error``,
        and the next job tries again."""
        if self._proc is None or not self._proc.is_alive():
            try:
                self._start_process()
            except Exception as exc:
                self._proc = None
                log.error("%s process could not start: %s", self.name, exc)
                self._failed(f"{self.name} process could not start: {type(exc).__name__}: {exc}")
                return
        try:
            self._conn.send(job)
        except Exception as exc:  # OSError, ValueError (closed), pickling errors
            self._failed(f"{self.name} process not reachable: {type(exc).__name__}: {exc}")

    def _start_process(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve,
            args=(self.factory, child, PROCESS_NICE),
            name=f"imudiag-{self.name}",
            daemon=True,
        )
        try:
            self._proc.start()
        except BaseException:
            parent.close()
            raise
        finally:
            child.close()
        self._conn = parent
        self._reader = threading.Thread(
            target=self._read,
            args=(parent, self._proc),
            name=f"imudiag-{self.name}-results",
            daemon=True,
        )
        self._reader.start()

    def _read(self, conn: Any, proc: Any) -> None:
        """The reader thread: publishes what the process sends until it ends."""
        while True:
            try:
                kind, payload = conn.recv()
            except (EOFError, OSError):
                break
            if kind == "ok":
                self._publish(payload)
            else:
                self._failed(payload)
        if not self._stop:
            proc.join(1.0)
            msg = (
                f"{self.name} process ended (exit code {proc.exitcode}); "
                "started again at the next batch"
            )
            log.error(msg)
            with self._cond:
                if self._running:  # the job it had is lost
                    self.errors += 1
                    self.last_error = msg
                    self._finish()
                else:
                    self.last_error = msg


__all__ = ["JOIN_TIMEOUT_S", "MODES", "PROCESS_NICE", "BatchWorker"]
