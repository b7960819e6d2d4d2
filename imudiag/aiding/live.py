"""Live GNSS aiding in the daemon: gpsd TPV reports beside the IMU stream.

The IMU's sample time is the device clock (the wire protocol's microsecond
counter), not UTC. The two clocks are tied by the arrivals: each TPV's UTC
time minus the newest IMU sample time when it arrived, median over the last
50 fixes (the *clock offset*); what is left (GNSS output latency, buffering)
is the *latency* estimated by cross-correlating |f| (:mod:`.align`) once a
window of epochs is there (or configured).

Every ``batch_s`` of fixes the new GNSS epochs are checked (F0 in motion,
:mod:`.moving`; a fault when 5 of the last 10 epochs fail) and their means
kept, and the gyros are checked in the buffer's turns against the GNSS course
rate (:mod:`.course_rate`, no-slip assumption; faults latched); every
``step_s`` the isolation runs over the last ``window_s`` (:mod:`.isolation`,
with the onset test of :mod:`.onset`). The IMU buffer keeps ``window_s`` + 30 s. :meth:`status`
says whether aiding is in use and why not: gpsd not reachable, no TPV yet, an
outage, no 3D fix, still collecting.

A batch (latency search, lever arm, isolation) costs up to about 0.5 s of CPU
per minute of fixes at 200 Hz, several at 1 kHz: it runs in a worker process
(:mod:`.worker`), so the sampling loop only gathers samples and fixes, hands a
batch the new ones (:class:`BatchInput`; the batches keep the IMU buffer) and
reads the last published :class:`BatchResult`. ``mode="thread"`` or
``"inline"`` run the same batches in a thread or in :meth:`LiveAiding.update`
(offline, deterministic tests).
"""

from __future__ import annotations

import functools
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..certificate import Certificate
from ..quasistatic import BAD_FLAGS
from ..samples import SampleBlock
from .align import estimate_latency, latency_sigma, unknown_latency_std, used_latency
from .course_rate import turn_check
from .gpsd_client import GpsdClient
from .isolation import IsolationTracker
from .joint import separate_latency_std
from .lever_arm import LeverArmEstimate
from .moving import (
    MovingConfig,
    accel_noise,
    epoch_observations,
    estimate_lever_arm,
    gyro_noise_si,
    solve_jointly,
)
from .onset import isolate_window
from .specific_force import GnssEpochs, ImuEpochs, ImuSeries, gnss_epochs
from .tpv import GnssTrack, track_from_reports
from .worker import JOIN_TIMEOUT_S, BatchWorker

#: F0 in motion is a fault when k of the last n checked epochs fail
F0_PERSIST_K, F0_PERSIST_N = 5, 10


@dataclass(frozen=True)
class BatchInput:
    """What the sampling loop hands a batch: the IMU samples that arrived since the last
    batch (the batches keep the buffer of ``buffer_s``; the loop copies nothing big and
    concatenates nothing per block), the fixes over the buffer, the clock offset and the
    certificate with its version (a reload is applied by the batch that first sees it)."""

    t: np.ndarray  #: new IMU sample times, s (device clock)
    accel: np.ndarray  #: (N, 3) new raw accelerometer samples, certificate units
    gyro: np.ndarray  #: (N, 3) new raw gyro samples, certificate units
    fixes: list[dict]  #: parsed TPV reports over the buffer, oldest first
    offset_s: float  #: clock offset, s: UTC = device time + offset
    certificate: Certificate
    certificate_version: int = 0  #: 0 at start, +1 per reload


@dataclass(frozen=True)
class BatchResult:
    """What a batch publishes (the loop reads it for :meth:`LiveAiding.status`)."""

    batches: int = 0  #: batches completed so far (a failed one is not counted)
    latency_s: float = 0.0
    latency_note: str = "not yet estimated"
    latency_std_s: float = math.nan  #: std of latency_s, s (0 when configured)
    lever_estimate: LeverArmEstimate | None = None
    joint: dict = field(default_factory=dict)  #: the joint latency-lever solution's report
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    last_batch: dict = field(default_factory=dict)
    f0_checked: int = 0
    f0_failed: int = 0
    f0_fault: bool = False
    windows: int = 0
    raised: tuple[dict, ...] = ()  #: the isolation's latched faults
    #: the last isolation window's onset test (:mod:`.onset`), None before the first
    onset: dict | None = None
    #: the gyros in turns over the buffer (:mod:`.course_rate`), and the latched gyro
    #: faults as (sensor, cause), sorted
    turns: dict = field(
        default_factory=lambda: {"verdict": "unknown", "reason": "no GNSS epoch checked yet"}
    )
    gyro_faults: tuple[tuple[str, str], ...] = ()
    certificate_version: int = 0  #: the certificate version the batches use


