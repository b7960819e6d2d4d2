"""The simulator makes each IEEE 952 noise term (flicker floor from a sum of Gauss-Markov
processes, Gauss-Markov bias, rate random walk, rate ramp), and the true certificate it
returns predicts the measured Allan deviation (closed form, per sensor)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imudiag.certificate import FLICKER_FACTOR, markov_allan_shape
from imudiag.noise_stats import overlapping_allan
from imudiag.sim import Effects, simulate, still
from imudiag.sim.processes import flicker_components
from imudiag.sim.scenarios import describe, parse_effects

RATE = 20.0


@pytest.mark.parametrize("band", [(0.1, 1000.0), (0.05, 2.0e4), (1.0, 10.0)])
def test_flicker_components_sum_to_a_flat_allan_floor(band: tuple[float, float]) -> None:
    tc, w = flicker_components(band)
    assert np.all(w >= 0) and np.all(np.diff(tc) > 0)
    tau = np.logspace(math.log10(band[0]), math.log10(band[1]), 200)
    total = markov_allan_shape(tau[:, None] / tc[None, :]) @ w
    assert np.all(np.abs(np.sqrt(total) - 1.0) < 0.01)


def _measured_vs_predicted(r, col: int, min_independent: int = 30):
    y = np.hstack([r.samples.gyro, r.samples.accel])[:, col]
    allan = overlapping_allan(y, RATE, points_per_decade=5)
    keep = (allan.independent >= min_independent) & (allan.tau >= 0.1)
    tri = r.certificate.gyro if col < 3 else r.certificate.accel
    pred = tri.allan_deviation(allan.tau[keep])[col % 3]
    return allan.tau[keep], allan.adev[keep], pred


def test_flicker_floor_is_simulated_and_predicted(default_certificate) -> None:
    b = 40.0  # counts: a floor of 26.6 counts, well above the white noise beyond 1 s
    tr = still(3600.0, rate_hz=RATE)
    r = simulate(
        default_certificate,
        tr,
        seed=3,
        effects=Effects(flicker={"gz": b}, flicker_band=(0.1, 1.0e4)),
    )
    assert r.certificate.gyro.noise.bias_instability.tolist() == [0.0, 0.0, b]
    tau, meas, pred = _measured_vs_predicted(r, 2)
    ratio = meas / pred
    assert np.all((ratio > 1 / 1.3) & (ratio < 1.3)), (tau, ratio)
    floor = tau >= 5.0
    # flat: the measured deviation beyond 5 s stays near 0.664 B
    assert np.all(np.abs(meas[floor] / (FLICKER_FACTOR * b) - 1.0) < 0.3)
    # the other gyros keep their white noise only
    tau, meas, pred = _measured_vs_predicted(r, 0)
    assert np.all(np.abs(np.log(meas / pred)) < math.log(1.3))


def test_rate_ramp_and_gauss_markov_are_predicted(default_certificate) -> None:
    tr = still(3600.0, rate_hz=RATE)
    eff = Effects(
        rate_ramp={"ax": 0.02}, bias_instability={"gy": (8.0, 30.0)}, bias_drift={"az": 0.5}
    )
    r = simulate(default_certificate, tr, seed=4, effects=eff)
    n = r.certificate.accel.noise
    assert n.rate_ramp.tolist() == [0.02, 0.0, 0.0]
    g = r.certificate.gyro.noise
    assert g.gauss_markov_sigma.tolist() == [0.0, 8.0, 0.0]
    assert g.gauss_markov_time[1] == 30.0
    for col in (1, 3, 5):
        tau, meas, pred = _measured_vs_predicted(r, col)
        ratio = meas / pred
        assert np.all((ratio > 1 / 1.35) & (ratio < 1.35)), (col, tau, ratio)


def test_effect_text_for_the_new_terms() -> None:
    e = parse_effects(["none", "flicker:gx:3.5", "flicker:ay:0.2:0.5:500", "rate_ramp:gz:-0.01"])
    assert e.flicker == {"gx": 3.5, "ay": 0.2} and e.flicker_band == (0.5, 500.0)
    assert e.rate_ramp == {"gz": -0.01}
    assert {"flicker", "rate_ramp"} <= set(describe(e))
    for bad in ("flicker:gx", "flicker:gx:-1", "flicker:gx:1:5:2", "rate_ramp:gx"):
        with pytest.raises(ValueError, match="effect"):
            parse_effects([bad])


def test_the_ramp_is_a_straight_line(default_certificate) -> None:
    tr = still(100.0, rate_hz=RATE)
    r = simulate(
        default_certificate, tr, seed=0, effects=Effects(white_noise=False, rate_ramp={"gx": 0.5})
    )
    base = simulate(default_certificate, tr, seed=0, effects=Effects(white_noise=False))
    d = r.samples.gyro[:, 0] - base.samples.gyro[:, 0]
    assert np.allclose(d, 0.5 * tr.t)


def test_quantization_is_simulated_and_predicted(default_certificate) -> None:
    """An integrating output counted in steps q (remainder carried): outputs are the
    certificate's bias plus whole steps, nothing is lost over the session, and the true
    certificate's Q = q / (rate sqrt(12)) predicts the measured Allan deviation."""
    step = 120.0  # counts per sample: Q = 1.73 count s at 20 Hz
    eff = Effects(quantization={"gy": step})
    r = simulate(default_certificate, still(1200.0, rate_hz=RATE), seed=6, effects=eff)
    q = r.certificate.gyro.noise.quantization
    assert q is not None and q.tolist() == pytest.approx([0.0, step / (RATE * math.sqrt(12)), 0.0])
    y = r.samples.gyro[:, 1]
    k = (y - y[0]) / step
    assert np.all(np.abs(k - np.round(k)) < 1e-6)  # whole steps apart
    # the remainder is carried: the mean is that of the unquantised output
    bias = default_certificate.gyro.bias[1]
    assert abs(np.mean(y) - bias) < 6.55 * math.sqrt(RATE / 2) / math.sqrt(y.shape[0]) * 5 + (
        step / y.shape[0]
    )
    tau, meas, pred = _measured_vs_predicted(r, 1)
    short = tau <= 0.3  # where 3 Q^2 / tau^2 dominates
    ratio = meas / pred
    assert np.all((ratio > 1 / 1.2) & (ratio < 1.2)), (tau, ratio)
    # and it is not white noise there: the white noise alone predicts too little
    white = default_certificate.gyro.noise.density[1] / np.sqrt(2.0 * tau[short])
    assert np.all(meas[short] > 1.3 * white)


