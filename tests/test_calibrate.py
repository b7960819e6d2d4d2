"""`imudiag calibrate`: scalar calibration on simulated and real multi-position sessions.

Real recordings (tests/data/real, see each SOURCE.md) with a ``--like``
certificate per recording (tests/data/diagnosis/like-*.yaml): calibrate, then
diagnose with the calibrated certificate (no fault expected) and with one
perturbed by 3 limits on one parameter (exactly that fault expected).
"""

from __future__ import annotations

import gzip
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag, run_imudiag_in_process

from imudiag.certificate import load, load_default
from imudiag.diagnosis.inputs import write_magnitudes
from imudiag.diagnosis.params import certificate_vector, limit_vector
from imudiag.logs import open_writer
from imudiag.sim import multi_position, simulate

DATA = Path(__file__).parent / "data"
LIKE = DATA / "diagnosis"
REAL = DATA / "real"


@pytest.fixture(scope="module")
def sim_session(tmp_path_factory):
    """A board whose true parameters are 1..5 limits off the bundled certificate."""
    like = load_default()
    true = like.copy()
    rng = np.random.default_rng(5)
    for t in (true.accel, true.gyro):
        lim = limit_vector(t)
        t.bias = t.bias + rng.uniform(-5, 5, 3) * lim[:3]
        t.scale_factor_error = t.scale_factor_error + rng.uniform(-5, 5, 3) * lim[3:6]
        t.misalignment = {k: v + rng.uniform(-3, 3) * lim[6] for k, v in t.misalignment.items()}
    traj = multi_position(n_attitudes=18, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=3)
    sim = simulate(true, traj, seed=4)
    d = tmp_path_factory.mktemp("cal")
    log = d / "session.npz"
    with open_writer(log, {"sample_rate": 200, "units": "gyro=count accel=count"}) as w:
        w.write(sim.samples)
    mags = d / "mags.csv"
    write_magnitudes(
        mags,
        traj.t,
        np.linalg.norm(traj.specific_force, axis=1),
        np.linalg.norm(traj.omega, axis=1),
    )
    return log, mags, true, d


def _errors(cert_path: Path, true) -> dict[str, np.ndarray]:
    cal = load(cert_path)
    return {
        t: (certificate_vector(cal.triad(t)) - certificate_vector(true.triad(t)))
        / limit_vector(true.triad(t))
        for t in ("accel", "gyro")
    }


@pytest.fixture(scope="module")
def exact_calibration(sim_session) -> tuple[Path, Path]:
    """``imudiag calibrate`` of the simulated session (the default, exact method), once per
    module: (certificate, summary)."""
    log, _, _, d = sim_session
    out, summary = d / "exact.yaml", d / "exact.json"
    r = run_imudiag(
        "calibrate",
        str(log),
        "--like",
        "config/default-certificate.yaml",
        "--out",
        str(out),
        "--json",
        str(summary),
    )
    assert r.returncode == 0, r.stderr
    return out, summary


def test_calibration_recovers_the_true_board(sim_session, exact_calibration, imudiag_cli):
    log, _, true, d = sim_session
    out, summary = exact_calibration
    err = _errors(out, true)
    assert np.all(np.abs(err["accel"]) < 0.1), err["accel"]
    assert np.all(np.abs(err["gyro"]) < 0.4), err["gyro"]
    s = json.loads(summary.read_text())
    spread = s["accel_norm_spread"]
    assert spread["after"]["rms"] < spread["before"]["rms"] / 100
    rot = s["rotation_residual_rms_deg"]
    assert rot["after"] < rot["before"] / 10
    assert s["undetermined"] == []
    cal = load(out)
    like = load_default()
    # units, scale factors and limits come from --like; noise is measured
    assert cal.accel.output_unit == like.accel.output_unit
    np.testing.assert_array_equal(cal.gyro.scale_factor, like.gyro.scale_factor)
    np.testing.assert_array_equal(cal.accel.limits.bias, like.accel.limits.bias)
    np.testing.assert_allclose(cal.accel.noise.density, like.accel.noise.density, rtol=0.1)
    # the accelerometer misalignment is written in the symmetric gauge
    m = cal.accel.misalignment
    assert m["xz"] == pytest.approx(-m["yz"]) and m["zy"] == pytest.approx(-m["xy"])
    # diagnosing the session with its own calibration finds nothing; with the old one, faults
    r = imudiag_cli("diagnose", str(log), "--certificate", str(out), "--json", "-")
    v = json.loads(r.stdout)["verdict"]
    assert v["faults"] == [] and (v["accel"], v["gyro"]) == ("ok", "ok")
    # (the diagnosis above is the real subprocess; the same command with the old one in process)
    r = run_imudiag_in_process("diagnose", str(log), "--json", "-", "--no-windows")
    assert json.loads(r.stdout)["verdict"]["accel"] == "fault"


