"""Every device of the shared fake-device harness (:data:`imudiag.bench.devices.ENCODERS`)
runs a bench scenario: the daemon (a real subprocess) reads the fake WitMotion WT901 and the
fake iSensor SPI Buffer board (its set-up dialogue answered) on a pty, and the fake IIO
device (a sysfs tree and a FIFO, unplugged by removing them); an accelerometer
fault, garbage, corrupted, lost and repeated samples and an unplug are judged as on the
native board, with the counters exact."""

from __future__ import annotations

from pathlib import Path

import pytest

from imudiag.bench import ScenarioError, loads, run_scenario
from imudiag.bench.devices import ENCODERS, SOURCE_URLS, make_encoder
from imudiag.certificate import load_default

#: the real-time tier (tests/conftest.py): the bench against fake devices on ptys
pytestmark = pytest.mark.realtime

SCENARIO = """
format: imudiag-bench-scenario/1
name: {device}-smoke
motion: static
duration: 8.0
seed: 3
speed: 4.0
device: {device}
injections:
  - {{t: 2.0, kind: bias, sensor: az, value: 800.0,
     expect: [{{triad: accel, cause: f0, within: 1.0}}]}}
  - {{t: 3.5, kind: garbage, bytes: 500}}
  - {{t: 4.2, kind: crc, frames: 5}}
  - {{t: 5.0, kind: unplug, outage: 1.0, within: 1.5, recover_within: 3.0}}
  - {{t: 6.5, kind: duplicate, frames: 2}}
  - {{t: 7.0, kind: lost, frames: 10}}
"""


@pytest.mark.parametrize("device", ["witmotion", "isensor", "iio"])
def test_bench_scenario_runs_on_the_fake_device(tmp_path: Path, device: str):
    text = SCENARIO.format(device=device)
    if device == "iio":  # a kernel buffer: no garbage, no corrupted frames (refused: below)
        text = "\n".join(ln for ln in text.splitlines() if "garbage" not in ln and "crc" not in ln)
    scenario = loads(text, f"{device}-smoke.yaml")
    report = run_scenario(scenario, diagnosis=False, workdir=tmp_path).report
    assert report["device"] == device
    assert report["passed"], report


STUCK_DEAD = """
format: imudiag-bench-scenario/1
name: {device}-stuck-dead
motion: static
duration: 7.0
seed: 5
speed: 4.0
device: {device}
injections:
  - {{t: 2.0, kind: stuck, sensor: gx,
     expect: [{{triad: gyro, sensor: gx, cause: stuck, within: 0.5}}],
     also: [{{triad: gyro, sensor: gx, cause: f0}}]}}
  - {{t: 4.5, kind: dead, sensor: ay,
     expect: [{{triad: accel, sensor: ay, cause: stuck, within: 0.5}}],
     also: [{{triad: accel, cause: f0}}]}}
"""


@pytest.mark.parametrize("device", sorted(ENCODERS))
def test_stuck_and_dead_channels_are_named_on_every_device(tmp_path: Path, device: str):
    """The stuck check in the device's own units (docs/service.md): counts (native), float
    SI (MAVLink HIGHRES_IMU), 16-bit words of the part's LSB (iSensor, in deg/s and g),
    the WT901's 16 g and 2000 deg/s over 32768: a frozen gyro and a dead accelerometer
    channel are named within 0.5 s of sample time (the fault's ``t_first``), and nothing
    is stuck before (a false alarm fails the report)."""
    scenario = loads(STUCK_DEAD.format(device=device), f"{device}-stuck-dead.yaml")
    report = run_scenario(scenario, diagnosis=False, workdir=tmp_path).report
    assert report["device"] == device
    assert report["passed"], report
    assert not report["false_alarms"], report["false_alarms"]


def test_iio_refuses_garbage_and_corrupted_frames():
    with pytest.raises(ScenarioError, match="no framing and no checksum"):
        loads(SCENARIO.format(device="iio"), "iio-smoke.yaml")


def test_every_device_has_a_source_url():
    assert set(SOURCE_URLS) == set(ENCODERS)
    for name in ENCODERS:
        assert (
            SOURCE_URLS[name]
            .format(path="/dev/x", rate=200.0)
            .startswith(name if name != "native" else "serial")
        )


def test_isensor_board_streams_only_while_its_capture_runs():
    """The board sends entry lines only after the host selected page 255 with the stream on;
    its data counter runs on meanwhile (the host counts the samples it missed)."""
    from imudiag.sim.board import SimulatedBoard
    from imudiag.sim.scenarios import scenario_motion

    cert = load_default()
    board = SimulatedBoard(cert, scenario_motion("static", 0), seed=0, duration_s=0.1)
    enc = make_encoder("isensor", cert)
    _, first = board.generate(5)
    assert enc.encode(first) == b""
    assert enc.answer(b"echo 0\r\n") == b"echo 0\r\n"  # echoed, then echo off
    assert enc.answer(b"write 0 0\r\nread 72\r\n") == b"405B\r\n"  # PROD_ID 16475
    enc.answer(b"stream 1\r\nwrite 0 FF\r\n")
    _, second = board.generate(5)
    lines = enc.split(enc.encode(second))
    assert len(lines) == 5 and all(is_sample for _, is_sample in lines)
    assert lines[0][0].split(b",")[14] == b"0006"  # DATA_CNTR: 5 samples before it


def test_a_device_vibration_report_in_the_device_convention_is_judged():
    """MAVLink's VIBRATION as the source reports it (docs/devices.md item 5) goes into the
    status's vibration object: levels in m/s^2, the accelerometers' clipping summed."""
    from imudiag.vibration import VibrationFigures, vibration_object

    device = {"accel_rms": [0.1, 0.2, 0.3], "unit": "m/s^2", "clipping": [1, 2, 0], "t": 3.0}
    figs = VibrationFigures.from_dict(device)
    assert figs.accel == [0.1, 0.2, 0.3] and figs.gyro is None
    assert figs.clipping == {"accel": 3, "gyro": 0} and figs.source == "device"
    obj = vibration_object(None, device)
    assert obj["accel"]["level"] == [0.1, 0.2, 0.3] and obj["accel"]["unit"] == "m/s^2"
