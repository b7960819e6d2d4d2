"""The sensor model and every effect, each recovered from simulated data within a stated
tolerance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imudiag.noise_stats import fit_gauss_markov, identify_noise, overlapping_allan, welch_psd
from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_ADC_ERROR, FLAG_GYRO_SATURATED, SampleBlock
from imudiag.sim import (
    BiasStep,
    Effects,
    PeriodicDisturbance,
    Simulator,
    TemperatureProfile,
    multi_position,
    simulate,
    still,
    turntable,
)
from imudiag.sim.trajectories import multi_position_motion


def model_si(cert, traj):
    """The certificate's noise-free outputs (N, 6) computed with TriadModel.forward_si."""
    return np.hstack([cert.gyro.forward_si(traj.omega), cert.accel.forward_si(traj.specific_force)])


def outputs(block: SampleBlock) -> np.ndarray:
    return np.hstack([block.gyro, block.accel])


def test_noise_free_model_is_the_certificate(default_certificate):
    tr = multi_position(n_attitudes=8, dwell_s=1.0, turn_s=1.0, rate_hz=100, seed=1)
    r = simulate(default_certificate, tr, effects=Effects.none())
    np.testing.assert_allclose(
        outputs(r.samples), model_si(default_certificate, tr), rtol=0, atol=1e-8
    )
    assert r.samples.temp is not None and np.all(r.samples.temp == 25.0)
    np.testing.assert_array_equal(r.samples.seq, np.arange(len(tr)))
    assert np.all(r.samples.flags == 0)
    assert r.samples.meta["sample_rate"] == 100.0


def test_white_noise_sigma_and_reproducibility(default_certificate):
    tr = still(200.0, rate_hz=200)
    a = simulate(default_certificate, tr, seed=11)
    b = simulate(default_certificate, tr, seed=11)
    c = simulate(default_certificate, tr, seed=12)
    np.testing.assert_array_equal(outputs(a.samples), outputs(b.samples))
    assert not np.array_equal(outputs(a.samples), outputs(c.samples))
    resid = outputs(a.samples) - model_si(default_certificate, tr)
    sigma = np.concatenate(
        [default_certificate.gyro.noise_sigma(200), default_certificate.accel.noise_sigma(200)]
    )
    # 40000 samples: the sample std is within 2 % of sigma (about 6 standard errors)
    np.testing.assert_allclose(resid.std(axis=0), sigma, rtol=0.02)
    assert np.all(np.abs(resid.mean(axis=0)) < 4 * sigma / math.sqrt(len(tr)))
    # Allan N at short tau and the PSD level agree with the density (sigma = d sqrt(rate/2))
    density = default_certificate.gyro.noise.density[0]
    terms = identify_noise(overlapping_allan(resid[:, 0], 200.0))
    assert abs(terms.density_one_sided / density - 1) < 0.03
    psd = welch_psd(resid[:, 0], 200.0, 1024)
    assert abs(math.sqrt(np.mean(psd.density[10:-10])) / density - 1) < 0.03


def test_chunked_simulator_equals_one_call(default_certificate):
    m = multi_position_motion(n_attitudes=6, dwell_s=1.0, turn_s=1.0, seed=2)
    tr = m.sample(200)
    eff = Effects.all_on(
        bias_step=[BiasStep("gz", 4.0, 15.0)], drop_rate=0.01, jitter_s=1e-4, adc_error_rate=0.01
    )
    whole = simulate(default_certificate, tr, seed=9, effects=eff).samples
    sim = Simulator(default_certificate, eff, (), 9)
    rng = np.random.default_rng(1)
    blocks, i = [], 0
    while i < len(tr):
        n = int(rng.integers(1, 400))
        blocks.append(sim.step(m.sample(200, i, min(n, len(tr) - i))))
        i += n
    joined = SampleBlock.concat(blocks)
    for name in ("t", "gyro", "accel", "temp", "flags", "seq"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name))


