"""ArduPilot DataFlash logs, read through pymavlink's DFReader.

One real log is shipped: pymavlink's own test.BIN (tests/data/real/ardupilot-dataflash,
SOURCE.md there), read as pymavlink reads it. pymavlink cannot write a log, so the other
files here are written byte for byte to ArduPilot's self-describing format (FMT messages, then
``A3 95 id payload`` records, as AP_Logger writes them) holding the real imucal
recording (tests/data/real/imucal-ferraris, SOURCE.md there) as ``IMU`` messages in
rad/s and m/s^2; every file is first checked with pymavlink's own reader.
"""

from __future__ import annotations

import gc
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag, run_imudiag_in_process, run_imudiag_without
from pymavlink import DFReader  # the [test] extra installs pymavlink

from imudiag.logs import LogError, LogOptions, lookup, open_log, read_log
from imudiag.samples import SampleBlock

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
HEAD = b"\xa3\x95"
#: IMU as current ArduPilot logs it (instance field I), and the older per-instance names
IMU_FMT, IMU_COLS = "QBffffffIIfBB", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH"
OLD_FMT, OLD_COLS = "QffffffIIf", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T"


def _fmt(type_id: int, name: str, fmt: str, cols: str) -> bytes:
    # FMT's own format uses DataFlash's n (char[4]), N (char[16]), Z (char[64]): 89 bytes
    length = 89 if name == "FMT" else 3 + struct.calcsize("<" + fmt)
    body = struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), cols.encode())
    return HEAD + bytes([128]) + body


def write_dataflash(path: Path, s, instances=(0, 1), old_names=False, each=None) -> Path:
    """``s`` (deg/s, m/s^2) as IMU messages; instance i's gyro is scaled by 1 + i / 100.
    ``each``: {instance: samples (rad/s, m/s^2)}, written as they are instead."""
    if each is not None:
        instances = tuple(each)
    gyro = np.radians(s.gyro) if each is None else None
    out = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")]
    names = {0: "IMU", 1: "IMU2", 2: "IMU3"}
    if old_names:
        out += [_fmt(131 + i, names[i], OLD_FMT, OLD_COLS) for i in instances]
    else:
        out.append(_fmt(131, "IMU", IMU_FMT, IMU_COLS))
    for k in range(len(s) if each is None else min(map(len, each.values()))):
        us = int(round(s.t[k] * 1e6)) + 5_000_000  # 5 s after boot
        for i in instances:
            g = gyro[k] * (1.0 + i / 100.0) if each is None else each[i].gyro[k]
            a = s.accel[k] if each is None else each[i].accel[k]
            if old_names:
                rec = struct.pack("<" + OLD_FMT, us, *g, *a, 0, 0, 31.5)
                out.append(HEAD + bytes([131 + i]) + rec)
            else:
                rec = struct.pack("<" + IMU_FMT, us, i, *g, *a, 0, 0, 31.5, 1, 1)
                out.append(HEAD + bytes([131]) + rec)
    path.write_bytes(b"".join(out))
    # the reference reader agrees the file is a DataFlash log
    log = DFReader.DFReader_binary(str(path), zero_time_base=True)
    assert log.recv_match(type=["IMU", "IMU2", "IMU3"]) is not None
    log.close()
    return path


@pytest.fixture(scope="module")
def session():
    return read_log(IMUCAL).slice(0, 3000)


def _same(got, s, scale=1.0):
    f32 = np.float32
    assert len(got) == len(s)
    np.testing.assert_allclose(got.t, s.t + 5.0, atol=1e-6)
    np.testing.assert_allclose(got.gyro, (np.radians(s.gyro) * scale).astype(f32), rtol=1e-6)
    np.testing.assert_allclose(got.accel, s.accel.astype(f32), rtol=1e-6)


def test_dataflash_and_wire_captures_share_bin_and_are_told_apart(tmp_path, session):
    log = write_dataflash(tmp_path / "00000042.BIN", session)
    assert lookup(log).name == "dataflash"
    wire = tmp_path / "capture.bin"
    # in process: test_sim_command.py writes a .bin capture in a real subprocess
    r = run_imudiag_in_process("simulate", "static", "--duration", "2", "--out", str(wire))
    assert r.returncode == 0, r.stderr
    assert lookup(wire).name == ".bin"


