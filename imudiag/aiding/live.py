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
``step_s`` the isolation runs over the last ``window_s`` (:mod:`.isolation`).
The IMU buffer keeps ``window_s`` + 30 s. :meth:`status` says whether aiding
is in use and why not: gpsd not reachable, no TPV yet, an outage, no 3D fix,
still collecting.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from ..certificate import Certificate
from ..samples import SampleBlock
from .align import estimate_latency
from .course_rate import turn_check
from .gpsd_client import GpsdClient
from .isolation import IsolationTracker
from .lever_arm import LeverArmEstimate
from .moving import (
    MovingConfig,
    accel_noise,
    epoch_observations,
    estimate_lever_arm,
    gyro_noise_si,
)
from .onset import isolate_window
from .specific_force import GnssEpochs, ImuEpochs, gnss_epochs, imu_epochs
from .tpv import GnssTrack, track_from_reports

#: F0 in motion is a fault when k of the last n checked epochs fail
F0_PERSIST_K, F0_PERSIST_N = 5, 10


class LiveAiding:
    """GNSS aiding of the daemon (module doc)."""

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
        self._t = np.zeros(0)
        self._acc = np.zeros((0, 3))
        self._gyr = np.zeros((0, 3))
        self.fixes: list[dict] = []
        self.offsets: deque[float] = deque(maxlen=50)
        self.last_fix_wall: float | None = None
        self.last_mode = 0
        self.f0_checked = 0
        self.f0_failed = 0
        self._recent: deque[bool] = deque(maxlen=F0_PERSIST_N)  #: last epochs' F0 failures
        self.f0_fault = False
        self.tracker = IsolationTracker(self.cfg.persist)
        self._hist_t = np.zeros(0)
        self._hist_means = np.zeros((0, 3))
        self._hist_var = np.zeros((0, 3))
        self._hist_mag = np.zeros(0)
        self._done_t = -math.inf  #: end (GNSS time) of the last epoch checked
        self._batch_t = -math.inf  #: GNSS time of the last batch
        self._window_t = -math.inf  #: GNSS time of the last isolation window
        self._last_batch_wall: float | None = None
        self.latency_s = self.cfg.latency_s if self.cfg.latency_s is not None else 0.0
        self.latency_determined = self.cfg.latency_s is not None
        self.latency_note = "configured" if self.cfg.latency_s is not None else "not yet estimated"
        self.windows = 0
        #: the last isolation window's onset test (:mod:`.onset`), None before the first
        self.last_onset: dict | None = None
        self.last_batch: dict = {}  #: GNSS epochs of the last batch: total, valid, rejected
        #: the lever arm estimate over the buffer (None before the first), and the one used
        self.lever_estimate: LeverArmEstimate | None = None
        self.lever_arm_m = np.asarray(self.cfg.lever_arm_m or (0.0, 0.0, 0.0), dtype=float)
        #: the gyros in turns over the buffer (status ``gyro_turns``); latched gyro faults
        self.turns: dict = {"verdict": "unknown", "reason": "no GNSS epoch checked yet"}
        self.gyro_faults: dict[tuple[str, str], dict] = {}

    def set_certificate(self, cert: Certificate) -> None:
        """A reloaded certificate: the history corrected with the old one is dropped."""
        self.cert = cert
        self._hist_t = self._hist_t[:0]
        self._hist_means = self._hist_means[:0]
        self._hist_var = self._hist_var[:0]
        self._hist_mag = self._hist_mag[:0]
        self.tracker = IsolationTracker(self.cfg.persist)
        self.gyro_faults = {}

    # -- input -------------------------------------------------------------

    def update(self, block: SampleBlock | None) -> None:
        """Take new IMU samples (or None), read gpsd, check new epochs when a batch is due."""
        if block is not None and len(block):
            self._t = np.concatenate([self._t, block.t])
            self._acc = np.concatenate([self._acc, block.accel])
            self._gyr = np.concatenate([self._gyr, block.gyro])
            keep = self._t >= self._t[-1] - self.buffer_s
            if not keep[0]:
                self._t, self._acc, self._gyr = self._t[keep], self._acc[keep], self._gyr[keep]
        reports = self.client.poll()
        now = self.clock()
        for r in reports:
            self.last_fix_wall = now
            self.last_mode = r["mode"]
            if self._t.size:
                self.offsets.append(r["t"] - self._t[-1])
            self.fixes.append(r)
        if reports:
            horizon = self.fixes[-1]["t"] - self.buffer_s
            if self.fixes[0]["t"] < horizon:
                self.fixes = [f for f in self.fixes if f["t"] >= horizon]
            if self.fixes[-1]["t"] - self._batch_t >= self.batch_s and self._t.size > 10:
                self._process()

    # -- processing ----------------------------------------------------------

    def _process(self) -> None:
        cfg = self.cfg
        acc = self.cert.accel
        self._batch_t = self.fixes[-1]["t"]
        self._last_batch_wall = self.clock()
        offset = float(np.median(self.offsets)) if self.offsets else 0.0
        t_utc = self._t + offset
        track = track_from_reports(self.fixes)
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
        if cfg.latency_s is None and ep.t1[-1] - self._window_t >= cfg.step_s:
            est = estimate_latency(t_utc, f_si, ep, gyro_si=w_si, max_latency_s=cfg.max_latency_s)
            if est.determined:
                self.latency_s, self.latency_determined = est.latency_s, True
                self.latency_note = f"estimated (correlation {est.correlation:.2f})"
            elif not self.latency_determined:
                self.latency_note = est.reason
            sig = accel_noise(self._acc, acc.noise_sigma(rate)) / acc.scale_factor * acc.unit_to_si
            plain = imu_epochs(
                t_utc, f_si, ep.t0, ep.t1, gyro_si=w_si, sigma_sample_si=sig,
                latency_s=self.latency_s,
            )  # fmt: skip
            self.lever_estimate = estimate_lever_arm(
                t_utc, w_si, self._gyr, self.cert.gyro, ep, plain, self.latency_s, rate
            )
            if cfg.lever_arm_m is None:
                self.lever_arm_m = self.lever_estimate.used()
        sig_raw = accel_noise(self._acc, acc.noise_sigma(rate))
        sig_si = sig_raw / acc.scale_factor * acc.unit_to_si
        im = imu_epochs(
            t_utc,
            f_si,
            ep.t0,
            ep.t1,
            gyro_si=w_si,
            accel_raw=self._acc,
            sigma_sample_si=sig_si,
            latency_s=self.latency_s,
            lever_arm_m=self.lever_arm_m,
        )
        self._check_turns(track, ep, im, rate)
        use = ep.valid & im.covered & np.isfinite(im.mag) & (ep.t0 >= self._done_t)
        if not np.any(use):
            return
        g, i = ep.mag[use], im.mag[use]
        f0 = 0.5 * (i * i / (g * g) - 1.0)
        sigma = np.sqrt(im.sigma_mag[use] ** 2 + ep.sigma_mag[use] ** 2) * i / (g * g)
        failed = np.abs(f0) > acc.limits.f0 + cfg.k_sigma_f0 * sigma
        self.f0_checked += int(f0.size)
        self.f0_failed += int(np.sum(failed))
        self._recent.extend(bool(x) for x in failed)
        self.f0_fault = sum(self._recent) >= F0_PERSIST_K
        self._done_t = float(ep.t1[use][-1])
        means, var, mag_in = epoch_observations(ep, im, acc, sig_raw)
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

    def _check_turns(self, track: GnssTrack, ep: GnssEpochs, im: ImuEpochs, rate: float) -> None:
        """The gyros in turns over the buffer (:mod:`.course_rate`, no-slip assumption);
        its faults are latched."""
        cfg = self.cfg
        rep = turn_check(
            track, ep, im, self.cert.gyro, gyro_noise_si(self._gyr, self.cert.gyro, rate),
            k_sigma_f0=cfg.k_sigma_f0, k_sigma=cfg.k_sigma, prior_factor=cfg.prior_factor,
            determined_std_ratio=cfg.determined_std_ratio,
        )  # fmt: skip
        for f in rep["faults"]:
            self.gyro_faults.setdefault((f.get("sensor", ""), f["cause"]), f)
        keys = ("assumption", "used", "rejected", "verdict", "reason", "f0", "turns")
        self.turns = {k: rep[k] for k in keys if k in rep}
        self.turns["span_s"] = round(float(ep.t1[-1] - ep.t0[0]), 1)
        self.turns["determined"] = [f"{d['sensor']} {d['cause']}" for d in rep["determined"]]

    # -- status ----------------------------------------------------------------

    def faults(self) -> list[dict]:
        """Faults for the status ``faults`` list: named ones as (triad, sensor, cause),
        groups with ``|``-joined sensors and causes and their ``one_of``."""
        out: list[dict] = []
        if self.f0_fault:
            out.append({"triad": "accel", "cause": "f0", "source": "moving_base"})
        for (sensor, cause), _ in sorted(self.gyro_faults.items()):
            out.append({"triad": "gyro", "cause": cause, "source": "moving_base"})
            if sensor:
                out[-1]["sensor"] = sensor
        for f in self.tracker.raised:
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
        elif self._t.size == 0:
            reason = "no IMU samples"
        elif self.f0_checked == 0:
            reason = f"collecting GNSS epochs (first check after {self.batch_s:g} s of fixes)"
        out: dict = {
            "source": self.url,
            "link": self.client.state,
            "in_use": reason == "",
            "reason": reason,
            "fixes": self.client.counters.tpv,
            "last_fix_age_s": None if age is None else round(age, 3),
            "mode": self.last_mode,
            "f0": {"checked": self.f0_checked, "failed": self.f0_failed, "fault": self.f0_fault},
            "windows": self.windows,
            "onset": self.last_onset,
            "last_batch": self.last_batch,
            "latency_s": round(self.latency_s, 4),
            "latency": self.latency_note,
            "clock_offset_s": round(float(np.median(self.offsets)), 4) if self.offsets else None,
            "lever_arm_m": [round(float(x), 3) for x in self.lever_arm_m],
            "lever_arm": dict(
                self.lever_estimate.to_json() if self.lever_estimate else {},
                configured=self.cfg.lever_arm_m is not None,
            ),
            "gyro_turns": dict(self.turns, faults=[list(k) for k in sorted(self.gyro_faults)]),
        }
        return out

    def close(self) -> None:
        self.client.close()


__all__ = ["LiveAiding"]
