"""One diagnosis or calibration of a whole recording: the code path of ``imudiag diagnose``,
``imudiag calibrate`` and of the library's :func:`imudiag.diagnose` / :func:`imudiag.calibrate`.

A recording is a log file (any format :func:`imudiag.logs.open_log` reads) or a
:class:`~imudiag.samples.SampleBlock` already in memory; it is streamed in blocks
twice: once to measure the unit's white noise (at most the first
:data:`NOISE_SECONDS`), once through the monitor and the diagnosis (or the
interval collector of the calibration).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..certificate import SENSOR_NAMES, Certificate
from ..errors import BadInput
from ..logs import open_log
from ..logs.options import LogOptions
from ..noise_estimate import NOISE_MISMATCH_FACTOR, NoiseMeter, compare
from ..quasistatic import BAD_FLAGS, DetectorPool
from ..samples import FLAG_SELF_TEST, SampleBlock
from ..vibration import vibration_object
from .config import CERTIFICATE_NOISE, DiagnosisConfig
from .inputs import MagnitudeTable, check_units, session_rate_hz
from .intervals import IntervalCollector, QuasiStaticInterval
from .known_rate import PLATEAU_DETECTOR
from .params import PARAM_KEYS, cause_unit
from .scalar_fit import NormalEquations, sample_rows
from .stream import StreamingDiagnoser
from .window import WindowResult

if TYPE_CHECKING:
    from ..monitor import F0Trace, Monitor
    from .calibrate import CalibrationResult

#: Longest stretch of a recording read to measure its white noise (s of sample time).
NOISE_SECONDS = 600.0
#: Samples per block streamed from a recording.
DEFAULT_BLOCK_SIZE = 65536

#: A recording: a log file's path or samples in memory.
Recording = str | Path | SampleBlock


#: Told how far a pass over a recording has got: (what the pass does, fraction read 0..1
#: or None when unknown, samples read).
ProgressCallback = Callable[[str, float | None, int], None]


@dataclass
class DiagnosisTrace:
    """What a diagnosis saw over time, for plots: every window's estimates (not only those
    kept for the report) and every F0 check (:class:`~imudiag.monitor.F0Trace` per triad).
    ``t0``: the recording's first sample time, s."""

    windows: list[WindowResult] = field(default_factory=list)
    f0: dict[str, F0Trace] = field(default_factory=dict)
    t0: float = float("nan")


def recording_name(data: Recording) -> str:
    """How reports name a recording: the path, or ``(samples)`` for one in memory."""
    return "(samples)" if isinstance(data, SampleBlock) else str(data)


@contextmanager
def blocks(
    data: Recording,
    block_size: int = DEFAULT_BLOCK_SIZE,
    options: LogOptions | None = None,
    progress: ProgressCallback | None = None,
    what: str = "reading",
    opened: list[Any] | None = None,
) -> Iterator[tuple[dict[str, Any], Iterator[SampleBlock]]]:
    """The recording's metadata and its samples in blocks of at most ``block_size``;
    ``progress`` is told ``(what, fraction read, samples read)`` after each block;
    ``opened`` (a list) gets the log reader (its ``counters`` for a wire capture)."""
    if block_size < 1:
        raise BadInput(f"block size: must be >= 1, got {block_size}")
    if isinstance(data, SampleBlock):
        if options is not None and options.given():
            raise BadInput("log options (columns, units, rate, ...) apply to log files only")
        n = len(data)

        def in_memory() -> Iterator[SampleBlock]:
            for i in range(0, n, block_size):
                yield data.slice(i, i + block_size)
                if progress is not None:
                    done = min(n, i + block_size)
                    progress(what, done / n, done)

        yield data.meta, in_memory()
        return
    with open_log(data, block_size=block_size, options=options) as reader:
        if opened is not None:
            opened.append(reader)
        if progress is None:
            yield reader.meta, iter(reader)
            return

        def from_file() -> Iterator[SampleBlock]:
            for block in reader:
                yield block
                progress(what, reader.fraction_read(), reader.samples_read)

        yield reader.meta, from_file()


