"""The ``imudiag-model-check/1`` document (spec/reports.md): checks and writing.

The document holds at least ``format``, ``effects`` (name, triad, sensor, value, unit,
significance; ``t`` for ``bias_step``, ``frequency`` for ``periodic_disturbance``),
``baseline``, ``extended`` and ``gain``; the model check adds ``quasi_static``,
``units``, ``evaluation``, ``comparison``, ``tested`` and ``untestable``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from .. import atomic
from .check import CATALOGUE, FORMAT

REQUIRED = ("format", "effects", "baseline", "extended", "gain")
EFFECT_KEYS = ("name", "triad", "sensor", "value", "unit", "significance")


def check_report(report: dict[str, Any]) -> None:
    """Raise ValueError naming the key when ``report`` breaks the spec's shape."""
    for key in REQUIRED:
        if key not in report:
            raise ValueError(f"model-check report: missing key {key!r}")
    if report["format"] != FORMAT:
        raise ValueError(f"model-check report: format is {report['format']!r}, not {FORMAT!r}")
    for i, e in enumerate(report["effects"]):
        for key in EFFECT_KEYS:
            if key not in e:
                raise ValueError(f"model-check report: effects[{i}] has no {key!r}")
        if e["name"] not in CATALOGUE:
            raise ValueError(f"model-check report: effects[{i}].name {e['name']!r} unknown")
        if e["name"] == "bias_step" and "t" not in e:
            raise ValueError(f"model-check report: effects[{i}] (bias_step) has no 't'")
        if e["name"] == "periodic_disturbance" and "frequency" not in e:
            raise ValueError(f"model-check report: effects[{i}] has no 'frequency'")
        if e["name"] == "g_sensitivity" and e["triad"] != "gyro":
            raise ValueError(f"model-check report: effects[{i}] g_sensitivity on {e['triad']}")


def dumps(report: dict[str, Any]) -> str:
    """JSON text of the report (checked first)."""
    check_report(report)
    return json.dumps(report, indent=1, allow_nan=False) + "\n"


def write(report: dict[str, Any], dest: str | Path) -> None:
    """Write the report to ``dest`` (a path, or ``-`` for standard output)."""
    text = dumps(report)
    if str(dest) == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        atomic.write_text_atomic(dest, text)


def summary(report: dict[str, Any]) -> list[str]:
    """A few human-readable lines."""
    q = report.get("quasi_static", {})
    lines = [
        f"{report.get('samples', 0)} samples, {q.get('chunks', 0)} quasi-static chunks "
        f"in {q.get('runs', 0)} still runs, {q.get('attitudes', 0)} attitudes"
    ]
    if not report["effects"]:
        lines.append("no effect beyond the certificate's model")
    for e in report["effects"]:
        extra = ""
        if "t" in e:
            extra = f" at t={e['t']} s"
        if "frequency" in e:
            extra = f" at {e['frequency']} Hz"
        lines.append(
            f"{e['name']} {e['sensor']}: {e['value']} {e['unit']}{extra} (z={e['significance']})"
        )
    for metric, by_triad in report["gain"].items():
        parts = [f"{t} {v}" for t, v in by_triad.items() if v is not None]
        if parts:
            lines.append(f"gain {metric}: " + ", ".join(parts))
    return lines


__all__ = ["check_report", "dumps", "summary", "write"]
