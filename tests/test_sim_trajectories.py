"""Trajectories: gravity and Earth rate at rest, attitude/omega consistency, scenario shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imudiag.sim import multi_position, relative_rotation, still, turntable, vehicle_run
from imudiag.sim.rotations import (
    attitude_with_up,
    axis_angle_matrix,
    rotation_vector,
    rpy_matrix,
)
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.trajectories import (
    EARTH_RATE,
    multi_position_motion,
    spread_up_directions,
    turntable_motion,
)

G = 9.80665


def integrate_gyro(omega: np.ndarray, dt: float) -> np.ndarray:
    """Body rotation from sampled rates: second-order increments with the coning term
    (independent of the simulator's analytic attitude)."""
    r = np.eye(3)
    theta = (omega[:-1] + omega[1:]) / 2.0 * dt + np.cross(omega[:-1], omega[1:]) * dt**2 / 12.0
    ang = np.linalg.norm(theta, axis=1)
    axis = theta / np.where(ang > 0, ang, 1.0)[:, None]
    for step in axis_angle_matrix(axis, ang):  # a product of N small rotations (test only)
        r = r @ step
    return r


def test_still_level_reads_gravity_up_and_earth_rate():
    tr = still(2.0, rate_hz=100, latitude_deg=30.0)
    assert len(tr) == 200 and tr.static.all()
    np.testing.assert_allclose(tr.specific_force, np.tile([0.0, 0.0, -G], (200, 1)), atol=1e-12)
    # NED, level, heading north: Earth rate (cos lat, 0, -sin lat) * Omega
    lat = math.radians(30.0)
    expected = EARTH_RATE * np.array([math.cos(lat), 0, -math.sin(lat)])
    np.testing.assert_allclose(tr.omega[0], expected, atol=1e-18)
    np.testing.assert_allclose(tr.t[:3], [0.0, 0.01, 0.02])


def test_still_tilted_attitude():
    tr = still(1.0, attitude_rpy_deg=(90.0, 0.0, 0.0))
    # rolled 90 deg right: body y points down, so f (pointing up) reads -g on y
    f = tr.specific_force[0]
    np.testing.assert_allclose(f, [0.0, -G, 0.0], atol=1e-12)
    c = rpy_matrix(90.0, 0.0, 0.0)
    np.testing.assert_allclose(f, c.T @ np.array([0, 0, -G]), atol=1e-12)
    assert abs(np.linalg.norm(f) - G) < 1e-12
    assert abs(np.linalg.norm(tr.omega[0]) - EARTH_RATE) < 1e-18


def test_multi_position_well_spread_and_static_magnitudes():
    tr = multi_position(n_attitudes=12, dwell_s=2.0, turn_s=1.0, rate_hz=100, seed=4)
    assert abs(tr.duration_s - (2.0 + 11 * 3.0)) < 1e-9
    ivs = tr.static_intervals()
    assert len(ivs) == 12
    ups = np.array([tr.specific_force[a] / G for a, _ in ivs])
    # at rest |f| = g and |omega| = Earth rate
    st = tr.static
    np.testing.assert_allclose(np.linalg.norm(tr.specific_force[st], axis=1), G, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tr.omega[st], axis=1), EARTH_RATE, rtol=1e-9)
    # both signs of every axis are visited
    for j in range(3):
        assert ups[:, j].max() > 0.99 and ups[:, j].min() < -0.99
    # the 9-parameter scalar regressors (x^2, y^2, z^2, x, y, z, xy, xz, yz) are well conditioned
    x, y, z = ups.T
    h = np.stack([x * x, y * y, z * z, x, y, z, x * y, x * z, y * z], 1)
    assert np.linalg.cond(h) < 20.0
    # a different seed visits another order
    other = multi_position(n_attitudes=12, dwell_s=2.0, turn_s=1.0, rate_hz=100, seed=5)
    assert not np.allclose(other.specific_force, tr.specific_force)


