"""Settings of the window diagnosis (all times in seconds)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

METHODS = ("exact", "linear", "moving-base")
GYRO_MODES = ("auto", "earth-rate", "rotation")
SHORT_HOLDS = ("auto", "always", "never")


@dataclass
class DiagnosisConfig:
    """How windows are formed, fitted and judged.

    method: ``exact`` (quasi-static intervals, exact model, the default),
    ``linear`` (the paper's literal linearised solution on the same intervals),
    ``moving-base`` (every sample, with a per-sample magnitude, note §6).
    """

    method: str = "exact"
    gyro_mode: str = "auto"  #: auto | earth-rate | rotation
    # quasi-static intervals
    detector_window_s: float = 0.5  #: s, trailing window of the static detector
    #: s, shorter still runs are not used (holds of 0.5-1 s are common in hand sessions; each
    #: interval is weighted by the noise of its mean, so a short one counts for less)
    min_interval_s: float = 0.5
    max_interval_s: float = 30.0  #: s, longer still runs are split
    #: ``calibrate`` only: the short-hold detector (a window of ``short_hold_window`` samples,
    #: the minimum hold from the measured noise and the rate, :func:`.session.collect_intervals`):
    #: ``auto`` when the default detector keeps fewer than ``short_hold_min_intervals`` holds
    #: or drops more holds as too short than it keeps; ``always``; ``never``
    short_holds: str = "auto"
    short_hold_window: int = 16  #: samples, the short-hold detector's window (and least hold)
    short_hold_min_intervals: int = 18  #: holds the default detector must keep (auto)
    trim_s: float = 0.25  #: s, dropped at the end of each still run
    #: s, how far a motion's gyro integral reaches into the still intervals on both sides:
    #: a smooth turn starts and ends below the detector's threshold (a 4 s raised-cosine
    #: turn for ~0.5 s each); leaving that out was a repeatable error of up to 8 mrad a turn
    motion_margin_s: float = 0.75
    max_motion_s: float = 20.0  #: s, longer motions are not integrated
    # windows
    window_intervals: int = 24  #: intervals per window (the most recent)
    window_max_s: float = 900.0  #: s, intervals older than this leave the window
    min_intervals: int = 2  #: a window is fitted once it has this many intervals
    attitude_separation_deg: float = 10.0  #: deg, distinct attitudes
    # moving-base windows (time based)
    moving_window_s: float = 60.0  #: s
    moving_step_s: float = 10.0  #: s
    # statistics and predicates
    prior_factor: float = 10.0  #: prior std at the certificate, in limits
    determined_std_ratio: float = 0.5  #: determined when std <= ratio x limit
    k_sigma: float = 4.0  #: a fault deviates by more than k_sigma std (and the limit)
    min_dof: float = 3.0  #: effective degrees of freedom a fit needs to be judged
    persist: int = 2  #: consecutive windows a deviation must persist
    max_windows_kept: int = 10000  #: windows kept for the report
    #: rad/s, a turntable's known rate: plateaus at it are the intervals and the gyro fit's
    #: magnitude (:mod:`.known_rate`); the accelerometers are not diagnosed. None: at rest
    known_rate_rad_s: float | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.gyro_mode not in GYRO_MODES:
            raise ValueError(
                f"gyro_mode must be one of {', '.join(GYRO_MODES)}, got {self.gyro_mode!r}"
            )
        if self.short_holds not in SHORT_HOLDS:
            raise ValueError(
                f"short_holds must be one of {', '.join(SHORT_HOLDS)}, got {self.short_holds!r}"
            )
        if self.short_hold_window < 4:
            raise ValueError(
                f"short_hold_window must be >= 4 samples, got {self.short_hold_window}"
            )
        if self.known_rate_rad_s is not None and not (
            math.isfinite(self.known_rate_rad_s) and self.known_rate_rad_s > 0
        ):
            raise ValueError(f"known_rate_rad_s must be > 0, got {float(self.known_rate_rad_s)!r}")
        if self.known_rate_rad_s is not None and self.method != "exact":
            raise ValueError("a known rate is used by the exact method only")
        if self.persist < 1 or self.window_intervals < 1 or self.min_intervals < 1:
            raise ValueError("persist, window_intervals and min_intervals must be >= 1")

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> DiagnosisConfig:
        """Build from a mapping; unknown keys raise ValueError naming the key."""
        d = dict(d or {})
        names = {f.name for f in fields(cls)}
        for k in d:
            if k not in names:
                raise ValueError(f"diagnosis.{k}: unknown key")
        return cls(**d)


__all__ = ["DiagnosisConfig", "METHODS", "GYRO_MODES", "SHORT_HOLDS"]