def test_quantization_effect_text() -> None:
    e = parse_effects(["quantization:gx:50", "quantization:ay:0.05"])
    assert e.quantization == {"gx": 50.0, "ay": 0.05}
    assert "quantization" in describe(e)
    with pytest.raises(ValueError, match="quantization:gx:0"):
        parse_effects(["quantization:gx:0"])
    with pytest.raises(ValueError, match="expected quantization:SENSOR:STEP"):
        parse_effects(["quantization:gx"])


def test_simulate_command_writes_the_quantization_it_simulates(tmp_path) -> None:
    """`imudiag simulate --effect quantization:S:STEP` in a real subprocess: the log's gx
    moves in whole steps, the true certificate carries Q = STEP / (rate sqrt(12)) (count
    s); a step of 0 is refused in one line naming the effect, exit 2."""
    from conftest import run_imudiag_in_process

    from imudiag.certificate import load
    from imudiag.logs import read_log

    out, true = tmp_path / "q.csv.gz", tmp_path / "true.yaml"
    # in process: simulate writes and refuses in real subprocesses in test_sim_command.py
    r = run_imudiag_in_process(
        "simulate", "still", "--duration", "20", "--rate", "50", "--effect",
        "quantization:gx:200", "--out", str(out), "--true-certificate", str(true),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    gx = read_log(out).gyro[:, 0]
    assert np.all(np.abs((gx - gx[0]) / 200.0 - np.round((gx - gx[0]) / 200.0)) < 1e-9)
    q = load(true).gyro.noise.quantization
    assert q is not None and q.tolist() == pytest.approx([200.0 / (50.0 * math.sqrt(12)), 0, 0])
    bad = run_imudiag_in_process(
        "simulate", "still", "--duration", "5", "--effect", "quantization:gx:0",
        "--out", str(tmp_path / "bad.csv.gz"),
    )  # fmt: skip
    assert bad.returncode == 2
    last = bad.stderr.strip().splitlines()[-1]
    assert "quantization:gx:0" in last and "STEP > 0" in last
    assert not (tmp_path / "bad.csv.gz").exists()