def test_spread_directions_more_than_fourteen():
    d = spread_up_directions(20, seed=1)
    assert d.shape == (20, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    with pytest.raises(ValueError):
        spread_up_directions(0)


@pytest.mark.parametrize("builder", ["multi", "turntable", "vehicle"])
def test_integrated_gyro_reproduces_attitude_change(builder):
    """Integrating omega (incl. Earth rate) carries the attitude to < 1e-6 rad."""
    if builder == "multi":
        tr = multi_position(n_attitudes=6, dwell_s=0.5, turn_s=1.5, rate_hz=200, seed=2)
        pairs = [
            (b - 1, c)
            for (_, b), (c, _) in zip(
                tr.static_intervals()[:-1], tr.static_intervals()[1:], strict=True
            )
        ]
    elif builder == "turntable":
        tr = turntable(90.0, axis="x", duration_s=6.0, rate_hz=200, ramp_s=1.0)
        # end points where the rate is steady (inside the spin-up the test's own
        # trapezoid rule errs by h^2/12 * d(rate)/dt, 5e-6 rad at 200 Hz)
        pairs = [(0, len(tr) - 1), (300, 1000)]
    else:
        tr = vehicle_run(
            still_s=1.0, accel_s=3.0, cruise_s=1.0, turn_s=2.0, final_s=1.0, rate_hz=200
        )
        pairs = [(0, len(tr) - 1)]
    for i, j in pairs:
        phi = relative_rotation(tr, i, j)
        r = integrate_gyro(tr.omega[i : j + 1], 1.0 / tr.rate_hz)
        err = np.linalg.norm(rotation_vector(phi.T @ r))
        assert err < 1e-6, (builder, i, j, err)
        # and Earth rate matters at this level: without it the change is off by Omega dt
    if builder == "multi":
        i, j = pairs[0]
        r_no_earth = tr.attitude[i].T @ tr.attitude[j]
        r = integrate_gyro(tr.omega[i : j + 1], 1.0 / tr.rate_hz)
        assert np.linalg.norm(rotation_vector(r_no_earth.T @ r)) > 1e-5


def test_turntable_rate_and_gravity():
    tr = turntable(30.0, axis="y", duration_s=4.0, rate_hz=100)
    w_ie_body = np.einsum(
        "nji,j->ni",
        tr.attitude,
        EARTH_RATE * np.array([math.cos(math.radians(45)), 0, -math.sin(math.radians(45))]),
    )
    np.testing.assert_allclose(
        tr.omega - w_ie_body, np.tile([0, math.radians(30), 0], (400, 1)), atol=1e-12
    )
    # the table axis is vertical: gravity stays on +y
    np.testing.assert_allclose(tr.specific_force, np.tile([0, G, 0], (400, 1)), atol=1e-9)
    assert not tr.static.any()


def test_vehicle_run_kinematics():
    tr = vehicle_run(rate_hz=100)  # defaults: 10 s still, 0->20 m/s in 8 s, 90 deg in 4 s
    assert abs(tr.duration_s - 32.0) < 1e-9
    assert tr.static[:1000].all() and not tr.static[1000:].any()
    f = tr.specific_force
    assert abs(f[:, 0].max() - 2 * 20.0 / 8.0) < 1e-3  # peak forward 5 m/s^2
    peak_rate = 2 * math.pi / 2 / 4.0
    w = tr.omega[:, 2] - tr.omega[0, 2]
    assert abs(np.max(np.abs(w)) - peak_rate) < 1e-3
    assert abs(f[:, 1].max() - 20.0 * peak_rate) < 2e-3  # lateral v * dpsi/dt
    np.testing.assert_allclose(f[:, 2], -G, atol=1e-12)
    # heading turned by 90 deg at the end
    np.testing.assert_allclose(tr.attitude[-1] @ [1, 0, 0], [0, 1, 0], atol=1e-9)


def test_motion_chunks_match_whole():
    m = multi_position_motion(n_attitudes=5, dwell_s=1.0, turn_s=1.0, seed=3)
    whole = m.sample(200)
    part = m.sample(200, 333, 500)
    np.testing.assert_array_equal(part.omega, whole.omega[333:833])
    np.testing.assert_array_equal(part.attitude, whole.attitude[333:833])
    endless = turntable_motion(10.0)
    assert endless.n_samples(100) is None
    with pytest.raises(ValueError):
        endless.sample(100)
    # the static scenario repeats (cyclic) and starts level
    st = scenario_motion("static", seed=1)
    a = st.sample(50, 0, 10)
    np.testing.assert_allclose(a.specific_force[0], [0, 0, -G], atol=1e-12)
    period = st.period_s
    b = st.evaluate(np.array([period + 0.0]), 50)
    np.testing.assert_allclose(b.specific_force[0], a.specific_force[0], atol=1e-9)


def test_attitude_with_up_and_rotation_vector():
    rng = np.random.default_rng(0)
    for u in rng.standard_normal((20, 3)):
        c = attitude_with_up(u, yaw_rad=rng.uniform(-3, 3))
        np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
        assert abs(np.linalg.det(c) - 1) < 1e-12
        np.testing.assert_allclose(c.T @ [0, 0, -G], G * u / np.linalg.norm(u), atol=1e-12)
    # rotation vectors round trip, including angles near pi
    axes = rng.standard_normal((50, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate(
        [rng.uniform(0, math.pi, 45), [0.0, 1e-8, math.pi - 1e-6, math.pi - 1e-3, 3.0]]
    )
    r = axis_angle_matrix(axes, angles)
    rv = rotation_vector(r)
    np.testing.assert_allclose(
        axis_angle_matrix(
            rv / np.maximum(np.linalg.norm(rv, axis=1), 1e-300)[:, None], np.linalg.norm(rv, axis=1)
        ),
        r,
        atol=1e-9,
    )


@pytest.mark.parametrize("scenario", ["urban", "hilly", "aircraft"])
def test_drive_steps_evaluated_per_block_are_the_sum_of_every_step(scenario: str) -> None:
    """A drive's speed, heading and grade profiles, evaluated on blocks (the simulator's
    reads, and a whole drive), equal bit for bit the sum over every raised-cosine step, the
    definition (``_Steps.eval`` evaluates each step only on the times it spans)."""
    from imudiag.sim.drive import drive_motion
    from imudiag.sim.trajectories import smooth_step

    motion = drive_motion(scenario, 300.0, seed=2)
    profiles = (motion.speed, motion.heading, motion.grade)
    assert sum(len(p.steps) for p in profiles) > 5
    rng = np.random.default_rng(7)
    starts = rng.uniform(-2.0, motion.duration_s + 2.0, 40)
    blocks = [a + np.arange(int(rng.integers(1, 200))) / 100.0 for a in starts]
    # blocks beginning exactly at a step's start and end
    blocks += [np.array([t0, t0 + dur]) for p in profiles for t0, dur, _ in p.steps[:5]]
    blocks.append(np.arange(0.0, motion.duration_s, 0.05))  # a whole drive
    blocks.append(rng.uniform(0.0, motion.duration_s, 50))  # out of order
    for steps in profiles:
        for t in blocks:
            x, dx, ddx = np.full(t.shape, steps.x0), np.zeros(t.shape), np.zeros(t.shape)
            for t0, dur, delta in steps.steps:
                tau = (t - t0) / dur
                s, ds = smooth_step(tau)
                x += delta * s
                dx += delta * ds / dur
                inside = (tau > 0) & (tau < 1)
                ddx += np.where(inside, delta * 2 * math.pi * np.sin(2 * math.pi * tau) / dur**2, 0)
            for got, want in zip(steps.eval(t), (x, dx, ddx), strict=True):
                np.testing.assert_array_equal(got, want)