class AidingBatches:
    """The state the batches carry from one to the next (epoch history, isolation
    tracker, latency and lever arm), the IMU buffer of ``buffer_s`` s, and the batch
    itself (call the instance with a :class:`BatchInput`). One caller at a time: the
    worker process or thread, or the loop in inline mode."""

    def __init__(self, certificate: Certificate, cfg: MovingConfig, buffer_s: float) -> None:
        self.cert = certificate
        self.cert_version = 0
        self.cfg = cfg
        self.buffer_s = buffer_s
        self._t = np.zeros(0)
        self._acc = np.zeros((0, 3))
        self._gyr = np.zeros((0, 3))
        self.batches = 0
        self.f0_checked = 0
        self.f0_failed = 0
        self._recent: deque[bool] = deque(maxlen=F0_PERSIST_N)  #: last epochs' F0 failures
        self.f0_fault = False
        self.tracker = IsolationTracker(cfg.persist)
        self._hist_t = np.zeros(0)
        self._hist_means = np.zeros((0, 3))
        self._hist_var = np.zeros((0, 3))
        self._hist_mag = np.zeros(0)
        self._done_t = -math.inf  #: end (GNSS time) of the last epoch checked
        self._window_t = -math.inf  #: GNSS time of the last isolation window
        self.latency_s = cfg.latency_s if cfg.latency_s is not None else 0.0
        self.latency_determined = cfg.latency_s is not None
        self.latency_note = "configured" if cfg.latency_s is not None else "not yet estimated"
        #: std of latency_s, s: 0 configured; before an estimate, :func:`.used_latency`'s
        self.latency_std_s = 0.0 if cfg.latency_s is not None else math.nan
        self.windows = 0
        #: the last isolation window's onset test (:mod:`.onset`), None before the first
        self.last_onset: dict | None = None
        self.last_batch: dict = {}  #: GNSS epochs of the last batch: total, valid, rejected
        #: the lever arm estimate over the buffer (None before the first), and the one used
        self.lever_estimate: LeverArmEstimate | None = None
        self.lever_arm_m = np.asarray(cfg.lever_arm_m or (0.0, 0.0, 0.0), dtype=float)
        self.joint: dict = {}  #: the joint latency and lever solution (:mod:`.joint`) reported
        #: the gyros in turns over the buffer (status ``gyro_turns``); latched gyro faults
        self.turns: dict = {"verdict": "unknown", "reason": "no GNSS epoch checked yet"}
        self.gyro_faults: dict[tuple[str, str], dict] = {}

    def _set_certificate(self, cert: Certificate) -> None:
        """A reloaded certificate: the history corrected with the old one is dropped."""
        self.cert = cert
        self._hist_t = self._hist_t[:0]
        self._hist_means = self._hist_means[:0]
        self._hist_var = self._hist_var[:0]
        self._hist_mag = self._hist_mag[:0]
        self.tracker = IsolationTracker(self.cfg.persist)
        self.gyro_faults = {}

    def result(self) -> BatchResult:
        """The state as published."""
        lever = self.lever_arm_m
        return BatchResult(
            batches=self.batches,
            latency_s=float(self.latency_s),
            latency_note=self.latency_note,
            latency_std_s=float(self.latency_std_s),
            lever_estimate=self.lever_estimate,
            joint=dict(self.joint),
            lever_arm_m=(float(lever[0]), float(lever[1]), float(lever[2])),
            last_batch=dict(self.last_batch),
            f0_checked=self.f0_checked,
            f0_failed=self.f0_failed,
            f0_fault=self.f0_fault,
            windows=self.windows,
            raised=tuple(dict(f) for f in self.tracker.raised),
            onset=None if self.last_onset is None else dict(self.last_onset),
            turns=dict(self.turns),
            gyro_faults=tuple(sorted(self.gyro_faults)),
            certificate_version=self.cert_version,
        )

    def __call__(self, job: BatchInput) -> BatchResult:
        """Take the new samples of ``job`` into the buffer (the last ``buffer_s`` s), run
        one batch (module doc) and return the state to publish."""
        if job.certificate_version != self.cert_version:
            self.cert_version = job.certificate_version
            self._set_certificate(job.certificate)
        if job.t.size:
            self._t = np.concatenate([self._t, job.t])
            self._acc = np.concatenate([self._acc, job.accel])
            self._gyr = np.concatenate([self._gyr, job.gyro])
            keep = self._t >= self._t[-1] - self.buffer_s
            if not keep[0]:
                self._t, self._acc, self._gyr = self._t[keep], self._acc[keep], self._gyr[keep]
        self._process(job)  # a failure here leaves the state as far as it got
        self.batches += 1
        return self.result()

    def _process(self, job: BatchInput) -> None:
        cfg = self.cfg
        acc = self.cert.accel
        t_utc = self._t + job.offset_s
        track = track_from_reports(job.fixes)
        period = track.period_s()
        if not math.isfinite(period) or period <= 0:
            return
        span = max(1, int(round(cfg.interval_s / period)))
        ep = gnss_epochs(track, span=span)
        self.last_batch = {"epochs": len(ep), "valid": int(np.sum(ep.valid)), "rejected": ep.counts}
        if not len(ep):
            return
        f_si = acc.inverse_si(self._acc)
        w_si = self.cert.gyro.inverse_si(self._gyr)
        rate = 1.0 / float(np.median(np.diff(self._t)))
        # the gyro noise over the buffer (rad/s per sample), once: lever rows, joint, turns
        gyro_sig_si = gyro_noise_si(self._gyr, self.cert.gyro, rate)
        # the accelerometers' white noise per sample over the buffer (raw units, and SI)
        sig_raw = accel_noise(self._acc, acc.noise_sigma(rate))
        sig_si = sig_raw / acc.scale_factor * acc.unit_to_si
        series = ImuSeries(t_utc, f_si, w_si)  # the buffer cut at every latency tried: once
        if cfg.latency_s is None and ep.t1[-1] - self._window_t >= cfg.step_s:
            est = estimate_latency(
                t_utc, f_si, ep, gyro_si=w_si, max_latency_s=cfg.max_latency_s,
                max_std_s=cfg.latency_tolerance_s, series=series,
            )  # fmt: skip
            if est.determined:
                self.latency_s, self.latency_std_s = est.latency_s, est.std_s
                self.latency_determined = True
                self.latency_note = (
                    f"estimated (correlation {est.correlation:.2f}, std {1e3 * est.std_s:.0f} ms)"
                )
            elif not self.latency_determined:  # the best estimate, its std widens the checks
                self.latency_s, self.latency_std_s = used_latency(est, cfg.max_latency_s)
                self.latency_note = (
                    f"undetermined: {est.reason}; used {self.latency_s:.3f} s with std "
                    f"{1e3 * self.latency_std_s:.0f} ms"
                )
            plain = series.epochs(ep.t0, ep.t1, sigma_sample_si=sig_si, latency_s=self.latency_s)
            self.lever_estimate = estimate_lever_arm(
                t_utc, w_si, gyro_sig_si, ep, plain, self.latency_s, rate
            )
            if cfg.lever_arm_m is None and math.isfinite(est.std_s):
                lat, self.lever_estimate, self.joint = solve_jointly(
                    t_utc, f_si, w_si, gyro_sig_si, ep, sig_si, rate,
                    self.latency_s, self.lever_estimate, cfg.max_latency_s, est.determined,
                    series=series,
                )  # fmt: skip
                if self.joint["used"]:
                    self.latency_s, self.latency_std_s = lat, float(self.joint["latency_std_s"])
                    self.latency_determined = True
                    self.latency_note = (
                        f"estimated (correlation {est.correlation:.2f}), solved with the "
                        f"lever arm (std {1e3 * self.joint['latency_std_s']:.3g} ms)"
                    )
                elif est.determined:  # a lever arm left out may pull the peak (.joint)
                    std = separate_latency_std(self.joint, self.latency_s, self.latency_std_s)
                    if std > cfg.latency_tolerance_s:
                        self.latency_std_s, self.latency_determined = std, False
                        self.latency_note = (
                            f"undetermined: the latency solved with the lever arm is "
                            f"{1e3 * std:.0f} ms from the correlation's; used "
                            f"{self.latency_s:.3f} s with std {1e3 * std:.0f} ms"
                        )
            if cfg.lever_arm_m is None:
                self.lever_arm_m = self.lever_estimate.used()
        im = series.epochs(
            ep.t0,
            ep.t1,
            accel_raw=self._acc,
            sigma_sample_si=sig_si,
            latency_s=self.latency_s,
            lever_arm_m=self.lever_arm_m,
        )
        self._check_turns(track, ep, im, gyro_sig_si)
        use = ep.valid & im.covered & np.isfinite(im.mag) & (ep.t0 >= self._done_t)
        if not np.any(use):
            return
        lat_std = self.latency_std_s
        if not math.isfinite(lat_std):  # no estimate yet: the latency is not known
            lat_std = unknown_latency_std(cfg.max_latency_s)
        sig_lat = latency_sigma(0.5 * (ep.t0 + ep.t1), im.mag, lat_std)
        g, i = ep.mag[use], im.mag[use]
        f0 = 0.5 * (i * i / (g * g) - 1.0)
        mag_var = im.sigma_mag[use] ** 2 + ep.sigma_mag[use] ** 2 + sig_lat[use] ** 2
        sigma = np.sqrt(mag_var) * i / (g * g)
        failed = np.abs(f0) > acc.limits.f0 + cfg.k_sigma_f0 * sigma
        self.f0_checked += int(f0.size)
        self.f0_failed += int(np.sum(failed))
        self._recent.extend(bool(x) for x in failed)
        self.f0_fault = sum(self._recent) >= F0_PERSIST_K
        self._done_t = float(ep.t1[use][-1])
        means, var, mag_in = epoch_observations(ep, im, acc, sig_raw, sig_lat)
        t_mid = 0.5 * (ep.t0 + ep.t1)
        self._hist_t = np.concatenate([self._hist_t, t_mid[use]])
        self._hist_means = np.concatenate([self._hist_means, means[use]])
        self._hist_var = np.concatenate([self._hist_var, var[use]])
        self._hist_mag = np.concatenate([self._hist_mag, mag_in[use]])
        keep = self._hist_t >= self._hist_t[-1] - cfg.window_s
        self._hist_t, self._hist_means = self._hist_t[keep], self._hist_means[keep]
        self._hist_var, self._hist_mag = self._hist_var[keep], self._hist_mag[keep]
        if self._hist_t.size >= cfg.min_epochs and self._hist_t[-1] - self._window_t >= cfg.step_s:
            self._window_t = float(self._hist_t[-1])
            wi = isolate_window(
                acc, self._hist_means, self._hist_var, self._hist_mag, self._hist_t,
                cfg.min_epochs_after_onset, k_sigma=cfg.k_sigma, prior_factor=cfg.prior_factor,
            )  # fmt: skip
            if wi.iso is not None:  # a withheld window neither raises nor breaks a streak
                self.tracker.update(wi.iso, self._window_t)
            self.last_onset = dict(wi.to_json(), t_window=round(self._window_t, 3))
            self.windows += 1

    def _check_turns(
        self, track: GnssTrack, ep: GnssEpochs, im: ImuEpochs, gyro_sigma_si: np.ndarray
    ) -> None:
        """The gyros in turns over the buffer (:mod:`.course_rate`, no-slip assumption;
        ``gyro_sigma_si`` (3,) the gyro noise, rad/s per sample); its faults are latched."""
        cfg = self.cfg
        rep = turn_check(
            track, ep, im, self.cert.gyro, gyro_sigma_si,
            k_sigma_f0=cfg.k_sigma_f0, k_sigma=cfg.k_sigma, prior_factor=cfg.prior_factor,
            determined_std_ratio=cfg.determined_std_ratio,
        )  # fmt: skip
        for f in rep["faults"]:
            self.gyro_faults.setdefault((f.get("sensor", ""), f["cause"]), f)
        keys = ("assumption", "used", "rejected", "verdict", "reason", "f0", "turns")
        self.turns = {k: rep[k] for k in keys if k in rep}
        self.turns["span_s"] = round(float(ep.t1[-1] - ep.t0[0]), 1)
        self.turns["determined"] = [f"{d['sensor']} {d['cause']}" for d in rep["determined"]]