def test_temperature_bias_by_regression(default_certificate):
    prof = TemperatureProfile(start_c=20.0, warmup_c=15.0, warmup_tau_s=100.0)
    eff = Effects(temperature=prof, temperature_bias={"gx": 1.5, "az": -0.8})
    tr = still(600.0, rate_hz=100)
    r = simulate(default_certificate, tr, seed=3, effects=eff)
    temp = r.samples.temp
    assert temp[0] == 20.0 and abs(temp[-1] - (20.0 + 15.0 * (1 - math.exp(-6)))) < 0.01
    # slope of output on temperature: +-2 % (standard error about 0.3 %)
    slope_gx = np.polyfit(temp, r.samples.gyro[:, 0], 1)[0]
    slope_az = np.polyfit(temp, r.samples.accel[:, 2], 1)[0]
    assert abs(slope_gx / 1.5 - 1) < 0.02
    assert abs(slope_az / -0.8 - 1) < 0.02
    assert abs(np.polyfit(temp, r.samples.gyro[:, 1], 1)[0]) < 0.03
    # the true certificate holds the coefficient (reference 25 degC)
    assert r.certificate.gyro.temperature.bias_coefficient[0] == 1.5
    assert r.certificate.gyro.temperature.reference == 25.0


def test_temperature_scale_by_regression(default_certificate):
    prof = TemperatureProfile(start_c=10.0, ramp_c_per_s=0.1)  # 10 -> 40 degC in 300 s
    eff = Effects(temperature=prof, temperature_scale={"gz": 5e-4})
    tr = turntable(100.0, axis="z", duration_s=300.0, rate_hz=100)
    r = simulate(default_certificate, tr, seed=4, effects=eff)
    g = default_certificate.gyro
    nx = (tr.omega / g.unit_to_si) @ g.n_matrix().T
    # U_z = B_z + S_z (1 + c (T - 25)) (N x)_z: regress (U_z - B_z) / (S_z (N x)_z) - 1 on T - 25
    y = (r.samples.gyro[:, 2] - g.bias[2]) / (g.scale_factor[2] * nx[:, 2]) - 1.0
    c = np.polyfit(r.samples.temp - 25.0, y, 1)[0]
    assert abs(c / 5e-4 - 1) < 0.03
    np.testing.assert_allclose(r.certificate.gyro.temperature.scale_coefficient, [0, 0, 5e-4])


def test_g_sensitivity_by_regression(default_certificate):
    g_true = np.array([[1.3, 0.2, 0.0], [0.0, 1.4, -0.3], [0.1, 0.0, 1.2]])
    tr = multi_position(n_attitudes=14, dwell_s=20.0, turn_s=1.0, rate_hz=100, seed=6)
    r = simulate(default_certificate, tr, seed=6, effects=Effects(g_sensitivity=g_true))
    st = tr.static
    resid = r.samples.gyro[st] - default_certificate.gyro.forward_si(tr.omega[st])
    f_in = tr.specific_force[st] / default_certificate.accel.unit_to_si
    a = np.hstack([f_in, np.ones((f_in.shape[0], 1))])
    coef, *_ = np.linalg.lstsq(a, resid, rcond=None)
    # gyro noise is 46 counts a sample at 100 Hz: each coefficient has a standard error
    # se (about 0.05 count per m/s^2 here); every one within 4 se, and se < 5 % of G's diagonal
    dof = a.shape[0] - a.shape[1]
    s2 = np.sum((resid - a @ coef) ** 2, axis=0) / dof
    se = np.sqrt(np.outer(np.diag(np.linalg.inv(a.T @ a))[:3], s2)).T
    assert np.all(se < 0.05 * 1.2)
    assert np.all(np.abs(coef[:3].T - g_true) < 4 * se)
    np.testing.assert_allclose(r.certificate.gyro.g_sensitivity, g_true)


def test_scale_nonlinearity_by_regression(default_certificate):
    tr = multi_position(n_attitudes=14, dwell_s=4.0, turn_s=1.0, rate_hz=100, seed=7)
    q = {"ax": 0.1, "ay": -0.05, "az": 0.08}
    r = simulate(default_certificate, tr, seed=7, effects=Effects(scale_nonlinearity=q))
    acc = default_certificate.accel
    nx = (tr.specific_force / acc.unit_to_si) @ acc.n_matrix().T
    resid = r.samples.accel - acc.forward_si(tr.specific_force)
    for j, name in enumerate(("ax", "ay", "az")):
        est = np.polyfit(nx[:, j] ** 2, resid[:, j], 1)[0]
        assert abs(est / q[name] - 1) < 0.1, (name, est)


