"""Time-stamp report of a log: sample rate estimated from ``t``, gaps, jitter, repeated stamps.

Nothing is resampled: irregular stamps are counted and stated, never smoothed.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np


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
        elif math.isfinite(rate) and abs(stated - rate) > 0.05 * rate:
            report.note = f"metadata sample_rate {stated:g} Hz disagrees with t ({rate:.6g} Hz)"
    return report
