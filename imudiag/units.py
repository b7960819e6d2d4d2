"""Unit names and exact conversions (ground floor): one place converts, every consumer sees
the certificate's units.

Physical units convert exactly: the standard gravity g = 9.80665 m/s^2 by definition
(CGPM 1901; ISO 80000-3), 1 deg = pi/180 rad, the SI prefix m = 1e-3. Raw ``count``
outputs convert to nothing: only the certificate's scale factor relates them to a
physical input, so counts against physical units is refused, never guessed.

- :func:`canonical`: a unit name as the project writes it (``m/s2`` -> ``m/s^2``).
- :func:`factor`: the exact factor from one unit of a triad to another.
- :func:`conform`: the conversion that brings a source's or log's declared units to a
  certificate's output units (:class:`Conversion`, applied to each :class:`SampleBlock`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from .errors import BadInput

if TYPE_CHECKING:  # the data floor sits above this one; only its types are named here
    from .certificate import Certificate
    from .samples import SampleBlock

#: Standard gravity, m/s^2 (exact by definition).
STANDARD_GRAVITY_M_S2 = 9.80665

#: Raw sensor outputs (ADC counts, LSB): no physical conversion exists.
COUNT = "count"

#: Each physical unit of a triad -> its size in SI (rad/s, m/s^2), exact.
TO_SI: dict[str, dict[str, float]] = {
    "gyro": {"rad/s": 1.0, "deg/s": math.pi / 180.0, "mrad/s": 1e-3},
    "accel": {"m/s^2": 1.0, "g": STANDARD_GRAVITY_M_S2, "mg": STANDARD_GRAVITY_M_S2 * 1e-3},
}
TRIADS = ("gyro", "accel")

#: Spellings seen in logs, data sheets and other tools' files -> the project's name.
_ALIASES = {
    "counts": COUNT,
    "lsb": COUNT,
    "m/s2": "m/s^2",
    "m/s**2": "m/s^2",
    "ms^-2": "m/s^2",
    "m*s^-2": "m/s^2",
    "mps2": "m/s^2",
    "dps": "deg/s",
    "deg/sec": "deg/s",
    "degree/s": "deg/s",
    "degrees/s": "deg/s",
    "°/s": "deg/s",
    "rad/sec": "rad/s",
    "rps": "rad/s",
    "mrad/sec": "mrad/s",
    "milli-g": "mg",
    "millig": "mg",
}


def canonical(unit: str) -> str:
    """``unit`` as the project spells it (lower case, no spaces, aliases resolved)."""
    u = str(unit).strip().replace(" ", "")
    low = u.lower()
    if low == "g" or low == "mg":
        return low
    return _ALIASES.get(low, low)


def units_of(triad: str) -> tuple[str, ...]:
    """Every unit name a ``triad`` ("gyro" or "accel") may be stated in, counts included."""
    return (*TO_SI[triad], COUNT)


def is_physical(triad: str, unit: str) -> bool:
    """True when ``unit`` is a physical unit of ``triad`` that converts exactly."""
    return canonical(unit) in TO_SI[triad]


def factor(triad: str, from_unit: str, to_unit: str) -> float:
    """Exact factor f with value_in_to_unit = f * value_in_from_unit.

    Raises :class:`BadInput` when the two cannot be converted (counts against a
    physical unit, or a unit this triad does not have).
    """
    a, b = canonical(from_unit), canonical(to_unit)
    if a == b:
        return 1.0
    table = TO_SI[triad]
    if a in table and b in table:
        return table[a] / table[b]
    raise BadInput(f"{triad}: {from_unit!r} cannot be converted to {to_unit!r}")


@dataclass(frozen=True)
class Conversion:
    """Per-triad factors that bring samples from their stated units to a certificate's."""

    #: triad -> (stated unit, certificate unit, factor); only triads that change
    steps: dict[str, tuple[str, str, float]]

    @property
    def identity(self) -> bool:
        """True when nothing changes."""
        return not self.steps

    def apply(self, block: SampleBlock) -> SampleBlock:
        """``block`` in the certificate's units (the same object when nothing changes)."""
        if not self.steps:
            return block
        changes: dict[str, Any] = {}
        for triad, (_, _, f) in self.steps.items():
            changes[triad] = getattr(block, triad) * f
        return replace(block, **changes)

    def describe(self) -> list[dict[str, Any]]:
        """For reports and status: ``[{"triad", "from", "to", "factor"}]`` per converted triad."""
        return [
            {"triad": t, "from": a, "to": b, "factor": f} for t, (a, b, f) in self.steps.items()
        ]

    def __str__(self) -> str:
        if not self.steps:
            return "no unit conversion"
        return ", ".join(f"{t} {a} -> {b} (x{f:.10g})" for t, (a, b, f) in self.steps.items())


