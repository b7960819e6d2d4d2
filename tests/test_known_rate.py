"""Issue 10 item 6: gyros on a turntable at a known rate (the paper's "known rate").

The sessions are written as gyro-only CSV files (no accelerometer columns, as a
rate-table log has) from the certificate's own sensor model: 12 mountings of the
unit on the table, each a 20 s plateau at the table rate, with the table stopped
for 4 s between mountings (stopped plateaus, to be set aside) and 1 s ramps.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag, run_imudiag_in_process

from imudiag.certificate import load, load_default
from imudiag.diagnosis.known_rate import parse_known_rate
from imudiag.diagnosis.params import limit_vector
from imudiag.errors import BadInput
from imudiag.sim.trajectories import spread_up_directions

RATE_HZ = 200.0
TABLE_DEG_S = 200.0  # 33 1/3 rpm


def _session(path: Path, gyro, seed: int, other_rate_at: int | None = None) -> None:
    """Write the turntable session of ``gyro`` (a TriadModel) to ``path`` (gyro only)."""
    rng = np.random.default_rng(seed)
    axes = spread_up_directions(12, seed)
    pieces = []
    for k, axis in enumerate(axes):
        rate = TABLE_DEG_S * (1.35 if k == other_rate_at else 1.0)
        ramp = np.linspace(0.0, 1.0, int(RATE_HZ))
        profile = (
            np.concatenate(
                [
                    np.zeros(int(4 * RATE_HZ)),  # stopped while the unit is remounted
                    ramp,
                    np.ones(int(20 * RATE_HZ)),
                    ramp[::-1],
                ]
            )
            * rate
        )
        pieces.append(profile[:, None] * axis[None, :])
    w_deg = np.concatenate(pieces + [np.zeros((int(4 * RATE_HZ), 3))])
    u = gyro.forward(w_deg)
    sigma = gyro.noise_sigma(RATE_HZ)
    u = u + rng.normal(size=u.shape) * sigma
    t = np.arange(u.shape[0]) / RATE_HZ
    with open(path, "w") as fh:
        fh.write("t,gx,gy,gz\n")
        for row in np.column_stack([t, u]):
            fh.write(",".join(f"{v:.6f}" for v in row) + "\n")


def _truth():
    cert = load_default()
    g = cert.gyro
    lim = limit_vector(g)
    g.scale_factor_error = g.scale_factor_error + np.array([3.0, -2.0, 1.5]) * lim[3:6]
    g.bias = g.bias + np.array([-2.0, 1.0, 2.5]) * lim[:3]
    g.misalignment = dict(g.misalignment)
    g.misalignment["xz"] += 2.0 * lim[6]
    return cert


@pytest.mark.parametrize(
    ("text", "rad_s"),
    [
        ("33.333rpm", 33.333 * 2 * math.pi / 60),
        ("200 deg/s", math.radians(200.0)),
        ("3.49rad/s", 3.49),
        ("0.5rev/s", math.pi),
    ],
)
def test_known_rate_parses_with_its_unit(text, rad_s):
    assert parse_known_rate(text) == pytest.approx(rad_s)


@pytest.mark.parametrize("text", ["200", "200 rps", "-3rad/s", "0rpm", "fast deg/s", "inf rpm"])
def test_known_rate_without_a_valid_value_and_unit_is_refused(text):
    with pytest.raises(BadInput, match="--known-rate"):
        parse_known_rate(text)


def test_turntable_calibration_within_a_tenth_of_a_percent(tmp_path):
    truth = _truth()
    log = tmp_path / "table.csv"
    _session(log, truth.gyro, seed=4)
    out, js = tmp_path / "cal.yaml", tmp_path / "cal.json"
    like = tmp_path / "like.yaml"
    load_default().save(like)
    r = run_imudiag(
        "calibrate",
        str(log),
        "--like",
        str(like),
        "--known-rate",
        "33.333333rpm",
        "--out",
        str(out),
        "--json",
        str(js),
    )
    assert r.returncode == 0, r.stderr
    summary = json.loads(js.read_text())
    kr = summary["known_rate"]
    assert kr["plateaus"] == 12 and kr["unit"] == "deg/s"
    assert kr["rate"] == pytest.approx(200.0, rel=1e-6)
    # the stopped plateaus between mountings are set aside, each with its reason
    stopped = [x for x in summary["rejected"] if "stopped plateau" in x["reason"]]
    assert len(stopped) >= 10 and kr["set_aside"] == len(stopped)
    assert "set aside interval" in r.stdout and "plateaus at 200 deg/s used" in r.stdout
    # scale factors within 0.1 % of the truth (the figure), biases within 0.05 deg/s
    cal = load(out).gyro
    s = truth.gyro.scale_factor
    rel = np.abs(cal.scale_factor_error - truth.gyro.scale_factor_error) / s
    assert np.all(rel < 1e-3), rel
    assert np.all(np.abs(cal.bias - truth.gyro.bias) / s < 0.05)
    # what a scalar method sees of N (a rotation of the frame is invisible): N N^T
    n_cal, n_true = cal.n_matrix(), truth.gyro.n_matrix()
    assert np.max(np.abs(n_cal @ n_cal.T - n_true @ n_true.T)) < 2e-4
    # |w|/rate - 1 over the plateaus: far tighter after
    spread = kr["norm_spread"]
    assert spread["after"]["rms"] < spread["before"]["rms"] / 5
    assert summary["generalisation"]["generalises"] is True
    assert summary["generalisation"]["quantity"] == "|w|/rate - 1"
    # held out by mounting (plateaus whose rate points the same way in the body), as another
    # session of the unit asks: 12 mountings, each left out in turn
    assert summary["generalisation"]["by"] == "attitude"
    assert summary["generalisation"]["attitudes_held_out"] == 12
    # the accelerometers are kept from --like and said to be
    assert np.allclose(load(out).accel.bias, load_default().accel.bias)
    assert any(
        u["triad"] == "accel" and "known-rate session" in u["reason"]
        for u in summary["undetermined"]
    )


def test_a_plateau_at_another_speed_is_set_aside(tmp_path):
    truth = _truth()
    log = tmp_path / "table.csv"
    _session(log, truth.gyro, seed=5, other_rate_at=7)
    like = tmp_path / "like.yaml"
    load_default().save(like)
    out, js = tmp_path / "cal.yaml", tmp_path / "cal.json"
    # in process: test_turntable_calibration_within_a_tenth_of_a_percent is the real subprocess
    r = run_imudiag_in_process(
        "calibrate",
        str(log),
        "--like",
        str(like),
        "--known-rate",
        "200deg/s",
        "--out",
        str(out),
        "--json",
        str(js),
    )
    assert r.returncode == 0, r.stderr
    summary = json.loads(js.read_text())
    other = [x for x in summary["rejected"] if "not at the known rate" in x["reason"]]
    # 270 deg/s, seen through the --like certificate (the unit's scale errors uncorrected)
    assert len(other) == 1 and 260.0 < other[0]["rate"] < 285.0
    assert summary["known_rate"]["plateaus"] == 11
    rel = np.abs(load(out).gyro.scale_factor_error - truth.gyro.scale_factor_error)
    assert np.all(rel / truth.gyro.scale_factor < 1e-3)


def test_a_gyro_only_log_needs_the_known_rate(tmp_path):
    log = tmp_path / "table.csv"
    _session(log, load_default().gyro, seed=6)
    like = tmp_path / "like.yaml"
    load_default().save(like)
    # in process: calibrate's refusal with exit 2 runs as a real subprocess in
    # test_option_validation.py (test_real_subprocess_per_command)
    r = run_imudiag_in_process(
        "calibrate", str(log), "--like", str(like), "--out", str(tmp_path / "o.yaml")
    )
    assert r.returncode == 2
    assert "ax" in r.stderr and not (tmp_path / "o.yaml").exists()


def test_diagnose_on_the_turntable_names_a_scale_factor_three_limits_off(tmp_path):
    truth = _truth()
    log = tmp_path / "table.csv"
    _session(log, truth.gyro, seed=7)
    good = tmp_path / "good.yaml"
    truth.save(good)
    r = run_imudiag(
        "diagnose",
        str(log),
        "--certificate",
        str(good),
        "--known-rate",
        "200deg/s",
        "--json",
        "-",
        "--no-windows",
    )
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["verdict"]["faults"] == [] and report["verdict"]["gyro"] == "ok"
    assert report["verdict"]["accel"] == "undetermined"
    assert report["f0"]["gyro"] == {"checked": 12, "failed": 0, "check": "known_rate"}
    bad = _truth()
    lim = limit_vector(bad.gyro)
    bad.gyro.scale_factor_error = bad.gyro.scale_factor_error + np.array([0.0, 3.0, 0.0]) * lim[3:6]
    path = tmp_path / "bad.yaml"
    bad.save(path)
    # the diagnosis with the good certificate above is the real subprocess; this one in process
    r = run_imudiag_in_process(
        "diagnose",
        str(log),
        "--certificate",
        str(path),
        "--known-rate",
        "200deg/s",
        "--json",
        "-",
        "--no-windows",
    )
    assert r.returncode == 0, r.stderr
    faults = json.loads(r.stdout)["verdict"]["faults"]
    named = [(f["triad"], f["sensor"], f["cause"]) for f in faults if f["cause"] != "f0"]
    assert named == [("gyro", "gy", "scale_factor")]
    for f in faults:
        if f["cause"] == "f0":
            assert f["triad"] == "gyro" and f["check"] == "known_rate"
            assert {"sensor": "gy", "cause": "scale_factor"} in f["explained_by"]
