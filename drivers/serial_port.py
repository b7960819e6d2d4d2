"""Serial transports through pyserial: CDC-ACM ports, ptys, and pyserial's URL handlers.

::

    serial:///dev/ttyACM0?baud=921600   a device path (baud is ignored by CDC-ACM)
    loop://                             pyserial's loopback (what is written is read back)
    socket://HOST:PORT                  a raw TCP socket (e.g. a bench's serial server)

Options (query or keyword): ``baud`` (bit/s, default 921600), ``exclusive``
(``1`` to lock the port, POSIX only). An unplugged device, a closed pty master
or a dropped socket raises SourceError.
"""

from __future__ import annotations

import os
import select
from typing import Any, ClassVar

import serial

from .base import SourceError, SourceURL, register
from .bytesource import ByteSource

DEFAULT_BAUD = 921600  #: bit/s
_MAX_READ = 1 << 20  #: bytes per read call at most


def _flag(value: str) -> bool:
    v = value.strip().lower()
    if v in ("1", "true", "yes", "on"):
        return True
    if v in ("0", "false", "no", "off", ""):
        return False
    raise ValueError(value)


@register("serial")
class SerialSource(ByteSource):
    """A wire-protocol byte stream read with pyserial ``serial_for_url``."""

    url_keys: ClassVar[tuple[str, ...] | None] = ("baud", "exclusive")

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        if url.scheme == "serial":
            if not url.target:
                raise SourceError(f"{url.url}: no device path (serial:///dev/ttyACM0)")
            self.port_url = url.target
        else:  # loop://, socket://host:port: pyserial's own URL, without our query
            self.port_url = f"{url.scheme}://{url.target}"
        self.baud = int(options.get("baud", url.get("baud", DEFAULT_BAUD, int)))
        excl = options.get("exclusive", url.get("exclusive", None, _flag))
        self.exclusive: bool | None = None if excl is None else bool(excl)
        self._port: serial.SerialBase | None = None
        self._timeout: float | None = None
        self._fd: int | None = None

    def _open_transport(self) -> None:
        kwargs: dict[str, Any] = {"baudrate": self.baud, "timeout": 0.1}
        if self.exclusive is not None and self.url.scheme == "serial":
            kwargs["exclusive"] = self.exclusive
        try:
            self._port = serial.serial_for_url(self.port_url, **kwargs)
        except (serial.SerialException, OSError, ValueError) as e:
            raise SourceError(f"{self.url.url}: cannot open {self.port_url}: {e}") from e
        self._timeout = 0.1
        self._fd = None
        if hasattr(self._port, "fd"):
            # a POSIX port (``serial://`` or a device protocol's port, not a pyserial URL
            # handler such as socket://): wait with select, read non-blocking, so the
            # port is never reconfigured (tcsetattr) for a new timeout
            self._port.timeout = 0
            self._timeout = 0
            self._fd = self._port.fileno()

    def _read_bytes(self, timeout_s: float) -> bytes:
        port = self._port
        assert port is not None
        try:
            if self._fd is not None:
                # pyserial opens the port non-blocking: one read takes what is there, and
                # only when nothing is there does the loop wait for it (pyserial's own read
                # would ask in_waiting and select as well: three system calls on every turn
                # of the daemon's loop instead of one)
                try:
                    data = os.read(self._fd, _MAX_READ)
                except BlockingIOError:
                    data = b""
                if not data:  # (a tty in raw mode with VMIN 0 reads 0 bytes, not EAGAIN)
                    ready, _, _ = select.select([self._fd], [], [], max(0.0, timeout_s))
                    if not ready:
                        return b""
                    try:
                        data = os.read(self._fd, _MAX_READ)
                    except BlockingIOError:
                        return b""
                if not data:  # ready yet nothing to read: the device hung up
                    raise SourceError(
                        f"{self.url.url}: device gone: ready to read but no data "
                        "(device disconnected or multiple access on port?)"
                    )
                return data
            if self._timeout != timeout_s:
                port.timeout = timeout_s
                self._timeout = timeout_s
            first = port.read(1)  # waits up to timeout_s for the first byte
            if not first:
                return b""
            waiting = int(getattr(port, "in_waiting", 0))  # every pyserial port class has it
            return first + port.read(min(waiting, _MAX_READ)) if waiting else first
        except (serial.SerialException, OSError) as e:
            raise SourceError(f"{self.url.url}: device gone: {e}") from e

    def write_bytes(self, data: bytes) -> None:
        """Send raw bytes to the port (bench tools; ``loop://`` echoes them back)."""
        if not self.is_open:
            raise SourceError(f"{self.url.url}: write on a closed source")
        self._write_bytes(bytes(data))

    def _write_bytes(self, data: bytes) -> bool:
        port = self._port
        assert port is not None
        try:
            port.write(data)
            port.flush()
        except (serial.SerialException, OSError) as e:
            raise SourceError(f"{self.url.url}: write failed: {e}") from e
        return True

    def _close_transport(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass


@register("loop")
class LoopSource(SerialSource):
    """pyserial's ``loop://``: bytes written come back (tests, demos)."""


@register("socket")
class SocketSource(SerialSource):
    """pyserial's ``socket://HOST:PORT``: a raw TCP byte stream."""

    def _read_bytes(self, timeout_s: float) -> bytes:
        # the socket handler's in_waiting is only 0 or 1: after the first byte,
        # take whatever has arrived with a non-blocking read (cheap for sockets)
        port = self._port
        assert port is not None
        try:
            port.timeout = timeout_s
            first = port.read(1)
            if not first:
                return b""
            port.timeout = 0
            return first + port.read(_MAX_READ)
        except (serial.SerialException, OSError) as e:
            raise SourceError(f"{self.url.url}: connection gone: {e}") from e
