"""Issue 12 item 2: the live status never contradicts itself: ``diagnosis`` comes from the
faults in force; what was ever raised is a counter."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.logs import open_writer
from imudiag.samples import SampleBlock
from imudiag.service.daemon import Daemon, DaemonSettings
from imudiag.sim import Fault, multi_position, simulate
from tests.helpers import CollectSink


def test_a_cleared_diagnosis_fault_leaves_the_live_verdict(tmp_path):
    cert = load_default()
    lim = cert.accel.limits.scale_factor_error[2]
    bad = simulate(
        cert,
        multi_position(n_attitudes=20, rate_hz=cert.sample_rate, seed=31),
        seed=32,
        faults=[Fault("scale_factor", "az", 0.0, 6 * lim)],
    ).samples
    good = simulate(
        cert, multi_position(n_attitudes=36, rate_hz=cert.sample_rate, seed=33), seed=34
    ).samples
    good = SampleBlock(
        t=good.t + bad.t[-1] + 1.0 / cert.sample_rate, gyro=good.gyro, accel=good.accel
    )
    bad = SampleBlock(t=bad.t, gyro=bad.gyro, accel=bad.accel)
    log = tmp_path / "fault-then-clean.npz"
    with open_writer(
        log, {"sample_rate": cert.sample_rate, "units": "gyro=count accel=count"}
    ) as w:
        w.write(bad)
        w.write(good)
    sink = CollectSink()
    daemon = Daemon(DaemonSettings(source_url=f"replay://{log}?speed=0"), [sink])
    assert daemon.run() == 0
    lines = [s for s in sink.lines if s["t"] is not None]
    for s in lines:
        live = {
            f["triad"]
            for f in s["faults"]
            if f["cause"] in ("bias", "scale_factor", "misalignment")
        }
        for triad in ("accel", "gyro"):
            assert (s["diagnosis"][triad] == "fault") == (triad in live), s
    raised_at = [s["t"] for s in lines if s["diagnosis"]["accel"] == "fault"]
    assert raised_at, "the 6-limit az scale fault was never raised"
    last = lines[-1]
    assert last["diagnosis"]["accel"] != "fault" and last["faults"] == []
    assert last["diagnosis"]["raised"] >= 1
    assert np.isfinite(last["t"])


@pytest.mark.realtime
def test_no_data_says_why_in_notes_and_the_log(tmp_path):
    """Issue 12 item 4: a missing device is named with the OS error, not only no_data."""
    import subprocess
    import sys

    from conftest import PROJECT_DIR

    missing = tmp_path / "ttyNOPE"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "imudiag",
            "run",
            "--source",
            f"serial://{missing}",
            "--no-data-timeout",
            "0.2",
        ],
        cwd=PROJECT_DIR,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        import json

        line = json.loads(proc.stdout.readline())  # the first status line: an event
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert line["state"] == "no_data" and line["link"] == "reconnecting"
    (note,) = line["notes"]
    assert str(missing) in note and "No such file or directory" in note
    assert "WARNING" in err and "No such file or directory" in err
