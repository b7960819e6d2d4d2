"""The daemon's status: one JSON object per line (spec/reports.md), and when to write it.

Every line starts with ``class`` (``STATUS``) and ``format`` (``imudiag-status/1``),
:mod:`imudiag.reports`. Keys required by the contract: ``t`` (sample time, s), ``state`` (ok,
degraded, fault, no_data), ``faults`` (triad, sensor where it can be told,
cause), ``counters`` (the receiver counters). Added keys: ``link``,
``static``, ``f0``, ``diagnosis``, ``certificate`` (with ``datasheet`` and ``note`` when it
is a data-sheet certificate), ``device`` (the source's identity), ``stuck_checked``,
``adc_errors``, ``notes``,
``status_link`` (NMEA sentences ``written`` and ``dropped`` when a serial link is set).

The record is built here from what the daemon holds (:func:`status_record`,
:func:`noise_object`, :func:`diagnosis_verdict`); the daemon's loop only decides when.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, TextIO

from ..certificate import Certificate, datasheet_of
from ..monitor import Monitor
from ..noise_estimate import METHOD as WHITE_NOISE_METHOD
from ..noise_estimate import compare
from ..reports import CLASSES, STATUS_FORMAT

STATUS_CLASS = CLASSES[STATUS_FORMAT]
TRIADS = ("accel", "gyro")
STATES = ("ok", "degraded", "fault", "no_data")
FAULT_KEYS = ("triad", "sensor", "cause")


def fault_key(fault: dict[str, Any]) -> tuple[str, str, str]:
    """Identity of a fault for change detection and de-duplication."""
    return (fault.get("triad") or "", fault.get("sensor") or "", fault.get("cause") or "")


def signature(state: str, faults: list[dict[str, Any]]) -> tuple[Any, ...]:
    """What makes a status line due at once when it changes: the state and the faults."""
    return (state, tuple(fault_key(f) for f in faults))


def merge_faults(*groups: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Faults of several checkers, de-duplicated, in a stable order, contract keys first
    (every fault has ``sensor``: null where the check cannot tell the axis, as for F0 of a
    triad or saturation)."""
    seen: dict[tuple[str, str, str], dict[str, Any]] = {}
    for group in groups:
        for f in group:
            key = fault_key(f)
            if key not in seen:
                ordered = {k: f.get(k) for k in FAULT_KEYS}
                ordered.update({k: v for k, v in f.items() if k not in FAULT_KEYS})
                seen[key] = ordered
    return [seen[k] for k in sorted(seen)]


def finite_or_none(x: float) -> float | None:
    """A float for JSON: None where it is not finite (JSON has no NaN)."""
    return float(x) if math.isfinite(x) else None


def status_record(
    *,
    t: float | None,
    state: str,
    faults: list[dict[str, Any]],
    counters: dict[str, int],
    link: str,
    monitor: Monitor,
    certificate: Certificate,
    reloads: int,
) -> dict[str, Any]:
    """The keys every status line has, in order: the contract's (``class``, ``format``,
    ``t`` sample time in s, ``state``, ``faults``, ``counters``), then the link state, the
    monitor's F0 checks per triad, ADC-error and self-test sample counts, the certificate."""
    return {
        "class": STATUS_CLASS,
        "format": STATUS_FORMAT,
        "t": None if t is None else round(t, 6),
        "state": state,
        "faults": faults,
        "counters": counters,
        "link": link,
        "static": monitor.static,
        "f0": {
            name: {
                "check": monitor.check_mode(name),
                "samples_per_check": monitor.samples_per_check(name),
                "checked": st.checked,
                "failed": st.failed,
                "last": finite_or_none(st.last_f0),
                **({"why": monitor.f0_why(name)} if not st.checked else {}),
                **({"unjudged": u} if (u := monitor.f0_unjudged(name)) else {}),
            }
            for name, st in monitor.state.items()
        },
        # the white-noise checks judged (the other triad at its noise) and set aside (both
        # triads shaken: vibration or motion, never a noise fault), per triad
        "noise_checks": {
            name: {"judged": st.noise_judged, "set_aside": st.noise_not_at_rest}
            for name, st in monitor.state.items()
        },
        # per triad and axis: whether the stuck check runs (docs/service.md)
        "stuck_checked": monitor.stuck_checked,
        "adc_errors": monitor.adc_errors,
        "self_test": monitor.self_test,
        "certificate": certificate_object(certificate, reloads),
    }


#: the device keys every source sets (docs/devices.md), first in the ``device`` object
DEVICE_KEYS = ("vendor", "product", "serial", "firmware", "datasheet")


def device_object(info: Mapping[str, Any]) -> dict[str, Any]:
    """The ``device`` status object: the source's ``device_info``, the shared keys first."""
    out = {k: info[k] for k in DEVICE_KEYS if k in info}
    out.update({k: v for k, v in info.items() if k not in out})
    return out


