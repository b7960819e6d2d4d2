"""Vibration of the installation: per-axis level of the high-passed specific force and
angular rate, and clipping counts (a check beside noise and saturation, issue 25).

High-frequency content on a vehicle is mostly motion, not the sensor's noise. As PX4 and
ArduPilot do (ArduPilot's VIBE: the standard deviation of the accelerometer high-passed at
5 Hz, per axis, m/s^2; clipping: samples at the sensor's range), the level here is the RMS
over ``window_s`` of each axis minus its trailing mean over ``1 / highpass_hz`` seconds (a
boxcar high-pass), in m/s^2 (accelerometers) and rad/s (gyros), from the raw outputs and
the certificate's scale factors (biases and slow motion are what the high-pass removes).
The windows are aligned on the stream's sample index, so the figures do not depend on how
the stream is cut into blocks. Clipping counts samples flagged saturated.

:class:`VibrationFigures` is the small structure a source may also fill from the
device's own figures (an autopilot's VIBRATION message: levels in m/s^2 and clipping
counts), handed over as ``Source.device_info["vibration"]`` in its :meth:`as_dict` form.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import units
from .certificate import Certificate, VibrationLimits
from .kernels import kernel
from .samples import FLAG_ACCEL_SATURATED, FLAG_GYRO_SATURATED, SampleBlock

#: What high vibration prevents, said in the status and the report beside the state.
HIGH_NOTE = (
    "high vibration: the white-noise check is not judged while both triads are shaken (it "
    "cannot tell vibration from a sensor's noise), few samples are still enough for the F0 "
    "checks and the window diagnosis, and clipped samples corrupt the velocity and attitude "
    "a navigation filter integrates; isolate or balance the mount"
)


@dataclass
class VibrationFigures:
    """One set of vibration figures: per-axis levels (RMS, ``accel`` m/s^2, ``gyro`` rad/s;
    None where not measured), clipped sample counts per triad, over ``window_s`` seconds,
    and who measured them (``imudiag`` or ``device``)."""

    accel: list[float] | None
    gyro: list[float] | None
    clipping: dict[str, int] = field(default_factory=lambda: {"accel": 0, "gyro": 0})
    window_s: float = 1.0
    source: str = "imudiag"

    def as_dict(self) -> dict[str, Any]:
        """JSON form, every number with its unit."""
        return {
            "source": self.source,
            "window_s": self.window_s,
            "accel": None if self.accel is None else {"level": self.accel, "unit": "m/s^2"},
            "gyro": None if self.gyro is None else {"level": self.gyro, "unit": "rad/s"},
            "clipping": dict(self.clipping),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> VibrationFigures:
        """Back from :meth:`as_dict`, or from a device source's ``device_info["vibration"]``
        in the device convention (docs/devices.md, item 5: ``accel_rms`` per axis in
        ``unit``, ``clipping`` a list of clipping counts per accelerometer, summed here)."""
        if "accel_rms" in d:
            unit = str(d.get("unit", "m/s^2"))
            k = units.factor("accel", unit, "m/s^2")
            clip = d.get("clipping") or []
            return cls(
                accel=[float(v) * k for v in d["accel_rms"]],
                gyro=None,
                clipping={"accel": int(sum(int(c) for c in clip)), "gyro": 0},
                window_s=float(d.get("window_s", 1.0)),
                source="device",
            )

        def levels(part: Any) -> list[float] | None:
            return None if not part else [float(v) for v in part["level"]]

        return cls(
            accel=levels(d.get("accel")),
            gyro=levels(d.get("gyro")),
            clipping={k: int(v) for k, v in (d.get("clipping") or {}).items()},
            window_s=float(d.get("window_s", 1.0)),
            source=str(d.get("source", "device")),
        )


class VibrationMeter:
    """Streaming vibration levels of both triads, block by block (module doc).

    ``rate_hz``: sample rate (Hz); ``window_s``: the RMS window (s); ``highpass_hz``: the
    corner of the boxcar high-pass (Hz).
    """

    def __init__(
        self,
        certificate: Certificate,
        rate_hz: float,
        window_s: float = 1.0,
        highpass_hz: float = 5.0,
    ) -> None:
        self.certificate = certificate
        self.limits = certificate.vibration or VibrationLimits()
        self.rate_hz = float(rate_hz)
        self.window_s = float(window_s)
        self.highpass_hz = float(highpass_hz)
        self.window = max(2, int(round(window_s * self.rate_hz)))
        self.hp = max(2, int(round(self.rate_hz / highpass_hz)))
        # raw outputs (gx..az) to rad/s and m/s^2 per axis
        g, a = certificate.gyro, certificate.accel
        self._to_si = np.concatenate(
            [
                g.unit_to_si / np.asarray(g.scale_factor, float),
                a.unit_to_si / np.asarray(a.scale_factor, float),
            ]
        )
        self._tail = np.zeros((0, 6))  # the last hp - 1 samples (raw, for the trailing mean)
        self._sumsq = np.zeros(6)  # of the window being filled, SI units^2
        self._count = 0  # samples in the window being filled
        self.seen = 0  #: samples fed
        self.last: np.ndarray | None = None  #: (6,) levels of the last whole window, SI
        self.peak = np.zeros(6)  #: (6,) the largest window level so far, SI
        self.windows = 0  #: whole windows measured
        self.high_windows = 0  #: of those, windows beyond the accelerometer ``high`` level
        self.clipping = {"accel": 0, "gyro": 0}  #: samples flagged saturated

    def update(self, block: SampleBlock) -> None:
        """Add the stream's next samples."""
        n = len(block)
        if n == 0:
            return
        if block.flags is not None:
            flags = np.asarray(block.flags).astype(np.int64)
            self.clipping["accel"] += int(np.count_nonzero(flags & FLAG_ACCEL_SATURATED))
            self.clipping["gyro"] += int(np.count_nonzero(flags & FLAG_GYRO_SATURATED))
        sq = self._highpassed(block)
        if not np.isfinite(sq).all():
            sq = np.nan_to_num(sq, nan=0.0, posinf=0.0, neginf=0.0)
        self._add_squares(sq)
        self.seen += n

    def _highpassed(self, block: SampleBlock) -> np.ndarray:
        """The block's high-passed samples squared (N, 6), SI units^2, the last ``hp - 1``
        samples kept for the next block's trailing means."""
        n, h = len(block), self.hp
        gyro = np.asarray(block.gyro, dtype=float)
        accel = np.asarray(block.accel, dtype=float)
        parts = kernel("highpass_parts")  # the compiled pass on the block as it is
        if parts is not None and np.isfinite(gyro).all() and np.isfinite(accel).all():
            sq = np.empty((n, 6))
            parts(self._tail, gyro, accel, h, self._to_si, sq)
            if h > 1:  # the tail's rows then the block's, the last h - 1 of them
                last = np.concatenate([gyro[-(h - 1) :], accel[-(h - 1) :]], axis=1)
                self._tail = np.concatenate([self._tail, last])[-(h - 1) :]
            return sq
        full = np.empty((self._tail.shape[0] + n, 6))
        full[: self._tail.shape[0]] = self._tail
        full[self._tail.shape[0] :, :3] = block.gyro
        full[self._tail.shape[0] :, 3:] = block.accel
        bad = ~np.isfinite(full)
        if bad.any():  # a non-finite output (the monitor counts it) adds no vibration and
            # must not reach the prefix sums: it stands at its axis's finite mean here
            count = np.count_nonzero(~bad, axis=0)
            fill = np.divide(
                np.where(bad, 0.0, full).sum(axis=0), count, out=np.zeros(6), where=count > 0
            )
            full = np.where(bad, fill, full)
        compiled = kernel("highpass_squares")  # the same operations in one pass: bit for bit
        if compiled is not None:
            sq = np.empty((n, 6))
            compiled(full, n, h, self._to_si, sq)
        else:
            x = full[self._tail.shape[0] :]
            # each sample minus the mean of the h samples ending at it (fewer at the stream's
            # start), from prefix sums of the samples centred on the first
            ref = full[0].copy()
            c = np.zeros((full.shape[0] + 1, 6))
            np.cumsum(full - ref, axis=0, out=c[1:])
            m = full.shape[0]
            hi = c[m - n + 1 : m + 1]
            if m - n + 1 - h >= 0:  # every window whole: contiguous slices, no gather
                mean = hi - c[m - n + 1 - h : m + 1 - h]
                mean /= h
            else:
                end = np.arange(m - n, m) + 1
                start = np.maximum(end - h, 0)
                mean = (hi - c[start]) / (end - start)[:, None]
            mean += ref
            hp = np.subtract(x, mean, out=mean)
            hp *= self._to_si
            sq = np.square(hp, out=hp)
        self._tail = full[-(h - 1) :].copy() if h > 1 else np.zeros((0, 6))
        return sq

    def _add_squares(self, sq: np.ndarray) -> None:
        """Add the squared high-passed samples ``sq`` (N, 6), SI units^2, to the windows."""
        n = sq.shape[0]
        # windows aligned on the stream index: the window being filled, then the block's
        # whole windows at once (each summed row by row as a slice of its own would be),
        # then the start of the next
        w = self.window
        pos = 0
        if self._count:
            pos = min(n, w - self._count)
            self._sumsq += sq[:pos].sum(axis=0)
            self._count += pos
            if self._count == w:
                self._windows_done(np.sqrt(self._sumsq / w)[None])
        whole = (n - pos) // w
        if whole:
            compiled = kernel("window_row_sums")  # the same sums in the same order
            if compiled is not None:
                sums = compiled(np.ascontiguousarray(sq), pos, whole, w)
            else:
                sums = sq[pos : pos + whole * w].reshape(whole, w, 6).sum(axis=1)
            self._windows_done(np.sqrt(sums / w))
            pos += whole * w
        if pos < n:
            self._sumsq += sq[pos:].sum(axis=0)
            self._count += n - pos

    def _windows_done(self, levels: np.ndarray) -> None:
        """Count whole windows of ``levels`` (M, 6) SI, in stream order; start a new one."""
        self.last = levels[-1]
        self.peak = np.maximum(self.peak, levels.max(axis=0))
        self.windows += levels.shape[0]
        self.high_windows += int(
            np.count_nonzero(levels[:, 3:].max(axis=1) > self.limits.accel_high)
        )
        self._sumsq = np.zeros(6)
        self._count = 0

    def figures(self) -> VibrationFigures | None:
        """The last whole window's figures, or None before one."""
        if self.last is None:
            return None
        return VibrationFigures(
            accel=[float(v) for v in self.last[3:]],
            gyro=[float(v) for v in self.last[:3]],
            clipping=dict(self.clipping),
            window_s=self.window_s,
        )


