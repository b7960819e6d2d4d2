"""A gyro's bias that steps mid-session (a shock, a power cycle) is named as that gyro's bias.

The windows of the diagnosis roll over the last 24 still intervals, so for most of a
session after a step they hold intervals from both sides of it. Before 2026-11-29 the
MEMS gyro's rest bias was the mean of every interval of the window, with the std the
larger of its noise and the means' scatter: the step's scatter made the std about a limit,
the parameter "not determined", and neither face named the cause (only the rest-rate F0
check on the axis). Now a window splits an axis's rest rate at a step
(:func:`imudiag.diagnosis.gyro_fit.rest_rate_steps`) and takes the bias from the intervals
after it; the step is listed in the window's ``rest_step``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.api import diagnose
from imudiag.certificate import load_default
from imudiag.diagnosis import diagnose_samples
from imudiag.diagnosis.gyro_fit import (
    REST_STEP_MIN_LIMITS,
    REST_STEP_MIN_SIDE,
    REST_STEP_SIGMA,
    rest_bias,
    rest_rate_steps,
    rest_rotation_fit,
)
from imudiag.sim import Fault, multi_position, simulate

DATA = Path(__file__).parent / "data"
REAL, LIKE = DATA / "real", DATA / "diagnosis"
K = 24  #: intervals of a window of the diagnosis (its default)
COUNTS = np.full(K, 600.0)  #: samples per interval (3 s at 200 Hz)


def _white_means(rng: np.random.Generator, sigma: np.ndarray) -> np.ndarray:
    """K interval means (K, 3) of white noise about a fixed bias, output units."""
    return 32_000.0 + sigma * rng.standard_normal((K, 3))


def test_white_noise_has_no_step() -> None:
    """2000 windows of white-noise means (each axis its own sigma): no step is found, the
    best split's score staying below the threshold."""
    rng = np.random.default_rng(2611)
    sigma = np.array([0.5, 2.0, 8.0])
    found = 0
    for _ in range(2000):
        means = _white_means(rng, sigma)
        found += len(rest_rate_steps(means, np.tile(sigma**2, (K, 1)), COUNTS))
    assert found == 0


def test_bias_wander_within_the_noise_has_no_step() -> None:
    """Means whose scatter is twice their stated noise (bias instability the certificate
    understates): the scatter sets each side's std, and no step is found."""
    rng = np.random.default_rng(2612)
    sigma = np.array([1.0, 1.0, 1.0])
    found = 0
    for _ in range(1000):
        means = _white_means(rng, 2.0 * sigma)
        found += len(rest_rate_steps(means, np.tile(sigma**2, (K, 1)), COUNTS))
    assert found == 0


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5, 6])
def test_a_step_is_found_on_its_axis_at_its_interval(seed: int) -> None:
    """A step of 15 to 60 sigma on a random axis at a random interval (with at least
    REST_STEP_MIN_SIDE intervals each side): found on that axis alone, at that interval,
    with the two levels of the means."""
    rng = np.random.default_rng(seed)
    sigma = np.array([1.0, 1.5, 2.0])
    means = _white_means(rng, sigma)
    axis = int(rng.integers(3))
    index = int(rng.integers(REST_STEP_MIN_SIDE, K - REST_STEP_MIN_SIDE + 1))
    size = float(rng.uniform(15.0, 60.0)) * sigma[axis] * float(rng.choice([-1.0, 1.0]))
    means[index:, axis] += size
    (step,) = rest_rate_steps(means, np.tile(sigma**2, (K, 1)), COUNTS)
    assert (step.axis, step.index) == (axis, index)
    assert step.z > REST_STEP_SIGMA
    assert step.after - step.before == pytest.approx(size, abs=3.0 * sigma[axis])
    assert step.after == pytest.approx(means[index:, axis].mean())


def test_a_step_too_near_the_window_end_is_not_split() -> None:
    """Fewer than REST_STEP_MIN_SIDE intervals after a step: not split (the window rolls
    on, and later windows see enough of the new level)."""
    rng = np.random.default_rng(7)
    sigma = np.ones(3)
    means = _white_means(rng, sigma)
    means[K - REST_STEP_MIN_SIDE + 1 :, 0] += 100.0
    assert rest_rate_steps(means, np.tile(sigma**2, (K, 1)), COUNTS) == []


