"""What the device protocols share: a decoder interface, a device timeline, a serial source.

The device protocols (``isensor://``, ``witmotion://``; ``iio://`` reads a character
device instead of a port) are sources beside the native wire protocol. Each has a
decoder with the native :class:`~imudiag.drivers.wire.Decoder`'s interface (``feed``,
``drop_pending``, ``device_info``, the shared :class:`~imudiag.drivers.wire.Counters`),
so :class:`~imudiag.drivers.bytesource.ByteSource` (and through it the serial
transport and :class:`~imudiag.drivers.reconnect.ReconnectingSource`) drives it the
way it drives the native decoder: counters and timeline survive a reconnect.

Every device decoder delivers samples in the device's physical units and declares
them as the log readers do (``meta["units"] = {"gyro": ..., "accel": ...}``, also in
``device_info["units"]``); converting them to a certificate's units is not done here.

``device_info`` keys every device source sets (docs/devices.md): ``vendor``,
``product``, ``serial``, ``firmware`` and ``datasheet`` (the name of a bundled
data-sheet certificate, ``config/datasheets/<datasheet>.yaml``, or None).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from imudiag.samples import SampleBlock

from .base import SourceError, SourceURL
from .serial_port import SerialSource
from .wire import Counters, PendingBytes

_FEW = 32  #: blocks of at most this many samples take the plain-Python timeline path
#: device_info keys every device source fills (None where the device does not say)
IDENTITY_KEYS = ("vendor", "product", "serial", "firmware", "datasheet")


def identity(**known: Any) -> dict[str, Any]:
    """A device_info dict with every :data:`IDENTITY_KEYS` key (None where not given)."""
    info: dict[str, Any] = {key: None for key in IDENTITY_KEYS}
    info.update(known)
    return info


class DeviceDecoder(PendingBytes, ABC):
    """Bytes of one device protocol in, :class:`SampleBlock` in physical units out.

    Byte accounting as the native decoder keeps it::

        counters.bytes == frame_bytes + counters.skipped_bytes + pending_bytes

    ``frame_bytes``: bytes of every frame (or line) that passed its checksum;
    ``skipped_bytes``: every other byte stepped over while resynchronising, the
    bytes of frames whose checksum failed included.
    """

    #: the units of the samples, as a log declares them
    units: dict[str, str] = {}

    def __init__(self, counters: Counters | None = None) -> None:
        self.counters = counters if counters is not None else Counters()
        self.device_info: dict[str, Any] = identity(units=dict(self.units))
        self.frame_bytes = 0
        self._pending = b""
        self._meta: dict[str, Any] = {"units": dict(self.units)}

    def feed(self, data: bytes | bytearray | memoryview) -> SampleBlock:
        """Decode ``data`` plus held-back bytes; returns the complete good samples."""
        buf = self._joined(data)
        block, used = self._decode(buf)
        self._pending = buf[used:]
        return block

    @abstractmethod
    def _decode(self, buf: bytes) -> tuple[SampleBlock, int]:
        """Samples of the whole frames in ``buf`` and how many bytes were consumed."""

    def _block(
        self,
        t: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        temp: np.ndarray | None,
        flags: np.ndarray,
    ) -> SampleBlock:
        """The block of the kept samples, counted as frames delivered."""
        n = int(t.shape[0])
        if n == 0:
            return SampleBlock.empty()
        self.counters.frames += n
        return SampleBlock(
            t=np.asarray(t, dtype=np.float64),
            gyro=np.ascontiguousarray(gyro, dtype=np.float64),
            accel=np.ascontiguousarray(accel, dtype=np.float64),
            temp=None if temp is None else np.asarray(temp, dtype=np.float64),
            flags=np.asarray(flags, dtype=np.uint16),
            meta=self._meta,
        )


class Timeline:
    """Device time stamps (integer ticks) -> strictly increasing seconds, with the native
    decoder's rules (spec/wire-protocol.md, applied to a device clock instead of seq):

    - a step of zero ticks is a duplicate: dropped, counted in ``duplicates``;
    - a step backwards (device restart, clock step) re-anchors: the sample gets the
      previous time plus the last normal interval, ``restarts`` counts it;
    - with ``nominal_dt_s`` known, a step of k > 1.5 nominal intervals counts
      round(k) - 1 lost samples.

    ticks are ``tick_s`` seconds each and wrap at ``modulus`` (None: never).
    ``origin_first``: time 0 is the first sample (else ticks x tick_s as sent).
    """

    def __init__(
        self,
        tick_s: float,
        modulus: int | None = None,
        nominal_dt_s: float | None = None,
        origin_first: bool = False,
    ) -> None:
        self.tick_s = float(tick_s)
        self.modulus = modulus
        self.nominal_dt_s = nominal_dt_s
        self.origin_first = origin_first
        self.restarts = 0
        self._last: int | None = None
        self._started = False
        self._t = 0.0
        self._last_dt = float(nominal_dt_s or 0.0)

    def reanchor(self) -> None:
        """The next tick starts a new count (the clock changed): it follows the last
        sample by one normal interval."""
        if self._last is not None:
            self._last = None
            self.restarts += 1

    def place(
        self, ticks: np.ndarray | list[int], counters: Counters
    ) -> tuple[np.ndarray, np.ndarray]:
        """``keep`` (N,) bool and the times, s, of the kept samples; updates the counters."""
        if len(ticks) <= _FEW:
            return self._place_few(ticks, counters)
        tk = np.asarray(ticks, dtype=np.int64)
        n = tk.shape[0]
        if n == 0:
            return np.zeros(0, bool), np.zeros(0)
        first = self._last is None
        prev = np.empty(n, np.int64)
        prev[1:] = tk[:-1]
        prev[0] = int(tk[0]) if self._last is None else self._last
        d = tk - prev
        if self.modulus:
            half = self.modulus // 2
            d = ((d + half) % self.modulus) - half
        keep = d != 0
        if first:
            keep[0] = True
        dup = n - int(np.count_nonzero(keep))
        if dup:
            counters.duplicates += dup
            d = d[keep]
        dt = d.astype(np.float64) * self.tick_s
        if first and not self._started:
            dt[0] = 0.0
            self._t = 0.0 if self.origin_first else float(tk[0]) * self.tick_s
            self._started = True
        elif first:  # re-anchored: one normal interval after the last sample
            dt[0] = self._last_dt
        nominal = self.nominal_dt_s
        if nominal:  # before the restarts get their stand-in interval: a restart loses nothing
            k = dt / nominal
            gaps = k[k > 1.5]
            if gaps.size:
                counters.lost += int(np.sum(np.rint(gaps) - 1))
        back = np.flatnonzero(dt < 0)
        if back.size:
            self.restarts += int(back.size)
            for r in back.tolist():
                dt[r] = dt[r - 1] if r > 0 and dt[r - 1] > 0 else self._last_dt
        t = self._t + np.cumsum(dt)
        kept_ticks = tk[keep]
        self._last = int(kept_ticks[-1])
        self._t = float(t[-1])
        positive = dt[dt > 0]
        if positive.size:
            self._last_dt = float(positive[-1])
        return keep, t

    def _place_few(self, ticks: Any, counters: Counters) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`place` for a daemon's read (a few samples) in plain Python: the same
        rules, without the fixed cost of a dozen numpy calls."""
        tl = ticks.tolist() if isinstance(ticks, np.ndarray) else list(ticks)
        keep = [True] * len(tl)
        times: list[float] = []
        last, t, last_dt = self._last, self._t, self._last_dt
        tick, mod, nominal = self.tick_s, self.modulus, self.nominal_dt_s
        half = mod // 2 if mod else 0
        for i, tk in enumerate(tl):
            if last is None:
                if self._started:  # re-anchored: one normal interval after the last sample
                    t += last_dt
                else:
                    t = 0.0 if self.origin_first else tk * tick
                    self._started = True
                last = tk
                times.append(t)
                continue
            d = tk - last
            if mod:
                d = ((d + half) % mod) - half
            if d == 0:
                keep[i] = False
                counters.duplicates += 1
                continue
            dt = d * tick
            if dt < 0:
                self.restarts += 1
                dt = last_dt
            elif nominal and dt > 1.5 * nominal:
                counters.lost += round(dt / nominal) - 1
            t += dt
            last = tk
            if dt > 0:
                last_dt = dt
            times.append(t)
        self._last, self._t, self._last_dt = last, t, last_dt
        return np.array(keep, dtype=bool), np.array(times, dtype=np.float64)


