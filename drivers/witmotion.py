"""``witmotion://DEVICE?baud=115200``: WitMotion WT901-class serial IMUs.

The WitMotion standard protocol: 11-byte frames ``0x55, type, 4 x int16
little-endian, checksum`` where the checksum is the low byte of the sum of the
first ten bytes. Frame types used:

- ``0x50`` time: year-2000, month, day, hour, minute, second (one byte each), ms (u16);
- ``0x51`` acceleration: ax ay az (v / 32768 x 16 g), temperature (v / 100 degC);
- ``0x52`` angular rate: wx wy wz (v / 32768 x 2000 deg/s), a fourth word (unused).

A sample is emitted when an acceleration frame is followed by its angular-rate
frame (the device sends them in that order each output period); an unpaired one
counts as a lost sample. Other frame types (angle 0x53, magnetic field 0x54,
quaternion 0x59, ...) are checked and skipped. Sample time: the time frame of the
period when the device sends it (turn it on in the WitMotion set-up tool: it makes
the timeline the device's own), else the sample count over ``rate``. Time starts at
0 at the first sample. Samples are in deg/s and g.

Query keys: ``baud`` (bit/s, default 115200), ``rate`` (the device's output rate,
Hz, default 200: the time step without time frames and the reference for lost
samples), ``model`` (product name reported, default ``WT901``), ``exclusive``.
"""

from __future__ import annotations

import datetime as _dt
import math
import struct
from typing import Any

import numpy as np

from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_GYRO_SATURATED, SampleBlock

from .base import SourceError, SourceURL, register
from .devicestream import DeviceDecoder, DeviceSerialSource, Timeline
from .wire import Counters

HEAD = 0x55
FRAME_SIZE = 11
TYPE_TIME = 0x50
TYPE_ACCEL = 0x51
TYPE_GYRO = 0x52
_TYPE_MIN, _TYPE_MAX = 0x50, 0x5F  #: the protocol's frame types
ACCEL_FULL_SCALE_G = 16.0  #: g at int16 full scale (32768)
GYRO_FULL_SCALE_DPS = 2000.0  #: deg/s at int16 full scale (32768)
TEMP_SCALE_C = 0.01  #: degC per count of the acceleration frame's fourth word
DEFAULT_RATE_HZ = 200.0
_EPOCH = _dt.datetime(2000, 1, 1)
_WORDS = struct.Struct("<4h")
_FEW_FRAMES = 64  #: reads of at most this many frames take the plain-Python path


def frame_checksum(body: bytes | np.ndarray) -> int:
    """The checksum byte of a frame's first ten bytes (low byte of their sum)."""
    return int(np.sum(np.frombuffer(bytes(body), dtype=np.uint8), dtype=np.int64)) & 0xFF