def clock_offset(offsets: Sequence[float]) -> float:
    """UTC minus device time, s, from the recent fixes' (fix time - newest sample time at
    arrival) values: a fix arrives after its time, late by the receiver's latency and by
    whatever held it (gpsd, the socket, a loaded machine), never early, so the values
    are at most the offset and the least-delayed arrivals tie the clocks best. The
    second largest (robust to one wrong time tag; the largest with fewer than 3 values;
    0 with none). A median moved by seconds when lines came late in bursts, beyond the
    latency search's range (benchmarks.live_drive_hour ``--hold``)."""
    if not offsets:
        return 0.0
    v = sorted(offsets)
    return float(v[-2] if len(v) >= 3 else v[-1])


class LiveAiding:
    """GNSS aiding of the daemon (module doc).

    ``mode`` (:class:`~.worker.BatchWorker`): ``"process"`` (default, the daemon) runs
    the batches in a worker process, ``"thread"`` in a thread, ``"inline"`` in
    :meth:`update` itself; the same results for the same inputs. :meth:`update` only
    gathers samples and fixes and hands a :class:`BatchInput` over when a batch is due
    and the worker is idle (a due batch waits for a later call otherwise)."""

    def __init__(
        self,
        url: str,
        certificate: Certificate,
        cfg: MovingConfig | None = None,
        batch_s: float = 10.0,
        outage_s: float = 2.0,
        client: GpsdClient | None = None,
        clock: Callable[[], float] = time.monotonic,
        reconnect_min_s: float = 0.5,
        reconnect_max_s: float = 10.0,
        mode: str = "process",
    ) -> None:
        self.url = url
        self.cert = certificate
        self.cfg = cfg or MovingConfig()
        self.batch_s = batch_s
        self.outage_s = outage_s
        self.clock = clock
        self.client = client or GpsdClient(
            url, min_backoff_s=reconnect_min_s, max_backoff_s=reconnect_max_s, clock=clock
        )
        self.buffer_s = self.cfg.window_s + 30.0
        #: samples not yet handed to a batch: (t, accel, gyro) per block
        self._pending: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque()
        self._t_last: float | None = None  #: newest sample time, s
        self._samples = 0  #: samples taken
        self._cert_version = 0
        self.fixes: list[dict] = []
        self.offsets: deque[float] = deque(maxlen=50)
        self.last_fix_wall: float | None = None
        self.last_mode = 0
        self._batch_t = -math.inf  #: GNSS time of the last batch handed over
        self._last_batch_wall: float | None = None
        self.worker: BatchWorker[BatchInput, BatchResult] = BatchWorker(
            functools.partial(AidingBatches, certificate, self.cfg, self.buffer_s),
            mode=mode,
            name="aiding-batch",
        )
        self._initial = BatchResult(
            latency_s=self.cfg.latency_s if self.cfg.latency_s is not None else 0.0,
            latency_note="configured" if self.cfg.latency_s is not None else "not yet estimated",
            latency_std_s=0.0 if self.cfg.latency_s is not None else math.nan,
            lever_arm_m=tuple(float(x) for x in (self.cfg.lever_arm_m or (0.0, 0.0, 0.0))),  # type: ignore[arg-type]
        )

    def set_certificate(self, cert: Certificate) -> None:
        """A reloaded certificate, applied at the next batch (which drops the history
        corrected with the old one)."""
        self.cert = cert
        self._cert_version += 1

    @property
    def published(self) -> BatchResult:
        """The last published batch result (before the first: the initial state)."""
        return self.worker.result or self._initial

    # -- input -------------------------------------------------------------

    def update(self, block: SampleBlock | None) -> None:
        """Take new IMU samples (or None), read gpsd, hand a batch over when one is due.
        Flagged samples (:data:`~imudiag.quasistatic.BAD_FLAGS`) are left out."""
        if block is not None:
            block = block.without_flags(BAD_FLAGS)
        if block is not None and len(block):
            self._pending.append((block.t, block.accel, block.gyro))
            self._t_last = float(block.t[-1])
            self._samples += len(block)
            # blocks the batch would drop from its buffer anyway (a worker long busy)
            while self._pending[0][0][-1] < self._t_last - self.buffer_s:
                self._pending.popleft()
        reports = self.client.poll()
        now = self.clock()
        for r in reports:
            self.last_fix_wall = now
            self.last_mode = r["mode"]
            if self._t_last is not None:
                self.offsets.append(r["t"] - self._t_last)
            self.fixes.append(r)
        if reports:
            horizon = self.fixes[-1]["t"] - self.buffer_s
            if self.fixes[0]["t"] < horizon:
                self.fixes = [f for f in self.fixes if f["t"] >= horizon]
        if (
            self.fixes
            and self.fixes[-1]["t"] - self._batch_t >= self.batch_s
            and self._samples > 10
            and not self.worker.busy
        ):
            new = list(self._pending)
            job = BatchInput(
                np.concatenate([b[0] for b in new]) if new else np.zeros(0),
                np.concatenate([b[1] for b in new]) if new else np.zeros((0, 3)),
                np.concatenate([b[2] for b in new]) if new else np.zeros((0, 3)),
                list(self.fixes),
                clock_offset(self.offsets),
                self.cert,
                self._cert_version,
            )
            if self.worker.submit(job):
                self._pending.clear()
                self._batch_t = self.fixes[-1]["t"]
                self._last_batch_wall = now

    # -- status ----------------------------------------------------------------

    def faults(self) -> list[dict]:
        """Faults for the status ``faults`` list: named ones as (triad, sensor, cause),
        groups with ``|``-joined sensors and causes and their ``one_of``."""
        res = self.published
        out: list[dict] = []
        if res.f0_fault:
            out.append({"triad": "accel", "cause": "f0", "source": "moving_base"})
        for sensor, cause in res.gyro_faults:
            out.append({"triad": "gyro", "cause": cause, "source": "moving_base"})
            if sensor:
                out[-1]["sensor"] = sensor
        for f in res.raised:
            if f["named"]:
                out.append(
                    {
                        "triad": "accel",
                        "sensor": f["sensor"],
                        "cause": f["cause"],
                        "source": "moving_base",
                    }
                )
            else:
                out.append(
                    {
                        "triad": "accel",
                        "sensor": "|".join(o["sensor"] for o in f["one_of"]),
                        "cause": "|".join(o["cause"] for o in f["one_of"]),
                        "source": "moving_base",
                        "one_of": [
                            {"sensor": o["sensor"], "cause": o["cause"]} for o in f["one_of"]
                        ],
                    }
                )
        return out

    def status(self) -> dict:
        """The ``aiding`` object of the daemon's status."""
        res = self.published
        worker = self.worker
        now = self.clock()
        age = None if self.last_fix_wall is None else now - self.last_fix_wall
        reason = ""
        if self.client.state != "connected":
            reason = self.client.last_error or "gpsd not connected"
        elif age is None:
            reason = "gpsd connected, no TPV report yet (no receiver, or no fix)"
        elif age > self.outage_s:
            reason = f"GNSS outage: no fix for {age:.1f} s; the static checks carry on at stops"
        elif self.last_mode < 3:
            reason = f"no 3D fix (mode {self.last_mode}): no vertical velocity"
        elif self._samples == 0:
            reason = "no IMU samples"
        elif res.f0_checked == 0:
            reason = f"collecting GNSS epochs (first check after {self.batch_s:g} s of fixes)"
        out: dict = {
            "source": self.url,
            "link": self.client.state,
            "in_use": reason == "",
            "reason": reason,
            "fixes": self.client.counters.tpv,
            "last_fix_age_s": None if age is None else round(age, 3),
            "mode": self.last_mode,
            "f0": {"checked": res.f0_checked, "failed": res.f0_failed, "fault": res.f0_fault},
            "windows": res.windows,
            "onset": res.onset,
            "last_batch": res.last_batch,
            "latency_s": round(res.latency_s, 4),
            "latency": res.latency_note,
            "latency_std_s": round(res.latency_std_s, 4)
            if math.isfinite(res.latency_std_s)
            else None,
            "clock_offset_s": round(clock_offset(self.offsets), 4) if self.offsets else None,
            "lever_arm_m": [round(float(x), 3) for x in res.lever_arm_m],
            "lever_arm": dict(
                res.lever_estimate.to_json() if res.lever_estimate else {},
                configured=self.cfg.lever_arm_m is not None,
            ),
            "gyro_turns": dict(res.turns, faults=[list(k) for k in res.gyro_faults]),
            "latency_lever": res.joint,
            # the batches: how they run, how many ran, the last failure (kept, not fatal)
            "batches": {
                "mode": worker.mode,
                "submitted": worker.submitted,
                "published": res.batches,
                "running": worker.busy,
                "errors": worker.errors,
                "last_error": worker.last_error,
                "certificate_version": res.certificate_version,
            },
        }
        return out

    def close(self, timeout_s: float = JOIN_TIMEOUT_S) -> None:
        """Stop the batch worker (waits at most ``timeout_s`` s for a running batch) and
        disconnect from gpsd."""
        self.worker.close(timeout_s)
        self.client.close()


__all__ = ["AidingBatches", "BatchInput", "BatchResult", "LiveAiding", "clock_offset"]