def saturation_flags(
    gyro_raw: np.ndarray, accel_raw: np.ndarray, lo: int, hi: int, flags: np.ndarray
) -> np.ndarray:
    """``flags`` with the saturation bits set where a raw output sits at ``lo`` or ``hi``."""
    from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_GYRO_SATURATED

    if gyro_raw.shape[0] == 0:  # every sample of the read dropped (repeats)
        return flags.astype(np.uint16)
    inside = lo < gyro_raw.min() and gyro_raw.max() < hi
    if inside and lo < accel_raw.min() and accel_raw.max() < hi:
        return flags.astype(np.uint16)  # the common case: nothing at full scale
    g = ((gyro_raw <= lo) | (gyro_raw >= hi)).any(axis=1)
    a = ((accel_raw <= lo) | (accel_raw >= hi)).any(axis=1)
    out = flags.astype(np.uint16)
    out[g] |= FLAG_GYRO_SATURATED
    out[a] |= FLAG_ACCEL_SATURATED
    return out


class DeviceSerialSource(SerialSource):
    """A device protocol on a serial port (CDC-ACM, FTDI/CH340 UART): pyserial for the
    bytes, the protocol's decoder for the samples.

    Subclasses set ``decoder`` in ``__init__`` (after this one) and may override
    :meth:`_configure` (run after the port opened: the host's set-up dialogue) and
    :meth:`write_command`.
    """

    default_baud = 115200  #: bit/s when the URL gives none

    def __init__(self, url: SourceURL, **options: Any) -> None:
        if "baud" not in options and "baud" not in url.params:
            options = {**options, "baud": self.default_baud}
        super().__init__(url, **options)

    def _open_transport(self) -> None:
        super()._open_transport()
        try:
            self._configure()
        except SourceError:
            self._close_transport()
            raise

    def _configure(self) -> None:
        """The host's set-up dialogue with the device (none by default)."""

    def write_command(self, line: str) -> None:
        """Device commands the protocol knows (see the subclass); others are refused."""
        raise ValueError(
            f"{self.url.scheme}://: unknown device command {line.strip()!r} "
            f"(this device takes none)"
        )
