"""``imudiag run`` as a real subprocess, its JSON status lines collected as they arrive.

Used by the bench and by the daemon/robustness tests. Every stdout line must
be one JSON object (spec/reports.md); lines that are not are kept in
:attr:`DaemonProcess.bad_lines` so a caller can fail on them.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

Status = dict[str, Any]


@dataclass(frozen=True)
class StatusRecord:
    """One status line and the monotonic wall-clock time (s) the reader got it."""

    wall_s: float
    status: Status


class DaemonProcess:
    """``python -m imudiag run ARGS`` with reader threads for stdout (status) and stderr.

    :meth:`wait_for` returns the first *new* status line matching a predicate
    (lines before the previous match are not looked at again); :attr:`records`
    keeps every line with its arrival time.
    """

    def __init__(
        self,
        args: Sequence[str],
        env: dict[str, str] | None = None,
        python: str = sys.executable,
        cwd: str | os.PathLike[str] | None = None,
    ) -> None:
        run_env = dict(os.environ if env is None else env)
        run_env.setdefault("PYTHONUNBUFFERED", "1")
        self.args = list(args)
        self.proc = subprocess.Popen(
            [python, "-m", "imudiag", "run", *self.args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=run_env,
            cwd=cwd,
        )
        self.records: list[StatusRecord] = []
        self.bad_lines: list[str] = []
        self.stderr: list[str] = []
        self._cond = threading.Condition()
        self._cursor = 0
        self._eof = False
        self._threads = [
            threading.Thread(target=self._read_stdout, daemon=True, name="daemon-stdout"),
            threading.Thread(target=self._read_stderr, daemon=True, name="daemon-stderr"),
        ]
        for t in self._threads:
            t.start()

    # -- readers ------------------------------------------------------------

    def _read_stdout(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            wall = time.monotonic()
            try:
                status = json.loads(line)
                ok = isinstance(status, dict)
            except json.JSONDecodeError:
                ok = False
            with self._cond:
                if ok:
                    self.records.append(StatusRecord(wall, status))
                else:
                    self.bad_lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self._eof = True
            self._cond.notify_all()

    def _read_stderr(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append(line)

    # -- queries ------------------------------------------------------------

    @property
    def all(self) -> list[Status]:
        """Every status line received so far, in order."""
        with self._cond:
            return [r.status for r in self.records]

    @property
    def last(self) -> Status | None:
        """The latest status line, or None before the first."""
        with self._cond:
            return self.records[-1].status if self.records else None

    def stderr_tail(self, chars: int = 2000) -> str:
        """The end of what the daemon wrote to standard error."""
        return "".join(self.stderr)[-chars:]

    def wait_record(
        self,
        predicate: Callable[[StatusRecord], bool],
        timeout_s: float = 20.0,
        since: int | None = None,
    ) -> tuple[int, StatusRecord] | None:
        """(index, record) of the first record at or after ``since`` matching, or None on
        timeout or when the daemon's stdout ended. ``since`` None: after the last match."""
        start = self._cursor if since is None else since
        deadline = time.monotonic() + timeout_s
        i = start
        with self._cond:
            while True:
                while i < len(self.records):
                    rec = self.records[i]
                    if predicate(rec):
                        if since is None:
                            self._cursor = i + 1
                        return i, rec
                    i += 1
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._eof:
                    if since is None:
                        self._cursor = i
                    return None
                self._cond.wait(min(remaining, 0.2))

    def wait_for(self, predicate: Callable[[Status], bool], timeout_s: float = 20.0) -> Status:
        """The first new status line for which ``predicate`` holds (AssertionError if none
        arrives within ``timeout_s`` seconds of wall time)."""
        found = self.wait_record(lambda r: predicate(r.status), timeout_s)
        if found is None:
            raise AssertionError(
                f"no matching status within {timeout_s} s; last: {self.all[-3:]}; "
                f"exit: {self.proc.poll()}; stderr: {self.stderr_tail()}"
            )
        return found[1].status

    # -- lifetime -----------------------------------------------------------

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int:
        """Send ``sig`` (if still running) and wait for the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        code = self.proc.wait(timeout_s)
        for t in self._threads:
            t.join(2.0)
        return code

    def kill(self) -> None:
        """Kill the process if it still runs (cleanup after a failure)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5.0)

    def __enter__(self) -> DaemonProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill()


__all__ = ["DaemonProcess", "Status", "StatusRecord"]
