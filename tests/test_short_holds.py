"""Issue 10 item 7: holds down to 0.5 s are used by default, each weighted by its noise."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from conftest import run_imudiag, run_imudiag_in_process

from imudiag.certificate import load, load_default
from imudiag.diagnosis.config import DiagnosisConfig
from imudiag.diagnosis.intervals import QuasiStaticInterval
from imudiag.diagnosis.params import certificate_vector, limit_vector


def test_default_minimum_hold_is_half_a_second():
    assert DiagnosisConfig().min_interval_s == 0.5


def test_a_short_interval_is_never_weighted_above_the_units_white_noise():
    quiet = np.diag([1e-4, 1e-4, 1e-4])  # 50 samples that happened to scatter little
    iv = QuasiStaticInterval(
        index=0,
        t_start=0.0,
        t_end=0.25,
        n=50,
        gyro_mean=np.zeros(3),
        accel_mean=np.array([0.0, 0.0, 1000.0]),
        gyro_cov=quiet,
        accel_cov=quiet,
        gyro_noise_var=np.array([4.0, 4.0, 4.0]),
        accel_noise_var=np.array([0.25, 1e-5, 0.25]),
    )
    np.testing.assert_allclose(iv.mean_var("gyro"), 4.0 / 50)
    np.testing.assert_allclose(iv.mean_var("accel"), np.array([0.25, 1e-4, 0.25]) / 50)
    bare = QuasiStaticInterval(
        index=0,
        t_start=0.0,
        t_end=0.25,
        n=50,
        gyro_mean=np.zeros(3),
        accel_mean=np.zeros(3),
        gyro_cov=quiet,
        accel_cov=quiet,
    )
    np.testing.assert_allclose(bare.mean_var("gyro"), 1e-4 / 50)


def test_forty_short_holds_are_all_used(tmp_path: Path):
    """40 holds of 1.6 s (0.85-1.1 s still once the detector has settled): the default uses
    all of them, twice the intervals and rotations of a 1 s minimum, and the calibration is
    at least as close to the truth."""
    log, truth = tmp_path / "short.csv.gz", tmp_path / "true.yaml"
    # the default calibration is the real subprocess; simulate and --min-interval in process
    r = run_imudiag_in_process(
        "simulate",
        "multiposition",
        "--param",
        "n=40",
        "--param",
        "dwell=1.6",
        "--param",
        "turn=1.0",
        "--seed",
        "5",
        "--out",
        str(log),
        "--true-certificate",
        str(truth),
    )
    assert r.returncode == 0, r.stderr
    like = load_default()
    lim = limit_vector(like.accel)
    like.accel.bias = like.accel.bias + 2 * lim[:3]
    like.accel.scale_factor_error = like.accel.scale_factor_error + 2 * lim[3:6]
    like.save(tmp_path / "like.yaml")
    figures = {}
    for opt in ((), ("--min-interval", "1.0")):
        out, js = tmp_path / f"cal{len(opt)}.yaml", tmp_path / f"cal{len(opt)}.json"
        r = (run_imudiag_in_process if opt else run_imudiag)(
            "calibrate",
            str(log),
            "--like",
            str(tmp_path / "like.yaml"),
            "--out",
            str(out),
            "--json",
            str(js),
            *opt,
        )
        assert r.returncode == 0, r.stderr
        s = json.loads(js.read_text())
        true = certificate_vector(load(truth).accel)
        err = (certificate_vector(load(out).accel) - true) / lim
        figures[opt] = (s["intervals"], s["rotations"], float(np.sqrt(np.mean(err**2))))
    (n_def, rot_def, err_def), (n_1, rot_1, err_1) = figures[()], figures[("--min-interval", "1.0")]
    assert n_def >= 38 and n_1 <= n_def / 2
    assert rot_def >= 2 * rot_1
    # both well within the limits of the truth (2 limits off in --like); the default no worse
    assert err_def < 0.1 and err_def <= err_1 * 1.1


def test_a_session_of_short_holds_alone_is_calibrated_from_them():
    """A hand session whose every hold is 0.6 s, the first too: the default detector (0.5 s
    window, 0.25 s trim) keeps none, and ``short_holds: auto`` takes the short-hold
    detector's. Until 2026-11-29 the short-hold pass ran only when the default one had
    kept at least one hold: such a session was refused as "never stood still"."""
    from imudiag.diagnosis.calibrate import calibrate
    from imudiag.diagnosis.session import collect_intervals
    from imudiag.sim import multi_position, simulate

    like = load_default()
    traj = multi_position(
        n_attitudes=24, dwell_s=0.6, turn_s=1.0, rate_hz=200.0, seed=3, first_dwell_s=0.6
    )
    samples = simulate(like, traj, seed=4).samples
    holds: dict = {}
    intervals, rate, _ = collect_intervals(samples, like, DiagnosisConfig(), holds=holds)
    assert holds["detector"].startswith("short holds") and "kept 0 of" in holds["detector"]
    assert len(intervals) == holds["used"] >= 22 and rate == 200.0
    res = calibrate(intervals, like, "exact", rate)
    assert res.refusals() == []
    # within a quarter of a limit of the truth (the simulated board is the certificate)
    dev = certificate_vector(res.certificate.accel) - certificate_vector(like.accel)
    assert np.all(np.abs(dev[:6]) < 0.25 * limit_vector(like.accel)[:6]), dev