def test_without_interval_times_the_bias_is_every_interval() -> None:
    """A calibration passes no times: its bias is the mean of every interval, step or
    not (the fit used by calibrate is unchanged)."""
    cert = load_default()
    rng = np.random.default_rng(8)
    sigma = np.ones(3)
    means = _white_means(rng, sigma)
    means[12:, 1] += 200.0
    var = np.tile(sigma**2, (K, 1))
    plain = rest_rotation_fit(cert.gyro, means, var, COUNTS, cert.earth_rate, None, 0.5)
    est, std = rest_bias(cert.gyro, means, var, COUNTS, cert.earth_rate)
    np.testing.assert_array_equal(plain.estimate[:3], est)
    np.testing.assert_array_equal(plain.std[:3], std)
    assert "rest_step" not in plain.extra
    starts = 4.5 * np.arange(K)
    split = rest_rotation_fit(
        cert.gyro, means, var, COUNTS, cert.earth_rate, None, 0.5, starts=starts
    )
    assert split.estimate[1] == pytest.approx(means[12:, 1].mean())
    assert split.std[1] < std[1] / 10
    assert [s["sensor"] for s in split.extra["rest_step"]] == ["gy"]
    assert split.extra["rest_step"][0]["t_after"] == pytest.approx(starts[12])
    np.testing.assert_array_equal(split.estimate[[0, 2]], est[[0, 2]])