def certificate_object(certificate: Certificate, reloads: int) -> dict[str, Any]:
    """The ``certificate`` status object: its serial and reload count; for a data-sheet
    certificate also ``datasheet`` (its key) and a ``note`` that it is no calibration."""
    out: dict[str, Any] = {"serial": str(certificate.device.get("serial", "")), "reloads": reloads}
    key = datasheet_of(certificate)
    if key:
        out["datasheet"] = key
        out["note"] = (
            f"data-sheet certificate {key}: the part's typical figures, not this unit's "
            "calibration; replace it with the certificate of imudiag calibrate"
        )
    return out


def noise_object(
    figures: Mapping[str, Any] | None, certificate: Certificate, window_s: float
) -> dict[str, Any] | None:
    """The ``noise`` object: per triad the white-noise density measured live (``density``,
    in the certificate's output unit per sqrt(Hz)), its ``ratio`` to the certificate's and
    whether they ``disagree``; None before the meter has a figure."""
    if figures is None:
        return None
    out: dict[str, Any] = {"method": WHITE_NOISE_METHOD, "window_s": window_s}
    for name, fig in figures.items():
        tri = certificate.triad(name)
        measured = [finite_or_none(float(v)) for v in fig.density]
        entry: dict[str, Any] = {"density": measured, "unit": f"{tri.output_unit}/sqrt(Hz)"}
        certified = tri.noise.density if tri.noise is not None else None
        if certified is not None and all(v is not None for v in measured):
            cmp = compare(fig.density, certified)
            ratios = cmp["ratio"]
            assert isinstance(ratios, list)
            entry["ratio"] = [round(float(r), 3) for r in ratios]
            entry["disagrees"] = bool(cmp["disagrees"])
        out[name] = entry
    return out


def diagnosis_verdict(
    faults: Iterable[Mapping[str, Any]],
    undetermined: Iterable[str],
    raised: int,
    since: Mapping[str, float | None] | None = None,
) -> dict[str, Any]:
    """The ``diagnosis`` object: per triad ``fault`` while a fault of it is in force, else
    ``undetermined`` or ``ok``; ``raised`` counts what was ever raised; ``since`` per triad
    the sample time, s, at which that verdict came in force (the end of the window that
    brought it; None before any window). The live verdict comes from the faults in force,
    never a latch that contradicts ``faults`` and ``state``."""
    in_force = {f["triad"] for f in faults}
    unseen = set(undetermined)
    view: dict[str, Any] = {
        name: "fault" if name in in_force else "undetermined" if name in unseen else "ok"
        for name in TRIADS
    }
    view["raised"] = raised
    if since is not None:
        at = {name: since.get(name) for name in TRIADS}
        view["since"] = {name: None if t is None else round(float(t), 6) for name, t in at.items()}
    return view


@dataclass
class StatusSchedule:
    """Decides when a status line is due: every ``period_s`` and at once on a change.

    The period runs on sample time while samples flow (a replay at full speed
    gives one line per second of data) and on wall-clock time otherwise (so
    ``no_data`` is still reported at the steady rate).
    """

    period_s: float = 1.0
    _last_t: float | None = None
    _last_wall: float | None = None
    _last_written_t: float | None = None  #: t of the last line written (for any reason)
    _prev_t: float | None = None  #: t at the previous call
    _last_signature: tuple[Any, ...] | None = field(default=None)

    def due(self, status: dict[str, Any], wall_s: float) -> bool:
        """True if ``status`` should be written now; records it as written if so."""
        return self.due_for(signature(status["state"], status["faults"]), status.get("t"), wall_s)

    def due_for(self, signature: tuple[Any, ...], t: float | None, wall_s: float) -> bool:
        """:meth:`due` from the parts it looks at: the status's :func:`signature` and ``t``
        (sample time, s), so a caller builds the whole status only when it is due."""
        changed = signature != self._last_signature
        by_sample = t is not None and (self._last_t is None or t - self._last_t >= self.period_s)
        by_wall = self._last_wall is None or wall_s - self._last_wall >= self.period_s
        # no new sample since the previous call or the last line written (a stall may
        # begin between two sample-time periods: the steady lines must go on all the same)
        sample_stalled = t is None or t == self._prev_t or t == self._last_written_t
        self._prev_t = t
        if changed or by_sample or (by_wall and sample_stalled):
            self._last_signature = signature
            self._last_wall = wall_s
            self._last_written_t = t
            if by_sample and t is not None:
                # keep to the period's grid, so a line per period on average whatever the
                # read size (reads of 0.06 s would otherwise drift to one line per 1.06 s)
                if self._last_t is None or t - self._last_t >= 2 * self.period_s:
                    self._last_t = t
                else:
                    self._last_t += self.period_s
            return True
        return False


class JsonLinesSink:
    """Writes status objects as single JSON lines to a text stream (flushed per line)."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.lines = 0

    def publish(self, status: dict[str, Any]) -> None:
        """Write one status line."""
        self.stream.write(json.dumps(status, separators=(",", ":"), allow_nan=False) + "\n")
        self.stream.flush()
        self.lines += 1

    def close(self) -> None:
        """Flush the stream (it is not closed: it may be stdout)."""
        try:
            self.stream.flush()
        except (OSError, ValueError):
            pass