def vibration_object(
    meter: VibrationMeter | None, device: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The ``vibration`` object of the status and the report: ``state`` (``ok``, ``high``,
    ``unknown``), the last window's levels and the peak (per axis, with units), clipping
    counts, the thresholds and a ``note`` saying what high vibration prevents. ``device``:
    figures a source measured itself (:class:`VibrationFigures` as a dict), judged the same
    way and preferred where given."""
    limits = meter.limits if meter is not None else VibrationLimits()
    out: dict[str, Any] = {"state": "unknown"}
    figs = VibrationFigures.from_dict(device) if device else None
    if figs is None and meter is not None:
        figs = meter.figures()
    if figs is not None:
        out.update(figs.as_dict())
    if meter is not None and meter.last is not None:
        out["peak"] = {
            "accel": [float(v) for v in meter.peak[3:]],
            "gyro": [float(v) for v in meter.peak[:3]],
            "unit": {"accel": "m/s^2", "gyro": "rad/s"},
        }
        out["windows"] = meter.windows
        out["high_windows"] = meter.high_windows
        out["highpass_hz"] = meter.highpass_hz
    out["thresholds"] = {
        "accel_high": limits.accel_high,
        "accel_severe": limits.accel_severe,
        "unit": "m/s^2",
        "clipping": limits.clipping,
        "gyro_high": limits.gyro_high,
        "gyro_unit": "rad/s",
        "source": "certificate" if meter is not None and meter.certificate.vibration else
        "default (ArduPilot: 30 and 60 m/s^2 VIBE levels, no clipping)",
    }  # fmt: skip
    if figs is None or figs.accel is None:
        return out
    accel = max(figs.accel)
    clipped = sum(figs.clipping.values())
    gyro_high = (
        limits.gyro_high is not None and figs.gyro is not None and max(figs.gyro) > limits.gyro_high
    )
    high = accel > limits.accel_high or clipped > limits.clipping or gyro_high
    out["state"] = "high" if high else "ok"
    if high:
        why = []
        if accel > limits.accel_high:
            level = "severe" if accel > limits.accel_severe else "high"
            why.append(f"accel level {accel:.3g} m/s^2 ({level}, limit {limits.accel_high:g})")
        if clipped > limits.clipping:
            why.append(f"{clipped} clipped samples (tolerated {limits.clipping})")
        if gyro_high:
            assert figs.gyro is not None and limits.gyro_high is not None
            why.append(f"gyro level {max(figs.gyro):.3g} rad/s (limit {limits.gyro_high:g})")
        out["note"] = "; ".join(why) + f": {HIGH_NOTE}"
    else:
        out["note"] = (
            "vibration below the limits; high-frequency content beyond the certificate's "
            "noise while both triads are shaken is reported here, never as a sensor fault"
        )
    if not math.isfinite(accel):
        out["state"] = "unknown"
    return out


__all__ = ["HIGH_NOTE", "VibrationFigures", "VibrationMeter", "vibration_object"]
