"""The fleet's per-log task and per-vehicle summary on real recordings (docs/fleet.md).

Three real MPU-6050 logs (tests/data/real/mpu6050: a 449-s still record, a 102-s
calibration session, a 90-degree turn) sit in one vehicle's folder, diagnosed against the
bundled board certificate, whose accelerometer noise the MPU's (51-77 counts a sample,
digital low-pass filter off) far exceeds: every log raises the accelerometers' ``noise``
faults. A fault with no parameter estimate behind it (``noise``, ``stuck``,
``saturation``) has no limit in the trend; the summary crashed formatting that missing
limit (``imudiag fleet tests/data/real`` ended in a TypeError and wrote no ``fleet.json``).

Here, in process (no Dask: tests/test_fleet.py runs the cluster): each record's verdict is
``imudiag.diagnose``'s on the same log and certificate (one answer), the vehicle is to be
looked at for the three noise faults with the log they were first raised in, the reasons
say so in words, and the HTML report renders them.
"""

from __future__ import annotations

import shutil
from datetime import datetime
from pathlib import Path

import pytest
from conftest import PROJECT_DIR

import imudiag
from imudiag.certificate import default_certificate_path
from imudiag.fleet.html import render
from imudiag.fleet.identity import GNSS_CLOCK_START
from imudiag.fleet.task import Job, diagnose_log
from imudiag.fleet.trends import summarize

REAL = PROJECT_DIR / "tests" / "data" / "real" / "mpu6050"
#: time order of the vehicle's logs (no start time in a CSV: ordered by path)
LOGS = ("calibration.csv.gz", "rot90x.csv.gz", "static.csv.gz")
#: the small PX4 ULog's topics read by pyulog to check the start the fleet gives it
GPS_AND_IMU = ["vehicle_gps_position", "sensor_combined"]


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> list[dict]:
    """The three logs copied into a vehicle folder ``mpu-01`` and diagnosed by the fleet's
    per-log task, each with the bundled certificate."""
    root = tmp_path_factory.mktemp("fleet-real")
    unit = root / "mpu-01"
    unit.mkdir()
    out = []
    for name in LOGS:
        log = unit / name
        shutil.copy(REAL / name, log)
        st = log.stat()
        out.append(diagnose_log(Job(str(log), "-", st.st_size, st.st_mtime_ns, str(root))))
    return out


def test_each_record_gives_the_verdict_of_diagnose(records: list[dict]) -> None:
    for rec in records:
        assert rec["status"] == "ok", rec["reason"]
        assert rec["vehicle"] == "mpu-01"
        assert Path(rec["certificate"]) == default_certificate_path()
        report = imudiag.diagnose(rec["path"], default_certificate_path())
        fleet, alone = rec["report"]["verdict"], report["verdict"]
        assert fleet["accel"] == alone["accel"] == "fault"
        assert fleet["gyro"] == alone["gyro"]
        assert {(f["triad"], f["sensor"], f["cause"]) for f in fleet["faults"]} == {
            (f["triad"], f["sensor"], f["cause"]) for f in alone["faults"]
        }


def test_a_fault_without_a_parameter_ranks_the_unit_with_its_log(records: list[dict]) -> None:
    summary = summarize(records)
    assert summary["logs"] == 3 and summary["errors"] == []
    (vehicle,) = summary["vehicles"]
    assert vehicle["vehicle"] == "mpu-01" and vehicle["look_at"] is True
    noise = {r["sensor"]: r for r in vehicle["reasons"] if r["cause"] == "noise"}
    assert set(noise) == {"ax", "ay", "az"}
    first = records[0]["path"]
    for r in noise.values():
        assert r["triad"] == "accel"
        assert r["limit"] is None and r["unit"] is None  # no estimate, no limit to state
        assert r["crosses_limit"] == first and r["crosses_limit_index"] == 0
        assert r["logs_beyond"] == 3  # raised in every log, not in the first alone
        assert r["why"] == f"raised as a fault from log 1 of 3 ({first}), in 3 of the 3"
    html = render(summary, records)
    assert "mpu-01" in html and "raised as a fault from log 1 of 3" in html


