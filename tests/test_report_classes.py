"""Every JSON object imudiag writes starts with ``class`` and ``format`` (imudiag/reports.py),
as gpsd tags each report with its class: status lines and every command's report."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from imudiag.certificate import default_certificate_path
from imudiag.reports import CLASSES, header

HEAD = ["class", "format"]


def _head(obj: dict, fmt: str) -> None:
    assert list(obj)[:2] == HEAD, list(obj)[:4]
    assert (obj["class"], obj["format"]) == (CLASSES[fmt], fmt)


def test_one_class_per_format():
    assert len(set(CLASSES.values())) == len(CLASSES)
    assert all(c == c.upper() and f.startswith("imudiag-") for f, c in CLASSES.items())
    with pytest.raises(KeyError):
        header("imudiag-nothing/1")


@pytest.mark.realtime
def test_status_lines(tmp_path):
    """`imudiag run` on a finite simulated session: every line a STATUS object."""
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "imudiag",
            "run",
            "--source",
            "sim://static?seed=2&speed=0&duration=5",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(lines) >= 5
    for obj in lines:
        _head(obj, "imudiag-status/1")


def test_command_reports(tmp_path, imudiag_cli, imudiag_in_process):
    """diagnose, calibrate, allan and model-check reports of one simulated session. The
    diagnosis as a real subprocess, the other commands in this process (each writes its
    report in a real subprocess in its own test file: test_sim_command, test_calibrate,
    test_sim_command's allan, test_modelcheck)."""
    log = tmp_path / "session.csv"
    r = imudiag_in_process(
        "simulate", "multiposition", "--duration", "60", "--seed", "3", "--out", str(log)
    )
    assert r.returncode == 0, r.stderr
    cert = str(default_certificate_path())
    runs = {
        "imudiag-diagnosis/1": ("diagnose", str(log)),
        "imudiag-calibration/1": (
            "calibrate",
            str(log),
            "--like",
            cert,
            "--out",
            str(tmp_path / "cal.yaml"),
            "--force",
        ),
        "imudiag-allan/1": ("allan", str(log)),
        "imudiag-model-check/1": ("model-check", str(log), "--certificate", cert),
    }
    for fmt, args in runs.items():
        out = tmp_path / f"{args[0]}.json"
        run = imudiag_cli if args[0] == "diagnose" else imudiag_in_process
        r = run(*args, "--json", str(out))
        assert r.returncode in (0, 1), r.stderr  # 1: a calibration refused still reports
        _head(json.loads(out.read_text()), fmt)