def _hidden_steps(n: int, seed: int) -> list:
    """``n`` bias steps picked at random from the catalogue (gyro axis, time in the
    session, size 3 to 9 limits, sign) under ``seed``."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        sensor = "g" + "xyz"[int(rng.integers(3))]
        at = round(float(rng.uniform(35.0, 80.0)), 1)
        factor = round(float(rng.uniform(3.0, 9.0)) * float(rng.choice([-1.0, 1.0])), 2)
        out.append(pytest.param(sensor, at, factor, id=f"{sensor}-{factor:+.2f}x-at-{at}s"))
    return out


@pytest.mark.parametrize("sensor, at_s, factor", _hidden_steps(3, seed=2911))
def test_a_hidden_bias_step_is_named_as_that_gyros_bias(
    sensor: str, at_s: float, factor: float
) -> None:
    """A 135-s multi-position session whose gyro bias steps mid-session: the verdict names
    that gyro's bias (and nothing else), first in a window after the step, the estimate
    the stepped bias; the windows after it list the step on that axis alone."""
    cert = load_default()
    axis = "xyz".index(sensor[1])
    limit = float(cert.gyro.limits.bias[axis])
    traj = multi_position(n_attitudes=30, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=41)
    sim = simulate(cert, traj, seed=46, faults=[Fault("bias", sensor, at_s, factor * limit)])
    diag = diagnose_samples(cert, sim.samples, rate_hz=traj.rate_hz)
    verdict = diag.verdict()
    assert [(f["triad"], f["sensor"], f["cause"]) for f in verdict["faults"]] == [
        ("gyro", sensor, "bias")
    ]
    assert (verdict["accel"], verdict["gyro"]) == ("ok", "fault")
    (fault,) = verdict["faults"]
    assert fault["t_first"] > at_s
    truth = float(cert.gyro.bias[axis]) + factor * limit
    assert abs(fault["estimate"] - truth) < max(4.0 * fault["std"], 0.3 * limit)
    stepped = [w for w in diag.windows if w.gyro.extra.get("rest_step")]
    assert stepped
    for w in stepped:
        (step,) = w.gyro.extra["rest_step"]
        assert step["sensor"] == sensor
        # the first interval of the new level holds the step (a 3-s hold) or is the next
        # one (a pose, 4.5 s, later)
        assert at_s - 3.0 <= step["t_after"] <= at_s + 4.5
        assert np.sign(step["after"] - step["before"]) == np.sign(factor)
    # no window before the step splits anything
    assert all(not w.gyro.extra.get("rest_step") for w in diag.windows if w.t_end < at_s)


def test_a_step_smaller_than_half_a_limit_is_not_split() -> None:
    """A step far beyond the noise but below REST_STEP_MIN_LIMITS of the bias limit (the
    slow wander of a real unit's rest rate scores so): the window's bias stays the mean
    of every interval."""
    cert = load_default()
    rng = np.random.default_rng(9)
    sigma = np.full(3, 0.1)
    means = _white_means(rng, sigma)
    small = 0.4 * REST_STEP_MIN_LIMITS * float(cert.gyro.limits.bias[2])
    means[12:, 2] += small
    var = np.tile(sigma**2, (K, 1))
    assert rest_rate_steps(means, var, COUNTS)  # beyond the noise
    fit = rest_rotation_fit(
        cert.gyro, means, var, COUNTS, cert.earth_rate, None, 0.5, starts=4.5 * np.arange(K)
    )
    assert "rest_step" not in fit.extra
    est, _ = rest_bias(cert.gyro, means, var, COUNTS, cert.earth_rate)
    np.testing.assert_array_equal(fit.estimate[:3], est)


def test_the_real_mpu6050_hold_has_no_step() -> None:
    """The MPU-6050's real 449-s still hold (tests/data/real/mpu6050): its gz rest rate
    wanders by 1.1 counts at 6.1 sigma between the hold's first and second half, 0.008 of
    its 131-count limit. No window splits it; the report is that of every interval."""
    report = diagnose(str(REAL / "mpu6050/static.csv.gz"), str(LIKE / "like-mpu6050.yaml"))
    assert report["windows"]
    assert not [w for w in report["windows"] if w["gyro"].get("rest_step")]


def _steps_by_definition(means, var, counts, min_size=0.0):
    """The split-by-split definition of rest_rate_steps: every split scored with
    _rest_mean_var of its two parts, the first highest kept per axis."""
    from imudiag.diagnosis.gyro_fit import _rest_mean_var

    k = means.shape[0]
    best: list = [None, None, None]
    for split in range(REST_STEP_MIN_SIDE, k - REST_STEP_MIN_SIDE + 1):
        m0, v0 = _rest_mean_var(means[:split], var[:split], counts[:split])
        m1, v1 = _rest_mean_var(means[split:], var[split:], counts[split:])
        z = np.abs(m1 - m0) / np.sqrt(v0 + v1)
        z[np.abs(m1 - m0) < min_size] = 0.0
        for a in range(3):
            if z[a] > REST_STEP_SIGMA and (best[a] is None or z[a] > best[a][2]):
                best[a] = (a, split, float(z[a]), float(m0[a]), float(m1[a]))
    return [b for b in best if b is not None]


def _random_window(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A seeded random window: 5 to 24 interval means (K, 3), their variances and sample
    counts (unequal), with a step of random size on a random axis in two thirds of them."""
    k = int(rng.integers(5, 25))
    sigma = rng.uniform(0.3, 3.0, 3)
    counts = rng.integers(200, 900, k).astype(float)
    means = 32_000.0 + sigma * rng.standard_normal((k, 3))
    if rng.random() < 2 / 3:
        means[int(rng.integers(1, k)) :, int(rng.integers(3))] += rng.uniform(-80, 80)
    var = np.tile(sigma**2, (k, 1)) * rng.uniform(0.5, 2.0, (k, 1))
    return means, var, counts


def test_the_prefix_sums_score_every_split_as_the_definition_does() -> None:
    """On 300 seeded random windows (5 to 24 intervals, unequal counts and noise, a step
    of random size on a random axis in two thirds of them, a size floor in half): the
    same steps, at the same intervals, the same sigma to 1e-9 and the same levels."""
    rng = np.random.default_rng(2913)
    found = 0
    for _ in range(300):
        means, var, counts = _random_window(rng)
        floor = float(rng.uniform(0, 20)) if rng.random() < 0.5 else 0.0
        want = _steps_by_definition(means, var, counts, floor)
        got = rest_rate_steps(means, var, counts, floor)
        assert [(s.axis, s.index) for s in got] == [(w[0], w[1]) for w in want]
        for s, w in zip(got, want, strict=True):
            assert s.z == pytest.approx(w[2], rel=1e-9)
            assert (s.before, s.after) == (w[3], w[4])
        found += len(got)
    assert found > 50  # 75 steps found on these windows


def test_the_compiled_scores_equal_the_plain_ones() -> None:
    """The rest-rate steps with the compiled kernels (numba, the ``fleet`` extra:
    :func:`imudiag.numba_kernels.rest_step_scores`) and without, on 300 seeded windows as
    above plus windows of one repeated mean (every score 0) and an interval of zero noise:
    the same steps, at the same intervals, the same sigma and levels, bit for bit."""
    from imudiag import kernels

    pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")
    rng = np.random.default_rng(2914)
    found = 0
    for trial in range(300):
        means, var, counts = _random_window(rng)
        if trial % 10 == 0:
            means[:] = means[0]
            var[int(rng.integers(len(counts)))] = 0.0
        floor = float(rng.uniform(0, 20)) if rng.random() < 0.5 else rng.uniform(0, 20, 3)
        got = {}
        for on in (False, True):
            with kernels.switched(on) as active:
                assert active == on, kernels.status()
                got[on] = rest_rate_steps(means, var, counts, floor)
        assert got[True] == got[False]
        found += len(got[True])
    assert found > 40  # 47 steps found on these windows
