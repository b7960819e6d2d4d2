"""Settings of the window diagnosis (all times in seconds)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

from .. import validate
from ..errors import BadInput

METHODS = ("exact", "linear", "moving-base")
#: Whether the window diagnosis's still detector trusts the certificate's noise density
#: (True) or measures the noise from the data (False, the default): the one default of
#: ``imudiag diagnose``, ``imudiag calibrate``, the library's :func:`imudiag.diagnose` and
#: :class:`~imudiag.diagnosis.StreamingDiagnoser`, and the daemon (docs/service.md).
CERTIFICATE_NOISE = False
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
        """Check every field (:mod:`imudiag.validate`): BadInput naming ``diagnosis.<key>``."""
        for name, check in _CHECKS.items():
            value = getattr(self, name)
            if value is not None or name != "known_rate_rad_s":
                check(value, f"diagnosis.{name}")
        if self.known_rate_rad_s is not None and self.method != "exact":
            raise BadInput(
                "diagnosis.known_rate_rad_s: a known rate is used by the exact method only"
            )

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> DiagnosisConfig:
        """Build from a mapping; an unknown key or a bad value raises BadInput naming the key."""
        d = dict(d or {})
        names = {f.name for f in fields(cls)}
        for k in d:
            if k not in names:
                raise BadInput(f"diagnosis.{k}: unknown key")
        return cls(**d)


def _positive(value: Any, where: str) -> float:
    return validate.number(value, where, 0.0, lo_open=True)


def _at_least_zero(value: Any, where: str) -> float:
    return validate.number(value, where, 0.0)


def _count(lo: int) -> Callable[[Any, str], int]:
    return lambda value, where: validate.integer(value, where, lo)


def _one_of(choices: tuple[str, ...]) -> Callable[[Any, str], str]:
    return lambda value, where: validate.text(value, where, choices)


#: The check of each field, value and key -> the value (BadInput naming the key).
_CHECKS: dict[str, Callable[[Any, str], Any]] = {
    "method": _one_of(METHODS),
    "gyro_mode": _one_of(GYRO_MODES),
    "detector_window_s": _positive,
    "min_interval_s": _positive,
    "max_interval_s": _positive,
    "short_holds": _one_of(SHORT_HOLDS),
    "short_hold_window": _count(4),
    "short_hold_min_intervals": _count(1),
    "trim_s": _at_least_zero,
    "motion_margin_s": _at_least_zero,
    "max_motion_s": _positive,
    "window_intervals": _count(1),
    "window_max_s": _positive,
    "min_intervals": _count(1),
    "attitude_separation_deg": lambda v, w: validate.number(v, w, 0.0, 180.0, lo_open=True),
    "moving_window_s": _positive,
    "moving_step_s": _positive,
    "prior_factor": _positive,
    "determined_std_ratio": _positive,
    "k_sigma": _positive,
    "min_dof": _at_least_zero,
    "persist": _count(1),
    "max_windows_kept": _count(1),
    "known_rate_rad_s": _positive,
}


__all__ = ["CERTIFICATE_NOISE", "DiagnosisConfig", "METHODS", "GYRO_MODES", "SHORT_HOLDS"]