class WitmotionDecoder(DeviceDecoder):
    """Incremental decoder of the WitMotion standard protocol (see the module doc)."""

    units = {"gyro": "deg/s", "accel": "g"}

    def __init__(
        self,
        counters: Counters | None = None,
        rate_hz: float = DEFAULT_RATE_HZ,
        product: str = "WT901",
    ) -> None:
        super().__init__(counters)
        self.rate_hz = float(rate_hz)
        self.device_info.update(
            vendor="WitMotion",
            product=product,
            datasheet="witmotion-" + product.lower(),
            rate_hz=self.rate_hz,
        )
        self.timeline = Timeline(1e-6, None, 1.0 / self.rate_hz, origin_first=True)
        self.other_frames = 0  #: good frames of other types (angle, magnetic field, ...)
        self.time_frames = 0  #: good time frames
        self.bad_times = 0  #: time frames with an impossible date (ignored)
        self.unpaired = 0  #: acceleration or rate frames whose partner never came
        self._acc: np.ndarray | None = None  # the pending acceleration frame's 4 words
        self._time_us: int | None = None  # time of the latest time frame, us since 2000
        self._time_fresh = False  # a time frame arrived since the last sample
        self._count = 0  # samples placed (the time base without time frames)
        self._last_tick: int | None = None
        self._clock_mode: str | None = None  # "time" or "count"
        self._minute_key: tuple[int, ...] | None = None  # date part of the last time frame
        self._minute_s = 0  # its seconds since 2000

    # -- bytes -> frames --------------------------------------------------

    def _scan(self, buf: bytes) -> tuple[list[np.ndarray], int]:
        """Good frames (row blocks of shape (k, 11)) in stream order, and bytes consumed."""
        c = self.counters
        arr = np.frombuffer(buf, dtype=np.uint8)
        n = len(buf)
        pos = 0
        out: list[np.ndarray] = []
        while n - pos >= FRAME_SIZE:
            m = (n - pos) // FRAME_SIZE
            if buf[pos] == HEAD:
                rows = arr[pos : pos + m * FRAME_SIZE].reshape(m, FRAME_SIZE)
                good = (
                    (rows[:, 0] == HEAD)
                    & (rows[:, 1] >= _TYPE_MIN)
                    & (rows[:, 1] <= _TYPE_MAX)
                    & ((rows[:, :10].sum(axis=1, dtype=np.int64) & 0xFF) == rows[:, 10])
                )
                run = m if good.all() else int(np.argmin(good))
                if run:
                    out.append(rows[:run])
                    self.frame_bytes += run * FRAME_SIZE
                    pos += run * FRAME_SIZE
                    continue
                # a header that fails: a frame with a bad checksum, or a 0x55 in garbage
                if _TYPE_MIN <= buf[pos + 1] <= _TYPE_MAX:
                    c.crc_errors += 1
                c.skipped_bytes += 1
                pos += 1
                continue
            idx = buf.find(bytes([HEAD]), pos)
            if idx < 0:
                c.skipped_bytes += n - pos
                pos = n
                break
            c.skipped_bytes += idx - pos
            pos = idx
        return out, pos

    def _decode(self, buf: bytes) -> tuple[SampleBlock, int]:
        few = self._few_frames(buf)
        if few is not None:  # a daemon's read: a few good frames, checked in plain Python
            frames, used = few
            self.frame_bytes += used
            return self._samples(frames), used
        parts, used = self._scan(buf)
        if not parts:
            return SampleBlock.empty(), used
        rows = parts[0] if len(parts) == 1 else np.concatenate(parts)
        words = np.ascontiguousarray(rows[:, 2:10]).view("<i2").reshape(-1, 4).tolist()
        frames = list(zip(rows[:, 1].tolist(), words, rows.tolist(), strict=True))
        return self._samples(frames), used

    @staticmethod
    def _few_frames(buf: bytes) -> tuple[list[tuple[int, Any, Any]], int] | None:
        """The frames of a short, aligned, all-good ``buf`` (and the bytes they take), or
        None when the general path is needed (nothing is counted here)."""
        m = len(buf) // FRAME_SIZE
        if m == 0 or m > _FEW_FRAMES:
            return None
        used = m * FRAME_SIZE
        if used < len(buf) and buf[used] != HEAD:
            return None
        frames = []
        for p in range(0, used, FRAME_SIZE):
            ftype = buf[p + 1]
            if buf[p] != HEAD or not _TYPE_MIN <= ftype <= _TYPE_MAX:
                return None
            if sum(buf[p : p + 10]) & 0xFF != buf[p + 10]:
                return None
            frames.append((ftype, _WORDS.unpack_from(buf, p + 2), buf[p : p + FRAME_SIZE]))
        return frames, used

    # -- frames -> samples -------------------------------------------------

    def _samples(self, frames: list[tuple[int, Any, Any]]) -> SampleBlock:
        """Pair the acceleration and rate frames; ``frames``: (type, 4 words, raw bytes)."""
        acc_rows: list[Any] = []
        gyr_rows: list[Any] = []
        ticks: list[int] = []
        flags: list[int] = []
        for ftype, words, raw in frames:
            if ftype == TYPE_ACCEL:
                if self._acc is not None:
                    self._unpaired()  # an acceleration frame without its rate frame
                self._acc = words
            elif ftype == TYPE_GYRO:
                acc = self._acc
                if acc is None:
                    self._unpaired()  # a rate frame without its acceleration frame
                    continue
                acc_rows.append(acc)
                gyr_rows.append(words)
                self._acc = None
                ticks.append(self._tick())
                flag = 0
                if max(words[:3]) >= 32767 or min(words[:3]) <= -32768:
                    flag |= FLAG_GYRO_SATURATED
                if max(acc[:3]) >= 32767 or min(acc[:3]) <= -32768:
                    flag |= FLAG_ACCEL_SATURATED
                flags.append(flag)
            elif ftype == TYPE_TIME:
                self._time_frame(raw)
            else:
                self.other_frames += 1
        if not acc_rows:
            return SampleBlock.empty()
        acc_a = np.array(acc_rows, dtype=np.float64)
        gyr_a = np.array(gyr_rows, dtype=np.float64)
        flag_a = np.array(flags, dtype=np.uint16)
        keep, t = self.timeline.place(np.array(ticks, dtype=np.int64), self.counters)
        if t.shape[0] != acc_a.shape[0]:
            acc_a, gyr_a, flag_a = acc_a[keep], gyr_a[keep], flag_a[keep]
        return self._block(
            t,
            gyr_a[:, :3] * (GYRO_FULL_SCALE_DPS / 32768.0),
            acc_a[:, :3] * (ACCEL_FULL_SCALE_G / 32768.0),
            acc_a[:, 3] * TEMP_SCALE_C,
            flag_a,
        )

    def _unpaired(self) -> None:
        """A half sample (its other frame failed its checksum or never came). With time
        frames the timeline counts the missing sample from the gap; without, this does."""
        self.unpaired += 1
        if self._time_us is None:
            self.counters.lost += 1

    def _time_frame(self, raw: Any) -> None:
        """A time frame (bytes or a list of its 11 byte values)."""
        key = tuple(raw[2:7])  # year .. minute: the date part changes once a minute
        ss = int(raw[7])
        ms = int(raw[8]) | (int(raw[9]) << 8)
        if key != self._minute_key:
            yy, mo, dd, hh, mi = (int(v) for v in key)
            try:
                when = _dt.datetime(2000 + yy, mo, dd, hh, mi)
            except ValueError:
                self.bad_times += 1
                return
            self._minute_key = key
            self._minute_s = int((when - _EPOCH).total_seconds())
        if ms > 999 or ss > 59:
            self.bad_times += 1
            return
        self.time_frames += 1
        self._time_us = (self._minute_s + ss) * 1_000_000 + ms * 1000
        self._time_fresh = True

    def _tick(self) -> int:
        """The time stamp, us, of the sample being completed."""
        step = int(round(1e6 / self.rate_hz))
        if self._time_us is not None:
            if self._clock_mode != "time":
                self._clock_mode = "time"
                self.timeline.reanchor()
            if self._time_fresh:
                tick = self._time_us
            else:  # this period's time frame was lost: one period after the last
                tick = (self._last_tick or self._time_us) + step
            self._time_fresh = False
        else:
            self._clock_mode = "count"
            tick = self._count * step
        self._count += 1
        self._last_tick = tick
        return tick


@register("witmotion")
class WitmotionSource(DeviceSerialSource):
    """A WitMotion serial IMU (see the module docstring for the URL)."""

    url_keys = ("baud", "rate", "model", "exclusive")
    default_baud = 115200

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        self.port_url = url.target
        if not self.port_url:
            raise SourceError(f"{url.url}: no device path (witmotion:///dev/ttyUSB0)")
        rate = float(url.get("rate", DEFAULT_RATE_HZ, float))
        if not (rate > 0 and math.isfinite(rate)):
            raise SourceError(f"{url.url}: bad value for 'rate': {rate}")
        self.decoder = WitmotionDecoder(self.counters, rate, str(url.get("model", "WT901")))
        self.device_info = self.decoder.device_info
