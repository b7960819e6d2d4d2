"""A pseudo-terminal that makes a (simulated) board look like a real serial device.

:class:`PtyPair` opens a pty in raw mode; its slave path (``/dev/pts/N``) is
opened by pyserial or by ``serial:///dev/pts/N`` like a CDC-ACM port.
:class:`BoardWriter` writes the board's byte stream into the master side from a
background thread at a real-time pace.

Unplugging and replugging::

    pair.close_master()          # the reader sees a hangup: pyserial raises,
                                 # serial:// raises SourceError; /dev/pts/N vanishes
    new = PtyPair(link=path)     # "replug": a new pty, the symlink ``path`` now
                                 # points at its slave; a source opened with
                                 # serial://<path> (e.g. ReconnectingSource)
                                 # finds the device again under the same name
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import threading
import time
import tty
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any


class PtyPair:
    """A pty in raw mode: ``master_fd`` (the board side), ``slave_path`` (the host side).

    link: optional path of a symlink made (atomically replaced) to point at the
    slave, so a replugged device keeps its name. The pair keeps its own slave
    fd open so the master is writable before the host opens the port.
    """

    def __init__(self, link: str | os.PathLike[str] | None = None) -> None:
        self.master_fd, self._slave_fd = os.openpty()
        self.slave_path = os.ttyname(self._slave_fd)
        tty.setraw(self._slave_fd)  # no echo, no CR/LF translation, no signals
        self.link = Path(link) if link is not None else None
        self._writers: list[Any] = []  # writer threads (a .stop()), stopped on unplug
        self._command_buf = b""
        if self.link is not None:
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            os.symlink(self.slave_path, tmp)
            os.replace(tmp, self.link)

    @property
    def master_open(self) -> bool:
        """True until :meth:`close_master`."""
        return self.master_fd >= 0

    def write(self, data: bytes) -> None:
        """Write all of ``data`` to the master side (the board sending), blocking."""
        write_all(self.master_fd, data)

    def read_commands(self, timeout_s: float = 0.0) -> list[str]:
        """Command lines the host wrote to the port (what the board receives), without ``\\n``.

        Waits up to ``timeout_s`` seconds for the first byte.
        """
        if not self.master_open:
            return []
        ready, _, _ = select.select([self.master_fd], [], [], timeout_s)
        while ready:
            try:
                chunk = os.read(self.master_fd, 4096)
            except OSError:
                break
            if not chunk:
                break
            self._command_buf += chunk
            ready, _, _ = select.select([self.master_fd], [], [], 0.0)
        *lines, self._command_buf = self._command_buf.split(b"\n")
        return [ln.decode("ascii", "replace") for ln in lines]

    def add_writer(self, writer: Any) -> None:
        """Register a writer thread (anything with ``stop()``) that :meth:`close_master` stops."""
        self._writers.append(writer)

    def remove_writer(self, writer: Any) -> None:
        """Forget a writer that has stopped."""
        if writer in self._writers:
            self._writers.remove(writer)

    def close_master(self) -> None:
        """Unplug: stop this pair's writers, close the master; readers get a hangup."""
        for w in list(self._writers):
            w.stop()
        if self.master_fd >= 0:
            os.close(self.master_fd)
            self.master_fd = -1

    def close(self) -> None:
        """Close both sides (the symlink, if any, is left dangling); safe to call twice."""
        self.close_master()
        if self._slave_fd >= 0:
            os.close(self._slave_fd)
            self._slave_fd = -1

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_all(fd: int, data: bytes, stop: threading.Event | None = None) -> int:
    """Write ``data`` to ``fd``, waiting for room; returns the bytes written (fewer if stopped)."""
    view = memoryview(data)
    done = 0
    while done < len(view):
        if stop is not None and stop.is_set():
            break
        _, ready, _ = select.select([], [fd], [], 0.05)
        if not ready:
            continue
        try:
            done += os.write(fd, view[done:])
        except BlockingIOError:
            continue
    return done


def chunked(data: bytes, size: int) -> Iterator[bytes]:
    """``data`` in consecutive pieces of ``size`` bytes (the last may be shorter)."""
    for i in range(0, len(data), size):
        yield data[i : i + size]


def read_available(fd: int) -> bytes:
    """Every byte that can be read from ``fd`` now, without waiting (b"" if none)."""
    data = b""
    while True:
        ready, _, _ = select.select([fd], [], [], 0.0)
        if not ready:
            break
        with contextlib.suppress(BlockingIOError):
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            data += chunk
            continue
        break
    return data


class BoardWriter(threading.Thread):
    """Background thread writing byte chunks to a pty master at a real-time pace.

    Chunk i is written at ``start + i / rate_hz`` seconds (e.g. one 40-byte
    frame per chunk at the board's sample rate, or 10 frames per chunk at
    rate/10); ``rate_hz`` None or 0 writes as fast as the reader takes them.
    Stops at the end of the chunks, on :meth:`stop`, or when the master is
    closed or hung up (the OSError is kept in :attr:`error`).
    """

    def __init__(
        self,
        target: PtyPair | int,
        chunks: Iterable[bytes],
        rate_hz: float | None = None,
    ) -> None:
        super().__init__(daemon=True, name="BoardWriter")
        if isinstance(target, PtyPair):
            self._pair: PtyPair | None = target
            self.fd = target.master_fd
            target._writers.append(self)
        else:
            self._pair = None
            self.fd = int(target)
        self.chunks = chunks
        self.rate_hz = rate_hz
        self.bytes_written = 0
        self.chunks_written = 0
        self.error: OSError | None = None
        self._stop_event = threading.Event()

    def run(self) -> None:
        period = 1.0 / self.rate_hz if self.rate_hz else 0.0
        start = time.monotonic()
        try:
            for i, chunk in enumerate(self.chunks):
                if period:
                    delay = start + i * period - time.monotonic()
                    if delay > 0 and self._stop_event.wait(delay):
                        break
                if self._stop_event.is_set():
                    break
                self.bytes_written += write_all(self.fd, chunk, self._stop_event)
                self.chunks_written += 1
        except OSError as e:  # EIO/EBADF when the pty went away
            if e.errno not in (errno.EIO, errno.EBADF, errno.EPIPE):
                raise
            self.error = e

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop writing and wait up to ``timeout_s`` seconds for the thread."""
        self._stop_event.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)
        if self._pair is not None and self in self._pair._writers:
            self._pair._writers.remove(self)
