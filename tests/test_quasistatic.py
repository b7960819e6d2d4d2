"""Quasi-static detector: against the simulator's truth, streaming, noise estimate, flags."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.quasistatic import QuasiStaticDetector, static_mask
from imudiag.samples import FLAG_ACCEL_SATURATED, SampleBlock
from imudiag.sim import Fault, multi_position, simulate, still, turntable


@pytest.fixture(scope="module")
def cert():
    return load_default()


@pytest.fixture(scope="module")
def session(cert):
    traj = multi_position(n_attitudes=10, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=4)
    return simulate(cert, traj, seed=11)


def _distance_to_static(truth_static: np.ndarray, idx: np.ndarray) -> np.ndarray:
    st = np.flatnonzero(truth_static)
    pos = np.searchsorted(st, idx)
    left = st[np.clip(pos - 1, 0, st.size - 1)]
    right = st[np.clip(pos, 0, st.size - 1)]
    return np.minimum(np.abs(idx - left), np.abs(right - idx))


def test_static_mask_matches_truth(cert, session):
    mask = static_mask(session.samples, cert, 200.0)
    truth = session.truth.static
    # samples called static while moving are only the first instants of a turn
    # (raised-cosine start: about 1 deg turned in the first 0.2 s of a 90 deg turn;
    # the interval collector trims 0.25 s off the end of every still run)
    false_static = np.flatnonzero(mask & ~truth)
    assert false_static.size < 0.05 * mask.sum()
    assert np.all(_distance_to_static(truth, false_static) <= 0.2 * 200)
    # most of every dwell is found (the trailing window costs 0.5 s at each start)
    assert (mask & truth).sum() > 0.75 * truth.sum()


def test_streaming_equals_one_shot_for_any_block_size(cert, session):
    one = static_mask(session.samples, cert, 200.0)
    for size in (1, 7, 100, 4096):
        det = QuasiStaticDetector(cert, 200.0)
        n = len(session.samples)
        parts = [det.update(session.samples.slice(i, i + size)) for i in range(0, n, size)]
        assert np.array_equal(np.concatenate(parts), one), size


def test_noise_estimated_when_certificate_has_none(cert, session):
    bare = cert.copy()
    bare.gyro.noise = None
    bare.accel.noise = None
    det = QuasiStaticDetector(bare, 200.0)
    mask = np.concatenate(
        [
            det.update(session.samples.slice(i, i + 2000))
            for i in range(0, len(session.samples), 2000)
        ]
    )
    sigma_true = cert.accel.noise_sigma(200.0)
    est = det.noise_sigma("accel")
    assert est is not None
    np.testing.assert_allclose(est, sigma_true, rtol=0.15)
    truth = session.truth.static
    assert (mask & truth).sum() > 0.7 * truth.sum()
    assert (mask & ~truth).sum() < 0.05 * mask.sum()


def test_slow_turn_about_the_vertical_is_not_static(cert):
    """Gravity does not move and the rate is constant: only the gyro mean check sees it
    (band: 8 bias limits = 4 deg/s for this certificate)."""
    traj = turntable(6.0, axis="-z", duration_s=10.0, rate_hz=200)
    sim = simulate(cert, traj, seed=3)
    assert not static_mask(sim.samples, cert, 200.0).any()


def test_gyro_bias_fault_still_static(cert):
    """A bias fault of 6 limits must not hide the still periods it is diagnosed on."""
    lim = cert.gyro.limits.bias[1]
    sim = simulate(cert, still(10.0, 200), seed=5, faults=[Fault("bias", "gy", 0.0, 6 * lim)])
    assert static_mask(sim.samples, cert, 200.0)[200:].all()


def test_saturation_flags_break_static(cert):
    sim = simulate(cert, still(5.0, 200), seed=6)
    b = sim.samples
    flags = np.zeros(len(b), dtype=np.uint16)
    flags[500] = FLAG_ACCEL_SATURATED
    blk = SampleBlock(t=b.t, gyro=b.gyro, accel=b.accel, flags=flags)
    mask = static_mask(blk, cert, 200.0)
    w = int(round(0.5 * 200))
    assert not mask[500 : 500 + w].any()
    assert mask[500 + w :].all() and mask[w:500].all()


def test_window_and_rate_defaults(cert):
    det = QuasiStaticDetector(cert)
    assert det.rate_hz == cert.sample_rate
    assert det.window == int(round(0.5 * cert.sample_rate))
    assert det.update(SampleBlock.empty()).shape == (0,)
    with pytest.raises(ValueError):
        QuasiStaticDetector(cert, rate_hz=-1.0)
    assert math.isclose(det.noise_sigma("gyro")[0], 6.55 * 10.0)