def test_bias_step_size_and_time(default_certificate):
    tr = still(60.0, rate_hz=200)
    r = simulate(
        default_certificate, tr, seed=8, effects=Effects(bias_step=[BiasStep("az", 37.3, 20.0)])
    )
    y = r.samples.accel[:, 2]  # noise 8.2 counts a sample
    n = y.shape[0]
    # change point: the split maximising the between-segment contrast (vectorised CUSUM)
    k = np.arange(1, n)
    c = np.cumsum(y)[:-1]
    contrast = np.abs(c / k - (y.sum() - c) / (n - k)) * np.sqrt(k * (n - k) / n)
    split = int(np.argmax(contrast)) + 1
    t_est = r.samples.t[split]
    size = y[split:].mean() - y[:split].mean()
    assert abs(t_est - 37.3) <= 0.05
    assert abs(size - 20.0) < 0.6  # standard error 0.15 count


def test_periodic_disturbance_from_spectrum(default_certificate):
    tr = still(200.0, rate_hz=200)  # noise 8.2 counts a sample: amplitude s.e. 0.06 count
    eff = Effects(periodic_disturbance=[PeriodicDisturbance("ay", 5.0, 13.7, 0.4)])
    r = simulate(default_certificate, tr, seed=9, effects=eff)
    y = r.samples.accel[:, 1] - r.samples.accel[:, 1].mean()
    psd = welch_psd(y, 200.0, 4096)
    f_peak = psd.frequency[np.argmax(psd.density)]
    assert abs(f_peak - 13.7) < 200.0 / 4096
    # refine: amplitude by least squares at the peak frequency, frequency by a fine search
    t = r.samples.t
    freqs = np.linspace(f_peak - 0.05, f_peak + 0.05, 201)
    amps = []
    for f in freqs:
        a = np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)], 1)
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        amps.append(math.hypot(*coef))
    best = int(np.argmax(amps))
    assert abs(freqs[best] - 13.7) < 0.002
    assert abs(amps[best] / 5.0 - 1) < 0.05


def test_bias_drift_random_walk_from_allan(default_certificate):
    tr = still(3600.0, rate_hz=50)
    r = simulate(default_certificate, tr, seed=10, effects=Effects(bias_drift={"gx": 2.0}))
    terms = identify_noise(overlapping_allan(r.samples.gyro[:, 0], 50.0))
    # K within 15 % (one hour: K is read from tau 10..360 s)
    assert terms.random_walk is not None and abs(terms.random_walk / 2.0 - 1) < 0.15
    assert abs(terms.density_one_sided / 6.55 - 1) < 0.03
    # the unaffected gy shows no random walk above the white noise
    gy = identify_noise(overlapping_allan(r.samples.gyro[:, 1], 50.0))
    assert gy.random_walk is None or gy.random_walk < 0.3
    assert r.certificate.gyro.noise.bias_random_walk[0] == 2.0


def test_bias_instability_gauss_markov(default_certificate):
    sigma, tau = 3.0, 20.0
    tr = still(7200.0, rate_hz=20)
    eff = Effects(white_noise=False, bias_instability={"ay": (sigma, tau)})
    r = simulate(default_certificate, tr, seed=12, effects=eff)
    x = r.samples.accel[:, 1] - default_certificate.accel.forward_si(tr.specific_force)[:, 1]
    # the process itself: stationary std and lag-1 coefficient a = exp(-dt / tau)
    assert abs(x.std() / sigma - 1) < 0.1
    a_hat = np.dot(x[1:], x[:-1]) / np.dot(x[:-1], x[:-1])
    assert abs(-0.05 / math.log(a_hat) / tau - 1) < 0.15
    # and its Allan curve with white noise on: fitted sigma within 20 %, tau within 30 %
    r2 = simulate(
        default_certificate, tr, seed=12, effects=Effects(bias_instability={"ay": (sigma, tau)})
    )
    s_fit, t_fit, _ = fit_gauss_markov(overlapping_allan(r2.samples.accel[:, 1], 20.0))
    assert abs(s_fit / sigma - 1) < 0.2
    assert abs(t_fit / tau - 1) < 0.3


