"""ByteSource: a Source that reads bytes from a transport and decodes them with the wire Decoder.

A transport subclass implements :meth:`ByteSource._open_transport`,
:meth:`ByteSource._read_bytes`, :meth:`ByteSource._close_transport` and, where
it can send to the board, :meth:`ByteSource._write_bytes`. The decoder (and its
counters, shared with :attr:`Source.counters`) lives as long as the source, so
a close/open cycle (a reconnect) keeps the counters and the seq/time state.
"""

from __future__ import annotations

import re
from abc import abstractmethod
from typing import Any, Protocol

from imudiag.samples import SampleBlock

from .base import Source, SourceError, SourceURL
from .wire import Decoder

#: Host-to-device commands of spec/wire-protocol.md.
_COMMAND_RE = re.compile(r"^(START|STOP|INFO|RATE [0-9]+(\.[0-9]+)?)$")


def format_command(line: str) -> bytes:
    """The bytes of a host command line (``START``, ``STOP``, ``INFO``, ``RATE <hz>``).

    Raises ValueError naming the command when it is not one of the protocol's.
    """
    text = line.strip()
    if not _COMMAND_RE.match(text):
        raise ValueError(
            f"unknown device command {line!r}: expected START, STOP, INFO or RATE <hz>"
        )
    return (text + "\n").encode("ascii")


class StreamDecoder(Protocol):
    """What a byte source needs of a protocol decoder (the native :class:`Decoder`, a device
    protocol's, docs/devices.md): incremental bytes in, samples out, counters kept in the
    :class:`~imudiag.drivers.wire.Counters` it was given, the device's identity."""

    device_info: dict[str, Any]

    def feed(self, data: bytes | bytearray | memoryview) -> SampleBlock:
        """The complete good samples of ``data`` plus what was held back."""
        ...

    def drop_pending(self) -> None:
        """Discard held-back bytes (a new connection), counting them as skipped."""
        ...


class ByteSource(Source):
    """Base of the byte transports (serial, HID, USB bulk, raw replay)."""

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        self.decoder: StreamDecoder = self._make_decoder()
        self.is_open = False

    def _make_decoder(self) -> StreamDecoder:
        """The protocol decoder, sharing :attr:`counters` (the native wire protocol's here;
        a device protocol's source returns its own)."""
        return Decoder(self.counters)

    # -- transport hooks ----------------------------------------------------

    @abstractmethod
    def _open_transport(self) -> None:
        """Open the device; raise SourceError (naming the device and why) if it cannot."""

    @abstractmethod
    def _read_bytes(self, timeout_s: float) -> bytes:
        """Bytes that arrived within ``timeout_s`` seconds (b"" if none); SourceError if gone."""

    @abstractmethod
    def _close_transport(self) -> None:
        """Release the device; must not raise."""

    def _write_bytes(self, data: bytes) -> bool:
        """Send ``data`` to the board; return False where the transport cannot write."""
        return False

    # -- Source interface -----------------------------------------------------

    def open(self) -> None:
        """Open the transport; held-back bytes of a previous connection are dropped."""
        if self.is_open:
            return
        self.decoder.drop_pending()
        self._open_transport()
        self.is_open = True

    def read(self, timeout_s: float = 0.1) -> SampleBlock:
        """Samples decoded from the bytes that arrived within ``timeout_s`` seconds."""
        if not self.is_open:
            raise SourceError(f"{self.url.url}: read on a source that is not open")
        try:
            data = self._read_bytes(timeout_s)
        except SourceError:
            self.close()
            raise
        block = self.decoder.feed(data) if data else SampleBlock.empty()
        self.device_info = self.decoder.device_info
        return block

    def close(self) -> None:
        """Close the transport; safe to call twice."""
        if self.is_open:
            self.is_open = False
            self._close_transport()

    def write_command(self, line: str) -> None:
        """Send a host command; silently not sent where the transport cannot write.

        A board may ignore commands; nothing waits for an answer (an ``INFO``
        answer arrives as a device-info frame and updates :attr:`device_info`).
        """
        data = format_command(line)
        if not self.is_open:
            raise SourceError(f"{self.url.url}: command {line.strip()!r} on a closed source")
        self._write_bytes(data)


def parse_vid_pid(url: SourceURL) -> tuple[int, int]:
    """``VID:PID`` (hexadecimal, optional ``0x``) of a ``hid://`` or ``usb://`` URL."""
    parts = url.target.strip("/").split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        vid, pid = (int(p, 16) for p in parts)
        if not (0 <= vid <= 0xFFFF and 0 <= pid <= 0xFFFF):
            raise ValueError
    except ValueError:
        raise SourceError(
            f"{url.url}: bad device id {url.target!r}: expected VID:PID in hex, e.g. 0483:5740"
        ) from None
    return vid, pid