class NoiseMeasure:
    """The report's ``noise`` part, measured along a pass over a recording's blocks: the
    unit's white noise (:class:`~imudiag.noise_estimate.NoiseMeter`, over at most the first
    :data:`NOISE_SECONDS`) beside the certificate's; each triad says which noise the still
    detector uses (``detector_noise``: ``data`` unless ``certificate_noise`` and the
    certificate has one). Feed :meth:`update` every block in order (units applied), then
    :meth:`report`."""

    def __init__(self, cert: Certificate, certificate_noise: bool = CERTIFICATE_NOISE) -> None:
        self.cert = cert
        self.certificate_noise = certificate_noise
        self._meter: NoiseMeter | None = None
        self._t0: float | None = None
        self.done = False  #: the first NOISE_SECONDS are in: later blocks are not needed

    def update(self, block: SampleBlock, rate_hz: float) -> None:
        """Feed the recording's next block (``rate_hz``: the session's sample rate, Hz)."""
        if self.done:
            return
        if self._meter is None:
            self._meter = NoiseMeter(rate_hz)
            self._t0 = float(block.t[0]) if len(block) else None
        good = None
        if block.flags is not None:
            flags = np.asarray(block.flags).astype(np.int64)
            good = (flags & (BAD_FLAGS | FLAG_SELF_TEST)) == 0
        self._meter.update(block.gyro, block.accel, good)
        t0 = self._t0
        if t0 is not None and len(block) and float(block.t[-1]) - t0 > NOISE_SECONDS:
            self.done = True

    def report(self) -> dict[str, Any]:
        """The ``noise`` part of the report from the blocks fed."""
        cert = self.cert
        figures = self._meter.result() if self._meter is not None else None
        report: dict[str, Any] = {"method": None, "mismatch_factor": NOISE_MISMATCH_FACTOR}
        for name, fig in (figures or {}).items():
            tri = cert.triad(name)
            certified = tri.noise.density if tri.noise is not None else None
            finite = np.isfinite(fig.density)
            if not finite.any():
                # a gyro-only log (known rate): nothing to measure on that triad
                report[name] = {"measured": None, "unit": f"{tri.output_unit}/sqrt(Hz)"}
                continue
            entry: dict[str, Any] = {
                "measured": fig.as_dict(),
                "unit": f"{tri.output_unit}/sqrt(Hz)",
            }
            entry.update(compare(fig.density, certified))
            if not finite.all():
                # an axis without a figure (a stuck or constant output has no noise to
                # measure; or every chunk of it flagged) is null and the others kept, as in
                # the daemon's noise object; no ratio is judged on a triad so measured
                entry["ratio"] = entry["disagrees"] = None
                entry["unmeasured"] = [
                    s for s, ok in zip(SENSOR_NAMES[name], finite, strict=True) if not ok
                ]
            report[name] = entry
            report["method"] = fig.method
        for name in ("gyro", "accel"):
            noise = cert.triad(name).noise
            has_cert = noise is not None and noise.density is not None
            used = "certificate" if self.certificate_noise and has_cert else "data"
            report.setdefault(name, {"measured": None})["detector_noise"] = used
        return report


def measure_noise(
    data: Recording,
    cert: Certificate,
    rate_hz: float | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    options: LogOptions | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    progress: ProgressCallback | None = None,
) -> dict[str, Any]:
    """The report's ``noise`` part (:class:`NoiseMeasure`) by a pass of its own over at most
    the first :data:`NOISE_SECONDS` of ``data``."""
    measure = NoiseMeasure(cert, certificate_noise)
    rate = None
    with blocks(data, block_size, options, progress, "measuring noise") as (meta, stream):
        units = check_units(recording_name(data), meta, cert)
        for block in stream:
            block = units.apply(block)
            if rate is None:
                rate = session_rate_hz(rate_hz, meta, block, cert, recording_name(data))
            measure.update(block, rate)
            if measure.done:
                break
    return measure.report()


def _magnitudes(magnitude: MagnitudeTable | str | Path | None) -> MagnitudeTable | None:
    if magnitude is None or isinstance(magnitude, MagnitudeTable):
        return magnitude
    return MagnitudeTable(magnitude)


