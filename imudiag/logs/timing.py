"""Time-stamp report of a log: sample rate estimated from ``t``, gaps, jitter, repeated stamps.

Nothing is resampled: irregular stamps are counted and stated, never smoothed.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..argtypes import MAX_RATE_HZ, MIN_RATE_HZ, rate_problem

#: Seconds per unit of ``t`` (``--time-unit``).
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: Largest relative difference between a stated rate (``--rate``, a log's ``sample_rate``)
#: and the rate of the log's time stamps (1 / median step) taken as agreement: 5 %, wider
#: than any crystal's error (50 ppm) and a host's jitter on the median step, narrower than
#: any confusion of rates (200 vs 250 Hz is 25 %).
RATE_TOLERANCE = 0.05
#: Time stamps the rate checks look at, from the start of a log.
RATE_CHECK_SAMPLES = 256


def step_rate_hz(t: np.ndarray) -> float:
    """1 / the median positive step of ``t`` (s), Hz; nan with no positive step."""
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[dt > 0]
    return 1.0 / float(np.median(dt)) if dt.size else math.nan


def first_block_rate_hz(t: np.ndarray) -> float | None:
    """The sample rate (Hz) the time stamps ``t`` (s) of a log's first block show, as
    ``imudiag diagnose`` and a replay take it when the log states none: 1 / the median
    step over more than two stamps; None when there are fewer or the median step is not
    positive (repeated stamps)."""
    t = np.asarray(t, dtype=float)
    if t.shape[0] <= 2:
        return None
    dt = float(np.median(np.diff(t)))
    return 1.0 / dt if dt > 0 else None


def time_unit_problem(t: np.ndarray, unit: str = "s", option: bool = True) -> str | None:
    """Why the time stamps ``t`` (s, read from a column in ``unit``) cannot be an IMU's,
    naming the unit the column is likely in, or None when their rate is plausible.
    ``option``: the format takes ``--time-unit`` (a text table, CSV, MATLAB, R)."""
    rate = step_rate_hz(t)
    if not math.isfinite(rate) or rate_problem(rate) is None:
        return None
    step = 1.0 / rate / TIME_UNITS[unit]  # the median step in the column's own unit
    text = (
        f"t steps by a median {step:.6g} {unit} per sample, {rate:.6g} Hz, not an IMU's "
        f"sample rate ({MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz)"
    )
    likely = {
        u: rate * TIME_UNITS[unit] / scale
        for u, scale in TIME_UNITS.items()
        if u != unit and rate_problem(rate * TIME_UNITS[unit] / scale) is None
    }
    if not likely:
        return text
    readings = " or ".join(f"in {u} ({r:.6g} Hz)" for u, r in likely.items())
    advice = (
        f"give --time-unit {next(iter(likely))}"
        if option and len(likely) == 1
        else ("give --time-unit with the unit of t" if option else "the log's clock is wrong")
    )
    return f"{text}; it is likely {readings}: {advice}"


def stated_rate_problem(stated_hz: float, t: np.ndarray, what: str = "--rate") -> str | None:
    """Why the rate ``stated_hz`` (named ``what``) disagrees with the time stamps ``t`` (s)
    by more than :data:`RATE_TOLERANCE`, giving both figures, or None when they agree (or
    ``t`` has no positive step)."""
    rate = step_rate_hz(t)
    if not math.isfinite(rate) or abs(stated_hz - rate) <= RATE_TOLERANCE * rate:
        return None
    return (
        f"{what} {stated_hz:g} Hz disagrees with the log's time stamps ({rate:.6g} Hz, median "
        f"step {1e3 / rate:.6g} ms) by {abs(stated_hz / rate - 1) * 100:.3g} %, more than "
        f"{RATE_TOLERANCE * 100:g} %: leave {what} out to use the time stamps"
    )


@dataclass
class TimingReport:
    """What the time stamps of a log show (times in s, rates in Hz)."""

    samples: int
    duration_s: float
    rate_hz: float  #: 1 / median step
    median_dt_s: float
    jitter_s: float  #: robust std of the step (1.4826 x MAD), gaps excluded
    gaps: int  #: steps longer than 1.5 median steps
    longest_gap_s: float  #: longest step (s), 0 when there is no gap
    repeated: int  #: steps of zero length (repeated stamps)
    backwards: int  #: steps of negative length
    metadata_rate_hz: float | None = None  #: the log's own ``sample_rate``, if a number
    note: str = ""  #: a disagreement or unusable metadata, in words

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``class: timing``)."""
        return {"class": "timing", **asdict(self)}

    def summary(self) -> str:
        """One line: rate, gaps, jitter, repeated stamps."""
        text = (
            f"{self.samples} samples over {self.duration_s:.3f} s, rate {self.rate_hz:.6g} Hz "
            f"(estimated from t), jitter {self.jitter_s * 1e6:.3g} us, {self.gaps} gaps"
        )
        if self.gaps:
            text += f" (longest {self.longest_gap_s:.4g} s)"
        if self.repeated:
            text += f", {self.repeated} repeated stamps"
        if self.backwards:
            text += f", {self.backwards} stamps going back"
        return text + (f"; {self.note}" if self.note else "")


def metadata_rate(meta: dict[str, Any]) -> float | None:
    """The log's ``sample_rate`` metadata as Hz, or None when absent or not a positive number."""
    value = meta.get("sample_rate")
    try:
        rate = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return rate if rate > 0 and math.isfinite(rate) else None


def timing_report(t: np.ndarray, meta: dict[str, Any] | None = None) -> TimingReport:
    """The time-stamp report of ``t`` (s); ``meta`` supplies a stated ``sample_rate`` to check."""
    t = np.asarray(t, dtype=float)
    n = int(t.shape[0])
    dt = np.diff(t)
    positive = dt[dt > 0]
    median_dt = float(np.median(positive)) if positive.size else math.nan
    rate = 1.0 / median_dt if median_dt > 0 else math.nan
    gap = dt > 1.5 * median_dt if positive.size else np.zeros(0, dtype=bool)
    regular = positive[positive <= 1.5 * median_dt] if positive.size else positive
    jitter = float(1.4826 * np.median(np.abs(regular - median_dt))) if regular.size else 0.0
    report = TimingReport(
        samples=n,
        duration_s=float(t[-1] - t[0]) if n else 0.0,
        rate_hz=rate,
        median_dt_s=median_dt,
        jitter_s=jitter,
        gaps=int(np.count_nonzero(gap)),
        longest_gap_s=float(dt[gap].max()) if np.any(gap) else 0.0,
        repeated=int(np.count_nonzero(dt == 0)),
        backwards=int(np.count_nonzero(dt < 0)),
    )
    if meta and "sample_rate" in meta:
        stated = metadata_rate(meta)
        report.metadata_rate_hz = stated
        if stated is None:
            report.note = (
                f"metadata sample_rate {meta['sample_rate']!r} is not a number; "
                "the rate estimated from t is used"
            )
        elif math.isfinite(rate) and abs(stated - rate) > RATE_TOLERANCE * rate:
            report.note = f"metadata sample_rate {stated:g} Hz disagrees with t ({rate:.6g} Hz)"
    return report
