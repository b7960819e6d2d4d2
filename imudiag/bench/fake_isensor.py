"""A fake iSensor SPI Buffer board with an ADIS16xxx behind it, on a pty (as gpsfake for gpsd).

:class:`FakeISensorBoard` answers the board's USB command line as its USB_CLI.md and
REGISTER_DEFINITION.md describe it (``read``, ``write``, ``stream``, ``delim``,
``echo``, ``cmd``; page 253-255 registers are the board's, other pages the IMU's),
and while a stream runs on page 255 it writes buffer-entry lines::

    UTC_LWR,UTC_UPR,TS_LWR,TS_UPR,SIG,DATA_0,...,DATA_n

``SIG`` is the sum of the other words. Entries come from :meth:`queue` (lines made
by the caller: a test's own encoder) or from :func:`entry_lines` (this module's
encoder for ADIS1647x/1650x 16-bit bursts, e.g. of the project's simulator's
samples). A write of GLOB_CMD's self-test bit is counted in
:attr:`self_tests` and, with ``self_test_fails``, sets DIAG_STAT bit 5 in the
entries that follow. It never imports the driver it stands in for.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterable

import numpy as np

from imudiag.samples import SampleBlock

from .pty import PtyPair

#: (PROD_ID address, range-model address, serial address, firmware address) of the IMU page 0
_REGS_1647X = {"prod_id": 0x72, "rang_mdl": 0x5E, "serial": 0x74, "firm_rev": 0x6C}


#: 16-bit output LSB (gyro deg/s, accel in the certificate's unit) of the fake ADIS parts:
#: the data sheets' figures (docs/devices.md); the fake needs its own copy, it never
#: imports the driver it stands in for
ISENSOR_LSB = {
    "adis16470": (0.1, 1 / 800),
    **{f"adis16475-{d}": (g, 1 / 4000) for d, g in ((1, 1 / 160), (2, 1 / 40), (3, 0.1))},
    **{f"adis16477-{d}": (g, 1 / 800) for d, g in ((1, 1 / 160), (2, 1 / 40), (3, 0.1))},
}


class ISensorBoardCLI:
    """The board's registers and command line (no I/O): :meth:`receive` takes the bytes
    the host sent and returns what the board answers (echo, ``read`` replies)."""

    def __init__(
        self,
        prod_id: int = 16475,
        range_model: int = 2,
        serial: int = 0x0A1B,
        firmware: int = 0x0107,
        board_firmware: int = 0x0118,
        self_test_fails: bool = False,
    ) -> None:
        self.pages: dict[int, dict[int, int]] = {253: {}, 254: {}, 255: {}, 0: {}, 3: {}, 4: {}}
        dash_bits = {1: 0b00, 2: 0b01, 3: 0b11}[range_model] << 2
        self.pages[253].update({0x6E: board_firmware})
        for i in range(6):
            self.pages[253][0x74 + 2 * i] = 0x1000 + i
        if prod_id == 16495:
            self.pages[0][0x7E] = prod_id
            self.pages[3][0x78] = firmware
            self.pages[4][0x20] = serial
        else:
            imu = self.pages[0]
            imu[_REGS_1647X["prod_id"]] = prod_id
            imu[_REGS_1647X["rang_mdl"]] = dash_bits | 0b11  # bits 1:0 read as 1 on the parts
            imu[_REGS_1647X["serial"]] = serial
            imu[_REGS_1647X["firm_rev"]] = firmware
        self.prod_id = prod_id
        self.page = 253
        self.delim = " "
        self.echo = True
        self.streaming = False
        self.self_test_fails = self_test_fails
        self.self_tests = 0
        self.commands: list[str] = []  #: every command line received, in order
        self.diag_or = 0  #: DIAG_STAT bits set in the entries (a failed self test)
        self._buf = b""

    @property
    def capturing(self) -> bool:
        """A stream runs on page 255: entry lines go out."""
        return self.streaming and self.page == 255

    def receive(self, data: bytes) -> bytes:
        """The board's answer to the bytes the host sent (whole lines; a partial line waits)."""
        *lines, self._buf = (self._buf + data).split(b"\n")
        return b"".join(self.command(ln.decode("ascii", "replace")) for ln in lines)

    def command(self, line: str) -> bytes:
        """The answer to one command line (without its line end)."""
        line = line.strip("\r").strip()
        if not line:
            return b""
        self.commands.append(line)
        out = (line + "\r\n").encode("ascii") if self.echo else b""  # echo until "echo 0"
        parts = line.split()
        cmd, args = parts[0], parts[1:]
        try:
            values = [int(a, 16) for a in args] if cmd != "delim" else []
        except ValueError:
            return out
        if cmd == "stream" and values:
            self.streaming = values[0] == 1
        elif cmd == "echo" and values:
            self.echo = values[0] == 1
        elif cmd == "delim" and args:
            self.delim = args[0][0]
        elif cmd == "write" and len(values) == 2:
            self._write(values[0], values[1] & 0xFF)
        elif cmd == "read" and values:
            end = values[1] if len(values) > 1 else values[0]
            regs = self.pages.setdefault(self.page, {})
            words = [regs.get(a, 0) for a in range(values[0], end + 1, 2)]
            out += (self.delim.join(f"{w:04X}" for w in words) + "\r\n").encode("ascii")
        # "cmd" (USER_COMMAND: clear buffer, flash update, ...) changes nothing here
        return out

    def entries(self, lines: list[bytes]) -> list[bytes]:
        """Entry lines as the board sends them now (DIAG_STAT bits of a failed self test)."""
        return [_or_diag(b, self.diag_or) for b in lines] if self.diag_or else lines

    def _write(self, addr: int, byte: int) -> None:
        if addr == 0:  # PAGE_ID
            self.page = byte
            return
        regs = self.pages.setdefault(self.page, {})
        word = regs.get(addr & ~1, 0)
        if addr & 1:
            word = (word & 0x00FF) | (byte << 8)
        else:
            word = (word & 0xFF00) | byte
        regs[addr & ~1] = word
        self_test = (self.page == 0 and addr == 0x68 and byte & 0x04) or (
            self.page == 3 and addr == 0x02 and byte & 0x02
        )
        if self_test:
            self.self_tests += 1
            if self.self_test_fails:
                self.diag_or = 0x0020


