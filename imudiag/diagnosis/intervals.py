"""Quasi-static intervals collected from a sample stream, and the motions between them.

Each interval is reduced to what the scalar fits need: the mean outputs of
both triads (averaged *before* any squaring, design note §3), their sample
covariance (the noise of the mean is ``cov / n``), duration, mean temperature
and the attitude (the certificate-corrected specific-force direction). The
gyro samples of the motion between two consecutive intervals are kept (up to
``max_motion_s``) so the rotation they integrate to can be checked against the
change of the measured gravity direction.

Runs of static samples shorter than ``min_interval_s`` are treated as motion;
each interval's mean is weighted by its noise (its sample variance, never below
the unit's white noise, over the samples averaged), so short holds count less;
the last ``trim_s`` of every run are dropped (the trailing detector window
reacts to the start of a motion a few samples late); the gyro integral of a
motion reaches ``motion_margin_s`` into the still intervals on both sides (a
smooth turn begins and ends below the detector's threshold, and those parts
must be integrated: still samples only add their noise); runs longer than
``max_interval_s`` are split so that a unit standing still for hours still
produces intervals, with bounded memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..certificate import Certificate
from ..kernels import kernel
from ..quasistatic import BAD_FLAGS, DetectorPool, QuasiStaticDetector, SharedDetectorReader
from ..samples import SampleBlock
from .config import DiagnosisConfig

#: the diagnosis settings' defaults (one definition, :mod:`.config`)
_DEFAULTS = DiagnosisConfig()

# column layout of the buffered rows (_BAD: saturation / ADC-error flag of the sample)
_T, _G, _A, _TEMP, _BAD = 0, slice(1, 4), slice(4, 7), 7, 8
_NCOL = 9


@dataclass
class MotionSegment:
    """Gyro samples from the last sample of one interval to the first of the next.

    ``t`` (M,) s and ``gyro`` (M, 3) raw outputs. ``usable`` is false when the
    motion was too long to keep or the stream had a time gap inside it;
    ``reason`` says why. ``memo``: what the window diagnosis derived from the motion
    alone for a given gyro scale (whether it is usable, its rotation increments), kept
    because a motion is in every window of its interval (up to 24 of them).
    """

    t: np.ndarray
    gyro: np.ndarray
    usable: bool = True
    reason: str = ""
    memo: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def duration_s(self) -> float:
        """Length of the motion, s."""
        return float(self.t[-1] - self.t[0]) if self.t.shape[0] > 1 else 0.0


@dataclass
class QuasiStaticInterval:
    """One still stretch reduced to means (output units) and their noise."""

    index: int  #: running number in the stream
    t_start: float  #: s, first sample
    t_end: float  #: s, last sample
    n: int  #: samples averaged
    gyro_mean: np.ndarray  #: (3,) raw gyro outputs
    accel_mean: np.ndarray  #: (3,) raw accelerometer outputs
    gyro_cov: np.ndarray  #: (3, 3) sample covariance, output units^2
    accel_cov: np.ndarray  #: (3, 3) sample covariance, output units^2
    temp: float | None = None  #: mean temperature, degC
    up: np.ndarray = field(default_factory=lambda: np.zeros(3))  #: unit specific force, body
    before: MotionSegment | None = None  #: the motion since the previous interval
    #: (3,) per-sample white-noise variance of the unit (output units^2) when the interval
    #: closed, from the still detector (measured from the data unless told to trust the
    #: certificate); None when not known yet
    gyro_noise_var: np.ndarray | None = None
    accel_noise_var: np.ndarray | None = None

    @property
    def duration_s(self) -> float:
        """Length of the interval, s."""
        return self.t_end - self.t_start

    def mean(self, triad: str) -> np.ndarray:
        """Mean raw output (3,) of ``gyro`` or ``accel``."""
        return self.gyro_mean if triad == "gyro" else self.accel_mean

    def cov(self, triad: str) -> np.ndarray:
        """Sample covariance (3, 3) of ``gyro`` or ``accel``, output units^2."""
        return self.gyro_cov if triad == "gyro" else self.accel_cov

    def mean_var(self, triad: str) -> np.ndarray:
        """Variance of the mean (3,), output units^2: the sample variance over n, never below
        the unit's white noise over n (a short interval's sample variance can be low by
        chance, and would weigh it far above its worth)."""
        var = np.diag(self.cov(triad))
        floor = self.noise_floor(triad)
        if floor is not None:
            var = np.maximum(var, floor)
        return var / max(self.n, 1)

    def noise_floor(self, triad: str) -> np.ndarray | None:
        """Per-sample white-noise variance (3,) of ``gyro`` or ``accel``, output units^2;
        None when not known."""
        return self.gyro_noise_var if triad == "gyro" else self.accel_noise_var

    @property
    def roll_pitch_deg(self) -> tuple[float, float]:
        """Roll and pitch (deg) of the attitude, from the specific-force direction."""
        f = self.up
        roll = math.degrees(math.atan2(-f[1], -f[2]))
        pitch = math.degrees(math.atan2(f[0], math.hypot(f[1], f[2])))
        return roll, pitch


def stacked_mean_var(
    intervals: list[QuasiStaticInterval], triad: str, covs: np.ndarray
) -> np.ndarray:
    """:meth:`QuasiStaticInterval.mean_var` of every interval (K, 3), output units^2, bit
    for bit, in a few whole-array operations; ``covs`` (K, 3, 3) their sample covariances
    (output units^2) in the same order."""
    floors = [iv.noise_floor(triad) for iv in intervals]
    if not intervals or any(f is None for f in floors):
        return np.array([iv.mean_var(triad) for iv in intervals])
    var = np.maximum(covs.diagonal(axis1=1, axis2=2), np.array(floors, dtype=float))
    counts = np.array([max(iv.n, 1) for iv in intervals], dtype=float)
    return var / counts[:, None]


def mean_and_cov(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x.mean(axis=0)`` and ``np.cov(x, rowvar=False)`` of samples ``x`` (N, 3), N >= 2,
    bit for bit: np.cov's own steps (a contiguous copy, its mean along the samples, the
    centred product), its mean kept (the same reduction in the same memory order as
    ``x.mean(axis=0)``), without np.cov's argument handling or a second mean."""
    c = np.array(x, dtype=float)
    ct = c.T
    avg = ct.mean(axis=1)
    mean = avg.copy()
    ct -= avg[:, None]
    cov = np.dot(ct, ct.T.conj())
    cov *= np.true_divide(1, c.shape[0] - 1)
    return mean, cov