def test_linear_and_moving_base_variants(sim_session, exact_calibration, imudiag_in_process):
    """The literal linearised calibration is measurably worse than the exact one. The
    commands' own entry point in this process: ``exact_calibration`` runs calibrate as a real
    subprocess, and test_option_validation's ``test_real_subprocess_per_command`` its refusal
    with exit 2."""
    imudiag_cli = imudiag_in_process
    log, mags, true, d = sim_session
    worst = {"exact": float(np.max(np.abs(_errors(exact_calibration[0], true)["accel"])))}
    for method in ("linear", "moving-base"):
        out = d / f"{method}.yaml"
        args = [
            "calibrate",
            str(log),
            "--like",
            "config/default-certificate.yaml",
            "--out",
            str(out),
            "--method",
            method,
        ]
        if method == "moving-base":
            args += ["--magnitude", str(mags)]
        r = imudiag_cli(*args)
        assert r.returncode == 0, r.stderr
        worst[method] = float(np.max(np.abs(_errors(out, true)["accel"])))
    assert worst["linear"] > 2 * worst["exact"]
    assert worst["moving-base"] < 1.0
    r = imudiag_cli(
        "calibrate",
        str(log),
        "--like",
        "config/default-certificate.yaml",
        "--out",
        str(d / "x.yaml"),
        "--method",
        "moving-base",
    )
    assert r.returncode == 2 and "--magnitude" in r.stderr


