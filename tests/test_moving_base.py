"""Moving-base diagnosis with GNSS aiding (imudiag.aiding.moving, imudiag.sim.drive).

Simulated drives: the IMU and the GNSS stream come from the same analytic
trajectory on the rotating WGS-84 Earth; faults are drawn at random under a
seed from what each drive makes observable, and must be named; parameters the
drive cannot separate must come out as a group (never a single wrong name),
parameters it cannot excite as undetermined with the reason.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from imudiag.aiding import gnss_epochs, imu_epochs, read_gpspipe_log
from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load, load_default
from imudiag.cli import main
from imudiag.logs import read_log, write_log
from imudiag.sim.drive import (
    DRIVE_SCENARIOS,
    EPOCH_UNIX,
    GnssSimConfig,
    drive_motion,
    gnss_reports,
    simulate_drive,
    write_gpspipe_log,
)
from imudiag.sim.faults import Fault

REAL = Path(__file__).parent / "data" / "real" / "gnss-imu-drive"
#: RTK-grade Doppler velocity (the real drive's measured noise is ~0.02 m/s)
RTK = GnssSimConfig(sigma_h_m_s=0.01, sigma_v_m_s=0.015)
FAULT_T = 300.0  #: s into the drive


def track_of(reports):
    return track_from_reports([parse_tpv(r) for r in reports])


@pytest.mark.parametrize("scenario", DRIVE_SCENARIOS)
def test_drive_imu_and_gnss_agree(scenario):
    # noise-free GNSS with a lever arm: the IMU's epoch |f| (moved to the antenna)
    # equals |dv/dt - g + (2 Omega + omega_en) x v| within 2e-3 m/s^2 (velocity
    # written to 1e-4 m/s, time to 1 ms)
    m = drive_motion(scenario, 300.0, seed=2)
    tr = m.sample(100.0)
    lever = (1.0, 0.5, -0.8)
    cfg = GnssSimConfig(
        sigma_h_m_s=0, sigma_v_m_s=0, outlier_rate=0, latency_s=0, lever_arm_m=lever
    )
    ep = gnss_epochs(track_of(gnss_reports(m, cfg)))
    im = imu_epochs(
        tr.t + EPOCH_UNIX,
        tr.specific_force,
        ep.t0,
        ep.t1,
        gyro_si=tr.omega,
        lever_arm_m=np.array(lever),
    )
    ok = ep.valid & im.covered
    assert np.sum(ok) > 0.9 * len(ep)
    assert np.max(np.abs(im.mag[ok] - ep.mag[ok])) < 2e-3


def run(scenario, seed, gnss=None, faults=(), duration=600.0, cert=None):
    cert = cert or load_default()
    res, reports, _ = simulate_drive(scenario, duration, cert, seed=seed, gnss=gnss, faults=faults)
    return moving_base_diagnosis(res.samples, cert, track_of(reports), MovingConfig())


@pytest.mark.parametrize("scenario", ["urban", "aircraft"])
def test_clean_drive_raises_nothing(scenario):
    out = run(scenario, seed=11)
    assert out["verdict"] == "ok", out["faults"]
    assert out["faults"] == []
    lat = out["gnss"]["latency"]
    # determined only within the 0.03 s tolerance (std 52 ms on the urban MEMS drive):
    # the best estimate is used anyway, its std widening the checks
    assert lat["determined"] == (lat["used_std_s"] <= 0.03)
    # simulated latency 0.12 s
    assert lat["latency_s"] == pytest.approx(0.12, abs=0.02)
    assert out["f0"]["failed"] == 0
    assert out["gyro"]["determined"] is False


def test_aircraft_fault_named():
    # steep coordinated turns and pull-ups spread |f| over 0.6-1.5 g: az bias and az scale
    # leave different traces; one of them, drawn under the seed, 3 limits, must be named
    rng = np.random.default_rng(15)
    cert = load_default()
    kind = str(rng.choice(["bias", "scale_factor"]))
    limit = {
        "bias": cert.accel.limits.bias[2],
        "scale_factor": cert.accel.limits.scale_factor_error[2],
    }[kind]
    value = float(rng.choice([-3, 3])) * float(limit)
    out = run(
        "aircraft",
        seed=15,
        gnss=RTK,
        faults=(Fault(kind, "az", FAULT_T, value),),
        duration=700.0,
        cert=cert,
    )
    assert out["verdict"] == "fault"
    named = [f for f in out["faults"] if f["named"]]
    assert [(f["sensor"], f["cause"]) for f in named] == [("az", kind)]
    f = named[0]
    assert f["t_first"] - EPOCH_UNIX > FAULT_T
    cert_value = {"bias": cert.accel.bias[2], "scale_factor": cert.accel.scale_factor_error[2]}[
        kind
    ]
    assert f["estimate"] - cert_value == pytest.approx(value, rel=0.2)
    assert all(f["named"] for f in out["faults"])


def test_car_vertical_fault_is_a_group_not_a_wrong_name():
    # on a level road f stays near the body vertical: az bias and az scale shift |f| alike,
    # so a 3-limit fault on either is reported as one of the two, never as the other
    rng = np.random.default_rng(16)
    cert = load_default()
    kind = str(rng.choice(["bias", "scale_factor"]))
    value = 3.0 * float(
        {
            "bias": cert.accel.limits.bias[2],
            "scale_factor": cert.accel.limits.scale_factor_error[2],
        }[kind]
    )
    out = run("urban", seed=16, faults=(Fault(kind, "az", FAULT_T, value),), cert=cert)
    assert out["verdict"] == "fault"
    assert out["faults"]
    for f in out["faults"]:
        assert not f["named"] or (f["sensor"], f["cause"]) == ("az", kind)
        if not f["named"]:
            assert ("az", kind) in [(o["sensor"], o["cause"]) for o in f["one_of"]]
            assert "indistinguishable" in f["reason"]
    undet = {(u["sensor"], u["cause"]): u for u in out["undetermined"]}
    assert "az scale_factor" in undet[("az", "bias")]["reason"]


def test_unexcited_parameter_is_undetermined_with_reason():
    # ax/ay misalignment needs f along x and y at once (accelerating in a turn): a car
    # barely does that; a 3-limit fault there raises nothing, and the report says why
    cert = load_default()
    value = 3.0 * float(cert.accel.limits.misalignment[0])
    out = run("urban", seed=17, faults=(Fault("misalignment", "ax/ay", FAULT_T, value),), cert=cert)
    assert out["faults"] == []
    undet = {(u["sensor"], u["cause"]): u for u in out["undetermined"]}
    assert "did not excite" in undet[("ax/ay", "misalignment")]["reason"]


def test_diagnose_cli_with_gnss(tmp_path, capsys):
    cert = load_default()
    res, reports, _ = simulate_drive("urban", 400.0, cert, seed=3)
    log = tmp_path / "drive.csv"
    gnss = tmp_path / "drive.tpv.json"
    write_log(log, res.samples)
    write_gpspipe_log(gnss, reports)
    out = tmp_path / "report.json"
    assert (
        main(["diagnose", str(log), "--gnss", str(gnss), "--json", str(out), "--no-windows"]) == 0
    )
    rep = json.loads(out.read_text())
    mb = rep["moving_base"]
    assert mb["verdict"] == "ok"
    assert mb["gnss"]["used"] > 300
    assert "moving base: GNSS" in capsys.readouterr().out
    # bad lever arm, GNSS without --gnss, GNSS log from another day: exit 2 naming it
    assert main(["diagnose", str(log), "--gnss", str(gnss), "--lever-arm", "1,2"]) == 2
    assert "--lever-arm" in capsys.readouterr().err
    assert main(["diagnose", str(log), "--lever-arm", "1,2,3"]) == 2
    assert "needs --gnss" in capsys.readouterr().err
    shifted = [dict(r, time="2020-01-01T00:00:00.000Z") for r in reports[:3]]
    other = tmp_path / "other.json"
    write_gpspipe_log(other, shifted)
    assert main(["diagnose", str(log), "--gnss", str(other)]) == 2
    assert "does not overlap" in capsys.readouterr().err


def test_real_drive_moving_base():
    # rtklibexplorer drive_0708 (SOURCE.md) with a nominal data-sheet certificate:
    # |f| reads 1.33 % high in motion as at rest; a level car cannot tell az bias
    # (13 mg, inside the nominal +-20 mg) from az scale (+1.3 %, outside +-0.5 %):
    # reported as a finding, not as a fault; no other parameter stands out
    cert = load(REAL / "nominal-certificate.yaml")
    out = moving_base_diagnosis(
        read_log(REAL / "imu.csv.gz"), cert, read_gpspipe_log(REAL / "gnss.tpv.json.gz")
    )
    assert out["gnss"]["used"] > 530
    lat = out["gnss"]["latency"]
    assert lat["latency_s"] == pytest.approx(0.13, abs=0.03)
    # the correlation's std (41 ms) is above the 0.03 s tolerance: undetermined, the
    # estimate used with its std
    assert not lat["determined"] and "tolerance" in lat["reason"]
    assert lat["std_s"] == pytest.approx(0.041, abs=0.005)
    assert lat["used_s"] == lat["latency_s"] and lat["used_std_s"] == lat["std_s"]
    assert out["verdict"] == "ok" and out["faults"] == []
    groups = {tuple(f["group"]): f for f in out["findings"]}
    assert list(groups) == [("az bias", "az scale_factor")]
    f = groups[("az bias", "az scale_factor")]
    assert f["deviation"] == pytest.approx([0.0133, 0.0133], abs=0.001)
    assert f["windows"] == out["windows_run"] == 8
    assert not f["fault"]
    # the text gives each deviation and std in its unit (the certificate's: g, g/g)
    assert f["text"].startswith("az bias +0.01") and " g (std " in f["text"]
    assert "az scale_factor +0.01" in f["text"] and " g/g (std " in f["text"]
    # F0 in motion sees it on the epochs where the noise margin is smallest
    assert 10 < out["f0"]["failed"] < 80
    assert out["f0"]["f0_median"] == pytest.approx(0.0131, abs=0.001)


def test_simulate_drive_with_gnss_log(tmp_path, capsys):
    log, gnss = tmp_path / "hilly.csv", tmp_path / "hilly.tpv.json"
    assert (
        main(
            [
                "simulate",
                "hilly",
                "--param",
                "length=120",
                "--rate",
                "100",
                "--seed",
                "4",
                "--out",
                str(log),
                "--gnss",
                str(gnss),
            ]
        )
        == 0
    )
    block = read_log(log)
    track = read_gpspipe_log(gnss)
    # the same clock: UTC Unix seconds from EPOCH_UNIX; GNSS at 5 Hz tagged 0.12 s late
    assert block.t[0] == pytest.approx(EPOCH_UNIX)
    assert track.period_s() == pytest.approx(0.2)
    assert track.t[0] == pytest.approx(EPOCH_UNIX + 0.12, abs=1e-3)
    assert abs(track.t[-1] - block.t[-1]) < 1.0
    lines = gnss.read_text().splitlines()
    assert [json.loads(x)["class"] for x in lines[:4]] == ["VERSION", "DEVICES", "WATCH", "TPV"]
    assert (
        main(
            [
                "simulate",
                "static",
                "--duration",
                "5",
                "--out",
                str(tmp_path / "s.csv"),
                "--gnss",
                str(tmp_path / "s.json"),
            ]
        )
        == 2
    )
    assert "--gnss: only the drive scenarios" in capsys.readouterr().err
