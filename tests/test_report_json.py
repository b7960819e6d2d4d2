"""Every report is valid JSON: a value not determined (NaN) is ``null`` (spec/reports.md)."""

from __future__ import annotations

import json
import math

import numpy as np

from imudiag.commands.diagnose import write_json
from imudiag.reports import json_text


def test_nan_in_a_nested_report_is_written_as_null(tmp_path):
    # the shape of the real crash: moving_base.gyro_turns.forward_axis.axis_body with 0
    # straight epochs is a NaN vector
    report = {
        "class": "DIAGNOSIS",
        "moving_base": {
            "gyro_turns": {
                "forward_axis": {
                    "axis_body": [math.nan, math.nan, math.nan],
                    "straight_epochs": 0,
                }
            },
            "f0": {"f0_median": np.float64("nan"), "checked": np.int64(3)},
            "limits": np.array([1.0, np.inf, -np.inf]),
        },
        "samples": 10,
    }
    out = tmp_path / "report.json"
    write_json(report, str(out))
    text = out.read_text()
    assert "NaN" not in text and "Infinity" not in text
    back = json.loads(text)  # strict: a NaN token would still parse, so check the text too
    fa = back["moving_base"]["gyro_turns"]["forward_axis"]
    assert fa == {"axis_body": [None, None, None], "straight_epochs": 0}
    assert back["moving_base"]["f0"] == {"f0_median": None, "checked": 3}
    assert back["moving_base"]["limits"] == [1.0, None, None]
    assert back["samples"] == 10


def test_finite_values_are_unchanged():
    report = {"a": [0.1, 1e-300, -2.5], "b": "NaN as text stays text", "c": None, "d": True}
    assert json.loads(json_text(report)) == report