NO_CONVERSION = Conversion({})

_UNIT_ITEM = re.compile(r"(gyro|accel)\s*=\s*(\S+)")


def stated_units(value: Any) -> dict[str, str]:
    """``{"gyro": unit, "accel": unit}`` from a log's ``units`` metadata: a mapping or text
    such as ``gyro=deg/s accel=g`` (either may be absent)."""
    if isinstance(value, Mapping):
        return {str(k): str(v) for k, v in value.items() if k in TRIADS}
    return {m.group(1): m.group(2).strip(",;") for m in _UNIT_ITEM.finditer(str(value))}


def conform_meta(meta: Mapping[str, Any], cert: Certificate, where: str) -> Conversion:
    """:func:`conform` for a log or source whose metadata may state ``units``
    (nothing stated: the certificate's units are assumed, as before)."""
    if meta.get("units") is None:
        return NO_CONVERSION
    try:
        return conform(stated_units(meta["units"]), cert, where)
    except BadInput as exc:
        if not meta.get("datasheet") or cert.device.get("datasheet") == meta["datasheet"]:
            raise
        named = meta["datasheet"]  # an autopilot's log: its IMU class's data sheet
        raise BadInput(
            f"{exc}; or --certificate auto (the {named!r} data sheet the log names)"
        ) from None


def conform(stated: Mapping[str, str], cert: Certificate, where: str) -> Conversion:
    """The conversion from the ``stated`` units (triad -> unit; a triad not stated is
    assumed to be in the certificate's units already) to ``cert``'s output units.

    ``where`` names the log or source in the message. Raises :class:`BadInput` naming
    both sides when they cannot be converted (counts against physical units, or two
    different units this module does not know).
    """
    steps: dict[str, tuple[str, str, float]] = {}
    for triad in TRIADS:
        unit = stated.get(triad)
        if unit is None:
            continue
        cu = cert.triad(triad).output_unit
        if canonical(unit) == canonical(cu):
            continue
        try:
            f = factor(triad, unit, cu)
        except BadInput:
            src = cert.source or "the certificate"
            raise BadInput(
                f"{where}: units: the {triad} outputs are in {unit!r} but {src}: "
                f"{triad}.output_unit is {cu!r}; {_why(triad, unit, cu)}"
            ) from None
        steps[triad] = (canonical(unit), canonical(cu), f)
    return Conversion(steps)


def _why(triad: str, unit: str, cu: str) -> str:
    a, b = canonical(unit), canonical(cu)
    if COUNT in (a, b):
        counted, physical = (unit, cu) if a == COUNT else (cu, unit)
        return (
            f"raw {counted!r} outputs relate to {physical!r} only through a calibration: use a "
            f"certificate whose {triad}.output_unit is {unit!r}, or a log in {cu!r} "
            f"(convert --quantum makes counts), or state the log's true units with --units"
        )
    known = ", ".join(units_of(triad))
    return (
        f"they cannot be converted (known {triad} units: {known}); "
        "state the true units with --units"
    )


__all__ = [
    "COUNT",
    "NO_CONVERSION",
    "STANDARD_GRAVITY_M_S2",
    "TO_SI",
    "Conversion",
    "canonical",
    "conform",
    "conform_meta",
    "factor",
    "is_physical",
    "stated_units",
    "units_of",
]
