"""ULog files of newer PX4 versions, written byte for byte to the ULog format (header, flag
bits, formats, subscriptions, data; docs.px4.io "ULog File Format") and checked with
pyulog: ``vehicle_imu`` as the only IMU topic (its integrated deltas over their intervals)
and ``sensor_gps`` with the newer field names (``latitude_deg``, ``altitude_ellipsoid_m``),
a boot clock 8.3 % slow against the receiver's UTC. The samples are the real imucal
session (tests/data/real/imucal-ferraris, SOURCE.md there)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import pyulog

from imudiag.aiding.log_clock import fit_clock
from imudiag.logs import open_log, read_log

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
UTC0 = 1_700_000_000.0
SLOW = 1.083
IMU_FMT = (
    "vehicle_imu:uint64_t timestamp;uint64_t timestamp_sample;float[3] delta_angle;"
    "float[3] delta_velocity;uint32_t delta_angle_dt;uint32_t delta_velocity_dt;"
)
GPS_FMT = (
    "sensor_gps:uint64_t timestamp;uint64_t time_utc_usec;double latitude_deg;"
    "double longitude_deg;double altitude_ellipsoid_m;float vel_n_m_s;float vel_e_m_s;"
    "float vel_d_m_s;float s_variance_m_s;bool vel_ned_valid;uint8_t fix_type;"
)


def _msg(kind: bytes, body: bytes) -> bytes:
    return struct.pack("<HB", len(body), kind[0]) + body


def write_ulog(path: Path, s) -> Path:
    out = [b"ULog\x01\x12\x35", struct.pack("<BQ", 1, 0)]
    out.append(_msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0)))
    out += [_msg(b"F", IMU_FMT.encode()), _msg(b"F", GPS_FMT.encode())]
    out.append(_msg(b"A", struct.pack("<BH", 0, 0) + b"vehicle_imu"))
    out.append(_msg(b"A", struct.pack("<BH", 0, 1) + b"sensor_gps"))
    w = np.radians(s.gyro)
    us = np.round((s.t - s.t[0]) * 1e6).astype(np.int64) + 2_000_000
    dt = int(round(1e6 / 102.4))
    next_fix, k = us[0], 0
    for i in range(len(s)):
        ts = int(us[i])
        body = struct.pack("<HQQ3f3fII", 0, ts + 300, ts, *(w[i] * dt * 1e-6),
                           *(s.accel[i] * dt * 1e-6), dt, dt)  # fmt: skip
        out.append(_msg(b"D", body))
        if ts >= next_fix:
            utc = int(round((UTC0 + SLOW * ts * 1e-6) * 1e6))
            body = struct.pack("<HQQdddffff?B", 1, ts + 100, utc, 47.0 + 1e-6 * k, 8.0, 450.0,
                               1.0, -2.0, 0.5, 0.3, True, 3)  # fmt: skip
            out.append(_msg(b"D", body))
            next_fix += 200_000
            k += 1
    path.write_bytes(b"".join(out))
    return path


@pytest.fixture(scope="module")
def ulog(tmp_path_factory):
    return write_ulog(tmp_path_factory.mktemp("ulg") / "new.ulg", read_log(IMUCAL).slice(0, 2000))


def test_vehicle_imu_alone_reads_as_pyulog_decodes_it(ulog):
    ref = pyulog.ULog(str(ulog))
    d = ref.get_dataset("vehicle_imu").data
    with open_log(ulog) as r:
        assert r.meta["source"].startswith("vehicle_imu instance 0")
    got = read_log(ulog)
    dta = d["delta_angle_dt"] * 1e-6
    dtv = d["delta_velocity_dt"] * 1e-6
    np.testing.assert_allclose(got.t, (d["timestamp_sample"] - ref.start_timestamp) * 1e-6)
    for k in range(3):
        np.testing.assert_allclose(got.gyro[:, k], d[f"delta_angle[{k}]"] / dta, rtol=1e-12)
        np.testing.assert_allclose(got.accel[:, k], d[f"delta_velocity[{k}]"] / dtv, rtol=1e-12)


def test_sensor_gps_with_the_newer_fields_and_its_slow_clock(ulog):
    ref = pyulog.ULog(str(ulog))
    d = ref.get_dataset("sensor_gps").data
    with open_log(ulog) as r:
        fixes = r.gnss()
    assert len(fixes) == len(d["timestamp"]) > 50
    np.testing.assert_allclose(fixes.lat_deg, d["latitude_deg"])
    np.testing.assert_allclose(fixes.alt_m, d["altitude_ellipsoid_m"])
    np.testing.assert_allclose(
        fixes.vel_ned, np.column_stack([d["vel_n_m_s"], d["vel_e_m_s"], d["vel_d_m_s"]])
    )
    np.testing.assert_allclose(fixes.t_gnss, d["time_utc_usec"] * 1e-6)
    clock = fit_clock(fixes, ulog.name)
    assert abs(clock.rate - SLOW) < 1e-6 and clock.residual_max_s < 1e-5