def diagnose_recording(
    data: Recording,
    cert: Certificate,
    config: DiagnosisConfig,
    *,
    rate_hz: float | None = None,
    magnitude: MagnitudeTable | str | Path | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    options: LogOptions | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    windows: bool = True,
    progress: ProgressCallback | None = None,
    trace: DiagnosisTrace | None = None,
) -> dict[str, Any]:
    """The diagnosis report of spec/reports.md for a whole recording (``imudiag diagnose``).

    ``rate_hz``: the sample rate (default the log's ``sample_rate``, else from ``t``).
    ``magnitude``: independent magnitudes for ``config.method == "moving-base"``
    (a :class:`~imudiag.diagnosis.inputs.MagnitudeTable` or its CSV path).
    ``windows``: include the per-window estimates. ``progress``: told how far each pass
    has got. ``trace``: filled with every window and F0 check (for plots). Raises
    :class:`~imudiag.errors.BadInput` (or a subclass: LogError, CertificateError) for input
    it cannot use.
    """
    from ..monitor import Monitor

    table = _magnitudes(magnitude)
    if table is not None and config.method != "moving-base":
        raise BadInput("--magnitude: only the moving-base method uses independent magnitudes")
    name = recording_name(data)
    noise = NoiseMeasure(cert, certificate_noise)  # measured along the same pass
    monitor = None
    diag = None
    rate = 0.0
    opened: list[Any] = []
    with blocks(data, block_size, options, progress, "diagnosing", opened) as (meta, stream):
        units = check_units(name, meta, cert)
        for block in stream:
            block = units.apply(block)
            if diag is None:
                rate = session_rate_hz(rate_hz, meta, block, cert, name)
                # one still detector for both when theirs are alike (the same settings and
                # noise figures: with the certificate's noise, or a certificate without any)
                pool = DetectorPool()
                monitor = Monitor(cert, rate_hz=rate, detectors=pool)
                diag = StreamingDiagnoser(
                    cert, config, rate_hz=rate, certificate_noise=certificate_noise, detectors=pool
                )
                if trace is not None:
                    trace.f0 = monitor.keep_f0_trace()
                    trace.t0 = float(block.t[0]) if len(block) else float("nan")
            assert monitor is not None
            noise.update(block, rate)
            monitor.update(block)
            done = diag.update(block, table.at(block.t) if table is not None else None)
            if trace is not None:
                trace.windows.extend(done)
    if diag is None or monitor is None:
        raise BadInput(f"{name}: no samples")
    done = diag.finish()
    monitor.flush()
    if trace is not None:
        trace.windows.extend(done)
    f0: dict[str, Any] = {
        t: {"checked": int(monitor.f0_checked[t]), "failed": int(monitor.f0_failed[t])}
        for t in ("accel", "gyro")
    }
    for t, entry in f0.items():  # when nothing was checked: which criterion failed, and how
        why = monitor.f0_why(t)
        if why is not None:
            if diag.intervals:
                why += (
                    f"; the window diagnosis's still detector (the data's noise) found "
                    f"{diag.intervals} still interval(s)"
                )
            entry["why"] = why
        unjudged = monitor.f0_unjudged(t)
        if unjudged is not None:
            entry["unjudged"] = unjudged
    known_fault = None
    if config.known_rate_rad_s is not None:
        # on a turntable the gyro F0 is checked per plateau against the table's rate
        st = diag.plateau_f0
        f0["gyro"] = {"checked": st["checked"], "failed": st["failed"], "check": "known_rate"}
        known_fault = diag.plateau_f0_fault()
    report = diag.report(f0=f0, windows=windows)
    add_monitor_faults(report["verdict"], monitor, cert, known_fault)
    report["log"] = name
    report["certificate"] = cert.source or "(bundled)"
    if cert.device.get("warning"):
        report["certificate_warning"] = str(cert.device["warning"])
    report["sample_rate"] = diag.rate_hz
    report["noise"] = noise.report()
    if not units.identity:  # what was converted, exactly (imudiag.units)
        report["unit_conversion"] = units.describe()
    report["vibration"] = vibration_object(monitor.vibration)
    wire = getattr(opened[0], "counters", None) if opened else None
    if wire is not None:  # a raw wire capture: its receiver counters (spec/wire-protocol.md)
        report["wire"] = wire.as_dict()
    report["self_test"] = monitor.self_test  # samples excluded: deflected on purpose
    report["adc_errors"] = monitor.adc_errors
    return report


