"""The streaming window diagnosis the daemon runs live and ``imudiag diagnose`` replays.

Blocks go in; quasi-static intervals are collected; each closed interval
completes a window over the most recent ``window_intervals`` intervals (no
older than ``window_max_s``), which is fitted and judged by the predicates.
With ``method="moving-base"`` windows are time based instead: every sample
enters the normal equations of the linearised model with a per-sample
magnitude (independent when one is passed to :meth:`update`, else the paper's
own estimate from the certificate-corrected output, which is circular: note §1).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from .. import validate
from ..certificate import Certificate
from ..quasistatic import DetectorPool
from ..reports import DIAGNOSIS_FORMAT, header
from ..samples import SampleBlock
from .config import CERTIFICATE_NOISE, DiagnosisConfig
from .intervals import IntervalCollector, QuasiStaticInterval
from .known_rate import PLATEAU_DETECTOR, classify_plateaus
from .params import CAUSES, TriadFit, sensor_of
from .predicates import PredicateTracker
from .scalar_fit import NormalEquations, corrected_normalised, normal_equation_fit, sample_rows
from .window import WindowResult, diagnose_window, distinct_attitudes

REPORT_FORMAT = DIAGNOSIS_FORMAT
TRIADS = ("accel", "gyro")


def _step_boundaries(res: WindowResult) -> list[tuple[str, int]]:
    """(triad, the window's first interval after the step) of each triad whose fit found a
    step change (its ``step_change``)."""
    return [
        (t, int(res.fit(t).extra["step_change"]["index"]))
        for t in TRIADS
        if "step_change" in res.fit(t).extra
    ]


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average of (N,) over n samples (shorter at the edges)."""
    if n <= 1 or x.shape[0] == 0:
        return x
    c = np.concatenate([[0.0], np.cumsum(x)])
    idx = np.arange(x.shape[0])
    lo = np.maximum(idx - n // 2, 0)
    hi = np.minimum(idx + n - n // 2, x.shape[0])
    return (c[hi] - c[lo]) / (hi - lo)


class StreamingDiagnoser:
    """Sliding-window 18-parameter diagnosis over a sample stream.

    ``certificate``: what the estimates are compared with. ``config``: a
    :class:`DiagnosisConfig` or a mapping of its fields. ``rate_hz``: sample
    rate (Hz), defaults to the certificate's. ``certificate_noise``: True makes
    the quasi-static detector trust the certificate's noise figure instead of
    measuring the noise from the data (default :data:`.config.CERTIFICATE_NOISE`, as
    :func:`imudiag.diagnose`). A bad setting or rate raises BadInput naming it.
    ``detectors``: where the interval collector's still detector comes from (a
    :class:`~imudiag.quasistatic.DetectorPool` shares it with the monitor's of ``imudiag
    diagnose`` when they are alike); None: its own.
    """

    def __init__(
        self,
        certificate: Certificate,
        config: DiagnosisConfig | dict[str, Any] | None = None,
        rate_hz: float | None = None,
        certificate_noise: bool = CERTIFICATE_NOISE,
        detectors: DetectorPool | None = None,
    ) -> None:
        if not isinstance(config, DiagnosisConfig):
            config = DiagnosisConfig.from_dict(config)
        self.config = config
        if rate_hz is not None:
            validate.sample_rate(rate_hz, "rate_hz")
        self.rate_hz = float(rate_hz or certificate.sample_rate)
        self.certificate = certificate
        #: whether the quasi-static detector trusts the certificate's noise density
        self.certificate_noise = certificate_noise
        self._detectors = detectors
        self._reset()

    def _reset(self) -> None:
        cfg = self.config
        self.collector = IntervalCollector(
            self.certificate,
            self.rate_hz,
            detector_window_s=cfg.detector_window_s,
            min_interval_s=cfg.min_interval_s,
            max_interval_s=cfg.max_interval_s,
            trim_s=cfg.trim_s,
            motion_margin_s=cfg.motion_margin_s,
            max_motion_s=cfg.max_motion_s,
            detector_options={
                "certificate_noise": self.certificate_noise,
                **(PLATEAU_DETECTOR if cfg.known_rate_rad_s is not None else {}),
            },
            detectors=self._detectors,
        )
        self.tracker = PredicateTracker(cfg.k_sigma, cfg.persist)
        self._window: deque[QuasiStaticInterval] = deque()
        self.intervals = 0  #: intervals collected
        self.windows: deque[WindowResult] = deque(maxlen=cfg.max_windows_kept)
        self.windows_run = 0
        self._determined = {t: np.zeros(9, dtype=bool) for t in TRIADS}
        self._reasons: dict[str, list[str]] = {t: ["no window was fitted"] * 9 for t in TRIADS}
        self.samples = 0
        #: per triad the live verdict (ok, fault, undetermined) and the sample time, s (the
        #: end of the window that brought it; None before a window), it came in force
        self.verdict_since: dict[str, tuple[str, float | None]] = {
            t: ("undetermined", None) for t in TRIADS
        }
        #: known-rate sessions: F0 of each plateau (checked, failed, squares, streak)
        self.plateau_f0: dict[str, Any] = {
            "checked": 0,
            "failed": 0,
            "sum_sq": 0.0,
            "streak": 0,
            "t_first": None,
        }
        # moving-base state
        self._chunks: deque[tuple[int, dict[str, NormalEquations]]] = deque()
        self._chunk_id: int | None = None
        self._chunk_ne: dict[str, NormalEquations] | None = None
        self._recent_up: deque[tuple[float, np.ndarray]] = deque()

    def set_certificate(self, certificate: Certificate) -> None:
        """Use a new certificate from now on (restarts intervals and predicates)."""
        self.certificate = certificate
        self._reset()

    # -- streaming ---------------------------------------------------------------

    def update(
        self, block: SampleBlock, magnitude: dict[str, np.ndarray] | None = None
    ) -> list[WindowResult]:
        """Feed a block; returns the windows it completed.

        ``magnitude`` (moving-base only): independent per-sample magnitudes,
        ``{"accel": (N,) m/s^2, "gyro": (N,) rad/s}``.
        """
        n = len(block)
        if n == 0:
            return []
        self.samples += n
        new = self.collector.update(block)
        if self.config.method == "moving-base":
            for iv in new:
                self._recent_up.append((iv.t_end, iv.up))
            return self._moving_update(block, magnitude)
        return self._intervals_closed(new)

    def finish(self) -> list[WindowResult]:
        """At the end of a stream: close the last still run and diagnose what is left."""
        new = self.collector.flush()
        if self.config.method == "moving-base":
            out = []
            if self._chunk_ne is not None and self._chunk_id is not None:
                self._chunks.append((self._chunk_id, self._chunk_ne))
                self._chunk_ne = None
                out.append(self._moving_window(self._chunk_id))
            return out
        return self._intervals_closed(new)

    def _intervals_closed(self, new: list[QuasiStaticInterval]) -> list[WindowResult]:
        cfg = self.config
        out = []
        for iv in new:
            self.intervals += 1
            if cfg.known_rate_rad_s is not None:
                self._plateau_f0(iv)
            self._window.append(iv)
            while len(self._window) > cfg.window_intervals:
                self._window.popleft()
            while self._window and iv.t_end - self._window[0].t_start > cfg.window_max_s:
                self._window.popleft()
            if len(self._window) >= cfg.min_intervals:
                res = diagnose_window(
                    self.certificate, list(self._window), cfg, index=self.windows_run
                )
                self._judge(res)
                out.append(res)
                # a step change (a fault onset) in the window: the next windows start at
                # it, holding the unit as it is now only (:mod:`.changepoint`), and the
                # faults raised by the windows that mixed both sides are withdrawn
                steps = _step_boundaries(res)
                for triad, first in steps:
                    if self.tracker.restart(triad, self._window[first].t_start):
                        self._note_verdicts(res.t_end)
                for _ in range(max((first for _, first in steps), default=0)):
                    self._window.popleft()
        return out

    def _plateau_f0(self, iv: QuasiStaticInterval) -> None:
        """F0 of one turntable plateau: 1/2 (|w|^2 / rate^2 - 1) of its certificate-corrected
        mean against the gyro's ``limits.f0``; plateaus off the rate (stopped) are not
        checked. Two failing in a row are a fault, as two windows are for a parameter."""
        tri = self.certificate.gyro
        assert self.config.known_rate_rad_s is not None
        rate_in = self.config.known_rate_rad_s / tri.unit_to_si
        keep, _ = classify_plateaus(tri, [iv], rate_in)
        if not keep[0]:
            return
        w = tri.inverse(iv.gyro_mean[None, :])[0]
        value = 0.5 * (float(w @ w) / rate_in**2 - 1.0)
        st = self.plateau_f0
        st["checked"] += 1
        st["sum_sq"] += value * value
        if abs(value) > float(tri.limits.f0):
            st["failed"] += 1
            st["streak"] += 1
            if st["streak"] >= self.config.persist and st["t_first"] is None:
                st["t_first"] = iv.t_end
        else:
            st["streak"] = 0

    def plateau_f0_fault(self) -> dict[str, Any] | None:
        """The gyro ``f0`` fault of a known-rate session (plateau F0 failing in a row)."""
        st = self.plateau_f0
        if st["t_first"] is None:
            return None
        return {
            "triad": "gyro",
            "sensor": None,
            "cause": "f0",
            "check": "known_rate",
            "estimate": math.sqrt(st["sum_sq"] / st["checked"]),
            "certificate": 0.0,
            "limit": float(self.certificate.gyro.limits.f0),
            "t_first": st["t_first"],
            "raised": 1,
            "failed": st["failed"],
            "checked": st["checked"],
        }

    def _judge(self, res: WindowResult) -> None:
        self.windows_run += 1
        for triad in TRIADS:
            fit = res.fit(triad)
            res.candidates.extend(self.tracker.update(fit, res.t_end, res.judgements.get(triad)))
            self._determined[triad] |= fit.determined
            for i in range(9):
                if not fit.determined[i]:
                    self._reasons[triad][i] = fit.reasons[i]
        self._note_verdicts(res.t_end)
        self.windows.append(res)

    def _note_verdicts(self, t: float) -> None:
        """Each triad's verdict now (fault in force, ok, undetermined) and since when (s)."""
        in_force = {f["triad"] for f in self.tracker.active()}
        for triad in TRIADS:
            now = (
                "fault"
                if triad in in_force
                else "ok"
                if self._determined[triad].all()
                else "undetermined"
            )
            if now != self.verdict_since[triad][0]:
                self.verdict_since[triad] = (now, float(t))

    # -- moving base -------------------------------------------------------------

    def _moving_update(
        self, block: SampleBlock, magnitude: dict[str, np.ndarray] | None
    ) -> list[WindowResult]:
        cfg = self.config
        ids = np.floor(block.t / cfg.moving_step_s).astype(np.int64)
        out = []
        bounds = np.flatnonzero(np.diff(ids)) + 1
        starts = np.concatenate([[0], bounds])
        stops = np.concatenate([bounds, [len(block)]])
        ne_blocks = {t: self._moving_equations(t, block, magnitude) for t in TRIADS}
        for s0, s1 in zip(starts, stops, strict=True):
            cid = int(ids[s0])
            if self._chunk_id is not None and cid != self._chunk_id:
                if self._chunk_ne is not None:
                    self._chunks.append((self._chunk_id, self._chunk_ne))
                out.append(self._moving_window(self._chunk_id))
                self._chunk_ne = None
            self._chunk_id = cid
            if self._chunk_ne is None:
                self._chunk_ne = {t: NormalEquations() for t in TRIADS}
            for t in TRIADS:
                h, z, w, y, nv = ne_blocks[t]
                self._chunk_ne[t].add(h[s0:s1], z[s0:s1], w[s0:s1], y[s0:s1], nv)
        return out

    def _moving_m0(self, triad: str) -> float:
        tri = self.certificate.triad(triad)
        si = self.certificate.gravity if triad == "accel" else 1.0  # m/s^2 or 1 rad/s
        return si / tri.unit_to_si

    def _moving_equations(
        self, triad: str, block: SampleBlock, magnitude: dict[str, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        tri = self.certificate.triad(triad)
        m0 = self._moving_m0(triad)
        raw = block.triad(triad)
        if magnitude is not None and triad in magnitude:
            mag = np.asarray(magnitude[triad], dtype=float) / tri.unit_to_si
        else:
            # the paper's own magnitude estimate (eqs. 17-18): circular, note §1
            y = corrected_normalised(tri, raw, m0)
            n_avg = max(1, int(round(self.config.detector_window_s * self.rate_hz)))
            mag = _moving_average(np.linalg.norm(y, axis=1), n_avg) * m0
        sigma = self.collector.detector.noise_sigma(triad)
        nv = None if sigma is None else (sigma / (tri.scale_factor * m0)) ** 2
        h, z, w, y, nv_out = sample_rows(tri, raw, mag, m0, nv)
        if magnitude is None or triad not in magnitude:
            # the errors-in-variables correction assumes a magnitude free of the triad's noise
            nv_out = None
        return h, z, w, y, nv_out

    def _moving_window(self, last_id: int) -> WindowResult:
        cfg = self.config
        span = max(1, int(round(cfg.moving_window_s / cfg.moving_step_s)))
        while self._chunks and self._chunks[0][0] <= last_id - span:
            self._chunks.popleft()
        t_end = (last_id + 1) * cfg.moving_step_s
        t_start = t_end - span * cfg.moving_step_s
        while self._recent_up and self._recent_up[0][0] < t_start:
            self._recent_up.popleft()
        fits: dict[str, TriadFit] = {}
        for triad in TRIADS:
            tot = NormalEquations()
            for _, ne in self._chunks:
                tot += ne[triad]
            fits[triad] = normal_equation_fit(
                self.certificate.triad(triad),
                tot,
                self._moving_m0(triad),
                "moving-base",
                cfg.determined_std_ratio,
                prior_factor=cfg.prior_factor,
            )
        ups = np.array([u for _, u in self._recent_up]) if self._recent_up else np.zeros((0, 3))
        res = WindowResult(
            index=self.windows_run,
            t_start=float(t_start),
            t_end=float(t_end),
            intervals=len(ups),
            attitudes=distinct_attitudes(ups, cfg.attitude_separation_deg),
            rotations=0,
            accel=fits["accel"],
            gyro=fits["gyro"],
            method="moving-base",
        )
        self._judge(res)
        return res

    # -- results -----------------------------------------------------------------

    @property
    def faults(self) -> list[dict]:
        """Faults active now (reports.md ``faults`` shape, plus ``std`` and ``t_last``)."""
        return self.tracker.active()

    @property
    def undetermined(self) -> list[dict]:
        """Parameters no window has determined so far, with the reason."""
        out = []
        no_window = self.windows_run == 0
        for triad in TRIADS:
            for i in range(9):
                if not self._determined[triad][i]:
                    reason = self._reasons[triad][i]
                    if no_window:
                        reason = self._no_window_reason()
                    out.append(
                        {
                            "triad": triad,
                            "sensor": sensor_of(triad, i),
                            "cause": CAUSES[i],
                            "reason": reason,
                        }
                    )
        return out

    def _no_window_reason(self) -> str:
        if self.samples == 0:
            return "no samples"
        if self.config.method == "moving-base":
            return "the log is shorter than one moving-base step"
        if self.intervals == 0:
            return "no quasi-static interval in the log (the unit never stood still long enough)"
        return (
            f"{self.intervals} quasi-static interval(s), fewer than the "
            f"{self.config.min_intervals} a window needs"
        )

    def verdict(self) -> dict:
        """The report's ``verdict``: per triad ok | fault | undetermined, faults, undetermined."""
        raised = self.tracker.all_raised()
        und = self.undetermined
        out: dict[str, Any] = {}
        for triad in TRIADS:
            if any(f["triad"] == triad for f in raised):
                out[triad] = "fault"
            elif any(u["triad"] == triad for u in und):
                out[triad] = "undetermined"
            else:
                out[triad] = "ok"
        out["faults"] = raised
        out["undetermined"] = und
        if self.tracker.withdrawn:
            # faults the windows raised on a mixture of both sides of a step change
            out["withdrawn"] = list(self.tracker.withdrawn)
        return out

    def report(
        self,
        samples: int | None = None,
        f0: dict[str, dict[str, int]] | None = None,
        windows: bool = True,
    ) -> dict:
        """The ``imudiag-diagnosis/1`` report (spec/reports.md)."""
        v = self.verdict()
        verdict = {
            "accel": v["accel"],
            "gyro": v["gyro"],
            "faults": v["faults"],
            "undetermined": v["undetermined"],
            **({"withdrawn": v["withdrawn"]} if "withdrawn" in v else {}),
        }
        return {
            **header(REPORT_FORMAT),
            "samples": int(self.samples if samples is None else samples),
            "f0": f0 if f0 is not None else {},
            "verdict": verdict,
            "method": self.config.method,
            "intervals": self.intervals,
            "windows_run": self.windows_run,
            "windows": [w.to_json() for w in self.windows] if windows else [],
        }


def diagnose_samples(
    certificate: Certificate,
    samples: SampleBlock,
    config: DiagnosisConfig | dict[str, Any] | None = None,
    rate_hz: float | None = None,
    magnitude: dict[str, np.ndarray] | None = None,
    block_size: int = 4096,
) -> StreamingDiagnoser:
    """Stream a whole block through a new diagnoser in blocks of ``block_size``; finished.

    ``magnitude``: per-sample independent magnitudes for the moving-base
    variant (``{"accel": (N,) m/s^2, "gyro": (N,) rad/s}``).
    """
    diag = StreamingDiagnoser(certificate, config, rate_hz=rate_hz)
    n = len(samples)
    for i in range(0, n, block_size):
        stop = i + block_size
        mag = None if magnitude is None else {k: v[i:stop] for k, v in magnitude.items()}
        diag.update(samples.slice(i, stop), mag)
    diag.finish()
    return diag


__all__ = ["StreamingDiagnoser", "REPORT_FORMAT", "diagnose_samples"]
