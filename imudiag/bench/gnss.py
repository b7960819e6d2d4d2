"""The GNSS side of an aided drive on the bench: a real gpsd reading the simulated receiver.

:class:`GnssFeed` starts Debian's ``gpsd`` on a free loopback port, reading a
pty as its receiver, and writes the drive's GNSS stream (u-blox UBX NAV-PVT +
NAV-VELNED per epoch, :mod:`imudiag.sim.ubx`) into that pty. The board feeder
calls :meth:`GnssFeed.send_until` after every write of IMU samples, so one
clock (the board's sample index at ``speed`` x real time) paces both streams:
an epoch of true time ``t`` leaves the receiver once the board has sent sample
time ``t + latency``, as a real receiver outputs it ``latency`` after its
time tag. (Replaying a file with gpsfake instead paces it by its own sleep
per packet, which drifts against the board by the cost of each write: the
daemon's clock offset would then move through the run.)

gpsd runs read-only (``-b``: it sends no configuration to the receiver) and in
the foreground; the bench owns it and stops it (:meth:`GnssFeed.close`).
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import socket
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

from imudiag.bench.pty import PtyPair
from imudiag.errors import BadInput, BenchError
from imudiag.sim.drive import DriveMotion, GnssSimConfig, gnss_reports

#: environment variable naming the gpsd executable (default: gpsd on PATH, then /usr/sbin)
GPSD_ENV = "IMUDIAG_GPSD"
GPSD_START_TIMEOUT_S = 10.0  #: wall time for gpsd to listen on its port, s


class MissingGnssTool(BadInput):
    """gpsd or pyubx2 is not installed: the aided bench cannot run (exit 2)."""


def find_gpsd() -> str | None:
    """Path of the gpsd executable: ``$IMUDIAG_GPSD`` if set, else gpsd on PATH or in
    /usr/sbin (Debian installs it there, outside a normal user's PATH); None if absent."""
    env = os.environ.get(GPSD_ENV)
    if env is not None:
        return env if os.path.isfile(env) and os.access(env, os.X_OK) else None
    return shutil.which("gpsd") or shutil.which("gpsd", path="/usr/sbin:/sbin")


def missing() -> str | None:
    """Why an aided bench run cannot run here (one line naming what to install), or None."""
    gpsd = find_gpsd()
    if gpsd is None:
        where = f" (${GPSD_ENV}={os.environ[GPSD_ENV]})" if GPSD_ENV in os.environ else ""
        return (
            f"a bench scenario with aiding needs gpsd (Debian package gpsd){where}, not found: "
            "apt-get install gpsd (gpsfake is not needed: the bench feeds gpsd itself)"
        )
    try:
        import pyubx2  # noqa: F401
    except ImportError:
        return (
            "a bench scenario with aiding needs the Python package 'pyubx2' (writes the "
            "GNSS stream as u-blox UBX for gpsd), not installed: pip install 'imudiag[gnss]'"
        )
    return None


def require() -> str:
    """The gpsd executable; :class:`MissingGnssTool` naming the packages when absent."""
    why = missing()
    if why is not None:
        raise MissingGnssTool(why)
    gpsd = find_gpsd()
    assert gpsd is not None
    return gpsd


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_listening(port: int, timeout_s: float, alive: Callable[[], bool] = lambda: True) -> bool:
    """True once 127.0.0.1:``port`` accepts a connection, False after ``timeout_s`` wall s
    or as soon as ``alive()`` is false (the server exited)."""
    deadline = time.monotonic() + timeout_s
    while alive():
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return True
        except OSError:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
    return False


class GnssFeed:
    """gpsd on ``127.0.0.1:port`` fed the UBX epochs of ``motion`` through a pty.

    Use as a context manager (or :meth:`start` / :meth:`close`); :attr:`url` is
    what the daemon's ``--aiding`` takes; :attr:`epochs_sent` counts epochs written.
    """

    def __init__(
        self, motion: DriveMotion, cfg: GnssSimConfig, seed: int, workdir: str | Path
    ) -> None:
        from imudiag.sim.ubx import ubx_epoch

        self.gpsd = require()
        self.cfg = cfg
        reports = [r for r in gnss_reports(motion, cfg, seed=seed) if r.get("class") == "TPV"]
        #: (board sample time s at which the epoch leaves the receiver, its UBX bytes)
        self.epochs = [
            (k / cfg.rate_hz + cfg.latency_s, ubx_epoch(r)) for k, r in enumerate(reports)
        ]
        self.workdir = Path(workdir)
        self.port = 0
        self.pair: PtyPair | None = None
        self.proc: subprocess.Popen[bytes] | None = None
        self.epochs_sent = 0
        self._stderr_path = self.workdir / "gpsd.stderr"

    @property
    def url(self) -> str:
        """``gpsd://127.0.0.1:PORT`` for the daemon's ``--aiding``."""
        return f"gpsd://127.0.0.1:{self.port}"

    def start(self) -> GnssFeed:
        """Start gpsd on a free port reading a new pty; wait until it listens."""
        self.pair = PtyPair()
        self.port = free_port()
        with open(self._stderr_path, "wb") as err:
            self.proc = subprocess.Popen(
                [self.gpsd, "-N", "-n", "-b", "-S", str(self.port), self.pair.slave_path],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=err,
            )
        proc = self.proc
        if wait_listening(self.port, GPSD_START_TIMEOUT_S, lambda: proc.poll() is None):
            return self
        if proc.poll() is not None:
            raise BenchError(f"gpsd exited with status {proc.returncode} at start: {self.stderr()}")
        raise BenchError(
            f"gpsd did not listen on 127.0.0.1:{self.port} within "
            f"{GPSD_START_TIMEOUT_S:g} s: {self.stderr()}"
        )

    def send_until(self, t_s: float) -> None:
        """Write every epoch due by board sample time ``t_s`` (s) into gpsd's pty."""
        if self.pair is None:
            return
        k = self.epochs_sent
        while k < len(self.epochs) and self.epochs[k][0] <= t_s:
            k += 1
        if k > self.epochs_sent:
            self.pair.write(b"".join(e[1] for e in self.epochs[self.epochs_sent : k]))
            self.epochs_sent = k
        # gpsd runs read-only (-b); whatever it might still write is read and dropped
        fd = self.pair.master_fd
        while select.select([fd], [], [], 0)[0]:
            try:
                if not os.read(fd, 4096):
                    break
            except OSError:
                break

    def stderr(self, chars: int = 500) -> str:
        """The end of what gpsd wrote to standard error."""
        with contextlib.suppress(OSError):
            return self._stderr_path.read_text(errors="replace")[-chars:].strip()
        return ""

    def close(self) -> None:
        """Stop gpsd (SIGTERM, then SIGKILL) and close the pty."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        if self.pair is not None:
            self.pair.close()
            self.pair = None

    def __enter__(self) -> GnssFeed:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = [
    "GPSD_ENV",
    "GnssFeed",
    "MissingGnssTool",
    "find_gpsd",
    "free_port",
    "missing",
    "require",
]
