"""The scalar method with a known rate: a gyro triad on a turntable (the paper's "known rate").

On a rate table turning at a known, constant rate, the certificate-corrected
gyro outputs of every plateau must have that magnitude, whatever the unit's
mounting; plateaus in several mountings determine the 9 gyro parameters as
Earth rate does for a navigation-grade unit at rest, but with a magnitude
thousands of times larger, so MEMS gyros can be calibrated. Plateaus are the
still intervals of a detector that checks only the gyro variance (a constant
rate is "still"; the accelerometers may be absent). A plateau whose magnitude
is far from the known rate is not at the table's rate (the table stopped, or
ran at another speed) and is set aside with the reason; the others go through
the outlier rejection of :func:`.scalar_fit.robust_exact_fit`.

Earth rate is neglected: it changes the magnitude by at most its projection on
the table axis (15 deg/h, 2e-5 of 200 deg/s).
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..certificate import TriadModel
from ..errors import BadInput
from .intervals import QuasiStaticInterval

#: Units of ``--known-rate`` and their value in rad/s.
RATE_UNITS = {
    "rpm": 2.0 * math.pi / 60.0,
    "rev/s": 2.0 * math.pi,
    "deg/s": math.pi / 180.0,
    "rad/s": 1.0,
}
#: A plateau whose magnitude is off the known rate by more than this fraction is not at
#: the table's rate (a scale error this large is not a calibration error).
PLATEAU_TOLERANCE = 0.2
#: Detector settings for plateaus: only the gyro variance counts, a rate about the
#: vertical is allowed (it is the table's).
PLATEAU_DETECTOR = {"triads": ("gyro",), "bias_margin": None}

_RATE = re.compile(r"\s*([-+0-9.eE]+)\s*([a-z/]+)\s*")


def parse_known_rate(text: str, where: str = "--known-rate") -> float:
    """``33.333rpm``, ``200 deg/s``, ``3.49rad/s``, ``0.5rev/s`` -> rad/s; BadInput otherwise."""
    m = _RATE.fullmatch(text or "")
    units = ", ".join(RATE_UNITS)
    if not m or m.group(2) not in RATE_UNITS:
        raise BadInput(f"{where}: expected VALUE followed by a unit ({units}), got {text!r}")
    try:
        value = float(m.group(1))
    except ValueError:
        raise BadInput(f"{where}: {m.group(1)!r} is not a number") from None
    if not math.isfinite(value) or value <= 0.0:
        raise BadInput(f"{where}: the rate must be a positive number, got {text!r}")
    return value * RATE_UNITS[m.group(2)]


def classify_plateaus(
    gyro: TriadModel, intervals: list[QuasiStaticInterval], rate_in: float
) -> tuple[np.ndarray, list[dict]]:
    """Which intervals are plateaus at the known rate ``rate_in`` (gyro input units).

    Returns the mask (K,) of the usable ones and, for the others, the interval,
    its magnitude and the reason (stopped, or another rate).
    """
    if not intervals:
        return np.zeros(0, dtype=bool), []
    means = np.array([iv.gyro_mean for iv in intervals])
    mag = np.linalg.norm(gyro.inverse(means), axis=1)
    keep = np.abs(mag / rate_in - 1.0) <= PLATEAU_TOLERANCE
    unit = gyro.input_unit
    out = []
    for iv, m, k in zip(intervals, mag, keep, strict=True):
        if k:
            continue
        what = (
            "stopped plateau"
            if m < 0.5 * rate_in
            else f"not at the known rate (off by {100.0 * (m / rate_in - 1.0):+.1f} %)"
        )
        out.append(
            {
                "point": f"interval {iv.index} ({iv.t_start:.2f}-{iv.t_end:.2f} s)",
                "rate": round(float(m), 6),
                "unit": unit,
                "reason": f"{what}: |w| = {m:.4g} {unit}, the table turns at {rate_in:.4g} "
                f"{unit} (beyond {PLATEAU_TOLERANCE:.0%})",
            }
        )
    return keep, out


__all__ = [
    "PLATEAU_DETECTOR",
    "PLATEAU_TOLERANCE",
    "RATE_UNITS",
    "classify_plateaus",
    "parse_known_rate",
]