def add_monitor_faults(
    verdict: dict[str, Any],
    monitor: Monitor,
    cert: Certificate,
    known_fault: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Complete a window diagnosis's ``verdict`` (:meth:`StreamingDiagnoser.verdict`, changed
    in place and returned) with the monitor's faults ever raised: persistent F0 failures
    (``explained_by``: the parameter faults the window diagnosis names on that triad),
    excess white noise at rest, stuck outputs and saturation, by the daemon's own checks and
    persistence. The one
    definition of the whole-stream verdict, for ``imudiag diagnose`` and the daemon's
    status (issue 25: one answer)."""
    named = list(verdict["faults"])
    for fault in named:  # the unit of estimate, certificate and limit (spec/reports.md)
        if fault["cause"] in PARAM_KEYS:
            fault["unit"] = cause_unit(cert.triad(fault["triad"]), fault["cause"])
    for fault in monitor.f0_faults() + ([known_fault] if known_fault else []):
        fault["explained_by"] = [
            {"sensor": f["sensor"], "cause": f["cause"]}
            for f in named
            if f["triad"] == fault["triad"]
        ]
        verdict["faults"].append(fault)
        verdict[fault["triad"]] = "fault"
    # excess white noise at rest (judged only while the other triad is at its noise, so
    # vibration is not noise)
    for fault in monitor.noise_faults():
        verdict["faults"].append(fault)
        verdict[fault["triad"]] = "fault"
    # a stuck output and saturation, as the daemon raises them (the monitor's checks)
    for fault in monitor.stuck_faults() + monitor.saturation_faults():
        verdict["faults"].append(fault)
        verdict[fault["triad"]] = "fault"
    return verdict


def _collect_pass(
    data: Recording,
    like: Certificate,
    config: DiagnosisConfig,
    rate_hz: float | None = None,
    table: MagnitudeTable | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    options: LogOptions | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: ProgressCallback | None = None,
    holds: dict[str, Any] | None = None,
    short: tuple[float, float, float, float] | None = None,
    stuck_out: list[dict[str, Any]] | None = None,
) -> tuple[
    list[QuasiStaticInterval], float, dict[str, tuple[NormalEquations, float]], np.ndarray | None
]:
    """One pass of the interval collector; ``short``: (window, minimum hold, trim, motion
    margin), s, in place of the configured ones. Also returns the accelerometer noise sigma
    (3,) per sample the detector measured (output units), None when unknown. ``stuck_out``,
    when given, gets the stuck outputs of the recording (the monitor's check)."""
    name = recording_name(data)
    known = config.known_rate_rad_s
    detector_options: dict[str, Any] = {"certificate_noise": certificate_noise}
    if known is not None:
        detector_options.update(PLATEAU_DETECTOR)
    collector = None
    stuck = None
    intervals: list[QuasiStaticInterval] = []
    moving: dict[str, tuple[NormalEquations, float]] = {}
    rate = None
    with blocks(data, block_size, options, progress, "collecting intervals") as (meta, stream):
        units = check_units(name, meta, like)
        for block in stream:
            block = units.apply(block)
            if collector is None:
                rate = session_rate_hz(rate_hz, meta, block, like, name)
                collector = IntervalCollector(
                    like,
                    rate,
                    detector_window_s=config.detector_window_s if short is None else short[0],
                    min_interval_s=config.min_interval_s if short is None else short[1],
                    max_interval_s=config.max_interval_s,
                    trim_s=config.trim_s if short is None else short[2],
                    motion_margin_s=config.motion_margin_s if short is None else short[3],
                    max_motion_s=config.max_motion_s,
                    detector_options=detector_options,
                )
                if table is not None:
                    moving = {
                        "accel": (NormalEquations(), like.gravity / like.accel.unit_to_si),
                        "gyro": (NormalEquations(), 1.0 / like.gyro.unit_to_si),
                    }
                if stuck_out is not None:
                    from ..monitor import MonitorConfig
                    from ..monitor.stuck import monitor_stuck_check

                    stuck = monitor_stuck_check(like, MonitorConfig(), rate)
            if stuck is not None and len(block):
                stuck.update(np.concatenate([block.gyro.T, block.accel.T]), block.t)
            intervals.extend(collector.update(block))
            if table is not None:
                mags = table.at(block.t)
                for triad, (ne, m0) in moving.items():
                    if triad in mags:
                        tri = like.triad(triad)
                        sigma = collector.detector.noise_sigma(triad)
                        nv = None if sigma is None else (sigma / (tri.scale_factor * m0)) ** 2
                        ne.add(
                            *sample_rows(
                                tri, block.triad(triad), mags[triad] / tri.unit_to_si, m0, nv
                            )
                        )
    if collector is None:
        raise BadInput(f"{name}: no samples")
    if stuck is not None and stuck_out is not None:
        from ..monitor.stuck import stuck_faults

        stuck_out.extend(stuck_faults(stuck))
    intervals.extend(collector.flush())
    moving = {k: v for k, v in moving.items() if v[0].n > 0}
    assert rate is not None
    if holds is not None:
        min_s = config.min_interval_s if short is None else short[1]
        trim_s = config.trim_s if short is None else short[2]
        holds.update(
            found=len(intervals) + collector.dropped_short,
            used=len(intervals),
            dropped={
                f"still for less than the minimum hold ({min_s:.3g} s after the {trim_s:.3g} s "
                "trim)": collector.dropped_short
            },
        )
    sigma = collector.detector.noise_sigma("accel")
    return intervals, float(rate), moving, None if sigma is None else np.asarray(sigma)


def collect_intervals(
    data: Recording,
    like: Certificate,
    config: DiagnosisConfig,
    rate_hz: float | None = None,
    table: MagnitudeTable | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    options: LogOptions | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: ProgressCallback | None = None,
    holds: dict[str, Any] | None = None,
    stuck: list[dict[str, Any]] | None = None,
) -> tuple[list[QuasiStaticInterval], float, dict[str, tuple[NormalEquations, float]]]:
    """The still intervals the calibration fits (time order), the sample rate (Hz) and, with
    independent magnitudes ``table``, each triad's moving-base normal equations and
    reference magnitude (input units). ``holds``, when given, is filled with the still runs
    found, used and dropped (with why) and the detector used; ``stuck``, when given, with
    the recording's stuck outputs (the monitor's check, :func:`..monitor.stuck.stuck_faults`).
    Raises
    :class:`~imudiag.errors.BadInput` without samples or without a still interval.

    Short holds (``config.short_holds``; not with a known rate or independent magnitudes):
    hand sessions hold each attitude 0.5-1 s, which the default detector (a 0.5 s trailing
    window, 0.25 s trim, 0.5 s minimum) cannot see. The short-hold detector has a window of
    ``config.short_hold_window`` samples (0.1 s at 155 Hz), a trim of 2 samples, and a
    minimum hold of the window or of the samples whose mean reaches a quarter of the
    accelerometer bias limit through the measured white noise, whichever is longer. Each
    hold's mean is weighted by its own noise in the fits
    (:meth:`.intervals.QuasiStaticInterval.mean_var`). ``auto`` takes the short-hold
    intervals when the default detector keeps fewer than ``short_hold_min_intervals``
    holds or drops more holds than it keeps.
    """
    first: dict[str, Any] = {}
    reading = (certificate_noise, options, block_size, progress)
    intervals, rate, moving, sigma = _collect_pass(
        data, like, config, rate_hz, table, *reading, first, stuck_out=stuck
    )
    mode = config.short_holds
    if table is not None or config.known_rate_rad_s is not None:
        mode = "never"
    dropped = sum(first["dropped"].values())
    if mode == "auto":
        mode = (
            "always"
            if len(intervals) < config.short_hold_min_intervals or dropped > len(intervals)
            else "never"
        )
    first["detector"] = (
        f"default ({config.detector_window_s:g} s window, {config.min_interval_s:g} s minimum hold)"
    )
    if mode == "always":
        window = int(config.short_hold_window)
        n_min = window
        lim = np.asarray(like.accel.limits.bias, dtype=float)
        if sigma is not None and np.all(np.isfinite(sigma)) and np.all(lim > 0):
            n_min = max(n_min, int(math.ceil(float(np.max((sigma / (0.25 * lim)) ** 2)))))
        short = (
            window / rate,
            n_min / rate,
            2.0 / rate,
            min(config.motion_margin_s, 0.3),
        )
        second: dict[str, Any] = {}
        try:
            s_iv, _, _, _ = _collect_pass(
                data,
                like,
                config,
                rate,
                None,
                certificate_noise,
                options,
                block_size,
                progress,
                second,
                short,
            )
        except BadInput:
            s_iv = []
        if len(s_iv) > len(intervals):
            intervals = s_iv
            second["detector"] = (
                f"short holds ({window} samples = {window / rate:.3g} s window, minimum hold "
                f"{n_min} samples = {n_min / rate:.3g} s; the default detector kept "
                f"{first['used']} of {first['found']})"
            )
            first = second
    if not intervals:  # after the short-hold pass: a session of short holds alone has none
        raise BadInput(
            f"{recording_name(data)}: no quasi-static interval found (the unit never stood "
            "still long enough): nothing to calibrate from"
        )
    if holds is not None:
        holds.update(first)
    return intervals, rate, moving


def calibrate_recording(
    data: Recording,
    like: Certificate,
    config: DiagnosisConfig,
    *,
    rate_hz: float | None = None,
    magnitude: MagnitudeTable | str | Path | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    options: LogOptions | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: ProgressCallback | None = None,
) -> CalibrationResult:
    """Calibrate from a whole recording (``imudiag calibrate``); the result's ``noise``
    holds the unit's white noise measured from the recording.

    ``like`` gives scale factors, units, limits and starting values. The result's
    ``generalisation`` and ``gyro_generalisation`` say whether the held-out checks
    accept the calibration (``refusals()``: why not); nothing is written here.
    ``progress``: told how far each pass has got. Raises
    :class:`~imudiag.errors.BadInput` when the recording cannot calibrate (no still
    interval, too few attitudes).
    """
    from .calibrate import calibrate, calibrate_known_rate  # not on diagnose's path

    table = _magnitudes(magnitude)
    if config.method == "moving-base" and table is None:
        raise BadInput(
            "--method moving-base: calibration needs independent magnitudes "
            "(--magnitude FILE); the triad's own magnitude cannot calibrate it"
        )
    if table is not None and config.method != "moving-base":
        raise BadInput("--magnitude: only the moving-base method uses independent magnitudes")
    known = config.known_rate_rad_s
    if known is not None and table is not None:
        raise BadInput("--known-rate: only the exact method (no --magnitude) uses a known rate")
    name = recording_name(data)
    noise_report = measure_noise(
        data, like, rate_hz, block_size, options, certificate_noise, progress
    )
    holds: dict[str, Any] = {}
    stuck: list[dict[str, Any]] = []
    reading = (certificate_noise, options, block_size, progress)
    intervals, rate, moving = collect_intervals(
        data, like, config, rate_hz, table, *reading, holds=holds, stuck=stuck
    )
    measured: dict[str, np.ndarray] = {}  # a triad's measured noise, every axis measured
    for triad in ("gyro", "accel"):
        entry = noise_report.get(triad) or {}
        if entry.get("measured") and not entry.get("unmeasured"):
            measured[triad] = np.asarray(entry["measured"]["density"], dtype=float)
    try:
        if known is not None:
            result = calibrate_known_rate(
                intervals, like, known, rate, config, source=name, noise_density=measured
            )
        else:
            result = calibrate(
                intervals,
                like,
                config.method,
                rate,
                moving or None,
                config,
                source=name,
                noise_density=measured,
            )
    except ValueError as exc:
        raise BadInput(f"{name}: {exc}") from None
    result.noise = noise_report
    result.holds = holds
    result.stuck = stuck
    return result


__all__ = [
    "collect_intervals",
    "DEFAULT_BLOCK_SIZE",
    "NOISE_SECONDS",
    "DiagnosisTrace",
    "ProgressCallback",
    "Recording",
    "blocks",
    "calibrate_recording",
    "add_monitor_faults",
    "diagnose_recording",
    "NoiseMeasure",
    "measure_noise",
    "recording_name",
]
