"""The compiled GNSS epoch cut (issue 28, :func:`imudiag.numba_kernels.epoch_cut`, numba from
the ``fleet`` extra) against the plain numpy cut it replaces in fleet workers
(:meth:`imudiag.aiding.specific_force.ImuSeries.epochs`).

The equality argument: the kernel does the plain path's operations in its order (the
rotation vector, Rodrigues' formula term by term, each epoch's sums from 0 in sample order
as ``np.bincount`` makes them, no fast-math), so the two can differ only where numba's sine
or cosine and numpy's round an angle differently (none on this project's x86-64 machines,
where both call the C library's; numpy builds with SIMD sine and cosine could differ in
the last bit). The latency search picks a maximum on a grid, where one bit could in
principle move the chosen lag; so the search itself is held equal: on the simulated drives
(urban, hilly, highway) and the real drive (tests/data/real/gnss-imu-drive) the kernel
gives the same chosen lag, a latency and std within 1e-9 s, the same verdict and reason,
and the whole moving-base section equal to the plain one."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.aiding import estimate_latency, gnss_epochs, read_gpspipe_log  # noqa: E402
from imudiag.aiding.specific_force import GateConfig, ImuSeries  # noqa: E402
from imudiag.aiding.tpv import parse_tpv, track_from_reports  # noqa: E402
from imudiag.certificate import load_default  # noqa: E402
from imudiag.sim.drive import GnssSimConfig, simulate_drive  # noqa: E402

REAL = Path(__file__).parent / "data" / "real" / "gnss-imu-drive"
FIELDS = ("mean_si", "mag", "sigma_mag", "comp_si", "mean_raw", "gyro_mean")


def both(fn):
    """``fn()`` with the plain cut, then with the kernel; the two results."""
    was = kernels.enabled()
    kernels.enable(False)
    try:
        plain = fn()
        assert kernels.enable(True), kernels.status()
        fast = fn()
    finally:
        kernels.enable(was)
    return plain, fast


def assert_epochs_close(fast, plain) -> None:
    np.testing.assert_array_equal(fast.count, plain.count)
    np.testing.assert_array_equal(fast.covered, plain.covered)
    for name in FIELDS:
        a, b = getattr(fast, name), getattr(plain, name)
        if a is None or b is None:
            assert a is None and b is None, name
            continue
        scale = max(1.0, float(np.nanmax(np.abs(b)))) if np.any(np.isfinite(b)) else 1.0
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * scale, err_msg=name)
        np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b), err_msg=name)


@pytest.mark.parametrize("seed", range(6))
def test_epoch_cut_kernel_equals_plain_on_random_records(seed):
    """Seeded random records with gaps; empty, overlapping and out-of-record epochs; with
    and without gyro, lever arm and the epochs' mean rates."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 4000))
    dt = rng.uniform(0.004, 0.006, n)
    dt[rng.random(n) < 0.01] = 0.5  # gaps in the IMU stream
    t = 100.0 + np.cumsum(dt)
    f = rng.normal(0.0, 3.0, (n, 3)) + [0.0, 0.0, 9.8]
    w = rng.normal(0.0, 0.4, (n, 3))
    w[: n // 3] *= 1e-14  # rotation vectors below the small-angle cut
    edges = np.sort(rng.uniform(t[0] - 2.0, t[-1] + 2.0, int(rng.integers(1, 60))))
    t0 = edges[:-1] if edges.size > 1 else edges
    t1 = t0 + rng.uniform(0.0, 1.5, t0.size)
    for gyro in (w, None):
        series = ImuSeries(t, f, gyro)
        for latency in (0.0, float(rng.uniform(-0.5, 0.5))):
            for lever in (None, rng.normal(0.0, 1.0, 3)):
                for means in (True, False):
                    kw = dict(sigma_sample_si=0.02, latency_s=latency, lever_arm_m=lever)
                    plain, fast = both(
                        lambda s=series, kw=kw, m=means: s.epochs(t0, t1, gyro_means=m, **kw)
                    )
                    assert_epochs_close(fast, plain)


def simulated(scenario: str):
    cert = load_default()
    latency = {"urban": 0.12, "hilly": 0.4, "highway": 0.05}[scenario]
    res, reports, _ = simulate_drive(
        scenario, 200.0, cert, seed=3, rate_hz=100.0, gnss=GnssSimConfig(latency_s=latency)
    )
    s = res.samples
    track = track_from_reports([x for x in (parse_tpv(r) for r in reports) if x])
    return s.t, cert.accel.inverse_si(s.accel), cert.gyro.inverse_si(s.gyro), track, 1.0


def real_drive():
    from imudiag.logs import read_log

    block = read_log(REAL / "imu.csv.gz")
    track = read_gpspipe_log(REAL / "gnss.tpv.json.gz")
    # the log's units are g and deg/s (SOURCE.md)
    return block.t, block.accel * 9.80665, np.radians(block.gyro), track, 0.5


@pytest.mark.parametrize("case", ["urban", "hilly", "highway", "real"])
def test_latency_search_chooses_the_same_lag(case):
    t, f, w, track, max_latency = real_drive() if case == "real" else simulated(case)
    epochs = gnss_epochs(track, span=max(1, int(round(1.0 / track.period_s()))))
    series = ImuSeries(t, f, w)

    def search():
        return estimate_latency(t, f, epochs, gyro_si=w, max_latency_s=max_latency, series=series)

    plain, fast = both(search)
    assert plain.lags_s is not None and fast.lags_s is not None
    assert plain.correlations is not None and fast.correlations is not None
    assert np.isfinite(plain.latency_s)
    searched = np.isfinite(plain.correlations)
    np.testing.assert_array_equal(np.isfinite(fast.correlations), searched)
    np.testing.assert_allclose(
        fast.correlations[searched], plain.correlations[searched], rtol=0, atol=1e-12
    )
    assert np.nanargmax(fast.correlations) == np.nanargmax(plain.correlations)
    assert abs(fast.latency_s - plain.latency_s) <= 1e-9
    assert abs(fast.std_s - plain.std_s) <= 1e-9 or fast.std_s == plain.std_s
    assert (fast.determined, fast.reason, fast.epochs) == (
        plain.determined,
        plain.reason,
        plain.epochs,
    )
    assert fast.to_json() == plain.to_json()


@pytest.mark.parametrize("which", ["epoch cut", "all kernels"])
def test_moving_base_section_with_the_kernel_equals_plain(which, monkeypatch):
    """The whole moving-base section (latency search, joint latency and lever-arm solve,
    final epochs, windows) with the compiled epoch cut alone equals the plain one within the
    report contract's cross-processor tolerance (and on this machine bit for bit where the
    sines agree); with every kernel on (the window fits' too) within that tolerance. Every
    verdict, count and string equal."""
    from imudiag.aiding import specific_force
    from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
    from imudiag.samples import SampleBlock
    from tests import test_diagnose_frozen_reports as frozen

    cert = load_default()
    res, reports, _ = simulate_drive("urban", 240.0, cert, 7, 200.0)
    block = res.samples
    track = track_from_reports([parse_tpv(r) for r in reports])
    samples = SampleBlock(t=block.t, gyro=block.gyro, accel=block.accel)
    plain = moving_base_diagnosis(samples, cert, track, MovingConfig())
    assert kernels.load(), kernels.status()
    if which == "epoch cut":  # the cut compiled, every other loop plain
        compiled = kernels._KERNELS["epoch_cut"]
        monkeypatch.setattr(
            specific_force, "kernel", lambda name: compiled if name == "epoch_cut" else None
        )
        fast = moving_base_diagnosis(samples, cert, track, MovingConfig())
    else:
        _, fast = both(lambda: moving_base_diagnosis(samples, cert, track, MovingConfig()))
    assert plain["windows_run"] >= 1
    diff = frozen.hardware_differences(
        json.loads(json.dumps(fast, default=str)), json.loads(json.dumps(plain, default=str))
    )
    assert not diff, f"{len(diff)} differences, first: " + "; ".join(diff[:8])


def test_the_cut_without_the_gyro_means():
    """The cut without the epochs' mean rates (the latency search's), kernel and plain."""
    cert = load_default()
    res, reports, _ = simulate_drive("urban", 60.0, cert, 2, 100.0)
    s = res.samples
    track = track_from_reports([parse_tpv(r) for r in reports])
    ep = gnss_epochs(track, GateConfig())
    series = ImuSeries(s.t, cert.accel.inverse_si(s.accel), cert.gyro.inverse_si(s.gyro))
    plain, fast = both(lambda: series.epochs(ep.t0, ep.t1, gyro_means=False))
    assert plain.gyro_mean is None and fast.gyro_mean is None
    assert_epochs_close(fast, plain)
