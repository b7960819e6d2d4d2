"""The per-sample F0 check where a sample's noise is comparable to the F0 limit.

At 4 kHz the bundled certificate's accelerometer white noise alone puts about a quarter of
a healthy unit's samples beyond the F0 limit (sigma_F0 = 0.009 against a limit of 0.01), so
a k-of-n persistence over single samples raised ``f0`` on a unit that is fine. The monitor
judges F0 on the mean of as many consecutive checked samples as make the noise of the mean
a quarter of the limit at most (13 at 4 kHz, 4 at 1 kHz, 1 at 200 Hz: unchanged there).
"""

from __future__ import annotations

import numpy as np

from imudiag.certificate import load_default
from imudiag.monitor import Monitor, MonitorConfig
from imudiag.sim import Fault, simulate, still

RATE = 4000.0


def _cert(rate_hz: float):
    cert = load_default()
    cert.sample_rate = rate_hz
    return cert


def _run(monitor: Monitor, block, step: int = 20) -> set[tuple]:
    """Feed ``block`` in daemon-sized reads; every fault ever in force."""
    ever: set[tuple] = set()
    for i in range(0, len(block), step):
        monitor.update(block.slice(i, min(len(block), i + step)))
        ever |= {(f["triad"], f["cause"]) for f in monitor.faults_in_force()}
    monitor.flush()
    ever |= {(f["triad"], f["cause"]) for f in monitor.active_faults}
    return ever


def test_samples_per_check_follow_the_noise_at_the_rate():
    for rate, m in ((100.0, 1), (200.0, 1), (1000.0, 4), (4000.0, 13)):
        mon = Monitor(_cert(rate))
        assert mon.samples_per_check("accel") == m, rate
        assert mon.samples_per_check("gyro") == 1  # MEMS rest-rate check: its own mean


def test_healthy_unit_at_4_khz_raises_no_f0_while_single_samples_did():
    cert = _cert(RATE)
    traj = still(20.0, rate_hz=RATE, attitude_rpy_deg=(3.0, -4.0, 10.0))
    block = simulate(cert, traj, seed=41).samples
    single = Monitor(cert, MonitorConfig(f0_noise_ratio=0.0))  # one sample per check
    assert single.samples_per_check("accel") == 1
    assert ("accel", "f0") in _run(single, block), "the false alarm this guards against"
    means = Monitor(cert)
    assert ("accel", "f0") not in _run(means, block)
    assert means.f0_checked["accel"] > 0.9 * len(block)


def test_an_accelerometer_bias_at_4_khz_is_still_raised():
    cert = _cert(RATE)
    acc = cert.accel
    # an az bias that puts F0 at about 2 limits on a level unit (F0 ~ b / g)
    bias = 2.0 * float(acc.limits.f0) * cert.gravity / acc.unit_to_si * float(acc.scale_factor[2])
    traj = still(20.0, rate_hz=RATE)
    block = simulate(cert, traj, seed=42, faults=[Fault("bias", "az", 5.0, bias)]).samples
    mon = Monitor(cert)
    assert ("accel", "f0") in _run(mon, block)
    fault = mon.f0_faults()[0]
    assert 5.0 <= fault["t_first"] < 5.2  # within 0.2 s of the onset
    assert fault["samples_per_check"] == 13
    assert np.isclose(fault["estimate"], 2.0 * float(acc.limits.f0), rtol=0.35)