def test_quantisation_and_saturation(default_certificate):
    tr = turntable(600.0, axis="x", duration_s=2.0, rate_hz=100, ramp_s=1.0)
    r = simulate(default_certificate, tr, seed=1, effects=Effects.board())
    u = outputs(r.samples)
    np.testing.assert_array_equal(u, np.round(u))
    assert u.min() >= 0 and u.max() <= 65535
    clean = model_si(default_certificate, tr)
    over = clean[:, 0] > 65535 + 50  # clearly beyond the range: saturated
    assert over.sum() > 50
    assert np.all(r.samples.gyro[over, 0] == 65535)
    assert np.all(r.samples.flags[over] & FLAG_GYRO_SATURATED)
    assert not np.any(r.samples.flags & FLAG_ACCEL_SATURATED)
    below = clean[:, 0] < 65535 - 50
    assert not np.any(r.samples.flags[below] & FLAG_GYRO_SATURATED)
    # per-triad ranges
    r2 = simulate(
        default_certificate, tr, seed=1, effects=Effects(saturation={"accel": (0.0, 36000.0)})
    )
    assert np.all(r2.samples.flags & FLAG_ACCEL_SATURATED)  # +g on x: 33078 + 4096 counts
    assert not np.any(r2.samples.flags & FLAG_GYRO_SATURATED)


def test_adc_errors(default_certificate):
    tr = still(100.0, rate_hz=200)
    clean = simulate(default_certificate, tr, seed=5, effects=Effects.board())
    bad = simulate(default_certificate, tr, seed=5, effects=Effects.board(adc_error_rate=0.01))
    flagged = (bad.samples.flags & FLAG_ADC_ERROR) != 0
    # 20000 samples at p = 0.01: 200 +- 14 expected; 4 sigma bounds
    assert 144 <= flagged.sum() <= 256
    diff = outputs(bad.samples) != outputs(clean.samples)
    assert not diff[~flagged].any()
    assert np.all(diff[flagged].sum(axis=1) <= 1)  # one garbage channel per error
    assert diff[flagged].sum() >= flagged.sum() - 2  # (a garbage value may equal the true one)


def test_dropped_frames_and_jitter(default_certificate):
    tr = still(50.0, rate_hz=200)
    r = simulate(default_certificate, tr, seed=6, effects=Effects(drop_rate=0.02, jitter_s=1e-4))
    s = r.samples
    lost = len(tr) - len(s)
    assert 200 - 4 * 14 <= lost <= 200 + 4 * 14
    assert np.all(np.diff(s.seq) >= 1) and np.any(np.diff(s.seq) > 1)
    assert np.all(np.diff(s.t) > 0)
    jitter = s.t - s.seq / 200.0
    assert abs(jitter.std() / 1e-4 - 1) < 0.05
    assert np.all(np.abs(jitter) <= 0.45 / 200 + 1e-9)
    # samples carry the truth row they came from
    np.testing.assert_allclose(s.accel[:, 2], model_si(default_certificate, tr)[s.seq, 5], atol=60)


def test_effects_validation():
    with pytest.raises(ValueError, match="unknown sensor"):
        Effects(bias_drift={"gq": 1.0})
    with pytest.raises(ValueError, match="drop_rate"):
        Effects(drop_rate=1.5)
    with pytest.raises(ValueError, match="3x3"):
        Effects(g_sensitivity=np.ones((2, 2)))
    e = Effects(g_sensitivity=[1.0, 2.0, 3.0], bias_step=[("gx", 1.0, 2.0)])
    np.testing.assert_array_equal(e.g_sensitivity, np.diag([1.0, 2.0, 3.0]))
    assert e.bias_step[0] == BiasStep("gx", 1.0, 2.0)
