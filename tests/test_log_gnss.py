"""GNSS from the log itself, and DataFlash logs of the 2014 era (``TimeMS``).

The 2014-era file is written byte for byte to ArduPilot's self-describing format (FMT, then
records; the ArduCopter 3.1 layouts of ``IMU`` and ``GPS``), checked with pymavlink's own
DFReader, and holds the real imucal recording (tests/data/real/imucal-ferraris). Its boot
clock runs 8.3 % slow against GPS time, as in the real log of issue 27. The ULog case is
pyulog's real test log (tests/data/real/px4-ulog, SOURCE.md there), read against pyulog.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import pyulog
from pymavlink import DFReader

from imudiag.aiding.log_clock import fit_clock
from imudiag.cli import main
from imudiag.errors import BadInput
from imudiag.logs import open_log, read_log
from imudiag.logs.gnss_fixes import gps_week_ms_to_unix

DATA = Path(__file__).parent / "data"
IMUCAL = DATA / "real" / "imucal-ferraris" / "session.csv.gz"
SI_CERT = DATA / "interop" / "like-si.yaml"
ULOG = DATA / "real" / "px4-ulog" / "sample_log_small.ulg"
HEAD = b"\xa3\x95"
SLOW = 1.083  # GPS s per boot s
IMU14 = ("Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
GPS14 = ("BIHBcLLeeEefI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T")
GPS14_STRUCT = "<BIHBhiiiiIifI"  # DataFlash c, L, e, E as struct h, i, i, I


def _fmt(type_id, name, fmt, cols):
    if name == "FMT":
        length = 89
    else:
        length = 3 + struct.calcsize(GPS14_STRUCT if name == "GPS" else "<" + fmt)
    body = struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), cols.encode())
    return HEAD + bytes([128]) + body


def write_2014_log(path: Path, s, jump_at: int | None = None) -> Path:
    """IMU (TimeMS, ms since boot) and GPS at 5 Hz (TimeMS/Week: GPS time; T: boot ms)."""
    out = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")]
    out += [_fmt(129, "IMU", *IMU14), _fmt(130, "GPS", *GPS14)]
    gyro = np.radians(s.gyro)
    boot_ms = np.round((s.t - s.t[0]) * 1e3).astype(int) + 20_000
    next_fix, k = boot_ms[0], 0
    for i in range(len(s)):
        out.append(
            HEAD + bytes([129]) + struct.pack("<" + IMU14[0], boot_ms[i], *gyro[i], *s.accel[i])
        )
        if boot_ms[i] >= next_fix:
            gps_ms = 300_000_000 + int(round(SLOW * boot_ms[i]))  # ms of week 1800
            if k == jump_at:
                gps_ms += 1000
            rec = struct.pack(GPS14_STRUCT, 3, gps_ms, 1800, 9, 80, 495_000_000 + k, 110_000_000,
                              0, 30000, 150, 9000, 0.25, int(boot_ms[i]))  # fmt: skip
            out.append(HEAD + bytes([130]) + rec)
            next_fix += 200
            k += 1
    path.write_bytes(b"".join(out))
    return path


@pytest.fixture(scope="module")
def session():
    return read_log(IMUCAL).slice(0, 3000)


@pytest.fixture(scope="module")
def log2014(tmp_path_factory, session):
    return write_2014_log(tmp_path_factory.mktemp("df") / "2014.BIN", session)


def test_a_2014_log_stamped_in_timems_reads_as_dfreader_reads_it(log2014):
    ref = DFReader.DFReader_binary(str(log2014), zero_time_base=True)
    rows = []
    while (m := ref.recv_match(type="IMU")) is not None:
        rows.append((m.TimeMS * 1e-3, m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ))
    want = np.asarray(rows)
    got = read_log(log2014)
    assert len(got) == len(want) == 3000
    np.testing.assert_array_equal(got.t, want[:, 0])
    np.testing.assert_array_equal(got.gyro, want[:, 1:4])
    np.testing.assert_array_equal(got.accel, want[:, 4:7])


def test_the_log_gps_ties_a_slow_boot_clock_to_gps_time_with_its_drift(log2014):
    with open_log(log2014) as r:
        fixes = r.gnss()
    ref = DFReader.DFReader_binary(str(log2014), zero_time_base=True)
    gps = []
    while (m := ref.recv_match(type="GPS")) is not None:
        gps.append(m)
    assert len(fixes) == len(gps) > 100
    np.testing.assert_array_equal(fixes.t_log, [m.T * 1e-3 for m in gps])
    want = gps_week_ms_to_unix(np.array([m.Week for m in gps]), np.array([m.TimeMS for m in gps]))
    np.testing.assert_array_equal(fixes.t_gnss, want)
    np.testing.assert_allclose(fixes.vel_ned[:, 2], 0.25, rtol=1e-6)  # VZ, down
    np.testing.assert_allclose(np.hypot(fixes.vel_ned[:, 0], fixes.vel_ned[:, 1]), 1.5)
    clock = fit_clock(fixes, "2014.BIN")
    assert clock.how == "fitted"
    assert abs(clock.rate - SLOW) < 2e-5  # not a constant offset: the 8.3 % drift
    assert clock.residual_max_s < 1e-3  # the 1 ms stamps' rounding only
    assert abs(clock.to_gnss(fixes.t_log[0]) - fixes.t_gnss[0]) < 1e-3


def test_a_gps_time_that_jumps_is_a_refusal_with_the_reason(tmp_path, session):
    bad = write_2014_log(tmp_path / "jump.BIN", session, jump_at=40)
    with open_log(bad) as r:
        fixes = r.gnss()
    with pytest.raises(BadInput, match=r"cannot tie the IMU clock to GNSS time: the fix at t = "):
        fit_clock(fixes, str(bad))


def test_diagnose_uses_the_log_gnss_and_writes_valid_json(log2014, tmp_path, capsys):
    out = tmp_path / "d.json"
    args = ["diagnose", str(log2014), "-c", str(SI_CERT), "--json", str(out), "-q", "--no-windows"]
    assert main(args) == 0  # --gnss auto is the default
    mb = json.loads(out.read_text())["moving_base"]  # strict JSON: NaN would be null
    clock = mb["gnss"]["clock"]
    assert clock["how"] == "fitted" and abs(clock["rate"] - SLOW) < 2e-5
    assert "IMU clock tied to GNSS time: rate 1.083" in capsys.readouterr().out
    assert main([*args, "--gnss", "none"]) == 0
    assert "moving_base" not in json.loads(out.read_text())
    bad = write_2014_log(tmp_path / "jump.BIN", read_log(IMUCAL).slice(0, 3000), jump_at=40)
    assert main(["diagnose", str(bad), "-c", str(SI_CERT), "--gnss", "log", "-q"]) == 2
    assert "cannot tie the IMU clock to GNSS time" in capsys.readouterr().err


def test_ulog_gps_against_pyulog_and_its_clock_fit():
    ref = pyulog.ULog(str(ULOG), message_name_filter_list=["vehicle_gps_position"])
    d = ref.get_dataset("vehicle_gps_position").data
    with open_log(ULOG) as r:
        fixes = r.gnss()
    assert len(fixes) == len(d["timestamp"]) == 32
    np.testing.assert_allclose(fixes.t_log, (d["timestamp"] - ref.start_timestamp) * 1e-6)
    np.testing.assert_allclose(fixes.t_gnss, d["time_utc_usec"] * 1e-6)
    np.testing.assert_allclose(fixes.lat_deg, d["lat"] * 1e-7)
    np.testing.assert_allclose(fixes.vel_ned[:, 0], d["vel_n_m_s"])
    clock = fit_clock(fixes, ULOG.name)
    # the real board's clock against its receiver's UTC: 499 ppm, 3.7 ms rms residual
    assert abs(clock.rate - 1.000499) < 2e-6
    assert clock.residual_rms_s < 0.005


def test_the_library_takes_gnss_too(log2014, session):
    import imudiag

    rep = imudiag.diagnose(log2014, str(SI_CERT), gnss="log", windows=False)
    assert abs(rep["moving_base"]["gnss"]["clock"]["rate"] - SLOW) < 2e-5
    assert "moving_base" not in imudiag.diagnose(log2014, str(SI_CERT), gnss="none")
    # samples in memory with the log's fixes: tied the same way
    with open_log(log2014) as r:
        fixes = r.gnss()
    block = read_log(log2014)
    rep = imudiag.diagnose(block, str(SI_CERT), gnss=fixes, windows=False)
    assert rep["moving_base"]["gnss"]["clock"]["fixes"] == len(fixes)


def test_a_fitted_clock_avoids_the_false_fault_a_constant_offset_raises():
    # a simulated clean urban drive (imudiag.sim.drive) whose IMU and GPS messages are
    # stamped by a boot clock 8.3 % slow, the fixes also carrying GPS time, as a
    # flight controller logs them: tied by the fitted offset and rate, nothing is raised;
    # tied by a constant offset (the old way: both clocks taken as UTC), the GNSS
    # accelerations are 8.3 % off and a false accelerometer scale-factor fault appears
    from dataclasses import replace

    from imudiag.aiding.log_clock import moving_base_for_recording
    from imudiag.aiding.tpv import parse_tpv, track_from_reports
    from imudiag.certificate import load_default
    from imudiag.logs.gnss_fixes import GnssFixes
    from imudiag.sim.drive import simulate_drive

    cert = load_default()
    res, reports, _ = simulate_drive("urban", 300.0, cert, seed=11)
    tr = track_from_reports([parse_tpv(r) for r in reports])
    boot0 = res.samples.t[0] - 20.0  # the board booted 20 s before the drive
    samples = replace(res.samples, t=(res.samples.t - boot0) / SLOW)
    fixes = GnssFixes(
        t_log=(tr.t - boot0) / SLOW, t_gnss=tr.t, lat_deg=tr.lat_deg, lon_deg=tr.lon_deg,
        alt_m=tr.alt_m, vel_ned=tr.vel_ned, eps=tr.eps, mode=tr.mode, status=tr.status,
        source="simulated GPS messages", clock="GPS time of each fix",
    )  # fmt: skip
    tied = moving_base_for_recording(samples, cert, "log", fixes, rate_hz=100.0 / SLOW)
    assert tied["gnss"]["clock"]["rate"] == pytest.approx(SLOW, abs=1e-9)
    assert tied["verdict"] == "ok" and tied["faults"] == []
    offset = tr.t[0] - fixes.t_log[0]
    shifted = replace(samples, t=samples.t + offset)
    mis = moving_base_for_recording(shifted, cert, tr, None, rate_hz=100.0)
    assert mis["verdict"] == "fault"
    assert [(f["sensor"], f["cause"]) for f in mis["faults"]] == [("ax", "scale_factor")]
