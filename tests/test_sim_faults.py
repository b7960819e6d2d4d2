"""Faults: applied at the right time with the right size, and the true certificate that follows."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.sim import Effects, Fault, apply_faults, multi_position, parse_fault, simulate, still
from imudiag.sim import turntable as turntable_traj


def outputs(block):
    return np.hstack([block.gyro, block.accel])


def clean_run(cert, tr, faults, seed=0, effects=None):
    eff = effects if effects is not None else Effects.none()
    return simulate(cert, tr, seed=seed, effects=eff, faults=faults)


def test_bias_fault_at_time_and_size(default_certificate):
    tr = still(20.0, rate_hz=100)
    base = clean_run(default_certificate, tr, [])
    r = clean_run(default_certificate, tr, [Fault("bias", "ax", 7.5, 150.0)])
    diff = outputs(r.samples) - outputs(base.samples)
    after = tr.t >= 7.5
    np.testing.assert_allclose(diff[after, 3], 150.0, atol=1e-9)
    np.testing.assert_allclose(diff[~after], 0.0, atol=1e-9)
    np.testing.assert_allclose(diff[:, [0, 1, 2, 4, 5]], 0.0, atol=1e-9)
    assert r.certificate.accel.bias[0] == default_certificate.accel.bias[0] + 150.0
    assert r.certificate_at(7.0).accel.bias[0] == default_certificate.accel.bias[0]


def test_scale_factor_fault_follows_true_certificate(default_certificate):
    tr = turntable_traj(50.0, axis="z", duration_s=10.0, rate_hz=100)
    fault = Fault("scale_factor", "gz", 4.0, 0.9)  # +0.9 count per deg/s on E_z
    r = clean_run(default_certificate, tr, [fault])
    after = tr.t >= 4.0
    faulted = r.certificate
    assert faulted.gyro.scale_factor_error[2] == pytest.approx(
        default_certificate.gyro.scale_factor_error[2] + 0.9
    )
    np.testing.assert_allclose(
        r.samples.gyro[after], faulted.gyro.forward_si(tr.omega[after]), atol=1e-8
    )
    np.testing.assert_allclose(
        r.samples.gyro[~after], default_certificate.gyro.forward_si(tr.omega[~after]), atol=1e-8
    )
    # the size: U_z grows by value * x_z (x in deg/s), about 0.9 * 50 = 45 counts
    base = clean_run(default_certificate, tr, [])
    dz = r.samples.gyro[after, 2] - base.samples.gyro[after, 2]
    x_z = np.degrees(tr.omega[after, 2])
    np.testing.assert_allclose(dz, 0.9 * x_z, rtol=1e-9)


@pytest.mark.parametrize("pair,index", [("ax/ay", 0), ("ax/az", 1), ("ay/az", 2)])
def test_misalignment_fault_changes_its_difference(default_certificate, pair, index):
    tr = multi_position(n_attitudes=8, dwell_s=1.0, turn_s=1.0, rate_hz=50, seed=3)
    fault = Fault("misalignment", pair, 5.0, 0.004)
    r = clean_run(default_certificate, tr, [fault])
    d0 = default_certificate.accel.misalignment_differences
    d1 = r.certificate.accel.misalignment_differences
    expected = d0.copy()
    expected[index] += 0.004
    np.testing.assert_allclose(d1, expected, atol=1e-15)
    after = tr.t >= 5.0
    np.testing.assert_allclose(
        r.samples.accel[after], r.certificate.accel.forward_si(tr.specific_force[after]), atol=1e-8
    )
    np.testing.assert_allclose(
        r.samples.accel[~after],
        default_certificate.accel.forward_si(tr.specific_force[~after]),
        atol=1e-8,
    )
    # a gyro pair works the same way
    g = clean_run(
        default_certificate, tr, [Fault("misalignment", pair.replace("a", "g"), 0.0, -0.002)]
    )
    assert g.certificate.gyro.misalignment_differences[index] == pytest.approx(
        default_certificate.gyro.misalignment_differences[index] - 0.002
    )


def test_stuck_dead_and_noise_faults(default_certificate):
    tr = still(40.0, rate_hz=100)
    faults = [
        Fault("stuck", "gy", 10.0),
        Fault("dead", "ax", 20.0),
        Fault("noise", "az", 15.0, 4.0),
        Fault("stuck", "gz", 5.0, 1234.0),
    ]
    base = simulate(default_certificate, tr, seed=2, effects=Effects.board())
    r = simulate(default_certificate, tr, seed=2, effects=Effects.board(), faults=faults)
    t = r.samples.t
    # stuck: frozen at its own value at t_s, unchanged before
    k = int(np.argmax(t >= 10.0))
    assert np.all(r.samples.gyro[k:, 1] == base.samples.gyro[k, 1])
    np.testing.assert_array_equal(r.samples.gyro[:k, 1], base.samples.gyro[:k, 1])
    assert np.all(r.samples.gyro[t >= 5.0, 2] == 1234.0)
    # dead: constant 0 counts from 20 s
    assert np.all(r.samples.accel[t >= 20.0, 0] == 0.0)
    assert np.all(r.samples.accel[t < 20.0, 0] == base.samples.accel[t < 20.0, 0])
    # noise: the az noise std grows by the multiplier (+-5 %: 2500 samples, se 1.4 %)
    before, after = r.samples.accel[(t > 2) & (t < 15), 2], r.samples.accel[t >= 15, 2]
    assert abs(after.std() / before.std() / 4.0 - 1) < 0.05
    assert r.certificate.accel.noise.density[2] == pytest.approx(
        4.0 * default_certificate.accel.noise.density[2]
    )
    # untouched sensors are identical
    np.testing.assert_array_equal(r.samples.gyro[:, 0], base.samples.gyro[:, 0])
    np.testing.assert_array_equal(r.samples.accel[:, 1], base.samples.accel[:, 1])


def test_parse_fault_and_errors():
    assert parse_fault("bias:ax:30:150") == Fault("bias", "ax", 30.0, 150.0)
    assert parse_fault("stuck:gy:5") == Fault("stuck", "gy", 5.0, None)
    assert parse_fault("misalignment:gx/gz:1:0.01").pair_key == (1, "zy")
    assert Fault("bias", "ax", 30.0, 150.0).to_text() == "bias:ax:30:150"
    for bad, msg in [
        ("bias:ax:30", "needs a finite value"),
        ("bias:qx:1:2", "unknown sensor"),
        ("wobble:ax:1:2", "unknown fault kind"),
        ("bias:ax:x:2", "numbers"),
        ("misalignment:ax:1:0.1", "pair"),
        ("misalignment:ax/gy:1:0.1", "pair"),
        ("bias:ax/ay:1:2", "one sensor"),
        ("bias:ax", "expected kind"),
    ]:
        with pytest.raises(ValueError, match=msg):
            parse_fault(bad)


def test_apply_faults_only_active_ones(default_certificate):
    faults = [Fault("bias", "gx", 10.0, 5.0), Fault("bias", "gx", 20.0, 7.0)]
    c15 = apply_faults(default_certificate, faults, 15.0)
    assert c15.gyro.bias[0] == default_certificate.gyro.bias[0] + 5.0
    c25 = apply_faults(default_certificate, faults, 25.0)
    assert c25.gyro.bias[0] == default_certificate.gyro.bias[0] + 12.0
    # the input is untouched, and the result round-trips through YAML
    assert default_certificate.gyro.bias[0] == 32888.0
    from imudiag.certificate import loads

    np.testing.assert_array_equal(loads(c25.dumps()).gyro.bias, c25.gyro.bias)