class FakeISensorBoard(threading.Thread):
    """The board's CLI (:class:`ISensorBoardCLI`) and stream on ``pair``'s master side (a
    background thread)."""

    def __init__(
        self,
        pair: PtyPair,
        prod_id: int = 16475,
        range_model: int = 2,
        serial: int = 0x0A1B,
        firmware: int = 0x0107,
        board_firmware: int = 0x0118,
        self_test_fails: bool = False,
    ) -> None:
        super().__init__(daemon=True, name="FakeISensorBoard")
        self.pair = pair
        self.cli = ISensorBoardCLI(
            prod_id, range_model, serial, firmware, board_firmware, self_test_fails
        )
        self.lines_sent = 0
        self._queue: deque[bytes] = deque()
        self._halt = threading.Event()

    @property
    def commands(self) -> list[str]:
        """Every command line received, in order."""
        return self.cli.commands

    @property
    def self_tests(self) -> int:
        """Self tests the host commanded (GLOB_CMD writes)."""
        return self.cli.self_tests

    # -- the caller's side -------------------------------------------------

    def queue(self, lines: Iterable[bytes]) -> None:
        """Entry lines to stream (sent while a stream runs on page 255)."""
        self._queue.extend(lines)

    @property
    def pending(self) -> int:
        """Entry lines not sent yet."""
        return len(self._queue)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the thread."""
        self._halt.set()
        if self.is_alive():
            self.join(timeout_s)

    # -- the board ---------------------------------------------------------

    def run(self) -> None:
        pair = self.pair
        while not self._halt.is_set() and pair.master_open:
            try:
                lines = pair.read_commands(0.0 if self._sending() else 0.02)
                for line in lines:
                    reply = self.cli.command(line)
                    if reply:
                        pair.write(reply)
            except OSError:
                return
            if self._sending():
                batch = [self._queue.popleft() for _ in range(min(50, len(self._queue)))]
                try:
                    pair.write(b"".join(self.cli.entries(batch)))
                except OSError:
                    return
                self.lines_sent += len(batch)

    def _sending(self) -> bool:
        return self.cli.capturing and bool(self._queue)


def _or_diag(line: bytes, bits: int) -> bytes:
    """An ADIS1647x entry line with DIAG_STAT |= bits, its checksums recomputed."""
    words = [int(w, 16) for w in line.strip().split(b",")]
    data = words[5:]
    data[1] |= bits
    data[10] = sum((w & 0xFF) + (w >> 8) for w in data[1:10]) & 0xFFFF
    return _line(words[:4], data)


def _line(head: list[int], data: list[int]) -> bytes:
    """An entry line: UTC, timestamp, SIG (the sum of every other word), DATA."""
    sig = (sum(head) + sum(data)) & 0xFFFF
    return (",".join(f"{w:04X}" for w in [*head, sig, *data]) + "\r\n").encode("ascii")


def entry_lines(
    block: SampleBlock,
    gyro_lsb: float,
    accel_lsb: float,
    temp_lsb: float = 0.1,
    first_count: int = 0,
) -> list[bytes]:
    """ADIS1647x/1650x 16-bit burst entries of ``block`` (outputs in the part's units;
    LSB sizes in those units), timestamps from ``block.t`` (microseconds, 32 bits)."""
    n = len(block)
    g = np.clip(np.rint(block.gyro / gyro_lsb), -32768, 32767).astype(np.int64) & 0xFFFF
    a = np.clip(np.rint(block.accel / accel_lsb), -32768, 32767).astype(np.int64) & 0xFFFF
    temp_c = block.temp if block.temp is not None else np.full(n, 25.0)
    tw = np.rint(np.asarray(temp_c) / temp_lsb).astype(np.int64) & 0xFFFF
    ts = np.rint(block.t * 1e6).astype(np.int64) & 0xFFFFFFFF
    out = []
    for i in range(n):
        cnt = (first_count + i) & 0xFFFF
        burst = [0, 0, *g[i].tolist(), *a[i].tolist(), int(tw[i]), cnt]
        checksum = sum((w & 0xFF) + (w >> 8) for w in burst[1:]) & 0xFFFF
        out.append(_line([0, 0, int(ts[i]) & 0xFFFF, int(ts[i]) >> 16], [*burst, checksum]))
    return out
