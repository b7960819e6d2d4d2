"""WHY THIS FILE STAYS (issue 30 item 6): with ``old_trailing.py``, the reference of
``tests/test_monitor_equivalence.py``: the monitor as it was before its per-read cost work
(issue 14), whose fault lists, counters and raises the shipped monitor must give after
every read. The shipped monitor's own fast paths are checked against plain ones (reads
gathered against every read checked, big blocks against daemon reads, the noise medians
settled by counts against medians taken, ``tests/test_median_side.py``; stuck runs, the
F0 screen and the noise check's positions against their definitions,
``tests/test_monitor_parts.py``); the checks themselves (F0 means, the rest rate, the
noise medians, persistence) have no second implementation in the package, and this is
it. Its still detector is the shipped one (the frozen ``old_quasistatic.py`` it used
before is gone: the detector is held to its own reference in
``tests/test_detector_equivalence.py``), so this compares the monitors alone. Do not edit
otherwise.

Per-sample monitor: certificate-corrected F0 checks, persistence, stuck and saturation.

Every sample of both triads is corrected with the certificate. The checks
(scalar-method.md section 1 and 5):

- accelerometer F0 = 1/2(|f|^2/g^2 - 1) against ``limits.f0``, only while the
  unit is quasi-static; during manoeuvres it is *not applicable*, not failed;
- gyro F0 against Earth rate where the certificate's noise makes Earth rate
  observable per sample (navigation-grade gyros); for MEMS gyros the rest-rate
  check instead: while quasi-static the certificate-corrected rate averaged
  over ``gyro_window_s`` (ending one detector window back, with everything
  since still: the detector's trailing window is late at the start of a
  turn) must not exceed Earth rate by more than the bias
  limit plus ``k_sigma`` standard deviations of that mean, per axis;
- k-of-n persistence before a triad is declared failed;
- stuck outputs (a channel repeating the same raw value for ``stuck_samples``
  samples where its noise makes that impossible) and saturation flags;
- excess noise: per channel, the white-noise sigma estimated from second
  differences over ``noise_window_s`` (var(d2 U) = 6 sigma^2 for white noise;
  smooth motion contributes almost nothing at the sample rate; squares are
  winsorised at 10 sigma of d2 so a step is not taken for noise) beyond
  ``noise_ratio`` times the certificate's sigma, judged on windows where the
  angular acceleration stayed below ``noise_motion_gate`` (a hand turn puts far
  more into second differences than the noise does; a steady rate does not;
  vibration and translation are still judged).

All of it is vectorised per block; state carries across blocks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imudiag.certificate import SENSOR_NAMES, TRIADS, Certificate, TriadModel
from imudiag.persistence import Persistence
from imudiag.quasistatic import QuasiStaticDetector
from imudiag.ringbuffer import SampleRing
from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_ADC_ERROR, FLAG_GYRO_SATURATED, SampleBlock
from imudiag.scalar import f0
from tests.reference.old_trailing import TrailingSum


@dataclass
class MonitorConfig:
    """Settings of the per-sample checks."""

    persistence_k: int = 20  #: failed checks among the last n checked samples to declare a fault
    persistence_n: int = 50  #: checked samples in the persistence window
    stuck_samples: int = 50  #: identical consecutive raw outputs that mean a stuck channel
    stuck_min_sigma: float = 1.0  #: output units; stuck check only where noise is at least this
    static_window_s: float = 0.5  #: window of the quasi-static detector, s
    gyro_window_s: float = 1.0  #: averaging window of the MEMS rest-rate check, s
    k_sigma: float = 5.0  #: standard deviations of margin in the gyro rest-rate check
    ring_capacity: int = 4096  #: samples kept in the ring buffer of recent samples
    noise_window_s: float = 1.0  #: window of the white-noise estimate, s
    noise_ratio: float = 2.0  #: estimated / certificate noise sigma that counts as excess noise
    #: the noise check judges only windows where the angular acceleration (rad/s^2, from the
    #: change of the 0.1 s mean rate) stayed below this: a hand turn puts far more into
    #: second differences than the noise; a steady rate (a gross bias, a turntable) does not
    noise_motion_gate: float = 0.5
    noise_check_s: float = 0.1  #: the noise check runs every this many seconds of samples
    #: excess-noise checks among the last n that raise the fault: 3 s of excess within 4 s, so
    #: a burst of a second or two (a hand on the unit, a knock) is not a noise fault
    noise_persistence_k: int = 30
    noise_persistence_n: int = 40
    #: noise beyond ``noise_gross_ratio`` times the certificate's is gross: 3 of 5 checks raise it
    noise_gross_ratio: float = 3.0
    earth_rate_noise_ratio: float = 0.2  #: per-sample Earth-rate F0 needs sigma_f0 < ratio*limit


@dataclass
class TriadState:
    """Running counters and last values of one triad's checks."""

    checked: int = 0  #: samples on which the F0 check applied
    failed: int = 0  #: of those, samples beyond the limit
    last_f0: float = float("nan")  #: last checked value: F0, or the rest-rate ratio (gyro)
    sum_f0_sq: float = 0.0  #: sum of the squared checked values (their RMS is the estimate)
    worst_axis: int | None = None  #: axis of the last gyro rest-rate failure
    persistence: Persistence | None = None
    saturation: Persistence | None = None
    stuck_run: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=np.int64))
    stuck_last: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    stuck_active: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=bool))
    noise: list[Persistence] = field(default_factory=list)  #: per axis, excess noise
    noise_gross: list[Persistence] = field(default_factory=list)  #: per axis, gross noise
    noise_tail: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  #: last raw samples
    noise_d2sq: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  #: last window
    noise_ratio_last: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))


