"""Well-formedness of the daemon's status lines (spec/reports.md), checked line by line."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from imudiag.reports import STATUS_FORMAT
from imudiag.service.status import STATES

COUNTER_KEYS = ("bytes", "frames", "crc_errors", "skipped_bytes", "lost", "duplicates")
VERDICTS = ("ok", "fault", "undetermined")
MONITOR_CAUSES = ("f0", "stuck", "saturation")  #: causes the per-sample monitor reports


class StatusLineError(ValueError):
    """A status line that breaks the contract; the message names the line and the key."""


def check_status_line(status: Any, where: str = "status") -> None:
    """Raise StatusLineError unless ``status`` has the keys and types of spec/reports.md."""
    if not isinstance(status, dict):
        raise StatusLineError(f"{where}: not a JSON object: {status!r}")
    if status.get("class") != "STATUS" or status.get("format") != STATUS_FORMAT:
        raise StatusLineError(
            f"{where}: class/format {status.get('class')!r}/{status.get('format')!r}, "
            f"not 'STATUS'/{STATUS_FORMAT!r}"
        )
    for key in ("t", "state", "faults", "counters"):
        if key not in status:
            raise StatusLineError(f"{where}: no key {key!r}")
    t = status["t"]
    if t is not None and (not isinstance(t, (int, float)) or not math.isfinite(t)):
        raise StatusLineError(f"{where}: t is not a finite number: {t!r}")
    if status["state"] not in STATES:
        raise StatusLineError(f"{where}: state {status['state']!r} not one of {STATES}")
    if not isinstance(status["faults"], list):
        raise StatusLineError(f"{where}: faults is not a list")
    for fault in status["faults"]:
        if not isinstance(fault, dict):
            raise StatusLineError(f"{where}: fault is not an object: {fault!r}")
        for key in ("triad", "cause"):
            if not isinstance(fault.get(key), str):
                raise StatusLineError(f"{where}: fault without a {key}: {fault!r}")
        if fault["triad"] not in ("gyro", "accel"):
            raise StatusLineError(f"{where}: fault triad {fault['triad']!r}")
    counters = status["counters"]
    if not isinstance(counters, dict) or set(counters) != set(COUNTER_KEYS):
        raise StatusLineError(
            f"{where}: counters keys {sorted(counters)} != {sorted(COUNTER_KEYS)}"
        )
    for key, value in counters.items():
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            raise StatusLineError(f"{where}: counters.{key} not a non-negative integer: {value!r}")
    diag = status.get("diagnosis")
    if diag is not None:
        if not isinstance(diag, dict):
            raise StatusLineError(f"{where}: diagnosis is not an object")
        for triad in ("accel", "gyro"):
            if diag.get(triad) not in VERDICTS:
                raise StatusLineError(f"{where}: diagnosis.{triad} {diag.get(triad)!r}")


class StatusStream:
    """A text stream for :class:`imudiag.service.status.JsonLinesSink` that checks every line.

    Each written line must be one JSON object, well-formed
    (:func:`check_status_line`), with ``t`` and every counter never going
    backwards. Keeps only the last status (memory stays flat however long it runs).
    """

    def __init__(
        self, on_faults: Callable[[float, list[dict[str, Any]]], None] | None = None
    ) -> None:
        """``on_faults(t, faults)`` is called whenever the fault list changes."""
        self.lines = 0
        self.last: dict[str, Any] | None = None
        self.errors: list[str] = []
        self.on_faults = on_faults
        self._partial = ""
        self._last_faults: list[dict[str, Any]] = []

    def write(self, text: str) -> int:
        """Receive text; every complete line is checked."""
        data = self._partial + text
        *lines, self._partial = data.split("\n")
        for line in lines:
            self._line(line)
        return len(text)

    def flush(self) -> None:
        """Nothing is buffered but a partial line."""

    def _line(self, line: str) -> None:
        self.lines += 1
        where = f"status line {self.lines}"
        try:
            status = json.loads(line)
            check_status_line(status, where)
            prev = self.last
            if prev is not None:
                if status["t"] is not None and prev["t"] is not None and status["t"] < prev["t"]:
                    raise StatusLineError(f"{where}: t went back {prev['t']} -> {status['t']}")
                for key in COUNTER_KEYS:
                    if status["counters"][key] < prev["counters"][key]:
                        raise StatusLineError(f"{where}: counters.{key} went back")
        except (ValueError, StatusLineError) as exc:
            if len(self.errors) < 100:
                self.errors.append(f"{exc} ({line[:200]!r})")
            return
        self.last = status
        if status["faults"] != self._last_faults:
            self._last_faults = status["faults"]
            if status["t"] is not None and self.on_faults is not None:
                self.on_faults(float(status["t"]), status["faults"])
