"""hid://VID:PID?serial=S — the board's USB HID interface (hidapi).

64-byte input reports (spec/wire-protocol.md): byte 0 report ID 0x01, byte 1
the number of whole frames that follow (0 or 1), the frame bytes, zero
padding. :func:`unpack_reports` turns many reports into the frame byte stream
at once; the bytes then go through the wire Decoder like any other transport.
hidapi hands over one report per call, so reading is one call per report; the
unpacking and decoding are vectorised over everything read in one
:meth:`HidSource.read` (``counters.bytes`` counts the frame bytes carried, not report
bytes). The protocol defines no HID output report, so host
commands are not sent over HID (a board must work without them).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import SourceError, SourceURL, register
from .bytesource import ByteSource, parse_vid_pid

HID_REPORT_SIZE = 64  #: bytes per input report
HID_REPORT_ID = 0x01
HID_PAYLOAD_SIZE = HID_REPORT_SIZE - 2  #: frame bytes a report can carry
MAX_REPORTS_PER_READ = 4096


def unpack_reports(reports: bytes | bytearray | np.ndarray) -> tuple[bytes, int]:
    """Frame bytes carried by consecutive 64-byte HID input reports.

    ``reports``: K*64 bytes or a (K, 64) uint8 array. Returns the concatenated
    frame bytes and the number of malformed reports (wrong report ID or a
    frame count other than 0 or 1), which carry nothing. The frame length is
    read from the frame's own length byte (6 + length bytes, at most 62).
    """
    a = np.asarray(reports, dtype=np.uint8) if isinstance(reports, np.ndarray) else None
    if a is None:
        a = np.frombuffer(bytes(reports), dtype=np.uint8)
    if a.size % HID_REPORT_SIZE:
        raise ValueError(f"HID reports: {a.size} bytes is not a multiple of {HID_REPORT_SIZE}")
    a = a.reshape(-1, HID_REPORT_SIZE)
    valid = (a[:, 0] == HID_REPORT_ID) & (a[:, 1] <= 1)
    carries = valid & (a[:, 1] == 1)
    frame_len = np.minimum(a[:, 5].astype(np.int64) + 6, HID_PAYLOAD_SIZE)
    cols = np.arange(HID_REPORT_SIZE)
    mask = carries[:, None] & (cols >= 2) & (cols < 2 + frame_len[:, None])
    return a[mask].tobytes(), int(np.count_nonzero(~valid))


def pack_reports(frames: list[bytes]) -> bytes:
    """HID input reports carrying one frame each (what the board sends); for tests and sims."""
    out = bytearray()
    for f in frames:
        if len(f) > HID_PAYLOAD_SIZE:
            raise ValueError(f"a {len(f)}-byte frame does not fit a HID report (max 62)")
        report = bytes([HID_REPORT_ID, 1]) + f
        out += report + bytes(HID_REPORT_SIZE - len(report))
    return bytes(out)


@register("hid")
class HidSource(ByteSource):
    """Wire frames from HID input reports, through hidapi (``pip install hidapi``)."""

    url_keys = ("serial",)

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        self.vid, self.pid = parse_vid_pid(url)
        self.serial: str | None = options.get("serial", url.get("serial"))
        self.bad_reports = 0  #: reports with a wrong ID or frame count
        self._dev: Any = None

    def _open_transport(self) -> None:
        try:
            import hid
        except ImportError as e:
            raise SourceError(f"{self.url.url}: hidapi is not installed ({e})") from e
        dev = hid.device()
        try:
            dev.open(self.vid, self.pid, self.serial)
            dev.set_nonblocking(1)
        except (OSError, ValueError) as e:
            serial = f" serial {self.serial}" if self.serial else ""
            raise SourceError(
                f"{self.url.url}: cannot open HID device {self.vid:04x}:{self.pid:04x}{serial}: {e}"
            ) from e
        self._dev = dev

    def _read_bytes(self, timeout_s: float) -> bytes:
        dev = self._dev
        try:
            first = dev.read(HID_REPORT_SIZE, max(1, int(timeout_s * 1000)))
            if not first:
                return b""
            reports = [first]
            while len(reports) < MAX_REPORTS_PER_READ:
                r = dev.read(HID_REPORT_SIZE)
                if not r:
                    break
                reports.append(r)
        except (OSError, ValueError) as e:
            raise SourceError(f"{self.url.url}: HID device gone: {e}") from e
        buf = b"".join(bytes(r[:HID_REPORT_SIZE]).ljust(HID_REPORT_SIZE, b"\0") for r in reports)
        data, bad = unpack_reports(buf)
        self.bad_reports += bad
        return data

    def _close_transport(self) -> None:
        dev, self._dev = self._dev, None
        if dev is not None:
            try:
                dev.close()
            except (OSError, ValueError):
                pass
