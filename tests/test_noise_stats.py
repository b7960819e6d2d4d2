"""Allan deviation against allantools, PSD against scipy, theory and IEEE 952 identification."""

from __future__ import annotations

import math

import allantools
import numpy as np
import pytest
from scipy import signal

from imudiag.certificate import load_default
from imudiag.noise_stats import (
    FLICKER_FACTOR,
    allan_m_values,
    fit_allan_terms,
    fit_gauss_markov,
    identify_noise,
    overlapping_allan,
    theoretical_adev,
    welch_psd,
)
from imudiag.sim import Effects, simulate, still


def white_plus_walk(n: int, rate: float, white: float, walk: float, seed: int) -> np.ndarray:
    """Rate samples with Allan N = white (u sqrt(s)) and random walk K = walk (u/sqrt(s))."""
    rng = np.random.default_rng(seed)
    return (
        rng.standard_normal(n) * white * math.sqrt(rate)
        + np.cumsum(rng.standard_normal(n)) * walk / math.sqrt(rate)
        + 1000.0
    )


def test_oadev_matches_allantools():
    y = white_plus_walk(50_000, 100.0, 0.5, 0.2, seed=1)
    ours = overlapping_allan(y, 100.0)
    taus, adev, err, n = allantools.oadev(y, rate=100.0, data_type="freq", taus=ours.tau)
    np.testing.assert_allclose(taus, ours.tau)
    np.testing.assert_allclose(ours.adev, adev, rtol=1e-10)
    np.testing.assert_allclose(ours.error, err, rtol=1e-10)
    np.testing.assert_array_equal(ours.n, n)
    # octave taus and a short series too
    y2 = white_plus_walk(1000, 10.0, 1.0, 0.0, seed=2)
    m = 2 ** np.arange(9)
    ours2 = overlapping_allan(y2, 10.0, m=m)
    _, adev2, _, _ = allantools.oadev(y2, rate=10.0, data_type="freq", taus=m / 10.0)
    np.testing.assert_allclose(ours2.adev, adev2, rtol=1e-10)


def test_m_values_and_errors():
    m = allan_m_values(10_000, points_per_decade=5)
    assert m[0] == 1 and m[-1] <= 5000 and np.all(np.diff(m) > 0)
    with pytest.raises(ValueError, match="at least 3"):
        overlapping_allan(np.ones(2), 1.0)
    with pytest.raises(ValueError, match="non-finite"):
        overlapping_allan(np.array([1.0, np.nan, 2.0, 3.0]), 1.0)


def test_welch_matches_scipy():
    rng = np.random.default_rng(3)
    y = rng.standard_normal(20_000) + np.sin(2 * np.pi * 7.0 * np.arange(20_000) / 100.0)
    for nperseg in (256, 1000):
        ours = welch_psd(y, 100.0, nperseg)
        f, p = signal.welch(y, fs=100.0, nperseg=nperseg)
        np.testing.assert_allclose(ours.frequency, f)
        np.testing.assert_allclose(ours.density, p, rtol=1e-10, atol=1e-15)


def test_allan_curve_of_white_plus_random_walk_matches_theory():
    """Eight one-hour sessions at 50 Hz, N = 0.5 u sqrt(s), K = 0.1 u/sqrt(s): the mean Allan
    variance follows N^2/tau + K^2 tau/3 within 10 % for tau up to a tenth of the record
    (the spread of eight records there is about 25 % / sqrt(8))."""
    rate, n_white, k_walk = 50.0, 0.5, 0.1
    m = allan_m_values(180_000, points_per_decade=8, max_fraction=0.1)
    avar = np.zeros(m.shape[0])
    for seed in range(8):
        y = white_plus_walk(180_000, rate, n_white, k_walk, seed=10 + seed)
        a = overlapping_allan(y, rate, m=m)
        avar += a.adev**2 / 8
    theory = theoretical_adev(a.tau, white=n_white, random_walk=k_walk)
    ratio = np.sqrt(avar) / theory
    assert np.all(np.abs(ratio - 1) < 0.10), np.round(ratio, 3)
    # short tau (many terms) is much tighter
    assert np.all(np.abs(ratio[a.tau < 1.0] - 1) < 0.01)


def test_simulated_allan_curve_matches_theory(default_certificate):
    """The simulator's white noise (certificate density) plus bias drift against theory."""
    k = 1.0
    r = simulate(
        default_certificate,
        still(3600.0, rate_hz=50),
        seed=21,
        effects=Effects(bias_drift={"gz": k}),
    )
    a = overlapping_allan(
        r.samples.gyro[:, 2],
        50.0,
        m=allan_m_values(180_000, points_per_decade=8, max_fraction=0.02),
    )
    n_white = default_certificate.gyro.noise.density[2] / math.sqrt(2.0)  # IEEE N
    ratio = a.adev / theoretical_adev(a.tau, white=n_white, random_walk=k)
    # tau up to 72 s (at least 50 independent differences): one record, within 20 %
    assert np.all(np.abs(ratio - 1) < 0.2), np.round(ratio, 3)
    assert np.all(np.abs(ratio[a.tau < 2.0] - 1) < 0.03)


