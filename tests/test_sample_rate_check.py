"""Issue 30 item 4: the daemon checks the samples at the rate the stream shows, and says
where that rate comes from (status ``sample_rate`` and ``sample_rate_from``).

- A replayed log is checked at the rate ``imudiag diagnose`` takes for it: the log's own
  ``sample_rate``, else what the time stamps of its first block show (the x-io NGIMU
  export, 49.4 Hz against a 200 Hz certificate: before, the daemon ran at 200 Hz and
  raised an accelerometer F0 fault that ``diagnose`` did not).
- A live stream that states no rate (the simulated board through the wire codec) is
  checked against its first 256 time stamps: a certificate's rate they contradict by
  more than 5 % is corrected to theirs, and the status says so with both figures.
- A rate the source states is kept when its stamps disagree, as ``diagnose`` keeps a log's
  ``sample_rate``, and the disagreement is said.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imudiag.api import diagnose
from imudiag.certificate import load_default
from imudiag.logs import open_writer
from imudiag.service.daemon import Daemon, DaemonSettings
from imudiag.sim import multi_position, simulate
from tests.helpers import CollectSink

DATA = Path(__file__).parent / "data"
NGIMU = DATA / "real" / "skinematics" / "ngimu-sensors.csv"
LIKE_SI = DATA / "interop" / "like-si.yaml"
BUNDLED = Path(__file__).parent.parent / "config" / "default-certificate.yaml"


def _run(url: str, cert: Path) -> list[dict[str, Any]]:
    sink = CollectSink()
    daemon = Daemon(DaemonSettings(source_url=url, certificate_path=str(cert)), [sink])
    assert daemon.run() == 0
    return [s for s in sink.lines if s["t"] is not None]


def test_a_replayed_log_without_a_stated_rate_is_checked_at_its_time_stamps_rate():
    lines = _run(f"replay://{NGIMU}?speed=0&step=2", LIKE_SI)
    report = diagnose(str(NGIMU), str(LIKE_SI), windows=False)
    last = lines[-1]
    assert report["sample_rate"] == pytest.approx(49.385, rel=1e-3)  # not the 200 Hz stated
    assert last["sample_rate"] == report["sample_rate"]  # the same figure, to the bit
    assert last["sample_rate_from"] == "the time stamps of the log's first block"
    assert last["device"]["sample_rate"] == report["sample_rate"]
    assert all(s["sample_rate"] == report["sample_rate"] for s in lines)
    assert not any("sample rate" in n for s in lines for n in s.get("notes", []))
    # both check F0 on the still stretches (their counts differ a little where the
    # certificate states no noise: docs/service.md, "What still differs")
    assert last["f0"]["accel"]["checked"] > 0 and report["f0"]["accel"]["checked"] > 0
    assert last["verdict"]["accel"] == report["verdict"]["accel"]
    assert [s for s in lines if s["state"] == "fault"] == []


def test_a_live_stream_contradicting_the_certificate_rate_is_corrected_and_said():
    """The bundled certificate says 200 Hz; the board sends 100 Hz (its device time
    stamps show it): the first 64 samples are held until their stamps are checked, and
    every sample is checked at 100 Hz."""
    cert = load_default()
    assert cert.sample_rate == 200
    lines = _run("sim://static?rate=100&speed=0&duration=20&seed=3", BUNDLED)
    last = lines[-1]
    assert all(s["sample_rate"] == pytest.approx(100.0, rel=1e-9) for s in lines)
    assert last["sample_rate_from"].startswith("the stream's time stamps")
    note = [n for n in last["notes"] if n.startswith("sample rate")]
    assert len(note) == 1
    assert re.fullmatch(
        r"sample rate: the certificate's 200 Hz disagrees with the stream's time stamps "
        r"\(100 Hz, median step over its first (6[4-9]) samples\) by 100 % \(more than 5 %\): "
        r"the samples are checked at 100 Hz",
        note[0],
    ), note[0]
    assert lines[0]["t"] <= 1.0  # the hold costs 0.64 s of sample time, nothing is lost
    assert last["counters"]["frames"] == 2000
    # a clean board stays clean at its true rate: no fault, and the noise meter measures
    # the board's noise at 100 Hz (at 200 Hz the same samples read as sqrt(2) more dense)
    assert [s for s in lines if s["state"] == "fault"] == []
    noise = last["noise"]
    for triad in ("accel", "gyro"):
        ratio = np.asarray(noise[triad]["ratio"], dtype=float)
        assert np.all(np.abs(np.log(ratio)) < np.log(1.3)), (triad, ratio)


def test_a_stream_shorter_than_the_hold_is_checked_all_the_same():
    """0.3 s of a 100 Hz board (30 samples, fewer than the 64 held): at the end of the
    stream the held samples are checked, at the rate their stamps show."""
    lines = _run("sim://static?rate=100&speed=0&duration=0.3&seed=3", BUNDLED)
    assert lines, "no status line with samples"
    assert lines[-1]["sample_rate"] == pytest.approx(100.0, rel=1e-9)
    assert lines[-1]["counters"]["frames"] == 30


def test_a_live_stream_at_the_certificate_rate_says_nothing():
    lines = _run("sim://static?speed=0&duration=5&seed=3", BUNDLED)
    assert {s["sample_rate"] for s in lines} == {200.0}
    assert {s["sample_rate_from"] for s in lines} == {"certificate"}
    assert not any("sample rate" in n for s in lines for n in s.get("notes", []))


def test_a_stated_rate_the_stamps_contradict_is_kept_and_said(tmp_path):
    """A log that says 200 Hz with stamps 10 ms apart: both faces keep the stated rate
    (``diagnose``'s timing report notes the disagreement); the daemon says it too."""
    cert = load_default()
    traj = multi_position(n_attitudes=6, dwell_s=3.0, turn_s=1.5, rate_hz=100, seed=4)
    samples = simulate(cert, traj, seed=5).samples
    log = tmp_path / "says-200.npz"
    with open_writer(log, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(samples)
    lines = _run(f"replay://{log}?speed=0&step=2", BUNDLED)
    report = diagnose(str(log), str(BUNDLED), windows=False)
    assert report["sample_rate"] == 200.0 == lines[-1]["sample_rate"]
    assert lines[-1]["sample_rate_from"] == "the source's sample_rate"
    note = [n for n in lines[-1]["notes"] if n.startswith("sample rate")]
    assert note == [
        "sample rate: the source's sample_rate says 200 Hz, the stream's time stamps show "
        "100 Hz by 100 % (more than 5 %); the stated rate is kept"
    ]
