"""The gyro magnitude in turns from the GNSS course rate (imudiag.aiding.course_rate).

Land vehicles under the no-slip assumption: the simulated drives (imudiag.sim.drive)
keep the body x axis along the velocity unless a slip is asked for; faults come from
the simulator (imudiag.sim.faults); the real drive is rtklibexplorer's drive_0708
(tests/data/real/gnss-imu-drive/SOURCE.md).
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imudiag.aiding import gnss_epochs, imu_epochs, read_gpspipe_log
from imudiag.aiding.course_rate import (
    ASSUMPTION,
    CourseConfig,
    course_epochs,
    fit_forward_axis,
    turn_check,
)
from imudiag.aiding.live import LiveAiding
from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.specific_force import GateConfig
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load, load_default
from imudiag.logs import read_log
from imudiag.samples import SampleBlock
from imudiag.sim.drive import EPOCH_UNIX, GnssSimConfig, drive_motion, gnss_reports, simulate_drive
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import scenario_motion

REAL = Path(__file__).parent / "data" / "real" / "gnss-imu-drive"
RTK = GnssSimConfig(sigma_h_m_s=0.01, sigma_v_m_s=0.015)
EXACT = GnssSimConfig(sigma_h_m_s=0, sigma_v_m_s=0, outlier_rate=0, latency_s=0)


def track_of(reports):
    return track_from_reports([parse_tpv(r) for r in reports])


def gyro_turns(scenario, seed, faults=(), gnss=None, slip=0.0, duration=600.0):
    cert = load_default()
    res, reports, _ = simulate_drive(
        scenario, duration, cert, seed=seed, gnss=gnss, faults=faults, slip_rad_per_m_s2=slip
    )
    out = moving_base_diagnosis(res.samples, cert, track_of(reports), MovingConfig())
    return out["gyro_turns"], cert


def test_course_rate_is_the_body_rate_without_noise():
    # exact kinematics, noise-free GNSS: the course rate plus the Earth and transport
    # rates has the magnitude of the body's inertial rate in every turn epoch (the
    # simulated car's pitch rate on grades is the only other term: 1e-3 rad/s allowed)
    m = drive_motion("hilly", 300.0, seed=3)
    tr = m.sample(100.0)
    track = track_of(gnss_reports(m, EXACT))
    ep = gnss_epochs(track)
    ce = course_epochs(track, ep)
    im = imu_epochs(tr.t + EPOCH_UNIX, tr.specific_force, ep.t0, ep.t1, gyro_si=tr.omega)
    w = np.linalg.norm(im.gyro_mean, axis=1)
    turn = ep.valid & im.covered & (ce.speed_min > 3.0) & (np.abs(ce.rate) > 0.05)
    assert np.sum(turn) > 20
    assert np.max(np.abs(w[turn] - ce.ref_rate[turn])) < 1e-3


def test_course_noise_propagation():
    # sigma of the course rate ~ sigma_v sqrt(2) / (v dt) at constant speed
    m = drive_motion("highway", 200.0, seed=1)
    sig = 0.03
    cfg = GnssSimConfig(sigma_h_m_s=sig, sigma_v_m_s=0.05, outlier_rate=0, latency_s=0)
    gate_track = track_of(gnss_reports(m, cfg, seed=1))
    gate = GateConfig(velocity_noise="stated")
    ep = gnss_epochs(gate_track, gate, span=5)
    ce = course_epochs(gate_track, ep, gate)
    fast = ep.valid & (ce.speed_min > 20.0)
    v = ce.speed_min[fast]
    expected = sig * math.sqrt(2.0) / (v * 1.0)
    assert ce.sigma_rate[fast] == pytest.approx(expected, rel=0.1)


def test_forward_axis_of_a_mounting_yawed_by_30_deg():
    # straight epochs: f varies along the vehicle's forward axis (braking) and vertical
    rng = np.random.default_rng(4)
    n = 200
    along = rng.normal(0.0, 1.0, n)
    f_vehicle = np.stack([along, np.zeros(n), np.full(n, -9.81)], 1)
    a = math.radians(30.0)
    rz = np.array([[math.cos(a), math.sin(a), 0], [-math.sin(a), math.cos(a), 0], [0, 0, 1]])
    f_body = f_vehicle @ rz.T + rng.normal(0.0, 0.02, (n, 3))
    fa = fit_forward_axis(f_body, along + rng.normal(0.0, 0.02, n))
    assert fa.determined
    assert fa.axis == pytest.approx(rz @ np.array([1.0, 0.0, 0.0]), abs=0.02)
    # without braking nothing tells the forward axis: undetermined with the reason
    flat = fit_forward_axis(f_body * np.array([0.0, 0.0, 1.0]), np.zeros(n))
    assert not flat.determined and "did not vary" in flat.reason


def test_clean_urban_drive_gyro_magnitude_passes():
    out, cert = gyro_turns("urban", seed=11)
    assert "no-slip" in out["assumption"] and out["assumption"] == ASSUMPTION
    assert out["verdict"] == "ok" and out["faults"] == []
    assert out["f0"]["checked"] >= 5 and out["f0"]["failed"] == 0 and not out["f0"]["fault"]
    assert out["forward_axis"]["determined"]
    assert out["forward_axis"]["axis_body"] == pytest.approx([1.0, 0.0, 0.0], abs=0.01)
    # the turns' integrated |omega| matches the GNSS course change
    assert out["turns"]["ratio_total"] == pytest.approx(1.0, abs=0.01)
    assert out["used"] == sum(round(b - a) for a, b in out["used_spans"])
    # a level road excites the vertical gyro only: gz determined, gx and gy not
    assert out["axes"]["gz"]["share_of_rate2"] > 0.99
    det = {(d["sensor"], d["cause"]) for d in out["determined"]}
    assert ("gz", "scale_factor") in det
    assert not {s for s, _ in det} - {"gz"}
    undet = {(u["sensor"], u["cause"]): u["reason"] for u in out["undetermined"]}
    for key in [("gx", "scale_factor"), ("gy", "bias")]:
        assert "did not excite" in undet[key]
    assert "second order" in undet[("gx/gy", "misalignment")]
    gz = out["fit"]["parameters"]["gz scale_factor"]
    assert abs(gz["deviation"]) < 3 * gz["std"]


def test_gz_scale_fault_is_named_never_a_wrong_sensor():
    cert = load_default()
    value = 3.0 * float(cert.gyro.limits.scale_factor_error[2])
    out, _ = gyro_turns("urban", seed=11, faults=(Fault("scale_factor", "gz", 0.0, value),))
    assert out["verdict"] == "fault"
    named = [(f["sensor"], f["cause"]) for f in out["faults"] if f.get("named")]
    assert named == [("gz", "scale_factor")]
    f = out["faults"][-1]
    assert f["deviation"] == pytest.approx(value, rel=0.3)
    # the injected 3 % shows in the turns' ratio
    assert out["turns"]["ratio_total"] == pytest.approx(
        1.0 + value / cert.gyro.scale_factor[2], abs=0.01
    )


def test_slipping_car_is_rejected_not_blamed_on_the_gyros():
    # a body heading that leads the course by 0.1 rad per m/s^2 of lateral acceleration:
    # the no-slip test rejects the turns where it shows (and the rest of those turns);
    # what is left determines nothing and no gyro fault is raised
    out, _ = gyro_turns("urban", seed=11, gnss=RTK, slip=0.1)
    assert out["rejected"]["slip"] >= 20
    assert out["rejected"]["slip_in_turn"] >= 10
    assert out["faults"] == [] and not out["f0"]["fault"]
    assert out["determined"] == []


def test_real_drive_gyro_magnitude_in_turns():
    # rtklibexplorer drive_0708: 26 turns (1780 deg) pass the no-slip test; the gyros'
    # integrated |omega| over them is the GNSS course change within 0.1 % (gz scale
    # error -0.0024 +- 0.0018, limit 0.005); gz bias +0.18 +- 0.04 deg/s, as measured at
    # the drive's stops (+0.17 deg/s over 66 s); gx, gy carry 2 % of |omega|^2: no fault
    cert = load(REAL / "nominal-certificate.yaml")
    out = moving_base_diagnosis(
        read_log(REAL / "imu.csv.gz"), cert, read_gpspipe_log(REAL / "gnss.tpv.json.gz")
    )["gyro_turns"]
    assert out["verdict"] == "ok" and out["faults"] == []
    assert out["forward_axis"]["determined"]
    assert 20 <= out["turns"]["count"] <= 32
    assert out["turns"]["ratio_total"] == pytest.approx(1.0, abs=0.01)
    assert out["rejected"]["slip"] > 0
    gz_scale = out["fit"]["parameters"]["gz scale_factor"]
    assert abs(gz_scale["deviation"]) < 0.003 and gz_scale["std"] < 0.003
    gz_bias = out["fit"]["parameters"]["gz bias"]
    assert gz_bias["deviation"] == pytest.approx(0.17, abs=0.05) and gz_bias["std"] < 0.06
    det = {(d["sensor"], d["cause"]) for d in out["determined"]}
    assert det == {("gz", "bias"), ("gz", "scale_factor")}
    json.dumps(out)  # JSON-ready


def test_turn_check_without_turns_is_undetermined():
    # a highway stretch with no turn above a 10 deg/s floor: unknown, with the reason
    m = drive_motion("highway", 120.0, seed=2)
    tr = m.sample(100.0)
    track = track_of(gnss_reports(m, EXACT))
    ep = gnss_epochs(track)
    im = imu_epochs(tr.t + EPOCH_UNIX, tr.specific_force, ep.t0, ep.t1, gyro_si=tr.omega)
    cfg = CourseConfig(min_rate_rad_s=math.radians(10.0))
    m_cfg = MovingConfig()
    out = turn_check(
        track, ep, im, load_default().gyro, np.full(3, 1e-3), cfg=cfg,
        k_sigma_f0=m_cfg.k_sigma_f0, k_sigma=m_cfg.k_sigma, prior_factor=m_cfg.prior_factor,
        determined_std_ratio=m_cfg.determined_std_ratio,
    )  # fmt: skip
    assert out["verdict"] == "unknown" and out["faults"] == []
    assert out["reason"]
    assert len(out["undetermined"]) == 6


def test_diagnose_cli_reports_the_gyros_in_turns(tmp_path):
    # the command anyone can run (docs/moving-base.md), as a real subprocess
    out = tmp_path / "report.json"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "imudiag",
            "diagnose",
            str(REAL / "imu.csv.gz"),
            "-c",
            str(REAL / "nominal-certificate.yaml"),
            "--gnss",
            str(REAL / "gnss.tpv.json.gz"),
            "--no-windows",
            "--quiet",
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "gyro in turns (no-slip assumption): ok:" in r.stdout
    gt = json.loads(out.read_text())["moving_base"]["gyro_turns"]
    assert gt["assumption"] == ASSUMPTION
    assert gt["verdict"] == "ok" and gt["used"] > 100
    assert gt["used_spans"] and all(b > a for a, b in gt["used_spans"])


@pytest.mark.parametrize("fault_limits", [0.0, 3.0])
def test_daemon_aiding_checks_the_gyros_in_turns(fault_limits):
    # the daemon's aiding (LiveAiding) with its real gpsd client on a loopback socket that
    # speaks gpsd's JSON: each TPV line is written when the IMU stream reaches its time,
    # the IMU fed in 50 ms blocks as the daemon reads it; a 3-limit gz scale fault is
    # latched as a named gyro fault of the moving base, a healthy unit raises nothing
    cert = load_default()
    value = fault_limits * float(cert.gyro.limits.scale_factor_error[2])
    faults = (Fault("scale_factor", "gz", 0.0, value),) if value else ()
    res, reports, _ = simulate_drive("urban", 400.0, cert, seed=11, faults=faults)
    times = np.array([r["t"] if r else np.nan for r in map(parse_tpv, reports)])
    s = res.samples
    now = [0.0]
    with socket.create_server(("127.0.0.1", 0)) as srv:
        aid = LiveAiding(
            f"gpsd://127.0.0.1:{srv.getsockname()[1]}", cert, clock=lambda: now[0], mode="inline"
        )
        aid.update(None)  # connects
        conn, _ = srv.accept()
        with conn:
            i = 0
            for k in range(0, len(s.t), 10):
                blk = SampleBlock(
                    t=s.t[k : k + 10], gyro=s.gyro[k : k + 10], accel=s.accel[k : k + 10]
                )
                now[0] = float(blk.t[-1] - s.t[0])
                lines = []
                while i < len(reports) and not times[i] > blk.t[-1]:
                    lines.append(json.dumps(reports[i]) + "\n")
                    i += 1
                if lines:
                    conn.sendall("".join(lines).encode())
                aid.update(blk)
        st = aid.status()
        aid.close()
    gt = st["gyro_turns"]
    assert "no-slip" in gt["assumption"] and gt["turns"]["count"] >= 2
    gyro_faults = [f for f in aid.faults() if f["triad"] == "gyro"]
    if value:
        assert gt["faults"] == [["gz", "scale_factor"]]
        assert aid.faults() == [
            {"triad": "gyro", "cause": "scale_factor", "source": "moving_base", "sensor": "gz"}
        ]
    else:
        assert gt["faults"] == [] and gyro_faults == [] and aid.faults() == []
        assert gt["turns"]["ratio_total"] == pytest.approx(1.0, abs=0.02)


def test_simulated_slip_turns_the_body_off_the_course():
    # the drive simulator's side slip (--param slip=K): the body x axis leads the velocity
    # by beta = K a_lat (a_lat = v psi', m/s^2); with K = 0 the body follows the course
    for k in (0.0, 0.05):
        m = scenario_motion("urban", 4, {"length": "300", "slip": str(k)})
        assert m.slip_rad_per_m_s2 == k
        tr = m.sample(50.0)
        vel = m.velocity_ned(tr.t)
        course = np.arctan2(vel[:, 1], vel[:, 0])
        heading = np.arctan2(tr.attitude[:, 1, 0], tr.attitude[:, 0, 0])
        p = m._profiles(tr.t)
        moving = p["v"] > 1.0
        beta = np.angle(np.exp(1j * (heading - course)))[moving]
        assert beta == pytest.approx(k * (p["v"] * p["dpsi"])[moving], abs=1e-9)
        # and the gyros sense the body's heading rate (course rate + beta'), Earth rate aside
        yaw_rate = np.gradient(np.unwrap(heading), tr.t)
        assert np.max(np.abs(yaw_rate - tr.omega[:, 2])) < 2e-3
    assert np.max(np.abs(beta)) > 0.05  # a visible slip in the turns
    with pytest.raises(ValueError, match="slip must be a number"):
        scenario_motion("urban", 4, {"slip": "x"})
