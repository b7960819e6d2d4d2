"""The diagnosis math on the pure sensor model: gauge, scalar fits, rotations, predicates."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.diagnosis.gauge import n_symmetric, p_matrix, polar, shape_of_p, shape_of_triad
from imudiag.diagnosis.gyro_fit import earth_rate_observable
from imudiag.diagnosis.params import TriadFit, certificate_vector, limit_vector
from imudiag.diagnosis.predicates import PredicateTracker, candidates
from imudiag.diagnosis.scalar_fit import exact_fit, linear_fit
from imudiag.diagnosis.window import clipped, distinct_attitudes, model_with
from imudiag.rotations import ordered_product, quat_matrix, rotvec_quat
from imudiag.sim.rotations import axis_angle_matrix
from imudiag.sim.trajectories import spread_up_directions

G = 9.80665


@pytest.fixture(scope="module")
def cert():
    return load_default()


def _means(triad, up, n, rng, magnitude=G):
    """Interval means of ``triad`` (pure model) at specific-force directions ``up``."""
    u = triad.forward_si(up * magnitude)
    sigma = triad.noise_sigma(200.0)
    return u + rng.normal(size=u.shape) * sigma / math.sqrt(n), np.tile(sigma**2 / n, (len(up), 1))


def _faulty(triad, index, value):
    t = copy.deepcopy(triad)
    if index < 3:
        t.bias = t.bias + np.eye(3)[index] * value
    elif index < 6:
        t.scale_factor_error = t.scale_factor_error + np.eye(3)[index - 3] * value
    else:
        key = ("xz", "zy", "yx")[index - 6]  # the simulator's convention for d1, d2, d3
        t.misalignment = dict(t.misalignment)
        t.misalignment[key] += value
    return t


def test_gauge_symmetric_n_reproduces_the_observable(cert):
    rng = np.random.default_rng(1)
    shape = rng.normal(scale=0.01, size=6)
    e, mis = n_symmetric(cert.accel, shape)
    t = model_with(cert.accel, certificate_vector(cert.accel))
    t.scale_factor_error, t.misalignment = e, mis
    n = t.n_matrix()
    np.testing.assert_allclose(n, n.T, atol=1e-15)
    np.testing.assert_allclose(n @ n.T, p_matrix(shape) @ p_matrix(shape), atol=1e-15)
    # the certificate's own differences are the shape's d, exactly in this gauge
    np.testing.assert_allclose(t.misalignment_differences, shape[3:], atol=1e-15)
    # polar decomposition of an arbitrary N
    p, q = polar(cert.gyro.n_matrix())
    np.testing.assert_allclose(p @ q, cert.gyro.n_matrix(), atol=1e-14)
    np.testing.assert_allclose(q @ q.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(shape_of_p(p_matrix(shape)), shape, atol=1e-15)


def test_model_with_certificate_estimate_is_the_certificate(cert):
    t = model_with(cert.accel, certificate_vector(cert.accel))
    np.testing.assert_allclose(
        t.n_matrix() @ t.n_matrix().T, cert.accel.n_matrix() @ cert.accel.n_matrix().T, atol=1e-15
    )
    np.testing.assert_allclose(t.bias, cert.accel.bias)


@pytest.mark.parametrize("index", range(9))
def test_exact_fit_isolates_each_accel_parameter(cert, index):
    """A fault of 4 limits on one parameter: recovered, and nothing else moves beyond noise."""
    rng = np.random.default_rng(100 + index)
    lim = limit_vector(cert.accel)
    truth = _faulty(cert.accel, index, 4.0 * lim[index])
    up = spread_up_directions(14, seed=index)
    means, mvar = _means(truth, up, 600, rng)
    fit = exact_fit(cert.accel, means, mvar, G)
    assert fit.determined.all()
    dev = fit.deviation
    assert abs(dev[index] - 4.0 * lim[index]) < max(4 * fit.std[index], 0.02 * lim[index])
    others = np.delete(np.arange(9), index)
    assert np.all(np.abs(dev[others]) < 4 * fit.std[others] + 1e-3 * lim[others])
    assert fit.rms_residual < 3e-4
    np.testing.assert_array_equal(candidates(fit, 4.0) != 0, np.arange(9) == index)


def test_linear_solution_misattributes_what_the_exact_fit_does_not(cert):
    """Note §2: the linearisation spreads a large bias fault onto the scale factors."""
    rng = np.random.default_rng(7)
    lim = limit_vector(cert.accel)
    truth = _faulty(cert.accel, 0, 6.0 * lim[0])
    up = spread_up_directions(14, seed=3)
    means, mvar = _means(truth, up, 600, rng)
    covs = np.array([np.diag(v * 600) for v in mvar])
    exact = exact_fit(cert.accel, means, mvar, G)
    lin = linear_fit(cert.accel, means, covs, np.full(len(up), 600.0), G)
    scale_err_exact = np.max(np.abs(exact.deviation[3:6]) / lim[3:6])
    scale_err_lin = np.max(np.abs(lin.deviation[3:6]) / lim[3:6])
    assert scale_err_exact < 0.05
    assert scale_err_lin > 3 * scale_err_exact


def test_few_attitudes_leave_parameters_undetermined(cert):
    rng = np.random.default_rng(8)
    up = spread_up_directions(3, seed=1)
    means, mvar = _means(cert.accel, up, 600, rng)
    fit = exact_fit(cert.accel, means, mvar, G)
    assert not fit.determined.all()
    assert not fit.determined[3:].any()
    assert all(r for r, d in zip(fit.reasons, fit.determined, strict=True) if not d)
    # an undetermined parameter is never a fault candidate, even with a fault
    assert not candidates(fit, 4.0)[3:].any()


def test_six_faces_determine_bias_and_scale_but_not_misalignment(cert):
    rng = np.random.default_rng(9)
    faces = np.vstack([np.eye(3), -np.eye(3)])
    means, mvar = _means(cert.accel, faces, 2000, rng)
    fit = exact_fit(cert.accel, means, mvar, G)
    assert fit.determined[:6].all()
    assert not fit.determined[6:].any()


def test_navigation_grade_decision():
    from imudiag.certificate import load

    nav = load("tests/data/diagnosis/nav-grade.yaml")
    assert earth_rate_observable(nav)
    assert not earth_rate_observable(load_default())


def test_quaternion_chain_equals_matrix_chain():
    rng = np.random.default_rng(2)
    th = rng.normal(scale=0.4, size=(13, 3))
    r = np.eye(3)
    for v in th:
        r = r @ axis_angle_matrix(v / np.linalg.norm(v), np.linalg.norm(v))
    np.testing.assert_allclose(quat_matrix(ordered_product(rotvec_quat(th))), r, atol=1e-14)
    assert np.allclose(rotvec_quat(np.zeros((2, 3))), [[1, 0, 0, 0], [1, 0, 0, 0]])


def test_clipping_and_attitudes():
    rng = np.random.default_rng(3)
    raw = rng.normal(0.0, 10.0, (300, 3)).round()
    raw[100:140, 1] += np.linspace(0, 5000, 40)
    assert not clipped(raw, np.zeros(3), np.full(3, 10.0))
    raw[120:140, 1] = raw[120:140, 1].max()
    raw[140:150, 1] = 32767
    assert clipped(raw, np.zeros(3), np.full(3, 10.0))
    up = np.array([[0, 0, 1.0], [0, 0.05, 1.0], [1.0, 0, 0]])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    assert distinct_attitudes(up, 10.0) == 2


def _fit_with(dev: float, std: float, cert) -> TriadFit:
    c = certificate_vector(cert.accel)
    est = c.copy()
    est[0] += dev
    return TriadFit(
        triad="accel",
        method="exact",
        estimate=est,
        std=np.full(9, std),
        certificate=c,
        limit=limit_vector(cert.accel),
        determined=np.full(9, std <= 10.5),
    )


def test_predicates_need_limit_sigma_and_persistence(cert):
    lim = cert.accel.limits.bias[0]
    tr = PredicateTracker(k_sigma=4.0, persist=2)
    # beyond the limit but within 4 sigma: not a candidate
    assert tr.update(_fit_with(1.5 * lim, lim, cert), 1.0) == []
    # beyond both, once: candidate, not yet a fault
    assert len(tr.update(_fit_with(3 * lim, 1.0, cert), 2.0)) == 1
    assert tr.active() == []
    # twice in a row: a fault, first seen at the first window of the streak
    tr.update(_fit_with(3 * lim, 1.0, cert), 3.0)
    (f,) = tr.active()
    assert (f["triad"], f["sensor"], f["cause"], f["t_first"]) == ("accel", "ax", "bias", 2.0)
    assert f["certificate"] == cert.accel.bias[0] and f["limit"] == lim
    # back within limits for `persist` windows: cleared, but kept in the raised list
    tr.update(_fit_with(0.0, 1.0, cert), 4.0)
    assert tr.active()
    tr.update(_fit_with(0.0, 1.0, cert), 5.0)
    assert tr.active() == [] and len(tr.all_raised()) == 1
    # a sign change restarts the streak
    tr2 = PredicateTracker(k_sigma=4.0, persist=2)
    tr2.update(_fit_with(3 * lim, 1.0, cert), 1.0)
    tr2.update(_fit_with(-3 * lim, 1.0, cert), 2.0)
    assert tr2.active() == []


def test_shape_of_certificate_matches_first_order_differences(cert):
    shape, _ = shape_of_triad(cert.gyro)
    # equal to first order; the second-order terms (e d, D^2) are a few 1e-5 here
    np.testing.assert_allclose(shape[3:], cert.gyro.misalignment_differences, atol=3e-5)
    np.testing.assert_allclose(shape[:3], cert.gyro.relative_scale_error, atol=3e-5)
