"""The simulated board behind a pty, with transport faults spliced into its byte stream.

:class:`BoardFeeder` writes the :class:`~imudiag.sim.board.SimulatedBoard`'s
frames into the master side of a :class:`~imudiag.bench.pty.PtyPair` whose
slave is reached through a stable symlink (like udev's ``/dev/imu0``), paced
at ``speed`` times real time by sample index. Transport injections are
inserted at their sample index:

- ``garbage`` / ``duplicate``: bytes inserted before the frame of that sample;
- ``crc``: the next ``frames`` sample frames sent with a broken CRC;
- ``lost``: the next ``frames`` samples' frames never sent;
- ``unplug``: the board stops, (optionally after the host read every byte
  sent) the symlink disappears and the pty is closed; after ``outage`` s of
  wall time a new pty appears behind the same symlink and the board resumes
  where it stopped once the host has the port open again. The board models a
  device that streams only while a host holds its port, so sample time and
  ``seq`` continue without a gap;
- ``stall``: the board sends nothing for ``outage`` s of wall time, the port
  stays open, then it resumes where it stopped.

The board waits for the host (:class:`Host`) to have the port open before
sending, because opening a serial port flushes its input (pyserial does).
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from imudiag.bench.pty import PtyPair, read_available
from imudiag.errors import BenchError
from imudiag.sim.board import SimulatedBoard

from .devices import DeviceEncoder
from .scenario import Injection
from .transport import corrupt_sample_frames, count_frames, garbage, last_frame


class Host(Protocol):
    """What the feeder needs to know about the reader (the daemon under test)."""

    def wait_connected(self, after_wall_s: float, timeout_s: float) -> float | None:
        """Monotonic time (s) at which the reader reported the port open after
        ``after_wall_s``, or None on timeout."""

    def wait_bytes_read(self, n: int, timeout_s: float) -> bool:
        """True once the reader reports at least ``n`` bytes read."""


class Port(Protocol):
    """Where the feeder writes: a pty (:class:`PtyPair`) or a device that lays itself out
    (:class:`.devices.IIOPort`)."""

    @property
    def master_fd(self) -> int:
        """The writing end."""

    @property
    def master_open(self) -> bool:
        """True while the device is plugged."""

    def close(self) -> None:
        """Unplug."""


class FeederError(BenchError):
    """The feeder could not go on (the reader never connected, or never drained)."""


@dataclass
class InjectionRecord:
    """What the feeder actually did for one transport injection."""

    injection: Injection
    sample_index: int  #: first sample at or after the injected bytes (lost: first dropped)
    t_s: float  #: sample time of ``sample_index``, s
    #: counter increments (None: not predictable, not checked)
    expected: dict[str, int | None] = field(default_factory=dict)
    frames_affected: int = 0  #: frames corrupted, dropped or repeated
    wall_s: float | None = None  #: monotonic time the bytes were queued / the outage began
    drained: bool | None = None  #: unplug: the reader had read every byte before
    wall_replug_s: float | None = None  #: outage: the new pty appeared / the board resumed
    wall_reconnected_s: float | None = None  #: unplug: the reader had the port open again
    t_last_s: float | None = None  #: outage: sample time of the last sample sent before


class BoardFeeder:
    """Feeds ``board`` into a pty behind ``link`` with ``injections`` (transport kinds only).

    Call :meth:`plug` before starting the reader (the symlink must exist),
    then :meth:`start`; :meth:`join` waits for the end of the session,
    :meth:`close` pulls the plug for good. Totals of what was sent are in
    :attr:`bytes_sent`, :attr:`sample_frames_sent` (good sample frames),
    :attr:`samples_generated`; injections done are in :attr:`records`.
    """

    def __init__(
        self,
        board: SimulatedBoard,
        link: str | os.PathLike[str],
        injections: list[Injection],
        speed: float,
        host: Host | None = None,
        chunk_s: float = 0.05,
        seed: int = 0,
        connect_timeout_s: float = 30.0,
        after_write: Callable[[float], None] | None = None,
        encoder: DeviceEncoder | None = None,
    ) -> None:
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"speed must be a positive number, got {speed!r}")
        if board.total_samples is None:
            raise ValueError("the board needs a finite session (duration_s)")
        self.board = board
        self.link = Path(link)
        self.rate_hz = board.rate_hz
        self.speed = float(speed)
        self.host = host
        self.chunk_n = max(1, int(round(chunk_s * self.rate_hz)))
        self.rng = np.random.default_rng(seed)
        self.connect_timeout_s = connect_timeout_s
        #: called with the sample time (s) of the last sample sent after every write
        #: (a second stream paced by the same clock, e.g. the GNSS receiver of a drive)
        self.after_write = after_write
        #: the fake device the samples go out as (None: the board's own wire bytes)
        self.encoder = encoder
        self.pending = sorted(injections, key=lambda i: i.t_s)
        self.records: list[InjectionRecord] = []
        self.pair: Port | None = None
        self.bytes_sent = 0
        self._samples_withheld = 0  # sample frames corrupted or never sent
        self.samples_generated = 0
        self.error: BaseException | None = None
        self.wall_started_s: float | None = None
        #: (monotonic time s, samples sent so far) after every write: the board's pace
        self.pace: list[tuple[float, int]] = []
        self._last_piece = b""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="BoardFeeder")

    # -- lifetime -----------------------------------------------------------

    def plug(self) -> Port:
        """A new pty with the symlink pointing at its slave (a device that is no serial
        port, IIO, lays itself out instead: :meth:`.devices.IIOEncoder.open_port`)."""
        open_port = getattr(self.encoder, "open_port", None)
        self.pair = PtyPair(link=self.link) if open_port is None else open_port(self.link)
        assert self.pair is not None
        return self.pair

    def unplug(self) -> None:
        """Remove the symlink (as udev does when the device goes) and close the pty."""
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        if self.pair is not None:
            self.pair.close()
            self.pair = None

    def start(self, host: Host | None = None) -> None:
        """Start feeding in a background thread (after :meth:`plug` and the reader's start)."""
        if host is not None:
            self.host = host
        if self.host is None:
            raise ValueError("BoardFeeder.start: no host to wait for")
        if self.pair is None:
            self.plug()
        self._thread.start()

    def join(self, timeout_s: float | None = None) -> bool:
        """Wait for the session to end; True if it did (check :attr:`error`)."""
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def stop(self) -> None:
        """Stop feeding early."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(5.0)

    def close(self) -> None:
        """Stop and unplug."""
        self.stop()
        self.unplug()

    @property
    def t_end_s(self) -> float:
        """Sample time of the last sample generated, s."""
        return (self.samples_generated - 1) / self.rate_hz

    # -- the feeding thread ---------------------------------------------------

    def _run(self) -> None:
        try:
            self._feed()
        except BaseException as exc:  # reported to the caller through .error
            self.error = exc

    def _answer_host(self) -> None:
        """A device with a set-up dialogue (:attr:`.DeviceEncoder.dialogue`): read what the
        host sent and write the device's answers (not counted in :attr:`bytes_sent`: the
        host reads them while it configures the device, not as its stream)."""
        enc, pair = self.encoder, self.pair
        if enc is None or not enc.dialogue or pair is None or not pair.master_open:
            return
        try:
            data = read_available(pair.master_fd)
        except OSError:
            return
        reply = enc.answer(data) if data else b""
        if reply:
            sent = self.bytes_sent
            self._write(reply)
            self.bytes_sent = sent

    def _wait_connected(self, after: float) -> float:
        assert self.host is not None
        if self.encoder is not None and self.encoder.dialogue:  # answer while it configures
            end = time.monotonic() + self.connect_timeout_s
            wall = None
            while wall is None and time.monotonic() < end and not self._stop.is_set():
                self._answer_host()
                wall = self.host.wait_connected(after, 0.02)
            self._answer_host()  # the last set-up commands, sent before it said connected
        else:
            wall = self.host.wait_connected(after, self.connect_timeout_s)
        if wall is None:
            raise FeederError(
                f"the reader did not open {self.link} within {self.connect_timeout_s:g} s"
            )
        return wall

    def _feed(self) -> None:
        board = self.board
        total = board.total_samples
        assert total is not None
        self._wait_connected(0.0)
        start_wall = time.monotonic()
        self.wall_started_s = start_wall
        start_index = 0
        index = 0
        while index < total and not self._stop.is_set():
            end = min(index + self.chunk_n, total)
            parts: list[bytes] = []
            outage: Injection | None = None
            self._answer_host()
            while self.pending and self._index_of(self.pending[0]) < end:
                inj = self.pending.pop(0)
                k = max(self._index_of(inj), index)
                if k > index:
                    parts.append(self._generate(k - index))
                    index = k
                if inj.kind in ("unplug", "stall"):
                    outage = inj
                    break
                index = self._inject(inj, index, parts)
                end = max(end, index)
            if outage is None and end > index:
                parts.append(self._generate(end - index))
                index = end
            due = start_wall + (index - start_index) / (self.rate_hz * self.speed)
            delay = due - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                break
            self._write(b"".join(parts))
            self.pace.append((time.monotonic(), index))
            if self.after_write is not None:
                self.after_write((index - 1) / self.rate_hz)
            if outage is not None:
                if outage.kind == "unplug":
                    self._do_unplug(outage, index)
                else:
                    self._do_stall(outage, index)
                start_wall = time.monotonic()
                start_index = index

    def _index_of(self, inj: Injection) -> int:
        return int(math.ceil(inj.t_s * self.rate_hz - 1e-9))

    def _generate(self, n: int) -> bytes:
        data, block = self.board.generate(n)
        if self.encoder is not None:
            data = self.encoder.encode(block)
        self.samples_generated = self.board.next_index
        if data:
            self._last_piece = data
        return data

    def _record(
        self, inj: Injection, index: int, expected: dict[str, int | None], affected: int
    ) -> InjectionRecord:
        rec = InjectionRecord(
            inj, index, index / self.rate_hz, expected, affected, wall_s=time.monotonic()
        )
        self.records.append(rec)
        return rec

    def _inject(self, inj: Injection, index: int, parts: list[bytes]) -> int:
        """Splice ``inj`` at sample ``index`` into ``parts``; returns the next sample index."""
        assert inj.count is not None
        if inj.kind == "garbage":
            if self.encoder is not None:  # bytes that never start one of its frames
                alphabet = np.frombuffer(self.encoder.garbage_alphabet, np.uint8)
                parts.append(self.rng.choice(alphabet, inj.count).tobytes())
            else:
                parts.append(garbage(inj.count, self.rng, sync_free=not inj.random))
            expected: dict[str, int | None] = {"skipped_bytes": inj.count}
            if inj.random:
                expected["crc_errors"] = None  # false frame candidates: not predictable
            self._record(inj, index, expected, 0)
            return index
        if inj.kind == "duplicate":
            if self.encoder is not None:
                spans = self.encoder.split(self._last_piece)
                frame = spans[-1][0] if spans else b""
            else:
                frame = last_frame(self._last_piece)
            if not frame:
                raise FeederError(f"injection {inj.number}: no frame sent yet to duplicate")
            parts.append(frame * inj.count)
            self._record(inj, index, {"duplicates": inj.count}, inj.count)
            return index
        n = min(inj.count, (self.board.total_samples or 0) - index)
        piece = self._generate(n)
        if inj.kind == "crc":
            if self.encoder is not None:
                bad, k, skipped = self._corrupt_device_frames(piece)
            else:
                bad, k = corrupt_sample_frames(piece)
                skipped = k * 40
            parts.append(bad)
            self._samples_withheld += k
            expected = {"crc_errors": k, "skipped_bytes": skipped, "lost": k}
            self._record(inj, index, expected, k)
        else:  # lost: the frames (of any type) of these samples are never sent
            if self.encoder is not None:
                spans = self.encoder.split(piece)
                frames, samples = len(spans), sum(1 for _, is_sample in spans if is_sample)
            else:
                frames, samples = count_frames(piece)
            self._samples_withheld += samples
            self._record(inj, index, {"lost": frames}, frames)
        return index + n

    def _corrupt_device_frames(self, piece: bytes) -> tuple[bytes, int, int]:
        """``piece`` with every sample frame the device can break broken (its checksum
        fails, no frame start inside): (bytes, frames broken, their bytes)."""
        assert self.encoder is not None
        out: list[bytes] = []
        k = skipped = 0
        for frame, is_sample in self.encoder.split(piece):
            bad = self.encoder.corrupt(frame) if is_sample else None
            if bad is None:
                out.append(frame)
            else:
                out.append(bad)
                k += 1
                skipped += len(bad)
        return b"".join(out), k, skipped

    def _write(self, data: bytes) -> None:
        """Write all of ``data`` to the pty master, waiting for room (stops on :meth:`stop`)."""
        assert self.pair is not None
        fd = self.pair.master_fd
        view = memoryview(data)
        done = 0
        while done < len(view) and not self._stop.is_set():
            _, ready, _ = select.select([], [fd], [], 0.05)
            if ready:
                try:
                    done += os.write(fd, view[done:])
                except BlockingIOError:
                    continue
        self.bytes_sent += done

    @property
    def sample_frames_sent(self) -> int:
        """Sample frames sent with a good CRC: generated minus never sent and corrupted."""
        return self.samples_generated - self._samples_withheld

    def _do_stall(self, inj: Injection, index: int) -> None:
        rec = self._record(inj, index, {}, 0)
        rec.t_last_s = (index - 1) / self.rate_hz
        assert inj.outage_s is not None
        self._stop.wait(inj.outage_s)
        rec.wall_replug_s = time.monotonic()

    def _do_unplug(self, inj: Injection, index: int) -> None:
        rec = self._record(inj, index, {}, 0)
        rec.t_last_s = (index - 1) / self.rate_hz
        drain_timeout = 10.0
        assert self.host is not None
        rec.drained = (
            self.host.wait_bytes_read(self.bytes_sent, drain_timeout) if inj.drain else False
        )
        if inj.drain and not rec.drained:
            raise FeederError(
                f"injection {inj.number}: the reader did not read the "
                f"{self.bytes_sent} bytes sent within {drain_timeout:g} s"
            )
        rec.wall_s = time.monotonic()
        self.unplug()
        assert inj.outage_s is not None
        if self._stop.wait(inj.outage_s):
            return
        self.plug()
        rec.wall_replug_s = time.monotonic()
        rec.wall_reconnected_s = self._wait_connected(rec.wall_replug_s)


__all__ = ["BoardFeeder", "FeederError", "Host", "InjectionRecord", "Port"]