def test_identify_white_and_random_walk():
    y = white_plus_walk(360_000, 100.0, 0.5, 0.5, seed=5)
    terms = identify_noise(overlapping_allan(y, 100.0))
    assert abs(terms.white_noise / 0.5 - 1) < 0.02
    assert abs(terms.density_one_sided / (0.5 * math.sqrt(2)) - 1) < 0.02
    assert abs(terms.random_walk / 0.5 - 1) < 0.15
    assert terms.white_taus[0] == 0.01 and terms.random_walk_taus[1] <= 400.0
    assert terms.sources == {"white_noise": "slope", "random_walk": "slope"}
    assert not terms.bias_floor  # white + walk has no flat floor: B is an upper bound
    fit = terms.fit
    assert abs(fit["white_noise"] / 0.5 - 1) < 0.02 and abs(fit["random_walk"] / 0.5 - 1) < 0.15
    d = terms.as_dict()
    assert set(d) >= {"white_noise", "bias_instability", "random_walk", "density_one_sided"}


def flicker_noise(n: int, rate: float, b: float, seed: int) -> np.ndarray:
    """Rate noise with one-sided PSD B^2 / (pi f) (IEEE 952 bias instability B), by FFT shaping
    of a record 8 times longer (so the first n samples keep power below 1 / record length)."""
    rng = np.random.default_rng(seed)
    n_out, n = n, 8 * n
    f = np.fft.rfftfreq(n, 1.0 / rate)
    s1 = np.zeros_like(f)
    s1[1:] = b**2 / (math.pi * f[1:])
    amp = np.sqrt(s1 * rate * n / 2.0)
    z = (rng.standard_normal(f.shape[0]) + 1j * rng.standard_normal(f.shape[0])) / math.sqrt(2)
    return np.fft.irfft(z * amp, n)[:n_out]


def test_identify_bias_instability_floor():
    rate, n = 20.0, 1 << 18  # 3.6 hours
    y = flicker_noise(n, rate, 0.3, seed=7) + np.random.default_rng(8).standard_normal(
        n
    ) * 0.1 * math.sqrt(rate)
    terms = identify_noise(overlapping_allan(y, rate))
    assert terms.bias_floor
    assert abs(terms.bias_instability / 0.3 - 1) < 0.15
    assert abs(terms.fit["bias_instability"] / 0.3 - 1) < 0.15
    # white noise is only 2/3 of the variance at the shortest tau: read from the joint fit
    assert terms.sources["white_noise"] == "fit"
    assert abs(terms.white_noise / 0.1 - 1) < 0.1
    assert terms.random_walk is None


def test_theoretical_terms():
    tau = np.array([0.1, 1.0, 10.0])
    np.testing.assert_allclose(theoretical_adev(tau, white=2.0), 2.0 / np.sqrt(tau))
    np.testing.assert_allclose(theoretical_adev(tau, random_walk=3.0), 3.0 * np.sqrt(tau / 3))
    np.testing.assert_allclose(theoretical_adev(tau, bias_instability=1.0), FLICKER_FACTOR)
    np.testing.assert_allclose(theoretical_adev(tau, quantization=1.0), np.sqrt(3) / tau)
    # Gauss-Markov: a random walk K^2 = 2 sigma^2 / T at short tau, white N^2 = 2 sigma^2 T at long
    s, t_c = 2.0, 50.0
    short, long_ = np.array([1e-4]), np.array([1e6])
    np.testing.assert_allclose(
        theoretical_adev(short, markov=(s, t_c)),
        theoretical_adev(short, random_walk=math.sqrt(2 * s**2 / t_c)),
        rtol=1e-3,
    )
    np.testing.assert_allclose(
        theoretical_adev(long_, markov=(s, t_c)),
        theoretical_adev(long_, white=math.sqrt(2 * s**2 * t_c)),
        rtol=1e-3,
    )


def test_fit_gauss_markov_on_a_clean_curve():
    tau = np.logspace(-1, 3, 40)
    adev = theoretical_adev(tau, white=0.5, markov=(3.0, 40.0))
    from imudiag.noise_stats import AllanResult

    a = AllanResult(
        tau=tau, adev=adev, error=adev * 0.01, n=np.full(40, 10**6), rate_hz=10.0, samples=10**8
    )
    s, t_c, n_w = fit_gauss_markov(a)
    assert abs(s / 3.0 - 1) < 0.01 and abs(t_c / 40.0 - 1) < 0.02 and abs(n_w / 0.5 - 1) < 0.01
    terms = fit_allan_terms(
        AllanResult(
            tau=tau,
            adev=theoretical_adev(tau, white=1.0, random_walk=0.2),
            error=adev,
            n=np.full(40, 10**6),
            rate_hz=10.0,
            samples=10**8,
        )
    )
    assert abs(terms["white_noise"] - 1.0) < 1e-6 and abs(terms["random_walk"] - 0.2) < 1e-6


def test_default_certificate_density_convention():
    """sigma per sample = density sqrt(rate / 2); Allan N = density / sqrt(2)."""
    cert = load_default()
    assert cert.gyro.noise_sigma(200.0)[0] == pytest.approx(6.55 * 10.0)
