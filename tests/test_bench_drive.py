"""The bench's aided drive: `imudiag bench drive-aided` runs the daemon as a real subprocess
against the simulated board over a pty AND a real gpsd (Debian's) reading the same drive's
GNSS stream as u-blox UBX through a second pty, both paced by the board's clock; a 3-limit
az bias injected mid-drive must be named by the moving-base path, without a false alarm
before it, while the status says aiding is in use.

Skips with the reason where gpsd or pyubx2 is missing (.ci/run installs gpsd and
gpsd-clients; pyubx2 is in the test extra).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from imudiag.bench import ScenarioError, load_bundled, loads
from imudiag.bench.gnss import GPSD_ENV, missing, wait_listening
from imudiag.bench.scenario import Expectation

WHY_NOT = missing()
needs_gpsd = pytest.mark.skipif(WHY_NOT is not None, reason=WHY_NOT or "")


@pytest.mark.realtime
@needs_gpsd
def test_drive_aided_names_the_az_fault_with_aiding_in_use(tmp_path: Path, imudiag_cli) -> None:
    out = tmp_path / "report.json"
    proc = imudiag_cli("bench", "drive-aided", "--json", str(out), "--strict", timeout=180.0)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "verdict: PASS" in proc.stdout
    assert "aiding: gpsd://127.0.0.1:" in proc.stdout and "in use from t = " in proc.stdout
    report = json.loads(out.read_text())
    assert report["scenario"] == "drive-aided" and report["passed"] is True
    assert report["daemon"]["exit_status"] == 0 and report["daemon"]["problems"] == []
    # no false alarm, before the fault or after it
    assert report["false_alarms"] == []
    (fault,) = report["faults"]
    assert fault["kind"] == "bias" and fault["sensor"] == "az" and fault["t"] == 60.0
    assert fault["result"] == "pass" and fault["premature_t"] is None and fault["wrong"] == []
    # named by the moving base as the group that holds az bias (a car cannot tell it from
    # az scale), within the scenario's sample-time bound
    matched = fault["matched"]
    assert matched["triad"] == "accel"
    assert set(matched["sensor"].split("|")) == {"az"}
    assert "bias" in matched["cause"].split("|")
    assert 0.0 < fault["latency_s"] <= fault["bound_s"] == 210.0
    # the status's aiding object: gpsd on the bench's loopback port, in use early on
    aiding = report["aiding"]
    assert aiding["problems"] == []
    assert aiding["source"].startswith("gpsd://127.0.0.1:")
    assert aiding["t_first_in_use"] <= aiding["in_use_within"] == 30.0
    final = aiding["final"]
    assert final["link"] == "connected" and final["in_use"] is True and final["mode"] == 3
    assert final["fixes"] > 1000 and final["windows"] >= 2
    assert final["f0"]["checked"] > 150
    # the IMU stream arrived whole
    assert report["counters"]["exact"] is True
    assert report["counters"]["observed"]["frames"] == 300 * 200
    # the bench stopped the gpsd it started: its port no longer listens
    port = int(aiding["source"].rsplit(":", 1)[1])
    assert not wait_listening(port, 0.0)


@pytest.mark.realtime
def test_a_gpsd_that_dies_at_start_is_a_bench_error_with_its_status(tmp_path: Path) -> None:
    if WHY_NOT is not None and "pyubx2" in WHY_NOT:
        pytest.skip(WHY_NOT)
    env = dict(os.environ, **{GPSD_ENV: "/bin/false"})
    proc = subprocess.run(
        [sys.executable, "-m", "imudiag", "bench", "drive-aided"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert proc.returncode == 1, proc.stderr
    assert "imudiag bench: gpsd exited with status 1 at start" in proc.stderr


def test_missing_gpsd_refuses_with_the_packages_named(tmp_path: Path) -> None:
    env = dict(os.environ, **{GPSD_ENV: str(tmp_path / "no-gpsd")})
    proc = subprocess.run(
        [sys.executable, "-m", "imudiag", "bench", "drive-aided"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert proc.returncode == 2, proc.stderr
    assert "package gpsd" in proc.stderr and "apt-get install gpsd" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_missing_pyubx2_refuses_with_the_pip_command(tmp_path: Path) -> None:
    from tests.conftest import run_imudiag_without

    if WHY_NOT is not None and "pyubx2" not in WHY_NOT:
        pytest.skip(WHY_NOT)  # gpsd itself is missing: that message comes first
    proc = run_imudiag_without("pyubx2", "bench", "drive-aided")
    assert proc.returncode == 2, proc.stderr
    assert "'pyubx2'" in proc.stderr and "pip install 'imudiag[gnss]'" in proc.stderr


def test_drive_aided_scenario_loads() -> None:
    sc = load_bundled("drive-aided")
    assert sc.motion == "highway" and sc.motion_params == {"length": "300"}
    assert sc.aiding is not None
    assert sc.aiding.rate_hz == 5.0 and sc.aiding.in_use_within == 30.0
    (inj,) = sc.sensor_injections
    assert inj.sensor == "az" and inj.value == 63.0
    assert inj.expect[0].group is True


def test_group_expectations_match_a_moving_base_group() -> None:
    e = Expectation("accel", "bias", "az", group=True)
    group = {"triad": "accel", "sensor": "az|az", "cause": "bias|scale_factor"}
    assert e.matches(group)
    assert e.matches({"triad": "accel", "sensor": "az", "cause": "bias"})
    assert not e.matches({"triad": "accel", "sensor": "ax|ax", "cause": "bias|misalignment"})
    assert not e.matches({"triad": "gyro", "sensor": "az|az", "cause": "bias|scale_factor"})
    # without group: a group does not name the fault
    assert not Expectation("accel", "bias", "az").matches(group)


BASE = "duration: 60\nmotion: drive\nmotion_params: {route: urban}\n"


@pytest.mark.parametrize(
    ("text", "where", "reason"),
    [
        ("duration: 5\naiding: {rate_hz: 5}\n", ":2: aiding", "needs a drive motion"),
        (BASE + "aiding: {rate: 5}\n", ":4: aiding.rate", "unknown key"),
        (BASE + "aiding: {rate_hz: 0}\n", ":4: aiding.rate_hz", "out of range"),
        (BASE + "aiding: {in_use_within: 90}\n", ":4: aiding.in_use_within", "out of range"),
        (BASE + "daemon:\n  aiding: gpsd://127.0.0.1:2947\n", ":5: daemon.aiding", "aiding:"),
        (
            BASE + "injections:\n  - t: 2\n    kind: bias\n    sensor: az\n    value: 63\n"
            "    expect:\n      - {triad: accel, cause: bias, group: yes please}\n",
            ":10: injections[0].expect[0].group",
            "expected true or false",
        ),
        ("duration: 60\nmotion: drive\n", ":2: motion", "needs motion_params.route"),
        (
            "duration: 400\nmotion: drive\nmotion_params: {route: hilly, length: 300}\n"
            "aiding: {}\n",
            ":1: duration",
            "longer than the hilly drive of seed 0",
        ),
        (
            "duration: 60\nmotion: drive\nmotion_params: {route: moon}\n",
            ":3: motion_params.route",
            "expected one of urban, highway, hilly, aircraft",
        ),
        (
            "duration: 60\nmotion: drive\nmotion_params: {route: urban, dwell: 3}\n",
            ":3: motion_params.dwell",
            "unknown parameter of motion urban",
        ),
    ],
)
def test_bad_aiding_sections_name_file_line_key_and_reason(
    text: str, where: str, reason: str
) -> None:
    with pytest.raises(ScenarioError) as err:
        loads(text, "s.yaml")
    message = str(err.value)
    assert message.startswith("s.yaml" + where), message
    assert reason in message


def test_an_aiding_section_takes_the_receiver_settings() -> None:
    sc = loads(
        textwrap.dedent(
            """\
            duration: 60
            motion: hilly
            aiding: {rate_hz: 10, sigma_h_m_s: 0.01, latency_s: 0.05, in_use_within: 20}
            """
        ),
        "s.yaml",
    )
    assert sc.aiding is not None
    cfg = sc.aiding.gnss_config()
    assert (cfg.rate_hz, cfg.sigma_h_m_s, cfg.sigma_v_m_s, cfg.latency_s) == (
        10.0,
        0.01,
        0.05,
        0.05,
    )
    assert loads("duration: 60\nmotion: hilly\n", "s.yaml").aiding is None
    # motion: drive with a route is the same scenario as the route's name
    assert loads(BASE, "s.yaml").motion == loads("duration: 60\nmotion: urban\n").motion
