"""``imudiag calibrate LOG --like auto``: an autopilot's log names its IMU's class (the
flight controller's MEMS IMU, the bundled data sheet mavlink-fc-imu, as ``--certificate
auto`` takes it), so a calibration flight of a PX4 or ArduPilot vehicle calibrates against
that data sheet without a certificate file. The certificate written is this unit's
calibration, no longer a data sheet: it carries no ``datasheet`` key (the daemon's status
would call it "the part's typical figures, not this unit's calibration") and says in its
``calibration`` which data sheet it was made like. A log that names none is refused in one
line naming ``--like``, exit 2.

The log: an ArduPilot DataFlash log (tests/test_dataflash_logs.py's writer, checked by
pymavlink's reader) of a simulated 24-attitude session of a unit whose az bias is 3 of the
data sheet's limits off its nominal 0 (seeded).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import REAL_DATA_DIR, run_imudiag, run_imudiag_in_process
from test_dataflash_logs import write_dataflash

from imudiag.certificate import FLIGHT_CONTROLLER_DATASHEET, datasheet_path, load
from imudiag.service.status import certificate_object
from imudiag.sim import multi_position, simulate

SEED = 29
OFF_LIMITS = 3.0  #: the unit's az bias off the data sheet's nominal, in its limits


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """(DataFlash log of the calibration session, the unit's true az bias in m/s^2)."""
    sheet = load(datasheet_path(FLIGHT_CONTROLLER_DATASHEET))
    unit = sheet.copy()
    unit.accel.bias = unit.accel.bias + np.array([0.0, 0.0, OFF_LIMITS]) * sheet.accel.limits.bias
    traj = multi_position(n_attitudes=24, dwell_s=3.0, turn_s=1.5, rate_hz=100, seed=SEED)
    samples = simulate(unit, traj, seed=SEED + 1).samples
    d = tmp_path_factory.mktemp("like-auto")
    log = write_dataflash(d / "00000007.BIN", samples, each={0: samples})
    return log, float(unit.accel.bias[2])


def test_calibrate_like_auto_writes_this_units_calibration(flight, tmp_path: Path) -> None:
    log, true_az = flight
    out, summary = tmp_path / "cal.yaml", tmp_path / "cal.json"
    r = run_imudiag(
        "calibrate", str(log), "--like", "auto", "--out", str(out), "--json", str(summary)
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(summary.read_text())["like"] == "auto"
    cal = load(out)
    sheet = load(datasheet_path(FLIGHT_CONTROLLER_DATASHEET))
    assert "datasheet" not in cal.device
    assert cal.device["calibration"].endswith(
        f"; like the data sheet {FLIGHT_CONTROLLER_DATASHEET}"
    )
    # scale factors, units and limits from the data sheet; the bias found
    assert cal.accel.output_unit == sheet.accel.output_unit == "m/s^2"
    np.testing.assert_array_equal(cal.accel.limits.bias, sheet.accel.limits.bias)
    assert abs(cal.accel.bias[2] - true_az) < 0.1 * sheet.accel.limits.bias[2]
    # the daemon's status takes it as a calibration, not as the part's typical figures
    assert "datasheet" not in certificate_object(cal, 0)
    assert certificate_object(sheet, 0)["datasheet"] == FLIGHT_CONTROLLER_DATASHEET
    # the data sheet itself sees the unit's offset bias; its own calibration sees nothing
    faults = {}
    for name, cert in (("auto", "auto"), ("own", str(out))):
        d = run_imudiag_in_process("diagnose", str(log), "-c", cert, "--json", "-")
        assert d.returncode == 0, d.stderr
        faults[name] = json.loads(d.stdout)["verdict"]["faults"]
    named = {(f["triad"], f["sensor"], f["cause"]) for f in faults["auto"] if f["cause"] != "f0"}
    assert ("accel", "az", "bias") in named
    assert faults["own"] == []


def test_like_auto_on_a_log_that_names_no_data_sheet_is_refused_naming_like(
    tmp_path: Path,
) -> None:
    log = REAL_DATA_DIR / "mpu6050" / "calibration.csv.gz"
    out = tmp_path / "cal.yaml"
    r = run_imudiag_in_process("calibrate", str(log), "--like", "auto", "--out", str(out))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"imudiag calibrate: error: {log}: --like auto: the log names no data-sheet "
        "certificate (autopilot logs do: PX4 ULog, ArduPilot DataFlash); give a certificate "
        "file (--like PATH)"
    ]
    assert not out.exists()
