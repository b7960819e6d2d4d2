"""``--certificate auto`` on autopilot logs: a PX4 ULog and an ArduPilot DataFlash log name
their IMU's class (the flight controller's MEMS IMU in SI units, as a MAVLink autopilot's
stream does: the bundled data-sheet certificate mavlink-fc-imu), so `diagnose`, the
daemon replaying the log and the fleet take the same certificate from the log itself. A log
that names none is refused with one line naming it (exit 2). Before, a folder of autopilot
logs against the bundled certificate (the simulated board, in counts) was one units error
per log, and nothing a fleet operator could run without writing a certificate first.

Real logs: pyulog's sample.ulg (tests/data/real/px4-ulog) and pymavlink's test.BIN
(tests/data/real/ardupilot-dataflash); SOURCE.md in each folder.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from conftest import PROJECT_DIR

import imudiag
from imudiag.certificate import FLIGHT_CONTROLLER_DATASHEET, datasheet_path
from imudiag.cli import main
from imudiag.errors import BadInput
from imudiag.fleet.task import Job, diagnose_log
from imudiag.logs import read_log
from imudiag.service.daemon import Daemon, DaemonSettings
from tests.helpers import CollectSink

REAL = PROJECT_DIR / "tests" / "data" / "real"
ULOG = REAL / "px4-ulog" / "sample.ulg"
DATAFLASH = REAL / "ardupilot-dataflash" / "test.BIN"
CSV = REAL / "mpu6050" / "rot90x.csv.gz"


@pytest.mark.parametrize("log", [ULOG, DATAFLASH], ids=["px4-ulog", "ardupilot-dataflash"])
def test_diagnose_and_the_daemon_take_the_data_sheet_the_log_names(log: Path) -> None:
    sheet = datasheet_path(FLIGHT_CONTROLLER_DATASHEET)
    auto = imudiag.diagnose(log, "auto", windows=False)
    named = imudiag.diagnose(log, sheet, windows=False)
    assert auto["certificate"] == named["certificate"] == str(sheet)
    assert auto["verdict"] == named["verdict"]
    assert auto["f0"] == named["f0"]
    # the daemon replaying the log takes it from the log's device identity: one answer
    sink = CollectSink()
    url = f"replay://{log}?speed=0&step=2"
    assert Daemon(DaemonSettings(source_url=url, certificate_path="auto"), [sink]).run() == 0
    last = [s for s in sink.lines if s["t"] is not None][-1]
    assert last["device"]["datasheet"] == FLIGHT_CONTROLLER_DATASHEET
    for triad in ("accel", "gyro"):
        assert last["verdict"][triad] == auto["verdict"][triad]
        assert last["f0"][triad]["checked"] == auto["f0"][triad]["checked"]


def test_a_log_that_names_no_data_sheet_is_refused_naming_it(capsys) -> None:
    assert main(["diagnose", str(CSV), "--certificate", "auto"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"imudiag diagnose: error: {CSV}: --certificate auto: the log names no data-sheet "
        "certificate (autopilot logs do: PX4 ULog, ArduPilot DataFlash); give a certificate "
        "file (--certificate PATH)"
    ]
    with pytest.raises(BadInput, match="a data-sheet certificate is named by a log file"):
        imudiag.diagnose(read_log(CSV), "auto")


def test_the_fleet_takes_each_logs_data_sheet(tmp_path: Path) -> None:
    records = {}
    for log in (DATAFLASH, CSV):
        copy = tmp_path / log.parent.name / log.name
        copy.parent.mkdir()
        shutil.copy(log, copy)
        st = copy.stat()
        job = Job(str(copy), "-", st.st_size, st.st_mtime_ns, str(tmp_path), certificate="auto")
        records[log] = diagnose_log(job)
    flown = records[DATAFLASH]
    assert flown["status"] == "ok", flown["reason"]
    assert flown["certificate"] == str(datasheet_path(FLIGHT_CONTROLLER_DATASHEET))
    assert flown["certificate_source"] == "--certificate: the log's data sheet"
    bench = records[CSV]
    assert bench["status"] == "error"
    assert bench["reason"].startswith(
        f"loading the certificate: {bench['path']}: --certificate auto: the log names no "
        "data-sheet certificate"
    )


def test_a_units_refusal_on_an_autopilot_log_points_at_auto(capsys) -> None:
    """The bundled certificate (counts) against a ULog (SI) is refused as before, and the
    one line now names the way out the log itself offers."""
    assert main(["diagnose", str(ULOG)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"imudiag diagnose: error: {ULOG}: units: the gyro outputs are in")
    assert line.endswith("; or --certificate auto (the 'mavlink-fc-imu' data sheet the log names)")