def test_a_value_not_determined_is_null_in_the_record_as_in_diagnose_json(
    tmp_path: Path,
) -> None:
    """The small real PX4 ULog (1298 samples, its own GNSS: the moving-base section) has no
    straight epochs, so the forward axis is not determined (NaN in the report): the record
    must be strict JSON with null there, as ``imudiag diagnose --json`` writes it (the run
    ended in 'Out of range float values are not JSON compliant' writing logs.jsonl). Its
    start, which the log does not state, is the UTC of its first sample through the
    diagnosis's tie of the log clock to the GNSS fixes' UTC."""
    import json

    from imudiag.reports import json_text

    unit = tmp_path / "px4"
    unit.mkdir()
    log = unit / "sample_log_small.ulg"
    shutil.copy(PROJECT_DIR / "tests" / "data" / "real" / "px4-ulog" / log.name, log)
    cert = PROJECT_DIR / "tests" / "data" / "diagnosis" / "like-px4.yaml"
    shutil.copy(cert, unit / "certificate.yaml")
    st = log.stat()
    rec = diagnose_log(Job(str(log), "-", st.st_size, st.st_mtime_ns, str(tmp_path)))
    assert rec["status"] == "ok", rec["reason"]
    text = json.dumps(rec, allow_nan=False)  # the records file's writer: strict JSON
    forward = json.loads(text)["report"]["moving_base"]["gyro_turns"]["forward_axis"]
    assert forward["determined"] is False and forward["axis_body"] == [None, None, None]
    # the log names no start (no time_ref_utc): its GNSS time gives it. Checked against
    # pyulog's own reading: the first fix's UTC (time_utc_usec) less its boot-time lead
    # over the first IMU sample (the fixes' UTC and boot stamps agree to about 10 ms)
    from pyulog import ULog

    topics = {d.name: d.data for d in ULog(str(log), GPS_AND_IMU).data_list}
    gps, imu = topics["vehicle_gps_position"], topics["sensor_combined"]
    utc_first_sample_s = (
        gps["time_utc_usec"][0] - (gps["timestamp"][0] - imu["timestamp"][0])
    ) / 1e6
    assert rec["start_source"] == GNSS_CLOCK_START
    start = datetime.fromisoformat(rec["start"]).timestamp()
    assert abs(start - utc_first_sample_s) < 0.05, (rec["start"], utc_first_sample_s)
    assert rec["start"].startswith("2021-04-21T06:30:58")
    alone = json.loads(json_text(imudiag.diagnose(log, cert)))
    assert alone["moving_base"]["gyro_turns"]["forward_axis"] == forward
    assert alone["verdict"] == json.loads(text)["report"]["verdict"]


def test_failed_logs_are_grouped_by_their_reason(tmp_path: Path) -> None:
    """Real logs in SI units against the bundled certificate (counts) fail alike: one kind
    of reason with the log's path as LOG, counted, the commonest first; the report says it."""
    for name in ("imucal-ferraris/session.csv.gz", "firm-rocket-launch/flight.csv.gz"):
        (tmp_path / name).parent.mkdir()
        shutil.copy(PROJECT_DIR / "tests" / "data" / "real" / name, tmp_path / name)
    (tmp_path / "bad" / "x.npz").parent.mkdir()
    (tmp_path / "bad" / "x.npz").write_bytes(b"not a zip")
    recs = []
    for log in sorted(tmp_path.rglob("*.*")):
        st = log.stat()
        recs.append(diagnose_log(Job(str(log), "-", st.st_size, st.st_mtime_ns, str(tmp_path))))
    summary = summarize(recs)
    kinds = summary["error_kinds"]
    assert [k["logs"] for k in kinds] == [2, 1]
    units, npz = kinds
    assert units["reason"].startswith("diagnosing: LOG: units: the gyro outputs are in 'deg/s'")
    assert units["first"] in {r["path"] for r in recs}
    assert npz["reason"].startswith("reading the log: LOG: ") and npz["first"].endswith("x.npz")
    html = render(summary, recs)
    assert 'id="error-kinds"' in html and "2 x diagnosing: LOG: units:" in html


def _every_real_recording() -> dict[str, tuple[Path, Path]]:
    """The real recordings shipped, each with its certificate (tests/test_exact_fit_kernel.py's
    table, that of tests/test_one_answer.py with the MPU-6050's still hold)."""
    pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")
    from tests.test_exact_fit_kernel import REAL_LOGS

    return REAL_LOGS


@pytest.mark.parametrize(
    "name",
    [
        "gnss-imu-drive", "xsens", "imucal", "mpu6050-calibration", "mpu6050-rot90x",
        "mpu6050-static", "px4-ulog", "ardupilot-dataflash", "firm-rocket", "x-io-ngimu",
        "x-io-ximu3",
    ],
)  # fmt: skip
def test_the_fleet_task_with_the_kernels_agrees_with_diagnose(name: str) -> None:
    """Issue 28: the fleet's per-log task runs the compiled kernels (its record says so),
    ``imudiag diagnose`` the plain loops; on every real recording with its certificate the
    record's report (windows dropped) equals the plain report within the reports'
    cross-processor tolerance, the verdicts, named faults and causes identical, and its kept
    parameters are the plain report's. (The 12th, the MT Manager export, needs read options
    a fleet job has no place for: tests/test_exact_fit_kernel.py diagnoses it both ways.)"""
    import json

    from imudiag import kernels
    from imudiag.fleet.task import kept
    from imudiag.reports import json_text
    from tests.test_exact_fit_kernel import assert_reports_agree

    log, cert = _every_real_recording()[name]
    st = log.stat()
    job = Job(str(log), "-", st.st_size, st.st_mtime_ns, str(log.parent), certificate=str(cert))
    rec = json.loads(json.dumps(diagnose_log(job), allow_nan=False))
    assert rec["status"] == "ok", rec["reason"]
    assert rec["kernels"] == "numba"
    with kernels.switched(False):
        loaded = imudiag.api.load_certificate(str(cert))
        alone = json.loads(json_text(imudiag.diagnose(log, loaded)))
    params = kept(alone, loaded, rec["instance"])  # drops the windows, as the record did
    assert_reports_agree(rec["report"], alone)
    verdict = {"verdict": alone["verdict"]}
    assert_reports_agree(
        {"parameters": rec["parameters"], **verdict}, {"parameters": params, **verdict}
    )