def _rows(block: SampleBlock) -> np.ndarray:
    n = len(block)
    out = np.empty((n, _NCOL))
    compiled = kernel("interval_rows")
    if compiled is not None:  # the same rows in one pass
        none = np.zeros(0)
        compiled(
            np.asarray(block.t, dtype=float),
            np.asarray(block.gyro, dtype=float),
            np.asarray(block.accel, dtype=float),
            none if block.temp is None else np.asarray(block.temp, dtype=float),
            np.zeros(0, dtype=np.int64)
            if block.flags is None
            else np.ascontiguousarray(block.flags, dtype=np.int64),
            int(BAD_FLAGS),
            out,
        )
        return out
    out[:, _T] = block.t
    out[:, _G] = block.gyro
    out[:, _A] = block.accel
    out[:, _TEMP] = np.nan if block.temp is None else block.temp
    out[:, _BAD] = 0.0
    if block.flags is not None:
        out[:, _BAD] = (np.asarray(block.flags).astype(np.int64) & BAD_FLAGS) != 0
    return out


class IntervalCollector:
    """Streaming collector: feed blocks, get the intervals that closed.

    ``certificate`` gives the detector thresholds and the attitude of each
    interval; ``rate_hz`` the sample rate (Hz, defaults to the certificate's).
    ``detectors``: where the still detector comes from, to share it with other consumers of
    the same stream (``imudiag diagnose``: the monitor's, when alike); None: its own.
    """

    def __init__(
        self,
        certificate: Certificate,
        rate_hz: float | None = None,
        detector_window_s: float = _DEFAULTS.detector_window_s,
        min_interval_s: float = _DEFAULTS.min_interval_s,
        max_interval_s: float = _DEFAULTS.max_interval_s,
        trim_s: float = _DEFAULTS.trim_s,
        motion_margin_s: float = _DEFAULTS.motion_margin_s,
        max_motion_s: float = _DEFAULTS.max_motion_s,
        max_time_step_s: float | None = None,
        detector_options: dict | None = None,
        detectors: DetectorPool | None = None,
    ) -> None:
        self.certificate = certificate
        self.rate_hz = float(rate_hz or certificate.sample_rate)
        make = QuasiStaticDetector if detectors is None else detectors.detector
        self.detector: QuasiStaticDetector | SharedDetectorReader = make(
            certificate, self.rate_hz, window_s=detector_window_s, **(detector_options or {})
        )
        self.min_n = max(3, int(round(min_interval_s * self.rate_hz)))
        self.max_n = max(self.min_n + 1, int(round(max_interval_s * self.rate_hz)))
        self.trim_n = max(0, int(round(trim_s * self.rate_hz)))
        self.margin_n = max(0, int(round(motion_margin_s * self.rate_hz)))
        self.max_motion_n = int(round(max_motion_s * self.rate_hz))
        self.max_time_step_s = (
            max_time_step_s if max_time_step_s is not None else 3.0 / self.rate_hz
        )
        self._run: list[np.ndarray] = []
        self._run_n = 0
        self._gap: list[np.ndarray] = []
        self._gap_n = 0
        self._gap_usable = True
        self._gap_reason = ""
        self._have_interval = False
        self._last_t: float | None = None
        self._count = 0
        self.samples = 0  #: samples seen
        self.static_samples = 0  #: samples flagged static by the detector
        #: still runs dropped as shorter than the minimum hold (after the trim)
        self.dropped_short = 0

    # -- buffers ---------------------------------------------------------------

    def _gap_append(self, rows: np.ndarray) -> None:
        if not self._have_interval or rows.shape[0] == 0:
            return
        if not self._gap_usable:
            return
        if self._gap_n + rows.shape[0] > self.max_motion_n:
            self._gap, self._gap_n = [], 0
            self._gap_usable = False
            self._gap_reason = "motion longer than max_motion_s"
            return
        if np.any(rows[:, _BAD] != 0):
            self._gap, self._gap_n = [], 0
            self._gap_usable = False
            self._gap_reason = "saturated or ADC-error samples in the motion"
            return
        self._gap.append(rows)
        self._gap_n += rows.shape[0]

    def _mark_time_gap(self) -> None:
        self._gap, self._gap_n = [], 0
        self._gap_usable = False
        self._gap_reason = "time gap in the samples"

    def _noise_var(self, triad: str) -> np.ndarray | None:
        sigma = self.detector.noise_sigma(triad)
        return None if sigma is None else np.asarray(sigma, dtype=float) ** 2

    def _emit(self, rows: np.ndarray) -> QuasiStaticInterval:
        """Reduce static rows to an interval; the rows' first sample closes the motion."""
        g = rows[:, _G]
        a = rows[:, _A]
        n = rows.shape[0]
        before = None
        if self._have_interval:
            if self._gap_usable:
                # ... and ends motion_margin_s into this interval
                seg = np.concatenate(self._gap + [rows[: self.margin_n + 1]])
                before = MotionSegment(t=seg[:, _T].copy(), gyro=seg[:, _G].copy())
            else:
                before = MotionSegment(
                    t=np.zeros(0), gyro=np.zeros((0, 3)), usable=False, reason=self._gap_reason
                )
        temp = rows[:, _TEMP]
        temp_mean = float(np.mean(temp)) if np.all(np.isfinite(temp)) else None
        if n > 1:  # in fleet workers one compiled pass each (the mean exact)
            moments = kernel("mean_cov3") or mean_and_cov
            gyro_mean, gyro_cov = moments(g)
            acc_mean, accel_cov = moments(a)
        else:
            gyro_mean, gyro_cov = g.mean(axis=0), np.zeros((3, 3))
            acc_mean, accel_cov = a.mean(axis=0), np.zeros((3, 3))
        try:
            f = self.certificate.accel.inverse(acc_mean[None, :])[0]
            up = f / np.linalg.norm(f)
        except (np.linalg.LinAlgError, FloatingPointError):
            up = np.zeros(3)
        iv = QuasiStaticInterval(
            index=self._count,
            t_start=float(rows[0, _T]),
            t_end=float(rows[-1, _T]),
            n=n,
            gyro_mean=gyro_mean,
            accel_mean=acc_mean,
            gyro_cov=gyro_cov,
            accel_cov=accel_cov,
            temp=temp_mean,
            up=up,
            before=before,
            gyro_noise_var=self._noise_var("gyro"),
            accel_noise_var=self._noise_var("accel"),
        )
        self._count += 1
        self._have_interval = True
        lead = rows[-min(n, self.margin_n + 1) :]  # the motion's integral starts here
        self._gap = [lead]
        self._gap_n = lead.shape[0]
        self._gap_usable = True
        self._gap_reason = ""
        return iv

    def _close_run(self, out: list[QuasiStaticInterval], final: bool = False) -> None:
        if not self._run:
            return
        rows = np.concatenate(self._run)
        self._run, self._run_n = [], 0
        keep = rows.shape[0] if final else rows.shape[0] - self.trim_n
        if keep >= self.min_n:
            out.append(self._emit(rows[:keep]))
            self._gap_append(rows[keep:])
        else:
            self.dropped_short += 1
            self._gap_append(rows)

    def _split_long_run(self, out: list[QuasiStaticInterval]) -> None:
        limit = self.max_n + self.trim_n + self.min_n
        if self._run_n < limit:
            return
        # the run joined once, and cut into max_n-row intervals from its start (was: joined
        # again after every cut, quadratic in a long hold's length)
        rows = np.concatenate(self._run)
        start = 0
        while rows.shape[0] - start >= limit:
            out.append(self._emit(rows[start : start + self.max_n]))
            self._gap = [rows[start + self.max_n - 1 : start + self.max_n]]
            self._gap_n = 1
            start += self.max_n
        rest = rows[start:]
        self._run, self._run_n = [rest], rest.shape[0]

    # -- streaming -------------------------------------------------------------

    def update(self, block: SampleBlock) -> list[QuasiStaticInterval]:
        """Feed a block; returns the intervals it closed, in order."""
        out: list[QuasiStaticInterval] = []
        n = len(block)
        if n == 0:
            return out
        mask = self.detector.update(block)
        self.samples += n
        self.static_samples += int(mask.sum())
        rows = _rows(block)
        t = rows[:, _T]
        prev = np.concatenate([[self._last_t if self._last_t is not None else t[0]], t[:-1]])
        jump = (t - prev) > self.max_time_step_s
        self._last_t = float(t[-1])
        # segment boundaries: changes of the mask and time gaps
        change = np.flatnonzero((np.diff(mask.astype(np.int8)) != 0) | jump[1:]) + 1
        starts = np.concatenate([[0], change])
        stops = np.concatenate([change, [n]])
        for s0, s1 in zip(starts, stops, strict=True):
            if jump[s0]:
                self._close_run(out)
                self._mark_time_gap()
            seg = rows[s0:s1]
            if mask[s0]:
                self._run.append(seg)
                self._run_n += seg.shape[0]
                self._split_long_run(out)
            else:
                self._close_run(out)
                self._gap_append(seg)
        return out

    def flush(self) -> list[QuasiStaticInterval]:
        """At the end of a stream: close a static run still open (no trimming)."""
        out: list[QuasiStaticInterval] = []
        self._close_run(out, final=True)
        return out


__all__ = ["IntervalCollector", "QuasiStaticInterval", "MotionSegment", "stacked_mean_var"]