REAL_CASES = [
    # recording, --like certificate, perturbed parameter (triad, index 0..5), diagnose options
    ("xsens-mti-multiposition/session.csv.gz", "like-xsens.yaml", ("accel", 0), ()),
    ("xsens-mti-multiposition/session.csv.gz", "like-xsens.yaml", ("gyro", 4), ()),
    ("imucal-ferraris/session.csv.gz", "like-imucal.yaml", ("accel", 5), ()),
    ("mpu6050/calibration.csv.gz", "like-mpu6050.yaml", ("gyro", 2), ()),
    # the MPU-6050 run has 11 still intervals in 9 attitudes: little redundancy, and
    # a single window that sees them all; the defaults (3 degrees of freedom, 2 windows)
    # leave its accelerometers undetermined (checked below), these options judge it
    (
        "mpu6050/calibration.csv.gz",
        "like-mpu6050.yaml",
        ("accel", 1),
        ("--min-dof", "1", "--persist", "1"),
    ),
]
#: with the default detector only (--short-holds never), 11 holds in 9 attitudes: with
#: parameters pinned at --like (before the prior, issue 29) an attitude left out was predicted
#: 40x worse than in sample (3.4e-3 against 8.5e-5) and refused; regularised toward --like
#: with its limits (the weak ax/ay misalignment 98 % the prior's) each attitude left out is
#: predicted at 2.8e-4: written. The short-hold detector (the default) finds 20 holds in 10
#: attitudes (held out 5.6e-4 against 2.3e-4 in sample): written
SMALL_SESSIONS = {"mpu6050/calibration.csv.gz"}
SENSORS = {"accel": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz")}
CAUSES = ("bias", "scale_factor", "misalignment")


def _calibrate(recording: str, like: str, d: Path, imudiag_cli) -> tuple[Path, dict]:
    """Calibrate a recording once per module (cached in ``d``)."""
    out = d / (recording.replace("/", "_") + ".yaml")
    summary = d / (recording.replace("/", "_") + ".json")
    if not out.exists():
        args = (
            "calibrate",
            str(REAL / recording),
            "--like",
            str(LIKE / like),
            "--out",
            str(out),
            "--json",
            str(summary),
        )
        if recording in SMALL_SESSIONS:
            # the default detector's holds alone: few redundant ones, but the prior keeps the
            # attitudes left out predictable: written, checked by attitude
            r = imudiag_cli(*args, "--short-holds", "never")
            assert r.returncode == 0, r.stderr
            gen = json.loads(summary.read_text())["generalisation"]
            assert gen["generalises"] is True and gen["by"] == "attitude"
            assert gen["leave_one_out_rms"] < 4 * gen["in_sample_rms"]
            assert gen["leave_one_out_rms"] < 1e-3  # was 3.4e-3 with the pins
            out.unlink()
        # the default (issue 29): the short-hold detector where the default one keeps few
        r = imudiag_cli(*args)
        assert r.returncode == 0, r.stderr
        assert json.loads(summary.read_text())["generalisation"]["generalises"] is True
    return out, json.loads(summary.read_text())


@pytest.fixture(scope="module")
def real_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("real")


@pytest.fixture(scope="module")
def own_runs() -> dict[tuple[str, ...], subprocess.CompletedProcess[str]]:
    """``imudiag diagnose`` of a recording with its own calibration, by (recording, options)."""
    return {}


@pytest.mark.parametrize(
    "recording, like, perturbed, options",
    REAL_CASES,
    ids=[f"{c[0].split('/')[0]}-{c[2][0]}{c[2][1]}" for c in REAL_CASES],
)
def test_real_recording(
    recording, like, perturbed, options, real_dir, own_runs, imudiag_in_process
):
    # the commands' own entry point in this process: test_calibration_recovers_the_true_board
    # runs calibrate and diagnose as real subprocesses
    imudiag_cli = imudiag_in_process
    cert_path, summary = _calibrate(recording, like, real_dir, imudiag_cli)
    spread = summary["accel_norm_spread"]
    # |a| over the still intervals: at least tenfold tighter after calibration
    assert spread["after"]["rms"] < spread["before"]["rms"] / 10
    # with its own calibration: no fault (some parameters may stay undetermined); the same
    # command (recording, calibration, options) runs once per module
    key = (recording, *options)
    if key not in own_runs:
        own_runs[key] = imudiag_cli(
            "diagnose",
            str(REAL / recording),
            "--certificate",
            str(cert_path),
            "--json",
            "-",
            "--no-windows",
            *options,
        )
    r = own_runs[key]
    assert r.returncode == 0, r.stderr
    v = json.loads(r.stdout)["verdict"]
    assert v["faults"] == []
    assert v["accel"] in ("ok", "undetermined") and v["gyro"] in ("ok", "undetermined")
    # perturb one parameter the session determines by 3 limits: exactly that fault
    triad, index = perturbed
    und = {
        (u["triad"], u["sensor"] if index < 6 else None, u["cause"])
        for u in summary["undetermined"]
    }
    assert (triad, SENSORS[triad][index % 3], CAUSES[index // 3]) not in und
    cert = load(cert_path)
    t = cert.triad(triad)
    lim = limit_vector(t)[index]
    if index < 3:
        t.bias = t.bias + np.eye(3)[index] * 3 * lim
    else:
        t.scale_factor_error = t.scale_factor_error + np.eye(3)[index - 3] * 3 * lim
    bad = real_dir / f"perturbed-{triad}{index}-{Path(recording).parent.name}.yaml"
    cert.save(bad)
    r = imudiag_cli(
        "diagnose",
        str(REAL / recording),
        "--certificate",
        str(bad),
        "--json",
        "-",
        "--no-windows",
        *options,
    )
    v = json.loads(r.stdout)["verdict"]
    raised = [(f["triad"], f["sensor"], f["cause"]) for f in v["faults"] if f["cause"] != "f0"]
    assert raised == [(triad, SENSORS[triad][index % 3], CAUSES[index // 3])]
    # a persistent F0 failure (the daemon's fault too) only on that triad, explained by it
    for f in v["faults"]:
        if f["cause"] == "f0":
            assert f["triad"] == triad
            assert {"sensor": SENSORS[triad][index % 3], "cause": CAUSES[index // 3]} in f[
                "explained_by"
            ]
    assert v[triad] == "fault"
    if options:
        # with the defaults the short session cannot name the cause, never a wrong name; the
        # persistent F0 failure is a fault (as the daemon raises it) that nothing explains
        r = imudiag_cli(
            "diagnose",
            str(REAL / recording),
            "--certificate",
            str(bad),
            "--json",
            "-",
            "--no-windows",
        )
        v = json.loads(r.stdout)["verdict"]
        assert v[triad] == "fault"
        assert [(f["triad"], f["cause"], f["explained_by"]) for f in v["faults"]] == [
            (triad, "f0", [])
        ]


def _head(recording: str, seconds: float, d: Path) -> Path:
    """The first ``seconds`` of a shipped CSV recording, as a CSV in ``d``."""
    lines = gzip.open(REAL / recording, "rt").read().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or ln.startswith("t,")]
    t0 = float(lines[len(head)].split(",")[0])
    body = [ln for ln in lines[len(head) :] if float(ln.split(",")[0]) < t0 + seconds]
    out = d / f"{Path(recording).parent.name}-{seconds:g}s.csv"
    out.write_text("\n".join(head + body) + "\n")
    return out


def test_a_calibration_that_follows_its_own_holds_is_refused(tmp_path, imudiag_cli):
    """The first 90 s of the Xsens session with the default detector: 6 holds, each left out
    predicted 22x worse than in sample (rms 1.7e-3 against 7.7e-5, limit 6.4x): refused
    with exit 1 and the reason, nothing written; ``--force`` writes it with the warning.
    (The whole MPU-6050 run with the default detector was this case while weak parameters
    were pinned at --like; regularised toward it, that run generalises, see SMALL_SESSIONS.)"""
    log = _head("xsens-mti-multiposition/session.csv.gz", 90.0, tmp_path)
    out, summary = tmp_path / "c.yaml", tmp_path / "c.json"
    args = ("calibrate", str(log), "--like", str(LIKE / "like-xsens.yaml"), "--out", str(out),
            "--json", str(summary), "--short-holds", "never")  # fmt: skip
    r = imudiag_cli(*args)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "does not generalise" in r.stderr or "follows its own holds" in r.stderr
    assert not out.exists()
    js = json.loads(summary.read_text())
    assert js["refused"] is True and js["generalisation"]["generalises"] is False
    assert js["generalisation"]["leave_one_out_rms"] > 10 * js["generalisation"]["in_sample_rms"]
    # the refusal above is the real subprocess; with --force in process (exact_calibration
    # runs a calibration that writes its certificate as a real subprocess)
    r = run_imudiag_in_process(*args, "--force")
    assert r.returncode == 0, r.stderr
    assert "WARNING" in r.stderr
    assert "does not generalise" in load(out).device["warning"]


def test_a_session_with_a_stuck_output_is_refused_naming_it(tmp_path):
    """gy frozen at t = 20 s of a simulated multi-position session: calibrate wrote a
    certificate (its gyro 'kept from --like') and said nothing of the frozen sensor; it is
    now refused with the monitor's reason, exit 1, nothing written; --force writes it with
    the warning. The same session unfrozen is calibrated."""
    from imudiag.sim import Fault

    cert = load_default()
    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=12)
    logs = {}
    for name, faults in (("clean", []), ("stuck", [Fault("stuck", "gy", 20.0, None)])):
        logs[name] = tmp_path / f"{name}.csv"
        with open_writer(
            logs[name], {"sample_rate": 200.0, "units": "gyro=count accel=count"}
        ) as w:
            w.write(simulate(cert, traj, seed=13, faults=faults).samples)
    like = Path(__file__).parent.parent / "config" / "default-certificate.yaml"
    out, summary = tmp_path / "c.yaml", tmp_path / "c.json"
    args = ("calibrate", str(logs["stuck"]), "--like", str(like), "--out", str(out),
            "--json", str(summary))  # fmt: skip
    r = run_imudiag_in_process(*args)
    assert r.returncode == 1, r.stderr
    assert "refused" in r.stderr and "gyro gy stuck (one raw value for 50 samples" in r.stderr
    assert "a stuck output cannot be calibrated" in r.stderr and not out.exists()
    js = json.loads(summary.read_text())
    (stuck,) = js["stuck"]
    assert (stuck["triad"], stuck["sensor"], stuck["raised"]) == ("gyro", "gy", 1)
    assert 20.0 < stuck["t_first"] < 20.5
    r = run_imudiag_in_process(*args, "--force")
    assert r.returncode == 0, r.stderr
    assert "gyro gy stuck" in load(out).device["warning"]
    clean = run_imudiag_in_process(
        "calibrate", str(logs["clean"]), "--like", str(like), "--out", str(tmp_path / "k.yaml")
    )
    assert clean.returncode == 0, clean.stderr


@pytest.mark.parametrize("seed", [1, 3])
def test_a_like_certificate_that_is_already_right_is_not_refused(tmp_path, seed):
    """Issue 10 item 2: with the true certificate as --like, a correct fit predicts held-out
    holds about n / dof times worse than --like does; that is not a failure to generalise.
    Before the allowance 5 of 6 such sessions were refused (held out 2x 'uncalibrated').
    Both commands in process: ``exact_calibration`` runs calibrate as a real subprocess,
    test_sim_command simulate."""
    log, truth = tmp_path / "s.csv.gz", tmp_path / "truth.yaml"
    r = run_imudiag_in_process(
        "simulate", "multiposition", "--duration", "120", "--seed", str(seed),
        "--out", str(log), "--true-certificate", str(truth),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    js = tmp_path / "c.json"
    r = run_imudiag_in_process(
        "calibrate", str(log), "--like", str(truth), "--out", str(tmp_path / "c.yaml"),
        "--json", str(js),
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    g = json.loads(js.read_text())["generalisation"]
    assert g["generalises"] is True
    # the allowance is what the redundancy explains, no more: held out within it
    assert g["leave_one_out_rms"] > g["uncalibrated_rms"]
