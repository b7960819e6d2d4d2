"""A gpsd client for the daemon: ``gpsd://HOST:PORT`` (default ``gpsd://127.0.0.1:2947``).

Speaks the gpsd JSON protocol: on connect it sends
``?WATCH={"enable":true,"json":true}`` and then reads one JSON object a line,
every object tagged with ``class``; TPV reports are returned by :meth:`poll`
(see :mod:`.tpv`). Never blocks the sampling loop: the socket is non-blocking,
a connection attempt waits at most ``connect_timeout_s``, and a lost or
refused connection is retried with a doubling back-off between
``min_backoff_s`` and ``max_backoff_s``, like the IMU source
(:class:`imudiag.drivers.reconnect.ReconnectingSource`).
"""

from __future__ import annotations

import errno
import json
import logging
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import urlsplit

from ..errors import BadInput
from .tpv import parse_tpv

log = logging.getLogger("imudiag.aiding")

DEFAULT_URL = "gpsd://127.0.0.1:2947"
WATCH = b'?WATCH={"enable":true,"json":true}\n'
MAX_LINE = 65536  #: bytes: a longer line is dropped (gpsd's own limit is far below)


def parse_gpsd_url(url: str) -> tuple[str, int]:
    """(host, port) of ``gpsd://HOST[:PORT]``; BadInput otherwise."""
    parts = urlsplit(url)
    if parts.scheme != "gpsd":
        raise BadInput(f"aiding: expected gpsd://HOST:PORT, got {url!r}")
    try:
        port = parts.port or 2947
    except ValueError:
        raise BadInput(f"aiding: bad port in {url!r}") from None
    host = parts.hostname or "127.0.0.1"
    return host, port


@dataclass
class GpsdCounters:
    connects: int = 0
    lines: int = 0
    tpv: int = 0
    bad_lines: int = 0

    def as_dict(self) -> dict[str, int]:
        return {
            "connects": self.connects,
            "lines": self.lines,
            "tpv": self.tpv,
            "bad_lines": self.bad_lines,
        }


class GpsdClient:
    """Non-blocking gpsd JSON client with reconnection (module doc)."""

    def __init__(
        self,
        url: str = DEFAULT_URL,
        min_backoff_s: float = 0.5,
        max_backoff_s: float = 10.0,
        connect_timeout_s: float = 0.2,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.url = url
        self.host, self.port = parse_gpsd_url(url)
        self.min_backoff_s = min_backoff_s
        self.max_backoff_s = max_backoff_s
        self.connect_timeout_s = connect_timeout_s
        self.clock = clock
        self.sock: socket.socket | None = None
        self.state = "disconnected"
        self.last_error = "not connected yet"
        self.counters = GpsdCounters()
        self._buf = b""
        self._backoff = min_backoff_s
        self._next_try = -float("inf")

    def _connect(self) -> None:
        now = self.clock()
        if now < self._next_try:
            return
        try:
            s = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
            s.setblocking(False)
            s.sendall(WATCH)
        except OSError as exc:
            self.last_error = (
                f"gpsd not reachable at {self.host}:{self.port}: {exc.strerror or exc}"
            )
            self._next_try = now + self._backoff
            self._backoff = min(self._backoff * 2.0, self.max_backoff_s)
            self.state = "disconnected"
            return
        self.sock = s
        self.state = "connected"
        self.last_error = ""
        self._buf = b""
        self._backoff = self.min_backoff_s
        self.counters.connects += 1
        log.info("aiding: connected to gpsd at %s:%d", self.host, self.port)

    def _drop(self, why: str) -> None:
        if self.sock is not None:
            try:
                self.sock.close()
            except OSError:
                pass
        self.sock = None
        self.state = "disconnected"
        self.last_error = why
        self._next_try = self.clock() + self._backoff
        self._backoff = min(self._backoff * 2.0, self.max_backoff_s)
        log.warning("aiding: %s", why)

    def poll(self) -> list[dict]:
        """TPV reports received since the last call (parsed by :func:`.tpv.parse_tpv`)."""
        if self.sock is None:
            self._connect()
            if self.sock is None:
                return []
        chunks = []
        while True:
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    break
                self._drop(f"gpsd connection lost: {exc.strerror or exc}")
                break
            if not data:
                self._drop("gpsd closed the connection")
                break
            chunks.append(data)
        if not chunks:
            return []
        self._buf += b"".join(chunks)
        *lines, self._buf = self._buf.split(b"\n")
        if len(self._buf) > MAX_LINE:
            self._buf = b""
            self.counters.bad_lines += 1
        out = []
        for line in lines:
            line = line.strip()
            if not line:
                continue
            self.counters.lines += 1
            try:
                obj = json.loads(line)
                r = parse_tpv(obj) if isinstance(obj, dict) else None
            except (ValueError, TypeError):
                self.counters.bad_lines += 1
                continue
            if r is not None:
                self.counters.tpv += 1
                out.append(r)
        return out

    def close(self) -> None:
        if self.sock is not None:
            try:
                self.sock.close()
            except OSError:
                pass
        self.sock = None
        self.state = "closed"


__all__ = ["DEFAULT_URL", "GpsdClient", "parse_gpsd_url"]
