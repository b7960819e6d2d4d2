"""Rest is rest without aiding: clean simulated car drives raise no fault in the monitor.

The drives are vibration-free (`imudiag simulate urban|highway|hilly`): smooth
raised-cosine accelerations, curves and grade changes. Before the drift tests of
the quasi-static detector, the peaks of accelerations and long gentle curves were
taken for rest and the F0 and gyro rest-rate checks failed a healthy unit. Fixed
seeds, 10-minute drives at the certificate's rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.monitor import Monitor
from imudiag.quasistatic import QuasiStaticDetector
from imudiag.sim.drive import EPOCH_UNIX
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.simulator import Simulator

CERT = load_default()
RATE = float(CERT.sample_rate)
SEED = 1
LENGTH_S = 600.0


def _drive(scenario: str, faults: tuple = (), **detector: object):
    """Feed the drive to a monitor in 10 s blocks; returns (monitor, static flags, truth)."""
    motion = scenario_motion(scenario, SEED, {"length": str(LENGTH_S)})
    total = motion.n_samples(RATE)
    sim = Simulator(CERT, None, list(faults), SEED)
    mon = Monitor(CERT)
    if detector:
        mon.detector = QuasiStaticDetector(CERT, RATE, **detector)  # type: ignore[arg-type]
    det = QuasiStaticDetector(CERT, RATE, **detector)  # type: ignore[arg-type]
    static, acc_n, rate_n, stopped = [], [], [], []
    chunk = int(10 * RATE)
    for start in range(0, total, chunk):
        traj = motion.sample(RATE, start, min(chunk, total - start))
        block = sim.step(traj)
        block.t = block.t + EPOCH_UNIX
        mon.update(block)
        static.append(det.update(block))
        _, w_nb, acc, still = motion.kinematics(traj.t)
        acc_n.append(np.linalg.norm(acc, axis=1))
        rate_n.append(np.linalg.norm(w_nb, axis=1))
        stopped.append(still)
    truth = {
        "acc": np.concatenate(acc_n),
        "rate": np.concatenate(rate_n),
        "stopped": np.concatenate(stopped),
    }
    return mon, np.concatenate(static), truth


@pytest.mark.parametrize("scenario", ["urban", "highway", "hilly"])
def test_clean_drive_raises_no_fault_without_aiding(scenario):
    mon, static, truth = _drive(scenario)
    assert mon.f0_faults() == [], mon.f0_faults()
    assert mon.active_faults == []
    # the F0 check still runs: at stops and at a steady speed (|f| = g there)
    assert mon.f0_checked["accel"] > 10 * RATE
    # no sample of a manoeuvre that moves |f| beyond the F0 limit is taken for rest:
    # a horizontal acceleration a changes F0 by a^2 / 2 g^2 (0.01 at 1.39 m/s^2)
    g = CERT.gravity
    beyond = truth["acc"] ** 2 / (2 * g * g) > CERT.accel.limits.f0
    assert np.count_nonzero(static & beyond) == 0
    # turning faster than the rest band (8 bias limits, 4 deg/s here) is never rest
    assert np.count_nonzero(static & (truth["rate"] > math.radians(4.5))) == 0
    # most of the time stopped is found (the first drift_window_s after braking is not)
    stopped = truth["stopped"]
    if stopped.sum() > 20 * RATE:
        assert np.count_nonzero(static & stopped) > 0.4 * stopped.sum()


def test_without_the_drift_tests_the_same_drives_fail_a_healthy_unit():
    """The reason for the drift tests: the half-second tests alone take the peaks of the
    urban accelerations for rest and raise an F0 fault on a healthy unit."""
    mon, _, _ = _drive("urban", drift_f0_fraction=None)
    assert [f["triad"] for f in mon.f0_faults()] == ["accel"]


def test_an_accelerometer_fault_on_a_drive_is_still_found_at_the_stops():
    """A bias fault of 2000 counts (4.8 m/s^2, far beyond the F0 limit) on the urban drive:
    the drift tests do not hide it, the stops and cruises judge it."""
    mon, _, _ = _drive("urban", (Fault("bias", "az", 100.0, 2000.0),))
    faults = mon.f0_faults()
    assert [f["triad"] for f in faults] == ["accel"]
    assert faults[0]["t_first"] - EPOCH_UNIX > 100.0