class Monitor:
    """Runs the per-sample checks over consecutive blocks of one stream."""

    def __init__(
        self,
        certificate: Certificate,
        config: MonitorConfig | None = None,
        rate_hz: float | None = None,
    ) -> None:
        """``rate_hz``: the stream's sample rate (default: the certificate's nominal rate)."""
        self.config = config or MonitorConfig()
        self._rate_override = rate_hz
        self.certificate = certificate
        self.ring = SampleRing(self.config.ring_capacity)
        self.samples = 0  #: samples seen
        self.adc_errors = 0  #: samples flagged with an ADC error (not checked)
        self.t_last: float | None = None  #: sample time of the last sample, s
        self.static = False  #: the last sample was quasi-static
        self.state: dict[str, TriadState] = {}
        self.set_certificate(certificate)

    # -- configuration ----------------------------------------------------

    def set_certificate(self, certificate: Certificate) -> None:
        """Use a new certificate from the next block on (persistence restarts)."""
        self.certificate = certificate
        cfg = self.config
        rate = self._rate_override or certificate.sample_rate
        self.rate_hz = rate
        self.detector = QuasiStaticDetector(certificate, rate, window_s=cfg.static_window_s)
        self.state = {}
        for name in TRIADS:
            st = TriadState()
            st.persistence = Persistence(cfg.persistence_k, cfg.persistence_n)
            st.saturation = Persistence(cfg.persistence_k, cfg.persistence_n)
            st.noise = [
                Persistence(cfg.noise_persistence_k, cfg.noise_persistence_n) for _ in range(3)
            ]
            st.noise_gross = [Persistence(3, 5) for _ in range(3)]
            self.state[name] = st
        self.gyro_mode = self._gyro_mode(certificate.gyro, rate)
        self._gyro_window = max(1, int(round(cfg.gyro_window_s * rate)))
        # the detector's window is trailing: the first samples of a turn still look
        # static. The rest-rate mean is therefore taken over a window that ends
        # ``lag`` samples (one detector window) back, and used only if the samples
        # after it are static too.
        self._gyro_lag = max(1, int(round(cfg.static_window_s * rate)))
        span = self._gyro_window + self._gyro_lag
        self._gyro_sum = TrailingSum(span, 3)
        self._gyro_recent = TrailingSum(self._gyro_lag, 3)
        self._static_sum = TrailingSum(span)
        self._noise_w = max(4, int(round(cfg.noise_window_s * rate)))
        self._noise_step = max(1, int(round(cfg.noise_check_s * rate)))
        self._noise_motion = TrailingSum(self._noise_w + 2)  # turning samples among d2's inputs
        self._accel_m = max(1, int(round(0.1 * rate)))  # angular acceleration: 0.1 s means
        self._rate_2m = TrailingSum(2 * self._accel_m, 3)
        self._rate_m = TrailingSum(self._accel_m, 3)

    def _gyro_mode(self, gyro: TriadModel, rate_hz: float) -> str:
        """``earth_rate`` if per-sample F0 on Earth rate is meaningful, else ``rest_rate``."""
        sigma = gyro.noise_sigma(rate_hz)
        if sigma is None:
            return "rest_rate"
        sigma_si = float(np.max(sigma / gyro.scale_factor)) * gyro.unit_to_si
        sigma_f0 = sigma_si / self.certificate.earth_rate
        observable = sigma_f0 < self.config.earth_rate_noise_ratio * gyro.limits.f0
        return "earth_rate" if observable else "rest_rate"

    # -- results ----------------------------------------------------------

    def check_mode(self, name: str) -> str:
        """``f0`` (F0 against the known magnitude) or ``rest_rate`` (MEMS gyro at rest)."""
        return self.gyro_mode if name == "gyro" and self.gyro_mode == "rest_rate" else "f0"

    @property
    def f0_checked(self) -> dict[str, int]:
        """Samples on which each triad's F0 check applied."""
        return {name: st.checked for name, st in self.state.items()}

    @property
    def f0_failed(self) -> dict[str, int]:
        """Checked samples beyond the F0 limit, per triad."""
        return {name: st.failed for name, st in self.state.items()}

    @property
    def active_faults(self) -> list[dict[str, Any]]:
        """Faults in force now: dicts with triad, sensor (where it can be told), cause, t_first."""
        out: list[dict[str, Any]] = []
        for name in TRIADS:
            st = self.state[name]
            if st.persistence is not None and st.persistence.active:
                fault: dict[str, Any] = {"triad": name, "cause": "f0"}
                if name == "gyro" and self.gyro_mode == "rest_rate" and st.worst_axis is not None:
                    fault["sensor"] = SENSOR_NAMES[name][st.worst_axis]
                fault["t_first"] = st.persistence.t_first
                out.append(fault)
            for axis in np.flatnonzero(st.stuck_active):
                out.append({"triad": name, "sensor": SENSOR_NAMES[name][axis], "cause": "stuck"})
            for axis, (p, gross) in enumerate(zip(st.noise, st.noise_gross, strict=True)):
                firsts = [q.t_first for q in (p, gross) if q.active and q.t_first is not None]
                if p.active or gross.active:
                    out.append(
                        {
                            "triad": name,
                            "sensor": SENSOR_NAMES[name][axis],
                            "cause": "noise",
                            "t_first": min(firsts) if firsts else None,
                        }
                    )
            if st.saturation is not None and st.saturation.active:
                out.append({"triad": name, "cause": "saturation", "t_first": st.saturation.t_first})
        return out

    def f0_faults(self) -> list[dict[str, Any]]:
        """Persistent F0 failures ever raised over the stream, per triad (``diagnose``'s faults).

        The same k-of-n persistence as the daemon's ``f0`` fault; ``estimate`` is
        the RMS of the checked values (F0, dimensionless; the rest-rate ratio for a MEMS
        gyro at rest), ``limit`` the certificate's F0 limit (1 for the ratio).
        """
        out: list[dict[str, Any]] = []
        for name in TRIADS:
            st = self.state[name]
            p = st.persistence
            if p is None or p.raised == 0:
                continue
            rest_rate = name == "gyro" and self.gyro_mode == "rest_rate"
            sensor = None
            if rest_rate and st.worst_axis is not None:
                sensor = SENSOR_NAMES[name][st.worst_axis]
            out.append(
                {
                    "triad": name,
                    "sensor": sensor,
                    "cause": "f0",
                    "check": "rest_rate" if rest_rate else "f0",
                    "estimate": math.sqrt(st.sum_f0_sq / st.checked)
                    if st.checked
                    else float("nan"),
                    "certificate": 0.0,
                    "limit": 1.0 if rest_rate else float(self.certificate.triad(name).limits.f0),
                    "t_first": p.t_first_raised,
                    "raised": p.raised,
                    "failed": st.failed,
                    "checked": st.checked,
                }
            )
        return out

    # -- the checks -------------------------------------------------------

    def update(self, block: SampleBlock) -> None:
        """Check every sample of ``block`` (consecutive with the previous block)."""
        n = len(block)
        if n == 0:
            return
        cert = self.certificate
        self.ring.push(block)
        self.samples += n
        self.t_last = float(block.t[-1])
        flags = block.flags if block.flags is not None else np.zeros(n, dtype=np.uint16)
        flags = flags.astype(np.uint16, copy=False)
        adc_error = (flags & FLAG_ADC_ERROR) != 0
        self.adc_errors += int(np.count_nonzero(adc_error))

        static = self.detector.update(block)
        self.static = bool(static[-1])
        temp = block.temp
        accel_in = cert.accel.inverse(block.accel, temp_c=temp)  # accel input units
        accel_si = accel_in * cert.accel.unit_to_si
        gyro_si = cert.gyro.inverse_si(
            block.gyro,
            temp_c=temp,
            accel_input=accel_in if cert.gyro.g_sensitivity is not None else None,
        )

        sat = {
            "gyro": (flags & FLAG_GYRO_SATURATED) != 0,
            "accel": (flags & FLAG_ACCEL_SATURATED) != 0,
        }
        for name in TRIADS:
            st = self.state[name]
            assert st.saturation is not None
            st.saturation.update(sat[name], block.t)

        # accelerometer F0 on quasi-static samples
        ok_a = static & ~adc_error & ~sat["accel"]
        self._record("accel", f0(accel_si[ok_a] / cert.gravity), block.t[ok_a])

        # gyro
        ok_g = static & ~adc_error & ~sat["gyro"]
        if self.gyro_mode == "earth_rate":
            self._record("gyro", f0(gyro_si[ok_g] / cert.earth_rate), block.t[ok_g])
        else:
            self._gyro_rest_rate(gyro_si, static, ok_g, block.t)

        self._stuck(block)
        # angular acceleration from the last 0.1 s mean rate minus the 0.1 s before it
        m = self._accel_m
        two, _ = self._rate_2m.update(gyro_si)
        one, _ = self._rate_m.update(gyro_si)
        alpha = np.linalg.norm(2.0 * one - two, axis=1) * (self.rate_hz / m) / m
        turning = ~(alpha <= self.config.noise_motion_gate)  # NaN (ADC error): turning
        turns, _ = self._noise_motion.update(turning.astype(float))
        self._noise(block, turns == 0)

    def _record(self, name: str, values: np.ndarray, t: np.ndarray) -> None:
        st = self.state[name]
        limit = self.certificate.triad(name).limits.f0
        failed = np.abs(values) > limit
        st.checked += int(values.size)
        st.failed += int(np.count_nonzero(failed))
        st.sum_f0_sq += float(np.sum(values * values))
        if values.size:
            st.last_f0 = float(values[-1])
        assert st.persistence is not None
        st.persistence.update(failed, t)

    def _gyro_rest_rate(
        self, gyro_si: np.ndarray, static: np.ndarray, ok: np.ndarray, t: np.ndarray
    ) -> None:
        """MEMS rest-rate check: moving mean of the corrected rate over a static window."""
        cert = self.certificate
        gyro = cert.gyro
        w, lag = self._gyro_window, self._gyro_lag
        sums, counts = self._gyro_sum.update(gyro_si)
        recent, _ = self._gyro_recent.update(gyro_si)
        still, _ = self._static_sum.update(static.astype(float))
        mean = (sums - recent) / w  # the w samples that end lag samples back
        # the averaging window and the lag after it were all still
        usable = ok & (counts == w + lag) & (still == w + lag)

        bias_lim_si = gyro.limits.bias / gyro.scale_factor * gyro.unit_to_si
        sigma = gyro.noise_sigma(self.rate_hz)
        sigma_mean_si = (
            np.zeros(3)
            if sigma is None
            else sigma / gyro.scale_factor * gyro.unit_to_si / math.sqrt(w)
        )
        thr = cert.earth_rate + bias_lim_si + self.config.k_sigma * sigma_mean_si
        m = mean[usable]
        excess = np.abs(m) / thr  # > 1 fails
        worst = excess.max(axis=1) if m.shape[0] else np.zeros(0)
        failed = worst > 1.0
        values = worst  # ratio of the worst axis' mean rate to its threshold
        st = self.state["gyro"]
        st.checked += int(m.shape[0])
        st.failed += int(np.count_nonzero(failed))
        st.sum_f0_sq += float(np.sum(values * values))
        if m.shape[0]:
            st.last_f0 = float(values[-1])
        if np.any(failed):
            st.worst_axis = int(np.argmax(excess[failed][-1]))
        assert st.persistence is not None
        st.persistence.update(failed, t[usable])

    def _stuck(self, block: SampleBlock) -> None:
        """Run length of identical raw outputs per channel, carried across blocks."""
        cfg = self.config
        for name in TRIADS:
            st = self.state[name]
            triad = self.certificate.triad(name)
            sigma = triad.noise_sigma(self.rate_hz)
            if sigma is None:
                continue
            enabled = sigma >= cfg.stuck_min_sigma
            raw = block.triad(name)
            prev = st.stuck_last
            same_prev = np.vstack([raw[:1] == prev, raw[1:] == raw[:-1]])  # (N, 3)
            n = raw.shape[0]
            idx = np.arange(n)[:, None]
            # index of the last change at or before each sample (-1: none in this block)
            last_change = np.maximum.accumulate(np.where(~same_prev, idx, -1), axis=0)
            carried = np.where(last_change < 0, st.stuck_run[None, :] + idx + 1, idx - last_change)
            run = carried  # samples in the current run of equal values, excluding its first
            st.stuck_run = run[-1].astype(np.int64)
            st.stuck_last = raw[-1].copy()
            st.stuck_active = enabled & (st.stuck_run >= cfg.stuck_samples - 1)

    def _noise(self, block: SampleBlock, calm: np.ndarray) -> None:
        """Excess white noise per channel from second differences, carried across blocks.

        Every ``noise_check_s`` of samples, per channel, sigma from the median of
        the squared second differences over the trailing ``noise_window_s``
        (median of chi^2_1 = 0.4549; var(d2) = 6 sigma^2 for white noise): a
        burst over less than half the window (a hand grabbing the unit, a knock,
        a step) leaves the median alone, where a mean would call it noise.
        ``calm`` (N,): the window ending at each sample saw no turn (angular
        acceleration below ``noise_motion_gate``); only those windows are judged.
        Excess noise (beyond ``noise_ratio``) must persist 3 s; gross noise
        (beyond ``noise_gross_ratio``) is raised after 3 of 5 checks.
        """
        w, step = self._noise_w, self._noise_step
        n = len(block)
        # check positions: samples whose index in the stream is a multiple of the step
        first = self.samples - n
        pos = np.arange((-first) % step, n, step)
        for name in TRIADS:
            st = self.state[name]
            triad = self.certificate.triad(name)
            sigma = triad.noise_sigma(self.rate_hz)
            raw = np.concatenate([st.noise_tail, block.triad(name)])
            st.noise_tail = raw[-2:]
            if sigma is None or raw.shape[0] < 3:
                continue
            if triad.output_unit == "count":  # whole counts add q^2/12 of quantisation noise
                sigma = np.sqrt(sigma**2 + 1.0 / 12.0)
            d2sq = np.diff(raw, n=2, axis=0) ** 2  # ends at the block's last len(d2sq) samples
            buf = np.concatenate([st.noise_d2sq, d2sq])
            st.noise_d2sq = buf[-w:]
            offset = buf.shape[0] - n  # buf row of block sample i is i + offset
            ok = pos[(pos + offset + 1 >= w) & calm[pos]]
            if ok.size == 0:
                continue
            ratio = np.empty((ok.size, 3))
            for j, i in enumerate(ok):
                end = i + offset + 1
                ratio[j] = np.sqrt(np.median(buf[end - w : end], axis=0) / (0.4549 * 6.0)) / sigma
            st.noise_ratio_last = ratio[-1]
            t = block.t[ok]
            for axis in range(3):
                st.noise[axis].update(ratio[:, axis] > self.config.noise_ratio, t)
                st.noise_gross[axis].update(ratio[:, axis] > self.config.noise_gross_ratio, t)
