"""replay://PATH?speed=1 — a recorded log played back as a live source.

``.bin`` raw captures go through the same wire :class:`Decoder` as live bytes
(so its counters report CRC errors, lost frames ... of the capture);
``.csv``, ``.csv.gz`` and ``.npz`` are read with :func:`imudiag.logs.open_log`.
``speed`` is the playback rate relative to the sample time ``t`` (1 = real
time, 10 = ten times faster, 0 = as fast as possible; then each read returns
at most ``step`` seconds of sample time, default 0.05 s, so the daemon's
checks, status lines and transitions follow sample time as they would live).
At the end
:meth:`read` raises :class:`EndOfStream`. A log that breaks a rule raises
:class:`imudiag.logs.LogError` (file, line, reason) when its block is reached.

``replay:///abs/path.bin`` and ``replay://relative/path.csv`` both work. A
user's text table is read with the query keys of the log commands' options:
``replay:///data/imu.txt?columns=t,gx,gy,gz,ax,ay,az&time_unit=ms`` (also
``units=gyro=deg/s,accel=g`` and ``rate=HZ`` for a table without time).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from imudiag.drivers.base import EndOfStream, Source, SourceError, SourceURL, register
from imudiag.drivers.wire import SAMPLE_FRAME_SIZE, Counters, Decoder
from imudiag.errors import BadInput
from imudiag.logs.options import URL_KEYS as LOG_URL_KEYS
from imudiag.logs.options import options_from_query
from imudiag.samples import SampleBlock

DEFAULT_BLOCK_SIZE = 16384  #: samples per block read from the file
DEFAULT_STEP_S = 0.05  #: sample time returned per read at speed 0, s
#: frames of a ``.bin`` capture decoded at a time: its counters (CRC errors, lost frames,
#: ...) reach the source's :attr:`counters` when the samples decoded with them are read,
#: so they accumulate in sample time (to within these frames), not all at the first read
BIN_CHUNK_FRAMES = 64


@register("replay")
class ReplaySource(Source):
    """Plays a sample log back, paced by its sample time ``t`` (seconds)."""

    url_keys = ("speed", "block_size", "step", *LOG_URL_KEYS)

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        if not url.target:
            raise SourceError(f"{url.url}: no file path (replay:///path/to/log.csv)")
        self.path = Path(url.target)
        speed = options.get("speed", url.get("speed", 1.0, float))
        self.speed = float(speed)
        if not np.isfinite(self.speed) or self.speed < 0:
            raise SourceError(f"{url.url}: bad value for 'speed': {speed!r} (need >= 0)")
        self.block_size = int(
            options.get("block_size", url.get("block_size", DEFAULT_BLOCK_SIZE, int))
        )
        if self.block_size < 1:
            raise SourceError(f"{url.url}: bad value for 'block_size': {self.block_size}")
        self.step_s = float(options.get("step", url.get("step", DEFAULT_STEP_S, float)))
        if not (np.isfinite(self.step_s) and self.step_s > 0):
            raise SourceError(f"{url.url}: bad value for 'step': {self.step_s!r} (need > 0 s)")
        try:  # columns, units, time_unit, rate: how to read a text table
            self.log_options = options_from_query(url.params)
        except BadInput as exc:
            raise SourceError(f"{url.url}: {exc}") from None
        self.decoder: Decoder | None = None
        self._wire_counters = Counters()
        self._counter_marks: list[tuple[int, dict[str, int]]] = []
        self._pulled = self._taken = 0  # samples decoded and read (a .bin capture)
        self._reader: Any = None
        self._blocks: Iterator[SampleBlock] | None = None
        self._buffer = SampleBlock.empty()
        self._exhausted = False
        self._t0: float | None = None
        self._wall0 = 0.0
        self._rate_said = False  # the log's sample rate stated in device_info (first block)

    def open(self) -> None:
        """Open the file; SourceError if missing, LogError if its header is bad."""
        if not self.path.is_file():
            raise SourceError(f"{self.url.url}: {self.path}: no such file")
        name = self.path.name.lower()
        self._buffer = SampleBlock.empty()
        self._exhausted = False
        self._t0 = None
        if name.endswith(".bin") and self._wire_capture():
            # the decoder counts into counters of its own; they are published as the
            # samples are read (:meth:`_publish_counters`)
            self._wire_counters = Counters()
            self._counter_marks = []
            self._pulled = self._taken = 0
            self.decoder = Decoder(self._wire_counters)
            self._blocks = self._bin_blocks()
        else:
            from imudiag.logs import open_log

            self._reader = open_log(self.path, self.block_size, options=self.log_options)
            self.device_info = dict(self._reader.meta)
            self._blocks = iter(self._reader)
        self._rate_said = False

    def _wire_capture(self) -> bool:
        """Whether a ``.bin`` file is a raw wire capture (not another format sharing the
        extension, an ArduPilot DataFlash log: told by its first bytes, as ``open_log``
        tells them)."""
        from imudiag.logs.registry import lookup

        return lookup(self.path).name == ".bin"

    def _bin_blocks(self) -> Iterator[SampleBlock]:
        assert self.decoder is not None
        try:
            fh = open(self.path, "rb")  # noqa: SIM115 - closed in finally, generator lifetime
        except OSError as e:
            raise SourceError(f"{self.url.url}: cannot read {self.path}: {e}") from e
        try:
            while chunk := fh.read(BIN_CHUNK_FRAMES * SAMPLE_FRAME_SIZE):
                yield self._temp_said(self.decoder.feed(chunk))
            yield self._temp_said(self.decoder.finish())
        finally:
            fh.close()

    def _temp_said(self, block: SampleBlock) -> SampleBlock:
        """Drop the frames' temp (0) when the capture's device info says it has none."""
        if self.decoder is not None and self.decoder.device_info.get("temperature") is False:
            block.temp = None
        return block

    def _pull(self) -> bool:
        """Append the next block of the file to the buffer; False at the end."""
        if self._exhausted or self._blocks is None:
            return False
        block = next(self._blocks, None)
        if block is None:
            self._exhausted = True
            return False
        if self.decoder is not None:
            self.device_info = self.decoder.device_info
            self._pulled += len(block)
            snapshot = self._wire_counters.as_dict()
            self._counter_marks.append((self._pulled, snapshot))
        else:
            self.counters.frames += len(block)
            if not self._rate_said:
                self._say_rate(block)
        if len(block):
            self._buffer = SampleBlock.concat([self._buffer, block]) if len(self._buffer) else block
        return True

    def _say_rate(self, first: SampleBlock) -> None:
        """State the log's sample rate in :attr:`device_info` as ``imudiag diagnose`` takes
        it (:func:`~imudiag.diagnosis.inputs.log_rate_hz`): the log's ``sample_rate`` where
        it states a number, else what the time stamps of its first block show, so that the
        daemon checks the samples at the rate ``diagnose`` does, not the certificate's."""
        from imudiag.logs.timing import first_block_rate_hz, metadata_rate

        self._rate_said = True
        if metadata_rate(self.device_info) is not None:
            return
        rate = first_block_rate_hz(first.t)
        if rate is not None:
            self.device_info["sample_rate"] = rate
            self.device_info["sample_rate_from"] = "the time stamps of the log's first block"

    def _take(self, n: int) -> SampleBlock:
        out = self._buffer.slice(0, n)
        self._buffer = self._buffer.slice(n, len(self._buffer))
        if self.decoder is not None:
            self._taken += len(out)
            self._publish_counters()
        return out

    def _publish_counters(self, everything: bool = False) -> None:
        """Copy into :attr:`counters` the capture's counters as of the samples read (all of
        them at the end of the file)."""
        latest = None
        marks = self._counter_marks
        while marks and (everything or marks[0][0] <= self._taken):
            latest = marks.pop(0)[1]
        if latest is not None:
            for key, value in latest.items():
                setattr(self.counters, key, value)

    def read(self, timeout_s: float = 0.1) -> SampleBlock:
        """The samples due by now (all of the next block at speed 0); EndOfStream at the end."""
        if self._blocks is None:
            raise SourceError(f"{self.url.url}: read on a source that is not open")
        if self.speed == 0:
            while not len(self._buffer) and self._pull():
                pass
            if not len(self._buffer):
                self._end()
            t = self._buffer.t
            if t[-1] - t[0] < self.step_s and not self._exhausted:
                self._pull()  # one step may span two file blocks
                t = self._buffer.t
            n = int(np.searchsorted(t, t[0] + self.step_s, side="left"))
            return self._take(max(n, 1))
        deadline = time.monotonic() + timeout_s
        if self._t0 is None:
            while not len(self._buffer) and self._pull():
                pass
            if not len(self._buffer):
                self._end()
            self._t0 = float(self._buffer.t[0])
            self._wall0 = time.monotonic()
        while True:
            now = time.monotonic()
            due_t = self._t0 + (now - self._wall0) * self.speed
            while not self._exhausted and (not len(self._buffer) or self._buffer.t[-1] <= due_t):
                self._pull()
            n_due = int(np.searchsorted(self._buffer.t, due_t, side="right"))
            if n_due:
                return self._take(n_due)
            if not len(self._buffer):
                self._end()
            next_wall = self._wall0 + (float(self._buffer.t[0]) - self._t0) / self.speed
            if next_wall > deadline:
                time.sleep(max(0.0, deadline - now))
                return SampleBlock.empty()
            time.sleep(max(0.0, next_wall - now))

    def _end(self) -> NoReturn:
        """The end of the file: every counter published, then EndOfStream."""
        if self.decoder is not None:
            self._publish_counters(everything=True)
        raise EndOfStream(str(self.path))

    def close(self) -> None:
        """Close the file; safe to call twice."""
        if self._blocks is not None and hasattr(self._blocks, "close"):
            self._blocks.close()
        self._blocks = None
        if self._reader is not None:
            self._reader.close()
            self._reader = None
