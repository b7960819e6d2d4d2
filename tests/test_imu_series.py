"""The moving-base diagnosis's fast cut of the IMU record into GNSS epochs
(:class:`imudiag.aiding.specific_force.ImuSeries`) equals the plain one
(:func:`~imudiag.aiding.specific_force.imu_epochs`) bit for bit: on a simulated drive with
its GNSS epochs at several latencies and lever arms, and on seeded random records with gaps,
empty, overlapping and out-of-record epochs."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.aiding.specific_force import (
    GateConfig,
    ImuSeries,
    _rodrigues,
    _rodrigues_rows,
    gnss_epochs,
    imu_epochs,
)
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load_default
from imudiag.sim.drive import simulate_drive

FIELDS = ("mean_si", "mag", "sigma_mag", "comp_si", "count", "covered", "mean_raw", "gyro_mean")


def assert_same(plain, fast) -> None:
    for name in FIELDS:
        a, b = getattr(plain, name), getattr(fast, name)
        if a is None or b is None:
            assert a is None and b is None, name
            continue
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(b, a, err_msg=name)


@pytest.fixture(scope="module")
def drive():
    cert = load_default()
    res, reports, _ = simulate_drive("urban", 240.0, cert, 7, 200.0)
    block = res.samples
    track = track_from_reports([parse_tpv(r) for r in reports])
    f = cert.accel.inverse_si(block.accel)
    w = cert.gyro.inverse_si(block.gyro)
    return block, track, f, w


@pytest.mark.parametrize("span", [1, 5])
def test_drive_epochs_equal_plain(drive, span):
    block, track, f, w = drive
    ep = gnss_epochs(track, GateConfig(), span=span)
    series = ImuSeries(block.t, f, w)
    for latency in (-0.4, 0.0, 0.123):
        for lever in (None, np.zeros(3), np.array([0.4, -0.2, 1.1])):
            kw = dict(
                sigma_sample_si=np.array([0.01, 0.02, 0.03]),
                latency_s=latency,
                lever_arm_m=lever,
                accel_raw=block.accel,
            )
            plain = imu_epochs(block.t, f, ep.t0, ep.t1, gyro_si=w, **kw)
            assert_same(plain, series.epochs(ep.t0, ep.t1, **kw))


@pytest.mark.parametrize("seed", range(6))
def test_random_records_equal_plain(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 3000))
    dt = rng.uniform(0.004, 0.006, n)
    dt[rng.random(n) < 0.01] = 0.5  # gaps in the IMU stream
    t = 100.0 + np.cumsum(dt)
    f = rng.normal(0.0, 3.0, (n, 3)) + [0.0, 0.0, 9.8]
    w = rng.normal(0.0, 0.4, (n, 3))
    edges = np.sort(rng.uniform(t[0] - 2.0, t[-1] + 2.0, int(rng.integers(1, 60))))
    t0 = edges[:-1] if edges.size > 1 else edges
    t1 = t0 + rng.uniform(0.0, 1.5, t0.size)  # some overlap the next, some are empty
    for gyro in (w, None):
        series = ImuSeries(t, f, gyro)
        for latency in (0.0, float(rng.uniform(-0.5, 0.5))):
            lever = rng.normal(0.0, 1.0, 3) if gyro is not None else None
            kw = dict(sigma_sample_si=0.02, latency_s=latency, lever_arm_m=lever)
            plain = imu_epochs(t, f, t0, t1, gyro_si=gyro, **kw)
            assert_same(plain, series.epochs(t0, t1, **kw))


def test_short_records_equal_plain():
    t0, t1 = np.array([0.0, 1.0]), np.array([1.0, 2.0])
    for n in (1, 2):
        t = np.linspace(0.5, 1.5, n)
        f, w = np.ones((n, 3)), np.full((n, 3), 0.1)
        assert_same(imu_epochs(t, f, t0, t1, gyro_si=w), ImuSeries(t, f, w).epochs(t0, t1))


def test_rotation_rows_equal_rodrigues():
    rng = np.random.default_rng(11)
    theta = rng.normal(0.0, 0.2, (5000, 3))
    theta[::7] = 0.0
    theta[::11] *= 1e-13  # below the small-angle cut
    x = rng.normal(0.0, 9.8, (5000, 3))
    rows = _rodrigues_rows(np.ascontiguousarray(theta.T), np.ascontiguousarray(x.T))
    np.testing.assert_array_equal(rows.T, _rodrigues(theta, x))


def test_moving_base_report_equals_the_plain_cuts(drive, monkeypatch):
    """The whole moving-base section with every cut made by the plain ``imu_epochs`` equals
    the one made through the series (latency search, joint solve, final epochs)."""
    import json

    from imudiag.aiding import specific_force
    from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
    from imudiag.samples import SampleBlock

    block, track, _, _ = drive
    cert = load_default()
    samples = SampleBlock(t=block.t, gyro=block.gyro, accel=block.accel)
    fast = moving_base_diagnosis(samples, cert, track, MovingConfig())

    def plain_cut(self, t0, t1, **kw):
        return imu_epochs(self.t, self.accel_si, t0, t1, gyro_si=self.gyro_si, **kw)

    monkeypatch.setattr(specific_force.ImuSeries, "epochs", plain_cut)
    plain = moving_base_diagnosis(samples, cert, track, MovingConfig())
    assert fast["windows_run"] >= 1
    assert json.dumps(fast, sort_keys=True, default=str) == json.dumps(
        plain, sort_keys=True, default=str
    )


def test_lever_arm_rows_from_the_series_equal_plain(drive):
    """The lever-arm rows with the series' epoch samples and [w]x [w]x made once equal the
    plain ones bit for bit (on the drive at several latencies, and on random records with
    gaps, empty, overlapping and out-of-record epochs)."""
    from imudiag.aiding.lever_arm import lever_arm_rows

    block, track, f, w = drive
    ep = gnss_epochs(track, GateConfig(), span=5)
    series = ImuSeries(block.t, f, w)
    for latency in (-0.4, 0.0, 0.123):
        mean = series.epochs(ep.t0, ep.t1, latency_s=latency).mean_si
        plain = lever_arm_rows(block.t, w, ep.t0, ep.t1, mean, latency)
        fast = lever_arm_rows(block.t, w, ep.t0, ep.t1, mean, latency, series=series)
        assert np.isfinite(plain).any()
        np.testing.assert_array_equal(fast, plain)
    for seed in range(4):
        rng = np.random.default_rng(50 + seed)
        n = int(rng.integers(2, 3000))
        dt = rng.uniform(0.004, 0.006, n)
        dt[rng.random(n) < 0.01] = 0.5
        t = 100.0 + np.cumsum(dt)
        gyro = rng.normal(0.0, 0.4, (n, 3))
        t0 = np.sort(rng.uniform(t[0] - 2.0, t[-1] + 2.0, int(rng.integers(1, 60))))
        t1 = t0 + rng.uniform(0.0, 1.5, t0.size)
        mean = rng.normal(0.0, 3.0, (t0.size, 3)) + [0.0, 0.0, 9.8]
        s = ImuSeries(t, np.zeros((n, 3)), gyro)
        plain = lever_arm_rows(t, gyro, t0, t1, mean, 0.05)
        np.testing.assert_array_equal(lever_arm_rows(t, gyro, t0, t1, mean, 0.05, series=s), plain)
