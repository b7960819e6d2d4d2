"""The ``class`` and ``format`` of every JSON object imudiag writes.

As gpsd tags each report with its ``class`` (TPV, SKY, VERSION), every top-level JSON
object imudiag writes (a daemon status line, a command's report) starts with ``class``,
what kind of object it is, and ``format``, the name and version of its contract; a
consumer reading a mixed stream tells them apart by ``class`` and refuses a ``format``
version it does not know. A contract that changes incompatibly gets a new version here.
"""

from __future__ import annotations

import json
import math
from typing import Any

STATUS_FORMAT = "imudiag-status/1"  #: a daemon status line (spec/reports.md)
DIAGNOSIS_FORMAT = "imudiag-diagnosis/1"  #: imudiag diagnose --json
CALIBRATION_FORMAT = "imudiag-calibration/1"  #: imudiag calibrate --json
MODEL_CHECK_FORMAT = "imudiag-model-check/1"  #: imudiag model-check --json
ALLAN_FORMAT = "imudiag-allan/1"  #: imudiag allan --json
BENCH_FORMAT = "imudiag-bench/1"  #: imudiag bench --json
FLEET_FORMAT = "imudiag-fleet/1"  #: imudiag fleet's DIR/fleet.json (docs/fleet.md)

#: format -> class: one entry per kind of JSON object.
CLASSES: dict[str, str] = {
    STATUS_FORMAT: "STATUS",
    DIAGNOSIS_FORMAT: "DIAGNOSIS",
    CALIBRATION_FORMAT: "CALIBRATION",
    MODEL_CHECK_FORMAT: "MODEL_CHECK",
    ALLAN_FORMAT: "ALLAN",
    BENCH_FORMAT: "BENCH",
    FLEET_FORMAT: "FLEET",
}


def header(fmt: str) -> dict[str, str]:
    """The first two keys of a JSON object of format ``fmt``: ``class`` and ``format``."""
    return {"class": CLASSES[fmt], "format": fmt}


def finite_or_null(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, +-inf: a value not determined) as None, so
    it is valid JSON (``null``); numpy scalars and arrays become plain numbers and lists."""
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return finite_or_null(obj.tolist())  # numpy arrays and scalars
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(report: Any, indent: int | None = 1) -> str:
    """The JSON text of a report, the one writer of every command's report: a value not
    determined (NaN, +-inf) is written as ``null`` (spec/reports.md), never as a bare
    ``NaN`` token, which is not JSON."""
    return json.dumps(finite_or_null(report), indent=indent, allow_nan=False)


__all__ = [
    "ALLAN_FORMAT",
    "BENCH_FORMAT",
    "CALIBRATION_FORMAT",
    "CLASSES",
    "DIAGNOSIS_FORMAT",
    "FLEET_FORMAT",
    "MODEL_CHECK_FORMAT",
    "STATUS_FORMAT",
    "finite_or_null",
    "header",
    "json_text",
]
