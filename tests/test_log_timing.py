"""Time-stamp reports (rate estimated, gaps, jitter, repeated stamps counted) and allan on them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process

from imudiag.logs.timing import timing_report

FIRM = Path(__file__).parent / "data" / "real" / "firm-rocket-launch" / "flight.csv.gz"


def test_timing_report_counts_gaps_repeats_and_jitter() -> None:
    rng = np.random.default_rng(7)
    t = np.arange(1000) * 0.01 + rng.normal(0, 20e-6, 1000)
    t = np.sort(t)
    t = np.delete(t, np.arange(500, 510))  # one gap of 11 steps
    t = np.insert(t, 100, t[100])  # one repeated stamp
    r = timing_report(t, {"sample_rate": "100"})
    assert r.rate_hz == pytest.approx(100.0, rel=1e-3)
    assert r.gaps == 1 and r.longest_gap_s == pytest.approx(0.11, abs=1e-3)
    assert r.repeated == 1 and r.backwards == 0
    assert 10e-6 < r.jitter_s < 60e-6
    assert r.metadata_rate_hz == 100.0 and r.note == ""
    assert "repeated stamps" in r.summary() and "1 gaps" in r.summary()


def test_timing_report_states_a_disagreeing_or_descriptive_rate() -> None:
    t = np.arange(200) / 50.0
    assert "disagrees" in timing_report(t, {"sample_rate": 100}).note
    note = timing_report(t, {"sample_rate": "about 90-100"}).note
    assert "not a number" in note and "estimated from t" in note


def test_allan_reads_the_bundled_firm_flight(tmp_path: Path) -> None:
    """Issue 12 item 7: 'sample_rate: about 90-100' is metadata text, not a fatal error."""
    out = tmp_path / "allan.json"
    # in process: allan writes its report in a real subprocess in test_sim_command.py
    proc = run_imudiag_in_process("allan", str(FIRM), "--json", str(out), "--sensors", "gx,az")
    assert proc.returncode == 0, proc.stderr
    assert "not a number" in proc.stderr and "estimated from t" in proc.stderr
    report = json.loads(out.read_text())
    assert 85 < report["rate_hz"] < 105
    assert report["timing"]["class"] == "timing"
    assert report["timing"]["rate_hz"] == report["rate_hz"]
    assert report["sensors"]["gx"]["allan"]["adev"]
