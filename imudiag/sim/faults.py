"""Faults injected at a time on one sensor, and their effect on the true model.

Kinds (``value`` units):

- ``bias``: output units added to B from ``t_s`` on.
- ``scale_factor``: output per input unit added to E (so e = E / S grows by value / S).
- ``misalignment``: rad added to a misalignment difference; ``sensor`` is the pair
  ``ax/ay`` (d1, added to D_xz), ``ax/az`` (d2, added to D_zy), ``ay/az`` (d3,
  added to D_yx), and ``gx/gy`` ... for the gyros.
- ``stuck``: the output freezes at its value at ``t_s`` (or at ``value``, output units,
  when given); no noise.
- ``noise``: the white-noise sigma is multiplied by ``value``.
- ``dead``: the output is the constant ``value`` (output units, default 0) with no noise.

Text form (command line, ``sim://`` query): ``kind:sensor:t_s[:value]``, e.g.
``bias:ax:30:150``, ``misalignment:gx/gz:10:0.004``, ``stuck:gy:5``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from imudiag.certificate import MISALIGNMENT_DIFFERENCES, Certificate

from .effects import sensor_index

KINDS = ("bias", "scale_factor", "misalignment", "stuck", "noise", "dead")
#: misalignment pair (axes) -> (difference index, the D key the fault changes: the
#: difference's plus key, so the fault adds its value to d)
PAIR_KEYS = {
    axes: (k, MISALIGNMENT_DIFFERENCES[k][0])
    for k, axes in enumerate((("x", "y"), ("x", "z"), ("y", "z")))
}
_NEEDS_VALUE = ("bias", "scale_factor", "misalignment", "noise")


@dataclass(frozen=True)
class Fault:
    """A fault of ``kind`` on ``sensor`` from ``t_s`` seconds on (see module docstring)."""

    kind: str
    sensor: str
    t_s: float
    value: float | None = None

    @property
    def amount(self) -> float:
        """The fault's value, for the kinds that need one (checked when it was made)."""
        if self.value is None:
            raise ValueError(f"fault {self.kind}:{self.sensor} has no value")
        return self.value

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(
                f"unknown fault kind {self.kind!r}; expected one of {', '.join(KINDS)}"
            )
        if not math.isfinite(self.t_s):
            raise ValueError(f"fault time must be finite, got {float(self.t_s)!r}")
        if self.kind in _NEEDS_VALUE and (self.value is None or not math.isfinite(self.value)):
            raise ValueError(f"a {self.kind} fault needs a finite value")
        if self.kind == "noise" and self.value is not None and self.value < 0:
            raise ValueError(f"a noise fault multiplier must be >= 0, got {self.value}")
        self.columns  # validates the sensor name  # noqa: B018

    @property
    def triad(self) -> str:
        """``gyro`` or ``accel``."""
        return "gyro" if self.sensor.startswith("g") else "accel"

    @property
    def columns(self) -> tuple[int, ...]:
        """Output columns 0..5 the fault touches (both of a misalignment pair)."""
        if self.kind == "misalignment":
            self.pair_key  # noqa: B018 - validation
            a, b = self.sensor.split("/")
            return sensor_index(a), sensor_index(b)
        if "/" in self.sensor:
            raise ValueError(f"a {self.kind} fault is on one sensor, got {self.sensor!r}")
        return (sensor_index(self.sensor),)

    @property
    def pair_key(self) -> tuple[int, str]:
        """(difference index 0..2, D key) of a misalignment fault."""
        parts = self.sensor.split("/")
        if len(parts) != 2 or parts[0][:1] != parts[1][:1] or parts[0][:1] not in ("g", "a"):
            raise ValueError(
                f"a misalignment fault names a pair like ax/ay, ax/az, ay/az, got {self.sensor!r}"
            )
        axes = tuple(sorted((parts[0][1:], parts[1][1:])))
        if axes not in PAIR_KEYS:
            raise ValueError(f"unknown misalignment pair {self.sensor!r}")
        for p in parts:
            sensor_index(p)
        return PAIR_KEYS[axes]

    def to_text(self) -> str:
        """The ``kind:sensor:t_s[:value]`` form."""
        base = f"{self.kind}:{self.sensor}:{self.t_s:g}"
        return base if self.value is None else f"{base}:{self.value:g}"


def parse_fault(text: str) -> Fault:
    """Parse ``kind:sensor:t_s[:value]`` (ValueError says what is wrong)."""
    parts = text.strip().split(":")
    if len(parts) not in (3, 4):
        raise ValueError(f"fault {text!r}: expected kind:sensor:t_s[:value]")
    kind, sensor, t_txt = parts[:3]
    try:
        t_s = float(t_txt)
        value = float(parts[3]) if len(parts) == 4 else None
    except ValueError:
        raise ValueError(f"fault {text!r}: time and value must be numbers") from None
    if t_s < 0:
        raise ValueError(f"fault {text!r}: the time must be >= 0 s (from the session's start)")
    try:
        return Fault(kind, sensor, t_s, value)
    except ValueError as exc:
        raise ValueError(f"fault {text!r}: {exc}") from None


def apply_faults(certificate: Certificate, faults: Iterable[Fault], t_s: float) -> Certificate:
    """A copy of ``certificate`` with the representable faults active at ``t_s`` applied
    (bias, scale_factor, misalignment; noise multiplies the noise density)."""
    cert = certificate.copy()
    for f in faults:
        if f.t_s > t_s:
            continue
        tri = cert.triad(f.triad)
        if f.kind == "bias":
            tri.bias[f.columns[0] % 3] += f.amount
        elif f.kind == "scale_factor":
            tri.scale_factor_error[f.columns[0] % 3] += f.amount
        elif f.kind == "misalignment":
            tri.misalignment[f.pair_key[1]] += f.amount
        elif f.kind == "noise" and tri.noise is not None and tri.noise.density is not None:
            tri.noise.density[f.columns[0] % 3] *= f.amount
    return cert
