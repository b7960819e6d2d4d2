"""DataFlash high-rate IMU data: raw IMU logging's ``ACC`` / ``GYR`` and the batch sampler's
``ISBH`` / ``ISBD`` bursts, written byte for byte to ArduPilot's layouts (FMT, then
records), checked with pymavlink's own DFReader, holding the real imucal recording
(tests/data/real/imucal-ferraris, SOURCE.md there)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink import DFReader

from imudiag.logs import open_log, read_log

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
HEAD = b"\xa3\x95"
LAYOUTS = {  # name: (id, DataFlash format, columns, struct format)
    "IMU": (131, "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", "<QBffffff"),
    "ACC": (132, "QBQfff", "TimeUS,I,SampleUS,AccX,AccY,AccZ", "<QBQfff"),
    "GYR": (133, "QBQfff", "TimeUS,I,SampleUS,GyrX,GyrY,GyrZ", "<QBQfff"),
    "ISBH": (134, "QHBBHHQf", "TimeUS,N,type,instance,mul,smp_cnt,SampleUS,smp_rate", "<QHBBHHQf"),
    "ISBD": (135, "QHHaaa", "TimeUS,N,seqno,x,y,z", "<QHH32h32h32h"),
}
ACC_MUL, GYR_MUL = 1000, 5000


def _fmt(type_id, name, fmt, cols, size):
    body = struct.pack("<BB4s16s64s", type_id, size, name.encode(), fmt.encode(), cols.encode())
    return HEAD + bytes([128]) + body


def _rec(name, *values):
    tid, _, _, st = LAYOUTS[name]
    return HEAD + bytes([tid]) + struct.pack(st, *values)


def write_log(path: Path, s, kind: str) -> Path:
    out = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89)]
    for name, (tid, fmt, cols, st) in LAYOUTS.items():
        out.append(_fmt(tid, name, fmt, cols, 3 + struct.calcsize(st)))
    gyro = np.radians(s.gyro)
    us = np.round(s.t * 1e6).astype(np.int64) + 1_000_000
    if kind == "raw":  # every sample as ACC and GYR, and IMU at a tenth of the rate
        for i in range(len(s)):
            out.append(_rec("ACC", us[i] + 50, 0, us[i], *s.accel[i]))
            out.append(_rec("GYR", us[i] + 60, 0, us[i], *gyro[i]))
            if i % 10 == 0:
                out.append(_rec("IMU", us[i] + 70, 0, *gyro[i], *s.accel[i]))
    else:  # bursts of 64 samples, accel then gyro, every other 64 samples
        n = 0
        for start in range(0, len(s) - 64, 128):
            for typ, vals, mul in ((0, s.accel, ACC_MUL), (1, gyro, GYR_MUL)):
                q = np.clip(np.round(vals[start : start + 64] * mul), -32768, 32767).astype(int)
                t_head = int(us[start + 63]) + 100
                rate = 102.4
                out.append(_rec("ISBH", t_head, n, typ, 0, mul, 64, int(us[start]), rate))
                for seq in range(2):
                    blk = q[32 * seq : 32 * seq + 32]
                    out.append(
                        _rec("ISBD", t_head + 10, n, seq, *blk[:, 0], *blk[:, 1], *blk[:, 2])
                    )
                n += 1
    path.write_bytes(b"".join(out))
    return path


@pytest.fixture(scope="module")
def session():
    return read_log(IMUCAL).slice(0, 1200)


def test_acc_gyr_are_read_in_preference_to_slower_imu_messages(tmp_path, session):
    log = write_log(tmp_path / "raw.BIN", session, "raw")
    ref = DFReader.DFReader_binary(str(log), zero_time_base=True)
    acc, gyr = [], []
    while (m := ref.recv_match(type=["ACC", "GYR"])) is not None:
        row = [m.SampleUS * 1e-6, *(getattr(m, m.get_type().title()[:3] + a) for a in "XYZ")]
        (acc if m.get_type() == "ACC" else gyr).append(row)
    ref.close()
    acc, gyr = np.asarray(acc), np.asarray(gyr)
    with open_log(log) as r:
        got = read_log(log)
        assert r.meta["source"].startswith("DataFlash ACC/GYR instance 0")
    # the ends where the accelerometer does not cover the gyro sample are left out
    np.testing.assert_array_equal(got.t, gyr[:, 0])
    np.testing.assert_array_equal(got.gyro, gyr[:, 1:])
    np.testing.assert_allclose(got.accel, acc[:, 1:], rtol=0, atol=0)


def test_batch_sampler_bursts_are_read_as_dfreader_decodes_them(tmp_path, session):
    log = write_log(tmp_path / "isb.BIN", session, "isb")
    ref = DFReader.DFReader_binary(str(log), zero_time_base=True)
    heads, data = {}, {}
    while (m := ref.recv_match(type=["ISBH", "ISBD"])) is not None:
        if m.get_type() == "ISBH":
            heads[m.N] = m
        else:
            data.setdefault(m.N, []).append(m)
    want = {0: [], 1: []}
    for n, h in heads.items():
        xyz = np.concatenate([np.column_stack([d.x, d.y, d.z]) for d in data[n]]) / h.mul
        t = h.SampleUS * 1e-6 + np.arange(len(xyz)) / h.smp_rate
        want[h.type].append(np.column_stack([t, xyz]))
    acc, gyr = np.concatenate(want[0]), np.concatenate(want[1])
    heads.clear(), data.clear()
    ref.close()
    with open_log(log) as r:
        got = read_log(log)
        assert r.meta["source"].startswith("DataFlash ISBH/ISBD batch sampler instance 0")
    assert len(got) == len(gyr) == 9 * 64
    np.testing.assert_allclose(got.t, gyr[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got.gyro, gyr[:, 1:])
    np.testing.assert_allclose(got.accel, acc[:, 1:], rtol=0, atol=1e-12)
    # the real samples, quantised to 1/mul
    np.testing.assert_allclose(
        got.accel,
        session.accel[: 64 * 18].reshape(9, 128, 3)[:, :64].reshape(-1, 3),
        atol=0.5 / ACC_MUL,
    )
