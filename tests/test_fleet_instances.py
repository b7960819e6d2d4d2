"""The fleet diagnoses every IMU instance of a multi-IMU log (issue 28 item 1, docs/fleet.md):
a DataFlash log's IMU 0, 1..., a ULog's raw instances where they are logged at the IMU's
rate. Redundant IMUs are where a single unit fails while its twins agree; before, the
fleet diagnosed the lowest instance alone and never saw the other.

A hidden fault is picked under a fixed seed from a catalogue (parameter and size, and which
of the two IMUs has it) and put in one instance of a simulated multi-position session
written as a two-IMU DataFlash log (ArduPilot's format, checked by pymavlink's reader:
tests/test_dataflash_logs.py); the fleet's per-log task must name that IMU, triad, sensor
and cause, and nothing on the other IMU. On the real logs: pymavlink's test.BIN has IMU 0
and IMU 1 at 50 Hz, both diagnosed; PX4's sample_log_small.ulg logs its three raw
instances at 1 Hz beside sensor_combined at 205 Hz, so they are listed as skipped with the
reason, not diagnosed.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import PROJECT_DIR
from test_dataflash_logs import write_dataflash

from imudiag.certificate import load
from imudiag.fleet.task import Job, diagnose_log
from imudiag.fleet.trends import label, summarize
from imudiag.sim import Fault, multi_position, simulate

CERT = PROJECT_DIR / "tests" / "data" / "diagnosis" / "like-px4.yaml"
REAL = PROJECT_DIR / "tests" / "data" / "real"
SEED = 2811
#: (triad, cause): the hidden faults a multi-position session determines, of 4 limits
CATALOGUE = [("accel", "bias"), ("accel", "scale_factor"), ("gyro", "bias")]
SENSORS = {"accel": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz")}


def _job(log: Path, root: Path) -> Job:
    st = log.stat()
    return Job(str(log), "-", st.st_size, st.st_mtime_ns, str(root), certificate=str(CERT))


@pytest.fixture(scope="module")
def hidden(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, tuple[int, str, str, str]]:
    """The record of a two-IMU DataFlash log with one hidden fault in one instance (24
    attitudes of 3 s at 100 Hz, 107 s: a fault of 4 limits is confirmed over two windows;
    12 attitudes of 4 s, 65 s, left it a candidate)."""
    rng = np.random.default_rng(SEED)
    triad, cause = CATALOGUE[rng.integers(len(CATALOGUE))]
    sensor = SENSORS[triad][rng.integers(3)]
    faulty = int(rng.integers(2))
    cert = load(CERT)
    model = cert.triad(triad)
    limit = {"bias": model.limits.bias, "scale_factor": model.limits.scale_factor_error}[cause]
    size = 4.0 * float(limit["xyz".index(sensor[1])])
    traj = multi_position(n_attitudes=24, dwell_s=3.0, turn_s=1.5, rate_hz=100, seed=SEED)
    imus = {
        i: simulate(
            cert,
            traj,
            seed=SEED + 1 + i,
            faults=[Fault(cause, sensor, 0.0, size)] if i == faulty else [],
        ).samples
        for i in (0, 1)
    }
    root = tmp_path_factory.mktemp("instances")
    (root / "uav-7").mkdir()
    log = write_dataflash(root / "uav-7" / "00000012.BIN", imus[0], each=imus)
    return diagnose_log(_job(log, root)), (faulty, triad, sensor, cause)


def test_the_hidden_fault_is_named_on_its_imu_alone(hidden) -> None:
    record, (faulty, triad, sensor, cause) = hidden
    assert record["status"] == "ok", record["reason"]
    assert record["instance"] == 0
    (other,) = record["instances"]
    assert other["instance"] == 1 and other["status"] == "ok", other["reason"]
    verdicts = {0: record["report"]["verdict"], 1: other["report"]["verdict"]}
    named = {
        i: {(f["triad"], f["sensor"], f["cause"]) for f in v["faults"] if f["cause"] != "f0"}
        for i, v in verdicts.items()
    }
    assert (triad, sensor, cause) in named[faulty], (faulty, verdicts[faulty])
    assert named[1 - faulty] == set(), (1 - faulty, verdicts[1 - faulty])
    assert verdicts[1 - faulty]["accel"] == verdicts[1 - faulty]["gyro"] == "ok"
    # each parameter carries its instance, in the record and in the summary's reasons
    assert {p["instance"] for p in record["parameters"]} == {0}
    assert {p["instance"] for p in other["parameters"]} == {1}
    (vehicle,) = summarize([record])["vehicles"]
    assert vehicle["vehicle"] == "uav-7" and vehicle["look_at"] is True
    reasons = {(r["instance"], r["triad"], r["sensor"], r["cause"]) for r in vehicle["reasons"]}
    assert (faulty, triad, sensor, cause) in reasons
    assert all(r[0] == faulty for r in reasons), reasons
    picked = [r for r in vehicle["reasons"] if r["sensor"] == sensor and r["cause"] == cause]
    assert label(picked[0]) == f"IMU {faulty} {triad} {sensor} {cause}"
    json.dumps(record, allow_nan=False)  # the records file's writer: strict JSON


def test_a_real_two_imu_ardupilot_log_has_both_diagnosed(tmp_path: Path) -> None:
    (tmp_path / "copter").mkdir()
    log = tmp_path / "copter" / "test.BIN"
    shutil.copy(REAL / "ardupilot-dataflash" / "test.BIN", log)
    record = diagnose_log(_job(log, tmp_path))
    assert record["status"] == "ok", record["reason"]
    assert record["instance"] == 0
    (other,) = record["instances"]
    assert other["instance"] == 1 and other["status"] == "ok" and other["rate_hz"] == 49.94
    assert other["samples"] == record["samples"] == 45
    assert other["report"]["log"] == record["report"]["log"]


def test_raw_instances_logged_far_below_the_imu_rate_are_skipped_with_the_reason(
    tmp_path: Path,
) -> None:
    (tmp_path / "px4").mkdir()
    log = tmp_path / "px4" / "sample_log_small.ulg"
    shutil.copy(REAL / "px4-ulog" / log.name, log)
    record = diagnose_log(_job(log, tmp_path))
    assert record["status"] == "ok", record["reason"]
    assert record["instance"] is None  # sensor_combined: the primary IMU, no instance
    assert [i["instance"] for i in record["instances"]] == [0, 1, 2]
    for item in record["instances"]:
        assert item["status"] == "skipped" and item["report"] is None
        assert item["reason"] == (
            f"logged at {item['rate_hz']} Hz, below 0.5 of the log's IMU rate (204.583 Hz): "
            "not diagnosed"
        )


def test_an_instance_past_the_time_limit_keeps_the_logs_own_report() -> None:
    """The per-log time limit running out while another IMU instance is diagnosed makes
    that instance an error with the reason; the log's report, made before, stays (the
    whole record used to become a timeout error)."""
    from imudiag.fleet.task import LogTimeout, other_instances

    meta = {
        "instance": 0,
        "sample_rate": 100.0,
        "imu_instances": [{"instance": i, "rate_hz": 100.0} for i in (0, 1, 2)],
    }

    def late(number: int) -> dict:
        raise LogTimeout("timeout: the diagnosis ran past 60 s (while fitting windows)")

    items = other_instances(meta, load(CERT), late)
    assert [(i["instance"], i["status"]) for i in items] == [(1, "error"), (2, "error")]
    assert items[0]["reason"] == (
        "instance 1: timeout: the diagnosis ran past 60 s (while fitting windows)"
    )
    assert items[0]["report"] is None and items[0]["parameters"] == []


def test_a_stuck_output_puts_its_unit_on_the_look_at_list(tmp_path: Path) -> None:
    """gy frozen at t = 20 s of a log: the fleet's record holds the stuck fault that
    ``diagnose`` names (before 2026-11-29 its verdict held none: the unit was not listed),
    and the vehicle is to be looked at for it, the reason saying where it was raised."""
    from imudiag.certificate import load_default
    from imudiag.logs import open_writer

    bundled = PROJECT_DIR / "config" / "default-certificate.yaml"
    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=7)
    frozen = simulate(load_default(), traj, seed=8, faults=[Fault("stuck", "gy", 20.0, None)])
    (tmp_path / "rover-3").mkdir()
    log = tmp_path / "rover-3" / "run-01.csv"
    with open_writer(log, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(frozen.samples)
    st = log.stat()
    job = Job(str(log), "-", st.st_size, st.st_mtime_ns, str(tmp_path), certificate=str(bundled))
    record = diagnose_log(job)
    assert record["status"] == "ok", record["reason"]
    stuck = [f for f in record["report"]["verdict"]["faults"] if f["cause"] == "stuck"]
    assert [(f["triad"], f["sensor"]) for f in stuck] == [("gyro", "gy")]
    (vehicle,) = summarize([record])["vehicles"]
    assert vehicle["vehicle"] == "rover-3" and vehicle["look_at"] is True
    (reason,) = [r for r in vehicle["reasons"] if r["cause"] == "stuck"]
    assert (reason["triad"], reason["sensor"]) == ("gyro", "gy")
    assert reason["why"].startswith("raised as a fault from log 1 of 1")
    json.dumps(record, allow_nan=False)
