"""Per-sample monitor: certificate-corrected F0 checks, persistence, stuck and saturation.

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
  samples where its noise makes that impossible: the certificate's noise sigma is at
  least ``stuck_min_sigma`` quantisation steps of the output, the step being 1 for
  counts and otherwise the smallest nonzero change between consecutive outputs seen,
  which is the LSB of a quantised physical output and next to nothing for a float one;
  any unit; a physical output, which its device may filter, must also have shown at
  most ``stuck_max_repeat`` identical consecutive pairs over ``stuck_history`` pairs)
  and saturation flags;
- excess noise: per channel, the white-noise sigma estimated from second
  differences over ``noise_window_s`` (var(d2 U) = 6 sigma^2 for white noise;
  smooth motion contributes almost nothing at the sample rate; squares are
  winsorised at 10 sigma of d2 so a step is not taken for noise) beyond
  ``noise_ratio`` times the certificate's sigma, judged on windows where the
  angular acceleration stayed below ``noise_motion_gate`` (a hand turn puts far
  more into second differences than the noise does; a steady rate does not;
  vibration and translation are still judged).

All of it is vectorised per block; state carries across blocks. The checks of their own
sit beside this module (:mod:`.noise`, :mod:`.stuck`), with the F0 screen that lets reads
be gathered into batches (:mod:`.batching`), the settings and per-triad state
(:mod:`.state`) and the plot trace (:mod:`.trace`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..certificate import SENSOR_NAMES, TRIADS, Certificate, TriadModel
from ..kernels import kernel
from ..persistence import Persistence
from ..quasistatic import DetectorPool, QuasiStaticDetector, SharedDetectorReader
from ..ringbuffer import SampleRing
from ..rowwise import rows_op, rows_over, rows_where
from ..samples import (
    FLAG_ACCEL_SATURATED,
    FLAG_ADC_ERROR,
    FLAG_GYRO_SATURATED,
    FLAG_SELF_TEST,
    SampleBlock,
)
from ..scalar import f0
from ..trailing import PrefixSums
from ..vibration import VibrationMeter
from .batching import F0Screen
from .noise import TRIADS_RING, NoiseCheck
from .state import MonitorConfig, TriadState
from .stuck import monitor_stuck_check, stuck_faults
from .trace import F0Trace


class Monitor:
    """Runs the per-sample checks over consecutive blocks of one stream."""

    def __init__(
        self,
        certificate: Certificate,
        config: MonitorConfig | None = None,
        rate_hz: float | None = None,
        detectors: DetectorPool | None = None,
    ) -> None:
        """``rate_hz``: the stream's sample rate (default: the certificate's nominal rate).
        ``detectors``: where the still detector comes from, to share it with other consumers
        of the same stream (``imudiag diagnose``); None: a detector of its own (the daemon)."""
        self.config = config or MonitorConfig()
        self._detectors = detectors
        self.detector: QuasiStaticDetector | SharedDetectorReader
        self._rate_override = rate_hz
        self.certificate = certificate
        self.ring = SampleRing(self.config.ring_capacity)
        self.samples = 0  #: samples seen
        self._adc_errors = 0
        self._self_test = 0
        self.t_last: float | None = None  #: sample time of the last sample, s
        self._static = False
        self._state: dict[str, TriadState] = {}
        # reads not yet through the detector and F0 checks; and blocks through them (with
        # their static flags and corrected rates) waiting for the other checks
        self._pending: list[SampleBlock] = []
        self._pending_n = 0
        self._staged: list[tuple[SampleBlock, np.ndarray, np.ndarray]] = []
        self._staged_n = 0
        self._checked_samples = 0  # samples through every check
        self._beyond = {"accel": 0, "gyro": 0}  # pending samples beyond the F0 limit
        self._unscreened: list[SampleBlock] = []  # pending reads not looked at yet
        self._unscreened_n = 0
        self._faults: list[dict[str, Any]] | None = []  # the faults in force (None: stale)
        #: every F0 check per triad, for plots (None: not kept; see :meth:`keep_f0_trace`)
        self.f0_trace: dict[str, F0Trace] | None = None
        self.set_certificate(certificate)

    def keep_f0_trace(self, max_points: int = 50_000) -> dict[str, F0Trace]:
        """Keep every F0 check from now on (thinned to ``max_points`` per triad and verdict)
        in :attr:`f0_trace`; returns it."""
        self.f0_trace = {
            name: F0Trace(
                self.check_mode(name),
                1.0 if self.check_mode(name) == "rest_rate" else self._limit[name],
                max_points,
            )
            for name in TRIADS
        }
        return self.f0_trace

    # -- configuration ----------------------------------------------------

    def set_certificate(self, certificate: Certificate) -> None:
        """Use a new certificate from the next block on (persistence restarts; the samples
        read before are checked with the previous one)."""
        if hasattr(self, "detector"):
            self.flush()
        self.certificate = certificate
        cfg = self.config
        rate = self._rate_override or certificate.sample_rate
        self.rate_hz = rate
        self._batch = max(0, int(round(cfg.batch_s * rate)))
        if self._detectors is None:
            self.detector = QuasiStaticDetector(certificate, rate, window_s=cfg.static_window_s)
        else:
            self.detector = self._detectors.detector(
                certificate, rate, window_s=cfg.static_window_s
            )
        self._faults = None
        self._state = {}
        for name in TRIADS:
            st = TriadState()
            st.persistence = Persistence(cfg.persistence_k, cfg.persistence_n)
            st.saturation = Persistence(cfg.persistence_k, cfg.persistence_n)
            st.noise = [
                Persistence(cfg.noise_persistence_k, cfg.noise_persistence_n) for _ in range(3)
            ]
            st.noise_gross = [Persistence(3, 5) for _ in range(3)]
            self._state[name] = st
        self.gyro_mode = self._gyro_mode(certificate.gyro, rate)
        #: the installation's vibration (:mod:`imudiag.vibration`), fed every sample
        self.vibration = VibrationMeter(certificate, rate)
        # per-certificate constants, computed once rather than on every block
        self._n_inv_t = {name: certificate.triad(name).n_inverse_t() for name in TRIADS}
        self._sigma = {name: certificate.triad(name).noise_sigma(rate) for name in TRIADS}
        self._limit = {name: float(certificate.triad(name).limits.f0) for name in TRIADS}
        # (a MEMS gyro's rest-rate check averages its own window: one value per sample)
        self._per_check = {
            name: 1 if name == "gyro" and self.gyro_mode == "rest_rate" else self._f0_group(name)
            for name in TRIADS
        }
        #: the F0 screen of the reads gathered (:mod:`.batching`)
        self._screen = F0Screen(certificate, self._n_inv_t, self._limit)
        # stuck outputs: both triads as one (6,) row, gyro then accel (the ring's column order)
        self._stuck = monitor_stuck_check(certificate, cfg, rate)
        self._gyro_window = max(1, int(round(cfg.gyro_window_s * rate)))
        # the MEMS rest-rate check's threshold per axis (rad/s): Earth rate, the bias limit
        # and k_sigma standard deviations of the window's mean
        gyro = certificate.gyro
        bias_lim_si = gyro.limits.bias / gyro.scale_factor * gyro.unit_to_si
        sigma_g = self._sigma["gyro"]
        sigma_mean_si = (
            np.zeros(3)
            if sigma_g is None
            else sigma_g / gyro.scale_factor * gyro.unit_to_si / math.sqrt(self._gyro_window)
        )
        self._rest_thr = certificate.earth_rate + bias_lim_si + cfg.k_sigma * sigma_mean_si
        # the detector's window is trailing: the first samples of a turn still look
        # static. The rest-rate mean is therefore taken over a window that ends
        # ``lag`` samples (one detector window) back, and used only if the samples
        # after it are static too.
        self._gyro_lag = max(1, int(round(cfg.static_window_s * rate)))
        span = self._gyro_window + self._gyro_lag
        self._span = span
        #: the excess-noise check (:mod:`.noise`)
        self._noise = NoiseCheck(certificate, cfg, rate)
        # the noise check reads its raw samples back from the ring of recent samples
        if self.ring.capacity < self._noise.window + 2:
            self.ring = SampleRing(self._noise.window + 2)
        self._noise_from = self._checked_samples  # the noise history restarts with it
        self._accel_m = max(1, int(round(0.1 * rate)))  # angular acceleration: 0.1 s means
        # every trailing window of the checks from prefix sums of the stream, one gather per
        # block: columns gx, gy, gz (corrected, rad/s), static (0/1), non-finite gyro (0/1);
        # P back by: lag, span (the rest-rate mean and the still count), m and 2m (the
        # angular acceleration from 0.1 s means)
        m = self._accel_m
        self._offsets = np.array([self._gyro_lag, span, m, 2 * m])
        self._prefix = PrefixSums(5, max(span, 2 * m))
        # turning samples among the inputs of the noise window's second differences
        self._turn_offsets = np.array([self._noise.window + 2])
        self._turn_prefix = PrefixSums(1, self._noise.window + 2)

    def _f0_group(self, name: str, sigma: np.ndarray | None = None) -> int:
        """Checked samples averaged per F0 check of ``name`` (see ``f0_noise_ratio``), for
        the per-sample noise ``sigma`` (output units; default: the certificate's)."""
        ratio = self.config.f0_noise_ratio
        tri = self.certificate.triad(name)
        if sigma is None:
            sigma = tri.noise_sigma(self.rate_hz)
        if ratio <= 0 or sigma is None:
            return 1
        magnitude = self.certificate.gravity if name == "accel" else self.certificate.earth_rate
        # F0 = (|u|^2 - 1) / 2 moves by the noise along u: sigma_F0 = sigma / magnitude
        sigma_f0 = float(np.max(sigma / tri.scale_factor)) * tri.unit_to_si / magnitude
        return max(1, math.ceil((ratio * sigma_f0 / float(tri.limits.f0)) ** 2 - 1e-9))

    def samples_per_check(self, name: str) -> int:
        """Consecutive checked samples whose mean F0 each F0 check of ``name`` judges."""
        return self._per_check[name]

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
    #
    # Every accessor below first runs the checks on the samples gathered so far
    # (:meth:`flush`), so what it returns holds for every sample read; the daemon's loop
    # reads :meth:`faults_in_force` instead, which never runs them.

    @property
    def state(self) -> dict[str, TriadState]:
        """Counters and check states per triad (after every sample read)."""
        self.flush()
        return self._state

    @property
    def static(self) -> bool:
        """The last sample read was quasi-static."""
        self.flush()
        return self._static

    @property
    def adc_errors(self) -> int:
        """Samples flagged with an ADC error (not checked)."""
        self.flush()
        return self._adc_errors

    @property
    def self_test(self) -> int:
        """Samples flagged as self-test (deflected on purpose; not checked)."""
        self.flush()
        return self._self_test

    @property
    def stuck_checked(self) -> dict[str, list[bool]]:
        """Per triad and axis whether the stuck check runs (the certificate's noise is at
        least ``stuck_min_sigma`` quantisation steps of the output, no step is known
        before the output first changed; a physical output's own repeat rate is low)."""
        self.flush()
        on = [bool(x) for x in self._stuck.enabled]
        return {name: on[3 * k : 3 * k + 3] for k, name in enumerate(TRIADS_RING)}

    @property
    def adc_errors_checked(self) -> int:
        """:attr:`adc_errors` among the samples checked so far (no :meth:`flush`)."""
        return self._adc_errors

    @property
    def pending_samples(self) -> int:
        """Samples read whose checks have not all run yet (at most a batch)."""
        return self._pending_n + self._staged_n

    def faults_in_force(self) -> list[dict[str, Any]]:
        """The faults in force without running the gathered samples' checks: exact for F0
        (a read that could change an F0 verdict runs those checks at once), as of the
        last batch for the slower ones (stuck, noise, saturation, the gyro rest rate).
        The same list object until a check has run (the daemon's loop compares it)."""
        if self._faults is None:
            self._faults = self._active_faults()
        return self._faults

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
        self.flush()
        return list(self.faults_in_force())

    def _active_faults(self) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for name in TRIADS:
            st = self._state[name]
            if st.persistence is not None and st.persistence.active:
                # sensor: the worst axis where the check can tell it (a MEMS gyro at rest),
                # else None (F0 is a triad check); the key is always there (reports.md)
                fault: dict[str, Any] = {"triad": name, "sensor": None, "cause": "f0"}
                if name == "gyro" and self.gyro_mode == "rest_rate" and st.worst_axis is not None:
                    fault["sensor"] = SENSOR_NAMES[name][st.worst_axis]
                fault["t_first"] = st.persistence.t_first
                out.append(fault)
            base = 0 if name == TRIADS_RING[0] else 3
            for stuck in np.flatnonzero(st.stuck_active):
                t_in = float(self._stuck.t_first[base + stuck])
                out.append(
                    {
                        "triad": name,
                        "sensor": SENSOR_NAMES[name][stuck],
                        "cause": "stuck",
                        "t_first": t_in if math.isfinite(t_in) else None,
                    }
                )
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
                    "samples_per_check": self._per_check[name],
                    "t_first": p.t_first_raised,
                    "raised": p.raised,
                    "failed": st.failed,
                    "checked": st.checked,
                }
            )
        return out

    def f0_unjudged(self, name: str) -> str | None:
        """Why the F0 check of ``name`` has judged nothing although it has still samples:
        fewer than one check averages (``samples_per_check``); None otherwise."""
        st = self.state[name]
        m = self._per_check[name]
        if not st.checked or not math.isnan(st.last_f0) or m <= st.checked:
            return None
        if self._sigma[name] is None:  # the noise the still detector measures (a unit never still)
            return (
                f"{st.checked} still samples, fewer than the {m} one F0 check averages at "
                "the noise the still detector measures in the data (the certificate states "
                "none): a unit that is never still"
            )
        return f"{st.checked} still samples, fewer than the {m} one F0 check averages"

    def f0_why(self, name: str) -> str | None:
        """Why the F0 check of ``name`` has checked no sample (None once it has): which
        criterion failed, with the figure and its threshold (issue 25 item 4)."""
        st = self.state[name]
        if st.checked:
            return None
        e = self.detector.explain
        cfg = self.config
        if self.samples == 0:
            return "no samples"
        if e["windows"] == 0:
            return f"no whole still-detector window ({cfg.static_window_s:g} s) yet"
        if e["static"] == 0:
            for tri in ("accel", "gyro"):
                if e[f"{tri}_variance_ok"] == 0:
                    has = self.certificate.triad(tri).noise_sigma(self.rate_hz) is not None
                    noise = "the certificate's" if has else "the data's"
                    return (
                        f"never still: no {cfg.static_window_s:g} s window of the {tri} "
                        f"variance within the still detector's limit (the sum over the axes "
                        f"of variance / {noise} white-noise variance); the quietest of "
                        f"{e['windows']} windows was {e[f'{tri}_least_ratio']:.3g} x that "
                        "limit: vibration or motion beyond the certificate's noise, or a "
                        "certificate noise figure too low (the report's noise section)"
                    )
            return (
                f"never still: {e['accel_variance_ok']} of {e['windows']} windows passed the "
                "variance test, but the gyro rate band or the drift tests (a vehicle's "
                "manoeuvre, a curve) failed every one"
            )
        if name == "gyro" and self.gyro_mode == "rest_rate":
            return (
                f"{e['static']} still samples, but no still stretch of "
                f"{self._span / self.rate_hz:.3g} s (the rest-rate mean over "
                f"{cfg.gyro_window_s:g} s and one detector window after it) without a "
                "saturation or ADC-error flag"
            )
        return f"{e['static']} still samples, every one flagged (saturation or ADC error)"

    def stuck_faults(self) -> list[dict[str, Any]]:
        """Stuck outputs ever raised over the stream, per sensor (``diagnose``'s faults: the
        daemon's ``stuck`` fault, the same check; :func:`.stuck.stuck_faults`)."""
        return stuck_faults(self._stuck)

    def saturation_faults(self) -> list[dict[str, Any]]:
        """Saturation ever raised over the stream, per triad (the daemon's ``saturation``
        fault: the samples' saturation flags, the same persistence; no axis can be told:
        ``sensor`` None): ``t_first`` the sample time (s) it first came in force, ``raised``
        how many times."""
        out: list[dict[str, Any]] = []
        for name in TRIADS:
            sat = self._state[name].saturation
            if sat is not None and sat.raised:
                out.append(
                    {
                        "triad": name,
                        "sensor": None,
                        "cause": "saturation",
                        "t_first": sat.t_first_raised,
                        "raised": sat.raised,
                    }
                )
        return out

    def noise_faults(self) -> list[dict[str, Any]]:
        """Excess-noise faults ever raised over the stream, per sensor (``diagnose``'s faults:
        the daemon's ``noise`` fault, the same checks and persistence). ``estimate``: the
        median white-noise sigma of the judged checks beyond the limit (output units),
        ``certificate`` the certificate's sigma at the stream's rate, ``limit``
        ``noise_ratio`` times it."""
        out: list[dict[str, Any]] = []
        for name in TRIADS:
            st = self.state[name]
            sigma = self._noise.sigma.get(name)
            if sigma is None:
                continue
            unit = self.certificate.triad(name).output_unit
            for axis, (p, gross) in enumerate(zip(st.noise, st.noise_gross, strict=True)):
                if p.raised == 0 and gross.raised == 0:
                    continue
                firsts = [q.t_first_raised for q in (p, gross) if q.t_first_raised is not None]
                excess = np.concatenate(st.noise_excess)[:, axis] if st.noise_excess else None
                beyond = None if excess is None else excess[excess > self.config.noise_ratio]
                worst = float(np.median(beyond)) if beyond is not None and beyond.size else math.nan
                out.append(
                    {
                        "triad": name,
                        "sensor": SENSOR_NAMES[name][axis],
                        "cause": "noise",
                        "estimate": worst * float(sigma[axis]) if math.isfinite(worst) else None,
                        "certificate": float(sigma[axis]),
                        "limit": self.config.noise_ratio * float(sigma[axis]),
                        "unit": unit,
                        "t_first": min(firsts) if firsts else None,
                        "raised": p.raised + gross.raised,
                    }
                )
        return out

    # -- the checks -------------------------------------------------------

    def update(self, block: SampleBlock) -> None:
        """Check every sample of ``block`` (consecutive with the previous block).

        The F0 verdicts are final when this returns. The samples are gathered and the
        checks run once per ``batch_s`` of them, unless a sample of ``block`` is beyond
        its F0 limit or the F0 persistence holds a failure: then the quasi-static detector
        and the F0 checks run at once (whether the sample counts depends on the unit
        being still). Gathering changes no result: every check carries its state from
        sample to sample, whatever the blocks (the noise estimate of a certificate
        without noise figures is the exception: it takes a quantile per block).
        """
        n = len(block)
        if n == 0:
            return
        self.samples += n
        self.t_last = float(block.t[-1])
        self._pending.append(block)
        self._pending_n += n
        self._unscreened.append(block)
        self._unscreened_n += n
        if self._pending_n + self._staged_n >= self._batch:
            self.flush()
        elif self._f0_may_change():
            self._f0_stage()

    def flush(self) -> None:
        """Run every check on the samples gathered so far."""
        if self._pending:
            self._f0_stage()
        if self._staged:
            self._slow_stage()

    def _f0_may_change(self) -> bool:
        """Whether the reads gathered could change an F0 verdict (the test every read makes).

        The samples beyond the F0 limit among the reads gathered since the F0 checks last
        ran bound the failures they can add, whether or not the unit was still: with the
        failures already in the persistence window they must stay below ``k``, or the
        fault could be raised. Reads not yet looked at count as beyond: they are looked
        at (all at once) only when that bound reaches ``k``, every few reads. A fault in
        force is checked on every read (passes clear it).
        """
        gyro_f0 = self.gyro_mode == "earth_rate"
        names = ("accel", "gyro") if gyro_f0 else ("accel",)
        unseen = self._unscreened_n
        for name in names:
            p = self._state[name].persistence
            assert p is not None
            if p.active:
                return True
            if p.tail_failures + self._beyond[name] + unseen >= p.k:
                break
        else:
            return False  # even if every sample not looked at failed
        parts = self._unscreened
        self._unscreened = []
        self._unscreened_n = 0
        for name, count in self._screen.count(parts, gyro_f0).items():
            self._beyond[name] += count
        for name in names:
            p = self._state[name].persistence
            assert p is not None
            if p.tail_failures + self._beyond[name] >= p.k:
                return True
        return False

    def _f0_stage(self) -> None:
        """The quasi-static detector and the F0 checks over the reads gathered."""
        pending = self._pending
        block = pending[0] if len(pending) == 1 else SampleBlock.concat(pending)
        self._pending = []
        self._pending_n = 0
        self._unscreened = []
        self._unscreened_n = 0
        self._beyond = {"accel": 0, "gyro": 0}
        self._faults = None
        n = len(block)
        cert = self.certificate
        flags = block.flags if block.flags is not None else np.zeros(n, dtype=np.uint16)
        flags = flags.astype(np.uint16, copy=False)
        adc_error = (flags & FLAG_ADC_ERROR) != 0
        self._adc_errors += int(np.count_nonzero(adc_error))
        self._self_test += int(np.count_nonzero(flags & FLAG_SELF_TEST))

        static = self.detector.update(block)
        self._static = bool(static[-1])
        temp = block.temp
        accel_in = cert.accel.inverse(block.accel, temp_c=temp, n_inv_t=self._n_inv_t["accel"])
        gyro_si = cert.gyro.inverse_si(
            block.gyro,
            temp_c=temp,
            accel_input=accel_in if cert.gyro.g_sensitivity is not None else None,
            n_inv_t=self._n_inv_t["gyro"],
        )

        # accelerometer F0 on quasi-static samples (accel_in, an array of our own, taken
        # to m/s^2 and then to fractions of g in place: the same products, no copies)
        ok = ~adc_error
        ok &= static
        ok_a = ok & ((flags & FLAG_ACCEL_SATURATED) == 0)
        accel_si = np.multiply(accel_in, cert.accel.unit_to_si, out=accel_in)
        self._record(
            "accel", f0(rows_over(accel_si, ok_a, cert.gravity)), rows_where(block.t, ok_a)
        )
        if self.gyro_mode == "earth_rate":
            ok &= (flags & FLAG_GYRO_SATURATED) == 0
            self._record("gyro", f0(gyro_si[ok] / cert.earth_rate), rows_where(block.t, ok))
        self._staged.append((block, static, gyro_si))
        self._staged_n += n

    def _slow_stage(self) -> None:
        """Saturation, the gyro rest rate, stuck outputs and excess noise over the blocks
        through the F0 stage."""
        staged = self._staged
        if len(staged) == 1:
            block, static, gyro_si = staged[0]
        else:
            block = SampleBlock.concat([b for b, _, _ in staged])
            static = np.concatenate([s for _, s, _ in staged])
            gyro_si = np.concatenate([g for _, _, g in staged])
        self._staged = []
        self._staged_n = 0
        self._faults = None
        n = len(block)
        self._checked_samples += n
        flags = block.flags if block.flags is not None else np.zeros(n, dtype=np.uint16)
        flags = flags.astype(np.uint16, copy=False)
        adc_error = (flags & FLAG_ADC_ERROR) != 0
        sat = {
            "gyro": (flags & FLAG_GYRO_SATURATED) != 0,
            "accel": (flags & FLAG_ACCEL_SATURATED) != 0,
        }
        for name in TRIADS:
            st = self._state[name]
            assert st.saturation is not None
            st.saturation.update(sat[name], block.t)
        self.vibration.update(block)

        # gyro
        rows = np.empty((n, 5))
        rows[:, :3] = gyro_si
        rows[:, 3] = static
        rows[:, 4] = 0.0
        finite = bool(np.isfinite(gyro_si).all())
        if not finite:  # an ADC error: zeroed in the sums, counted in a column of its own
            bad = ~np.isfinite(gyro_si).all(axis=1)
            rows[bad, :3] = 0.0
            rows[:, 4] = bad
        # P at each row and ``_offsets`` rows back (views on diagnose's big blocks: no copies)
        now, back, idx = self._prefix.update_views(rows, self._offsets)

        if self.gyro_mode != "earth_rate":
            ok_g = static & ~adc_error & ~sat["gyro"]
            self._gyro_rest_rate(now, back, idx, ok_g, block.t)

        # angular acceleration from the last 0.1 s mean rate minus the 0.1 s before it:
        # (2 (P[s] - P[s-m]) - (P[s] - P[s-2m])) / m per 0.1 s (in place: the same
        # operations in the same order as now - 2 back2 + back3, fewer (N, 3) arrays)
        m = self._accel_m
        compiled = kernel("turning_rows")
        if compiled is not None:  # the same operations in one pass
            turns = compiled(
                now, back[2], back[3], self.rate_hz / m, m,
                float(self.config.noise_motion_gate), not finite,
            )  # fmt: skip
        else:
            d = np.multiply(2.0, back[2][:, :3])
            np.subtract(now[:, :3], d, out=d)
            d += back[3][:, :3]
            alpha = np.einsum("ij,ij->i", d, d)
            np.sqrt(alpha, out=alpha)
            alpha *= self.rate_hz / m
            alpha /= m
            if not finite:
                alpha[now[:, 4] - back[3][:, 4] > 0] = np.nan
            turning = ~(alpha <= self.config.noise_motion_gate)  # NaN (ADC error): turning
            turns = turning[:, None].astype(float)
        tnow, tback, _ = self._turn_prefix.update_views(turns, self._turn_offsets)
        first = self._checked_samples - n
        pos = self._noise.positions(first, self._noise_seen(n), tnow[:, 0] == tback[0][:, 0])
        # both triads' raw outputs channel by channel (6, h + n), gyro then accel (the
        # ring's column order), after the h samples before the block that the noise
        # check's windows reach back to (from the ring, pushed after this)
        h = min(self._noise.window + 1, self._noise_seen(n), len(self.ring)) if pos.size else 0
        chan = np.empty((6, h + n))
        if h:
            chan[:, :h] = self.ring.latest(h)[:, 1:7].T
        chan[:3, h:] = block.gyro.T
        chan[3:, h:] = block.accel.T
        active = self._stuck.update(chan[:, h:], block.t)
        self._state["gyro"].stuck_active = active[:3]
        self._state["accel"].stuck_active = active[3:]
        if pos.size:
            self._noise.judge(block.t, chan, pos, self._state)
        self.ring.push(block)

    def _record(self, name: str, values: np.ndarray, t: np.ndarray) -> None:
        """Checked F0 values (dimensionless) at sample times ``t`` (s): counters, and the
        k-of-n persistence over checks of ``samples_per_check`` samples each (their mean)."""
        st = self._state[name]
        limit = self._limit[name]
        st.checked += int(values.size)
        st.sum_f0_sq += float(np.sum(values * values))
        if self._sigma[name] is None:
            # the certificate states no noise: the still detector measures the data's
            # (the quietest windows so far), and each check averages as many samples as
            # that noise needs, as it would for the certificate's. A unit that is never
            # still (hand-held) shows a noise far above the F0 limit: no check completes
            # on its few "quietest" samples, rather than failing on its motion
            data_sigma = self.detector.noise_sigma(name)
            if data_sigma is not None:
                self._per_check[name] = self._f0_group(name, data_sigma)
        m = self._per_check[name]
        if m > 1:
            carry_v, carry_t = st.carry
            if carry_v.size:
                values = np.concatenate([carry_v, values])
                t = np.concatenate([carry_t, t])
            k = values.size // m
            st.carry = (values[k * m :].copy(), t[k * m :].copy())
            values = values[: k * m].reshape(k, m).mean(axis=1)
            t = t[m - 1 : k * m : m]  # a check's time: its last sample's
        failed = np.abs(values) > limit
        if self.f0_trace is not None:
            self.f0_trace[name].add(t, values, failed)
        st.failed += m * int(np.count_nonzero(failed))
        if values.size:
            st.last_f0 = float(values[-1])
        assert st.persistence is not None
        st.persistence.update(failed, t)

    def _gyro_rest_rate(
        self,
        now: np.ndarray,
        back: tuple[np.ndarray, ...],
        idx: np.ndarray,
        ok: np.ndarray,
        t: np.ndarray,
    ) -> None:
        """MEMS rest-rate check: moving mean of the corrected rate over a static window.

        ``now`` (N, 5), ``back`` four (N, 5), ``idx`` (N,): the prefix sums (see ``_offsets``).
        """
        w, span = self._gyro_window, self._span
        compiled = kernel("rest_rate_rows")
        if compiled is not None:  # the same operations in one pass
            thr = np.asarray(self._rest_thr, dtype=float)
            worst, usable = compiled(now, back[0], back[1], w, thr, ok, idx, span)
        else:
            # per axis, the mean of the w samples that end lag samples back as a ratio to its
            # threshold (> 1 fails): for every sample, in place, then kept where usable
            excess = np.subtract(back[0][:, :3], back[1][:, :3])
            excess /= w
            np.abs(excess, out=excess)
            rows_op(np.divide, excess, self._rest_thr, out=excess)
            still = now[:, 3] - back[1][:, 3]
            # the averaging window and the lag after it were all still
            usable = ok & (idx + 1 >= span) & (still == span)
            # the ratio of the worst axis (elementwise maxima: a reduction along rows of 3
            # costs 20 times more; NaN stays NaN either way)
            worst = np.maximum(excess[:, 0], excess[:, 1])
            np.maximum(worst, excess[:, 2], out=worst)
        values = rows_where(worst, usable)  # ratio of the worst axis' mean rate to its threshold
        failed = values > 1.0
        st = self._state["gyro"]
        t_used = rows_where(t, usable)
        if self.f0_trace is not None:
            self.f0_trace["gyro"].add(t_used, values, failed)
        st.checked += int(values.size)
        st.failed += int(np.count_nonzero(failed))
        st.sum_f0_sq += float(np.sum(values * values))
        if values.size:
            st.last_f0 = float(values[-1])
        if np.any(failed):
            last = np.flatnonzero(usable)[np.flatnonzero(failed)[-1]]
            # that row's ratios again (the same operations as for every row above)
            row = np.abs((back[0][last, :3] - back[1][last, :3]) / w) / self._rest_thr
            st.worst_axis = int(np.argmax(row))
        assert st.persistence is not None
        st.persistence.update(failed, t_used)

    def _noise_seen(self, n: int) -> int:
        """Samples before the block of ``n`` just counted, since the certificate was set
        (the noise history restarts with it)."""
        return self._checked_samples - n - self._noise_from
