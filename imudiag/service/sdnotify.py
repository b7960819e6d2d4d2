"""The systemd notification protocol (sd_notify) in a few lines of standard library.

systemd passes a Unix datagram socket in ``NOTIFY_SOCKET`` (a filesystem path,
or an abstract-namespace name written with a leading ``@``) to a service of
``Type=notify``; the service sends newline-separated ``KEY=value`` fields:
``READY=1`` once started, ``STATUS=...`` free text for ``systemctl status``,
``WATCHDOG=1`` at least once per ``WATCHDOG_USEC`` microseconds (we ping at
half of it), ``RELOADING=1`` / ``STOPPING=1`` around a reload and at shutdown.
The watchdog is ours only if ``WATCHDOG_PID`` is unset or equals our pid.

Without ``NOTIFY_SOCKET`` (run by hand, under the bench) every call is a no-op.
A notification never raises nor blocks (the socket is non-blocking): a vanished
socket or a full receive queue is logged once, counted in ``failures`` and
ignored, so telling the supervisor can never stall the sampling; a watchdog
ping that could not be sent is retried on the next tick.

:class:`WatchdogGate` pings the watchdog only while valid frames arrive, so a
daemon whose samples stop flowing is restarted by systemd.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Mapping

log = logging.getLogger(__name__)


def _socket_address(name: str) -> str | bytes:
    """``@name`` is the abstract namespace (leading NUL byte); anything else a path."""
    if name.startswith("@"):
        return b"\0" + name[1:].encode()
    return name


class Notifier:
    """Sends sd_notify datagrams to ``socket_name``; a no-op when it is ``None``.

    ``watchdog_usec`` is the watchdog timeout in microseconds (``None`` or 0:
    no watchdog). ``watchdog_pid`` is the pid the watchdog belongs to (``None``:
    any); when it is not ``pid`` (default: our own) the watchdog is disabled.
    """

    def __init__(
        self,
        socket_name: str | None,
        watchdog_usec: int | None = None,
        watchdog_pid: int | None = None,
        pid: int | None = None,
    ) -> None:
        self.socket_name = socket_name or None
        pid = os.getpid() if pid is None else pid
        self.watchdog_usec = watchdog_usec if watchdog_usec and watchdog_usec > 0 else None
        if watchdog_pid is not None and watchdog_pid != pid:
            self.watchdog_usec = None  # another process of the service owns the watchdog
        self.sent = 0  #: datagrams sent successfully
        self.failures = 0  #: datagrams that could not be sent
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Notifier:
        """Read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID`` (default ``os.environ``).

        A malformed ``WATCHDOG_USEC`` or ``WATCHDOG_PID`` disables the watchdog,
        as libsystemd's ``sd_watchdog_enabled`` does.
        """
        env = os.environ if environ is None else environ
        usec: int | None
        try:
            usec = int(env.get("WATCHDOG_USEC", ""))
        except ValueError:
            usec = None
        wd_pid: int | None = None
        raw_pid = env.get("WATCHDOG_PID", "")
        if raw_pid:
            try:
                wd_pid = int(raw_pid)
            except ValueError:
                wd_pid = -1  # never equals a real pid: watchdog disabled
        return cls(env.get("NOTIFY_SOCKET") or None, usec, wd_pid)

    # -- state ---------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        """True when a notify socket was given."""
        return self.socket_name is not None

    @property
    def watchdog_enabled(self) -> bool:
        """True when systemd expects watchdog pings from this process."""
        return self.enabled and self.watchdog_usec is not None

    @property
    def watchdog_interval_s(self) -> float | None:
        """Seconds between watchdog pings: half of ``WATCHDOG_USEC``; ``None`` without watchdog."""
        if not self.watchdog_enabled:
            return None
        assert self.watchdog_usec is not None
        return self.watchdog_usec / 2e6

    # -- sending -------------------------------------------------------------

    def notify(self, *fields: str) -> bool:
        """Send ``KEY=value`` fields in one datagram; True if it was sent."""
        if self.socket_name is None or not fields:
            return False
        data = "\n".join(fields).encode("utf-8", errors="replace")
        with self._lock:
            try:
                if self._sock is None:
                    # non-inheritable; non-blocking: a full receiver queue must not stall us
                    self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                    self._sock.setblocking(False)
                self._sock.sendto(data, _socket_address(self.socket_name))
            except OSError as exc:
                if self.failures == 0:
                    log.warning("sd_notify to %s failed: %s", self.socket_name, exc)
                self.failures += 1
                return False
            self.sent += 1
            return True

    def ready(self, status: str | None = None) -> bool:
        """``READY=1`` (start-up finished), optionally with a status text."""
        fields = ["READY=1"]
        if status is not None:
            fields.append(_status_field(status))
        return self.notify(*fields)

    def status(self, text: str) -> bool:
        """``STATUS=text``, shown by ``systemctl status`` (newlines become spaces)."""
        return self.notify(_status_field(text))

    def watchdog(self) -> bool:
        """``WATCHDOG=1``; sent only when the watchdog is enabled for this process."""
        if not self.watchdog_enabled:
            return False
        return self.notify("WATCHDOG=1")

    def reloading(self) -> bool:
        """``RELOADING=1`` (send :meth:`ready` when the reload is done)."""
        return self.notify("RELOADING=1")

    def stopping(self) -> bool:
        """``STOPPING=1``: shutdown has begun."""
        return self.notify("STOPPING=1")

    def close(self) -> None:
        """Close the datagram socket (reopened on the next notification)."""
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _status_field(text: str) -> str:
    return "STATUS=" + " ".join(str(text).splitlines())


class WatchdogGate:
    """Pings the watchdog every ``interval_s`` seconds, but only while valid frames arrive.

    The daemon calls :meth:`frames_arrived` whenever a block of valid samples
    arrives and :meth:`tick` on every pass of its loop, both with the same
    monotonic clock in seconds (``time.monotonic()``). A ping is sent when at
    least ``interval_s`` has passed since the previous ping *and* frames
    arrived since then; the first ping goes out as soon as frames arrive. While
    samples stop flowing the watchdog starves and systemd restarts the service.
    ``interval_s`` defaults to the notifier's :attr:`Notifier.watchdog_interval_s`.
    """

    def __init__(self, notifier: Notifier, interval_s: float | None = None) -> None:
        self.notifier = notifier
        self.interval_s = notifier.watchdog_interval_s if interval_s is None else interval_s
        self.pings = 0  #: WATCHDOG=1 datagrams sent
        self.last_ping_s: float | None = None  #: clock of the last ping, s
        self.last_frames_s: float | None = None  #: clock of the latest frames_arrived, s
        self._fresh = False

    @property
    def enabled(self) -> bool:
        """True when the watchdog is armed for this process."""
        return self.interval_s is not None and self.notifier.watchdog_enabled

    @property
    def starved(self) -> bool:
        """True while no frames arrived since the last ping."""
        return not self._fresh

    def frames_arrived(self, now_s: float) -> None:
        """Valid frames arrived at ``now_s`` (monotonic s)."""
        self._fresh = True
        self.last_frames_s = now_s

    def tick(self, now_s: float) -> bool:
        """Ping if due and fed; returns True when a ping was sent. ``now_s``: monotonic s."""
        if not self.enabled or not self._fresh:
            return False
        assert self.interval_s is not None
        if self.last_ping_s is not None and now_s - self.last_ping_s < self.interval_s:
            return False
        if not self.notifier.watchdog():
            return False
        self.pings += 1
        self.last_ping_s = now_s
        self._fresh = False
        return True


__all__ = ["Notifier", "WatchdogGate"]
