"""The accelerometer window fit's cost work (issue 14) leaves every number as it was, bit
for bit: the windows' mean variances stacked in whole-array operations equal the
per-interval ones on the real Xsens intervals (and with a noise floor unknown, and with an
empty interval); P of one shape built from Python floats equals the stacked form's; the
certificate's shape and rotation kept from an earlier polar decomposition equal a fresh one; the
fit to every interval the rejection makes first equals a fit made afresh; and the robust
excess variance with noise_estimate.medians equals the one with np.median it replaced
(written out below as it was).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from test_rotation_jacobian import LIKE_XSENS, collect_xsens_intervals

from imudiag.certificate import load, load_default
from imudiag.diagnosis.gauge import p_matrix, polar, shape_of_p, shape_of_triad
from imudiag.diagnosis.intervals import stacked_mean_var
from imudiag.diagnosis.robust import point_diagnostics
from imudiag.diagnosis.scalar_fit import exact_fit, robust_exact_fit_and_plain
from imudiag.sim.trajectories import spread_up_directions

_CHI2_1_MEDIAN = 0.454936423119572


@pytest.fixture(scope="module")
def xsens_intervals():
    """The still intervals of the real Xsens recording, as the diagnosis collects them."""
    intervals = collect_xsens_intervals(load(LIKE_XSENS))
    assert len(intervals) >= 24
    return intervals


def _per_interval(intervals, triad):
    return np.array([iv.mean_var(triad) for iv in intervals])


def _stacked(intervals, triad):
    covs = np.array([iv.cov(triad) for iv in intervals])
    return stacked_mean_var(intervals, triad, covs)


@pytest.mark.parametrize("triad", ["accel", "gyro"])
def test_stacked_mean_var_equals_per_interval_on_real_windows(xsens_intervals, triad):
    """Windows of 24 consecutive intervals, every 8th start: the same bytes."""
    assert all(iv.noise_floor(triad) is not None for iv in xsens_intervals)
    for start in range(0, len(xsens_intervals) - 23, 8):
        window = xsens_intervals[start : start + 24]
        want = _per_interval(window, triad)
        got = _stacked(window, triad)
        assert got.shape == want.shape == (24, 3)
        assert got.tobytes() == want.tobytes()


def test_stacked_mean_var_with_unknown_floor_and_empty_interval(xsens_intervals):
    """A floor not known yet (None) and an interval of no samples (n = 0): as per interval."""
    window = [copy.deepcopy(iv) for iv in xsens_intervals[:6]]
    window[2].n = 0
    got = _stacked(window, "accel")
    assert got.tobytes() == _per_interval(window, "accel").tobytes()
    assert np.all(np.isfinite(got[2]))
    window[4].accel_noise_var = None
    got = _stacked(window, "accel")
    assert got.tobytes() == _per_interval(window, "accel").tobytes()
    assert _stacked([], "accel").shape == (0,)


def _robust_excess_with_numpy_median(u, nv, m):
    """robust._robust_excess as it was (np.median of the 15 trial rows)."""
    ok = np.isfinite(u)
    if ok.sum() < 3:
        return 0.0
    u, nv, m = u[ok], nv[ok], m[ok]
    a = u / m
    if float(np.median(a)) <= _CHI2_1_MEDIAN:
        return 0.0
    lo, hi = 0.0, float(np.max(a * nv)) + 1e-300
    steps = np.arange(1, 16) / 16.0
    inv_nv = 1.0 / nv
    for _ in range(40):
        trial = lo + (hi - lo) * steps
        below = np.median(a / (1.0 + trial[:, None] * inv_nv), axis=1) <= _CHI2_1_MEDIAN
        k = int(np.argmax(below)) if below.any() else trial.size
        if k > 0:
            lo = float(trial[k - 1])
        if k < trial.size:
            hi = float(trial[k])
        if hi - lo <= 1e-10 * hi:
            break
    return hi


@pytest.mark.parametrize("n", [17, 24, 25])
def test_robust_excess_equals_numpy_median_version(n):
    """Point diagnostics of a linear fit whose scatter exceeds its noise (fixed seed; odd
    and even point counts): the excess variance and the standardised figures, bit for bit."""
    rng = np.random.default_rng(14 + n)
    jac = rng.normal(size=(n, 9))
    noise_var = rng.uniform(0.5, 2.0, size=n) * 1e-8
    r = rng.normal(size=n) * np.sqrt(noise_var) * 3.0
    r[n // 3] += 40.0 * np.sqrt(noise_var[n // 3])  # one gross outlier
    w = 1.0 / noise_var
    cov = np.linalg.pinv(jac.T @ (jac * w[:, None]) + np.eye(9) * 1e-2)
    diag = point_diagnostics(jac, r, noise_var, cov)
    assert diag.excess_var > 0.0
    sw = np.sqrt(w)
    a_all, s_all = jac * sw[:, None], sw * r
    h = np.einsum("ij,jk,ik->i", a_all, cov, a_all)
    ok = h <= 0.99
    u = np.where(ok, s_all * np.where(ok, s_all / np.where(ok, 1.0 - h, 1.0), np.nan), np.nan)
    u = u / (noise_var * w)
    want = _robust_excess_with_numpy_median(u, np.where(ok, noise_var, 1.0), np.ones(n))
    assert diag.excess_var == want


def test_p_matrix_of_one_shape_equals_the_stacked_form():
    """P of each shape alone (the fits' path) against P of all of them at once: the same
    bytes, signed zeros and a subnormal included (fixed seed)."""
    rng = np.random.default_rng(14)
    shapes = rng.normal(size=(500, 6)) * 0.3
    shapes[0] = [-0.0, 0.0, -0.0, -0.0, 0.0, -1e-320]
    shapes[1] = [0.5, -0.5, 1e-17, 1e300, -1e-300, np.nan]
    stacked = p_matrix(shapes)
    for i, s in enumerate(shapes):
        one = p_matrix(s)
        assert one.shape == (3, 3) and one.dtype == np.float64
        assert one.tobytes() == stacked[i].tobytes(), i


def _same(a, b) -> bool:
    """Two values equal bit for bit (arrays by their bytes, containers element-wise)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("kind", ["clean", "outlier", "step"])
def test_plain_fit_kept_from_the_rejection_equals_a_fresh_one(seed, kind):
    """Seeded windows of 24 accelerometer holds, clean, with one bumped hold (rejected) and
    with a bias step half way (rejection withheld): the plain fit handed back equals
    exact_fit over every mean, every field bit for bit."""
    cert = load_default()
    tri = cert.accel
    rng = np.random.default_rng(seed)
    up = spread_up_directions(24, seed)
    sigma = tri.noise_sigma(200.0)
    means = tri.forward_si(up * 9.80665) + rng.normal(size=up.shape) * sigma / 20.0
    var = np.tile(sigma**2 / 400.0, (24, 1))
    if kind == "outlier":
        means[9] += 40.0 * np.sqrt(var[9]) * up[9]
    elif kind == "step":
        means[12:] += 30.0 * np.sqrt(var[0])
    g_in = 9.80665 / tri.unit_to_si
    labels = [f"interval {i}" for i in range(24)]
    fit, plain = robust_exact_fit_and_plain(
        tri, means, var, g_in, labels=labels, min_dof=3.0, prior_factor=10.0
    )
    fresh = exact_fit(tri, means, var, g_in, prior_factor=10.0)
    if kind == "outlier":
        assert plain is not fit and fit.extra.get("rejected")
    for name, value in vars(fresh).items():
        if name not in ("kept", "point_labels") or plain is not fit:
            assert _same(getattr(plain, name), value), name


def test_shape_of_triad_kept_equals_a_fresh_polar_decomposition():
    """Asked again for the same N (every window), the kept shape and rotation equal a polar
    decomposition made afresh, bit for bit, and are copies (changing one changes nothing)."""
    cert = load_default()
    for tri in (cert.accel, cert.gyro, load(LIKE_XSENS).accel):
        p, q = polar(tri.n_matrix())
        for _ in range(3):
            shape, rot = shape_of_triad(tri)
            assert shape.tobytes() == shape_of_p(p).tobytes()
            assert rot.tobytes() == q.tobytes() and rot.strides == q.strides
            shape += 1.0
            rot[:] = 0.0
        other = copy.deepcopy(tri)
        other.misalignment = dict(other.misalignment, xz=other.misalignment["xz"] + 1e-3)
        p2, q2 = polar(other.n_matrix())
        assert shape_of_triad(other)[0].tobytes() == shape_of_p(p2).tobytes()
        assert shape_of_triad(other)[1].tobytes() == q2.tobytes()
