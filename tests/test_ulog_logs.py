"""PX4 ULog flight logs, read through pyulog: real files from pyulog's own test data.

tests/data/real/px4-ulog/ (SOURCE.md and LICENSE.md there): ``sample.ulg`` (69 s,
``sensor_combined`` only) and ``sample_log_small.ulg`` (raw ``sensor_gyro`` /
``sensor_accel`` of 3 instances at 1 Hz beside ``sensor_combined`` at 205 Hz).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag, run_imudiag_in_process, run_imudiag_without

from imudiag.logs import LogError, LogOptions, lookup, open_log, read_log

DATA = Path(__file__).parent / "data" / "real" / "px4-ulog"
SAMPLE = DATA / "sample.ulg"
SMALL = DATA / "sample_log_small.ulg"


def test_ulg_is_found_by_extension_and_magic():
    assert lookup(SAMPLE).name == ".ulg"
    assert SAMPLE.read_bytes()[:7] == b"ULog\x01\x12\x35"


def test_sensor_combined_is_read_in_si_with_its_source_named():
    with open_log(SAMPLE) as reader:
        blocks = list(reader)
        meta = dict(reader.meta)
    s = blocks[0].concat(blocks)
    assert len(s) == 17070
    assert meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
    assert meta["source"].startswith("sensor_combined, 250 Hz")
    assert "no raw sensor_gyro/sensor_accel topics" in meta["source"]
    assert 245 < meta["sample_rate"] < 255  # the median step (the mean is 247 Hz: gaps)
    assert np.all(np.diff(s.t) > 0) and s.t[0] >= 0.0
    # a flight log: |f| about g on the median, gyro rates of a flying vehicle
    a = np.linalg.norm(s.accel, axis=1)
    assert 9.5 < float(np.median(a)) < 10.1
    assert float(np.max(np.abs(s.gyro))) < 20.0  # rad/s


def test_raw_topics_at_1_hz_are_not_chosen_unless_asked():
    with open_log(SMALL) as reader:
        n = sum(len(b) for b in reader)
        source = reader.meta["source"]
    assert source.startswith("sensor_combined")
    assert "instances 0, 1, 2" in source and "--instance N reads them" in source
    assert n > 1000
    raw = read_log_with(SMALL, LogOptions(instance=1))
    assert 4 <= len(raw) <= 6
    assert raw.temp is not None and np.all(np.isfinite(raw.temp))
    assert 9.0 < float(np.median(np.linalg.norm(raw.accel, axis=1))) < 10.6


def read_log_with(path: Path, options: LogOptions):
    with open_log(path, options=options) as reader:
        blocks = list(reader)
        assert reader.meta["source"].startswith(
            f"sensor_gyro/sensor_accel instance {options.instance}"
        )
    return blocks[0].concat(blocks)


def test_unknown_instance_lists_the_ones_there():
    with pytest.raises(LogError, match=r"--instance 7: .*instances with both: 0, 1, 2"):
        open_log(SMALL, options=LogOptions(instance=7))


def test_a_truncated_ulog_or_a_foreign_file_is_exit_2(tmp_path):
    bad = tmp_path / "notes.ulg"
    bad.write_text("not a flight log\n")
    r = run_imudiag("allan", str(bad))
    assert r.returncode == 2 and "not a ULog file" in r.stderr and str(bad) in r.stderr


def test_commands_take_a_ulog_and_say_which_topic(tmp_path):
    out = tmp_path / "flight.csv"
    r = run_imudiag("convert", str(SAMPLE), str(out))
    assert r.returncode == 0, r.stderr
    back = read_log(out)
    assert len(back) == 17070
    # the converted log says where its samples came from, and in which units
    head = out.read_text().splitlines()[:4]
    assert "# source: sensor_combined, 250 Hz" in head[0]
    assert head[1] == "# units: gyro=rad/s accel=m/s^2"  # the spec's line (issue 27)
    # the first conversion is the real subprocess, the other commands in process
    r = run_imudiag_in_process("convert", str(SMALL), str(tmp_path / "raw.csv"), "--instance", "2")
    assert r.returncode == 0, r.stderr
    assert len(read_log(tmp_path / "raw.csv")) <= 6
    r = run_imudiag_in_process("allan", str(SAMPLE), "--json", str(tmp_path / "a.json"))
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "a.json").read_text())
    assert report["rate_hz"] == pytest.approx(250, abs=5) and report["gaps"] == 8


def test_missing_pyulog_is_exit_2_with_the_pip_command():
    r = run_imudiag_without("pyulog", "allan", str(SAMPLE))
    assert r.returncode == 2, r.stderr
    assert "'pyulog'" in r.stderr and "pip install 'imudiag[px4]'" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_ulog_in_si_against_a_certificate_in_counts_names_both_units(tmp_path):
    # in process: test_a_truncated_ulog_or_a_foreign_file_is_exit_2 refuses a ULog in a real
    # subprocess, test_text_tables.py a log in SI against a certificate in counts
    r = run_imudiag_in_process("diagnose", str(SAMPLE), "--json", str(tmp_path / "d.json"))
    assert r.returncode == 2
    assert "'rad/s'" in r.stderr and "'count'" in r.stderr
    assert not (tmp_path / "d.json").exists()


def test_a_ulog_read_again_is_not_parsed_again_until_it_changes(tmp_path):
    """A diagnosis reads a log twice and a fleet once per instance: pyulog's parse is kept
    (read only) while the file's size and modification time are unchanged, and a reader
    from it gives what a cold one gives."""
    import shutil

    from imudiag.logs import ulog

    log = shutil.copy(SMALL, tmp_path / "small.ulg")
    first = read_log_with(log, LogOptions(instance=1))
    kept = ulog._LAST.get(log, "imu+gps", lambda: pytest.fail("parsed again"))
    start, topics = kept
    with pytest.raises(ValueError, match="read-only"):
        topics[("sensor_gyro", 1)]["x"][0] = 0.0
    again = read_log_with(log, LogOptions(instance=1))
    ulog._LAST.forget()
    cold = read_log_with(log, LogOptions(instance=1))
    for got in (again, cold):
        np.testing.assert_array_equal(got.gyro, first.gyro)
        np.testing.assert_array_equal(got.accel, first.accel)
        np.testing.assert_array_equal(got.t, first.t)
    shutil.copy(SAMPLE, log)  # another log written over the same path
    with open_log(log) as reader:
        assert sum(len(b) for b in reader) == 17070
    assert ulog._LAST.get(log, "imu+gps", lambda: pytest.fail("parsed again")) is not kept