def test_instance_0_by_default_and_the_others_listed(tmp_path, session):
    log = write_dataflash(tmp_path / "a.bin", session)
    with open_log(log) as reader:
        got = next(iter(reader))
        meta = dict(reader.meta)
    _same(got, session)
    assert meta["source"].startswith("DataFlash IMU instance 0 (the lowest")
    assert "instances in the log: 0, 1" in meta["source"]
    assert meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
    assert meta["sample_rate"] == pytest.approx(102.4, abs=0.1)
    assert np.allclose(got.temp, 31.5)
    with open_log(log, options=LogOptions(instance=1)) as reader:
        _same(next(iter(reader)), session, scale=1.01)
    with pytest.raises(LogError, match=r"--instance 2: no IMU of that instance \(have 0, 1\)"):
        open_log(log, options=LogOptions(instance=2))


def test_older_logs_name_the_instance_in_the_message(tmp_path, session):
    log = write_dataflash(tmp_path / "old.bin", session, instances=(0, 1, 2), old_names=True)
    with open_log(log, options=LogOptions(instance=2)) as reader:
        _same(next(iter(reader)), session, scale=1.02)
        assert "instances in the log: 0, 1, 2" in reader.meta["source"]


def test_commands_take_a_dataflash_log(tmp_path, session):
    log = write_dataflash(tmp_path / "flight.bin", session)
    out = tmp_path / "flight.csv"
    r = run_imudiag("convert", str(log), str(out), "--instance", "1")
    assert r.returncode == 0, r.stderr
    _same(read_log(out), session, scale=1.01)
    # in process: test_a_real_ardupilot_log_through_allan runs allan as a real subprocess
    r = run_imudiag_in_process("allan", str(log))
    assert r.returncode == 0, r.stderr
    assert "3000 samples at 102" in r.stdout


def test_missing_pymavlink_is_exit_2_with_the_pip_command(tmp_path, session):
    log = write_dataflash(tmp_path / "m.bin", session.slice(0, 50))
    r = run_imudiag_without("pymavlink", "allan", str(log))
    assert r.returncode == 2, r.stderr
    assert "'pymavlink'" in r.stderr and "pip install 'imudiag[ardupilot]'" in r.stderr
    assert "Traceback" not in r.stderr


REAL = Path(__file__).parent / "data" / "real" / "ardupilot-dataflash" / "test.BIN"


@pytest.mark.parametrize("instance", [0, 1])
def test_a_real_ardupilot_log_reads_as_pymavlink_reads_it(instance: int) -> None:
    """pymavlink's own test log (a real flight, SOURCE.md there): every IMU sample of the
    instance, in SI units and seconds since boot, as pymavlink's DFReader decodes it."""
    reader = DFReader.DFReader_binary(str(REAL))
    want = []
    while (m := reader.recv_match(type=["IMU", "IMU2"])) is not None:
        # current logs tag the instance (field I); this 2019 one names it IMU, IMU2
        if getattr(m, "I", {"IMU": 0, "IMU2": 1}[m.get_type()]) == instance:
            want.append([m.TimeUS / 1e6, m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ])
    reader.close()
    expected = np.array(want)
    assert len(expected) > 40  # about a second at 50 Hz
    with open_log(REAL, options=LogOptions(instance=instance)) as reader:
        block = SampleBlock.concat(list(reader))
        meta = reader.meta
    assert meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
    np.testing.assert_allclose(block.t, expected[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(block.gyro, expected[:, 1:4], rtol=1e-6, atol=0)
    np.testing.assert_allclose(block.accel, expected[:, 4:7], rtol=1e-6, atol=0)
    g = np.linalg.norm(block.accel, axis=1)
    assert 9.0 < float(np.median(g)) < 10.6  # a real unit in flight: about 1 g
    assert "instances in the log: 0, 1" in meta["source"]


def test_a_real_ardupilot_log_through_allan() -> None:
    """The commands read it as they read any log: the rate and the gaps are stated."""
    r = run_imudiag("allan", str(REAL))
    assert r.returncode == 0, r.stderr
    assert "samples at 49.9" in r.stdout and "gaps" in r.stdout


def test_reading_a_log_leaves_no_file_open() -> None:
    """The reader closes pymavlink's map and file once it has read the log (they were left
    to the garbage collector, which warned of an unclosed file)."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", ResourceWarning)
        block = read_log(REAL)
        gc.collect()
    assert len(block) > 40
    assert [w for w in seen if issubclass(w.category, ResourceWarning)] == []
