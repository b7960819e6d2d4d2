"""The compiled window-fit kernel (issue 28, :mod:`imudiag.diagnosis.kernels`, numba from the
``fleet`` extra) against the plain numpy loop it replaces in fleet workers: the same exact
fits on random interval means (fixed seeds), the plain loop where the kernel gives up (an
ill-conditioned solve), and whole reports of the frozen-report inputs (a real Xsens MTi
recording and a simulated board capture) equal to the frozen reports within the tolerance
that holds reports across processors (rounding differences only: verdicts, faults, counts and
every string equal)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag.certificate import load_default  # noqa: E402
from imudiag.diagnosis import kernels  # noqa: E402
from imudiag.diagnosis.scalar_fit import (  # noqa: E402
    MAX_SHAPE,
    RESIDUAL_FLOOR,
    exact_fit,
    robust_exact_fit,
)

#: The kernel solves its 9x9 normal equations by elimination, the plain loop by LAPACK's SVD
#: least squares: the fits agree to rounding, amplified by the fit's conditioning (about 1e-9
#: relative on parameters near zero here); held to the reports' cross-processor tolerance.
RTOL = 1e-7


@pytest.fixture
def both():
    """Runs ``fn`` with the plain loop, then with the kernel; the two results."""
    was = kernels.enabled()

    def run(fn):
        kernels.enable(False)
        plain = fn()
        assert kernels.enable(True), kernels.status()
        try:
            fast = fn()
        finally:
            kernels.enable(was)
        return plain, fast

    yield run
    kernels.enable(was)


def fit_arrays(fit):
    return {
        "estimate": fit.estimate,
        "std": fit.std,
        "determined": fit.determined,
        "loo": fit.loo_deviation,
        "z": fit.point_z,
        "rms": np.array([fit.rms_residual]),
        "dof": np.array([fit.dof]),
        "excess": np.array([fit.excess_var]),
        # the part of each variance estimated from the residuals (the Student-t threshold):
        # a difference of two variances, compared at the scale of the variance
        "estimated_var": fit.estimated_var,
    }


def assert_fits_close(fast, plain):
    """Every array of two fits (:func:`fit_arrays`) equal within :data:`RTOL` of each value or
    of its scale: an estimate's std, the largest of a column of shifts or of the z scores
    (a value near zero, the difference of two nearly equal numbers, keeps only absolute
    accuracy)."""
    scale = {
        "estimate": plain["std"],
        "loo": None if plain["loo"] is None else np.max(np.abs(plain["loo"]), axis=0),
        "z": None if plain["z"] is None else np.max(np.abs(plain["z"])),
        "estimated_var": np.where(np.isfinite(plain["std"]), plain["std"] ** 2, 0.0),
    }
    for key in plain:
        if plain[key] is None:
            assert fast[key] is None, key
            continue
        a, b = np.asarray(fast[key], dtype=float), np.asarray(plain[key], dtype=float)
        tol = RTOL * (np.abs(b) + (scale.get(key) if scale.get(key) is not None else 0.0))
        bad = ~((np.abs(a - b) <= tol) | ((a == b) | (np.isnan(a) & np.isnan(b))))
        assert not bad.any(), f"{key}: {a[bad]} != {b[bad]} (tolerance {tol[bad]})"


def random_means(seed: int, k: int, outlier: bool = False):
    """(means, variances, magnitudes) of ``k`` still attitudes of the default certificate's
    accelerometers with biases and scale errors off the certificate, output units."""
    rng = np.random.default_rng(seed)
    model = load_default().accel
    up = rng.normal(size=(k, 3))
    up /= np.linalg.norm(up, axis=1)[:, None]
    g = 9.80665 / model.unit_to_si
    scale = model.scale_factor * (1.0 + rng.normal(0.0, 2e-3, 3))
    bias = model.bias + rng.normal(0.0, 5.0, 3)
    means = bias + scale * up * g + rng.normal(0.0, 0.5, (k, 3))
    if outlier:
        means[rng.integers(k)] += 40.0
    return model, means, np.full((k, 3), 0.3), np.full(k, g)


@pytest.mark.parametrize("seed", range(6))
def test_exact_fit_kernel_equals_plain(both, seed):
    model, means, var, mag = random_means(seed, 8 + 5 * seed)
    for kw in ({}, {"prior_factor": 3.0}, {"start": "certificate"}):
        plain, fast = both(lambda kw=kw: fit_arrays(exact_fit(model, means, var, mag, **kw)))
        assert_fits_close(fast, plain)


@pytest.mark.parametrize("seed", range(3))
def test_robust_fit_kernel_rejects_what_plain_rejects(both, seed):
    model, means, var, mag = random_means(100 + seed, 16, outlier=True)
    labels = [f"interval {i}" for i in range(16)]
    plain, fast = both(lambda: robust_exact_fit(model, means, var, mag, labels=labels))
    assert plain.extra.get("rejected"), "the injected outlier is rejected"
    assert fast.extra.get("rejected") == plain.extra.get("rejected")
    np.testing.assert_array_equal(fast.kept, plain.kept)
    assert_fits_close(fit_arrays(fast), fit_arrays(plain))


def test_kernel_gives_up_where_its_solve_breaks_down(both):
    # a mean that is not a number: the damped normal matrix is too, the kernel's elimination
    # has no pivot, and the plain loop (SVD least squares) runs the fit instead
    model, means, var, mag = random_means(7, 10)
    means[4, 1] = np.nan
    m0 = mag[0]
    assert kernels.enable(True)
    try:
        got = kernels.exact_gauss_newton(
            np.zeros(9), 0.0, means / (model.scale_factor * m0), mag / m0,
            var / (model.scale_factor * m0) ** 2, np.ones(9), np.zeros(9), 20, MAX_SHAPE,
            RESIDUAL_FLOOR**2,
        )  # fmt: skip
    finally:
        kernels.enable(False)
    assert got is None

    def outcome():
        try:
            return fit_arrays(exact_fit(model, means, var, mag))
        except Exception as exc:  # noqa: BLE001 - the same failure either way
            return type(exc).__name__

    plain, fast = both(outcome)
    if isinstance(plain, str):
        assert fast == plain
    else:
        for key in plain:
            if plain[key] is not None:
                np.testing.assert_array_equal(fast[key], plain[key], err_msg=key)


def test_enable_off_is_the_plain_loop(both):
    model, means, var, mag = random_means(3, 12)
    kernels.enable(False)
    assert not kernels.enabled() and kernels.status().startswith("plain")
    assert kernels.exact_gauss_newton(np.zeros(9), 0.0, means, mag, var, *[np.zeros(9)] * 2,
                                      20, MAX_SHAPE, 0.0) is None  # fmt: skip


@pytest.mark.parametrize("name", ["board-static-bin", "xsens-mti"])
def test_reports_with_the_kernel_equal_the_frozen_ones(name, tmp_path, monkeypatch):
    """The whole `imudiag diagnose` report with the kernel (``IMUDIAG_KERNELS=numba``) on a
    real recording and a simulated capture: equal to the frozen reports (written by the plain
    loop) within the cross-processor tolerance, every non-float equal. The real recording as a
    real subprocess (the variable read by a new process), the capture in this process (the
    runner switches the kernels as a new process would)."""
    from tests import test_diagnose_frozen_reports as frozen

    if name not in frozen.CASES:
        pytest.fail(f"no frozen case {name}: {sorted(frozen.CASES)}")
    monkeypatch.setenv("IMUDIAG_KERNELS", "numba")
    want = json.loads((frozen.FROZEN / f"{name}.json").read_text())
    got = frozen.diagnose_report(name, tmp_path, in_process=name != "xsens-mti")
    diff = frozen.hardware_differences(got, want)
    assert not diff, f"{len(diff)} differences, first: " + "; ".join(diff[:8])


@pytest.mark.parametrize("seed", range(4))
def test_product_sensitivity_kernel_equals_plain(seed):
    """The motions' rotations and their sensitivity to N^-1 (the gyro rotation fit), on
    random blocks: empty segments, angles below the series thresholds (1e-4 and 1e-2 rad)
    and above."""
    from imudiag.rotations import segment_product_plan, segmented_product_sensitivity

    rng = np.random.default_rng(seed)
    lengths = rng.integers(0, 40, size=12)
    lengths[3] = 0
    k = int(lengths.sum())
    inc = rng.normal(size=(k, 3)) * 10 ** rng.uniform(-6, -0.5, size=(k, 1))
    ell = np.eye(3) + rng.normal(0.0, 1e-2, (3, 3))
    theta = inc @ ell.T
    q0, s0 = segmented_product_sensitivity(theta, inc, lengths, segment_product_plan(lengths))
    assert kernels.enable(True)
    try:
        q1, s1 = kernels.product_sensitivity(theta, inc, lengths)
    finally:
        kernels.enable(False)
    assert q1.shape == q0.shape and s1.shape == s0.shape
    np.testing.assert_allclose(q1, q0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(s1, s0, rtol=0, atol=1e-13 * max(1.0, float(np.abs(s0).max())))


def test_a_fleet_task_uses_the_kernels_in_its_own_thread_only(tmp_path, monkeypatch):
    """A fleet task runs its diagnosis with the kernels (its record says so) and leaves the
    calling process's choice as it was; ``IMUDIAG_KERNELS=plain`` keeps the plain loops."""
    from imudiag.fleet.simulate import write_flight
    from imudiag.fleet.task import Job, diagnose_log

    log = tmp_path / "flight.npz"
    write_flight(log, load_default(), "multiposition", 120.0, 100.0, [], 3, {"sample_rate": 100.0})
    st = log.stat()
    job = Job(str(log), "-", st.st_size, st.st_mtime_ns, str(tmp_path))
    kernels.enable(False)
    rec = diagnose_log(job)
    assert rec["status"] == "ok", rec["reason"]
    assert rec["kernels"] == "numba" and not kernels.enabled()
    monkeypatch.setenv("IMUDIAG_KERNELS", "plain")
    rec_plain = diagnose_log(job)
    assert rec_plain["kernels"] == "plain (IMUDIAG_KERNELS=plain)" and not kernels.enabled()
    assert rec_plain["report"]["verdict"] == rec["report"]["verdict"]


@pytest.mark.parametrize("fit_frame", [False, True])
def test_ninv_derivatives_and_predictions_kernels_equal_plain(fit_frame):
    """The rotation fit's N^-1 and its derivatives (frame rotations below and above the
    series thresholds) and its predicted directions with their derivatives, compiled
    against the plain numpy (random, seeded)."""
    from imudiag.diagnosis.gauge import shape_of_triad
    from imudiag.diagnosis.gyro_fit import ninv_derivatives, predict_with_jacobian
    from imudiag.rotations import segment_product_plan

    shape_c, q_c = shape_of_triad(load_default().gyro)
    rng = np.random.default_rng(5)
    npar = 9 if fit_frame else 6
    lengths = rng.integers(1, 30, size=8)
    inc = rng.normal(size=(int(lengths.sum()), 3)) * 0.05
    stack = {"turning": inc, "lengths": lengths, "plan": segment_product_plan(lengths)}
    up0 = rng.normal(size=(8, 3))
    up0 /= np.linalg.norm(up0, axis=1)[:, None]
    for scale in (0.0, 1e-5, 3e-3, 0.05):
        x = rng.normal(size=npar) * scale
        kernels.enable(False)
        plain = ninv_derivatives(shape_c, q_c, x, fit_frame)
        pred0 = predict_with_jacobian(stack, *plain, up0)
        assert kernels.enable(True)
        try:
            fast = ninv_derivatives(shape_c, q_c, x, fit_frame)
            pred1 = predict_with_jacobian(stack, *plain, up0)
        finally:
            kernels.enable(False)
        for a, b in zip(fast + pred1, plain + pred0, strict=True):
            assert a.shape == b.shape
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * max(1.0, float(np.abs(b).max())))


def _rotation_case(seed: int, truth_off: float):
    """(gyro model, motions, per-sample gyro variance, Earth rate) of a simulated session of
    14 attitudes turned by hand, its gyro shape ``truth_off`` limits off the certificate."""
    from imudiag.diagnosis.gyro_fit import gyro_sample_var
    from imudiag.diagnosis.intervals import IntervalCollector
    from imudiag.diagnosis.params import limit_vector
    from imudiag.diagnosis.window import rotation_pairs
    from imudiag.sim import multi_position, simulate

    like = load_default()
    truth = like.copy()
    rng = np.random.default_rng(seed)
    lim = limit_vector(truth.gyro)
    truth.gyro.scale_factor_error = truth.gyro.scale_factor_error + truth_off * lim[
        3:6
    ] * rng.uniform(-1.0, 1.0, 3)
    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200.0, seed=seed)
    block = simulate(truth, traj, seed=seed + 1).samples
    coll = IntervalCollector(like, like.sample_rate)
    ivs = coll.update(block) + coll.flush()
    return like.gyro, rotation_pairs(like, like.accel, ivs), gyro_sample_var(ivs), like.earth_rate


#: (seed, fit_frame, the shape's offset in limits, motions fitted): 13 motions, and 5 (with
#: the frame's 9 parameters some of them too influential to be left out: no deletion
#: figures there)
ROTATION_CASES = [
    (1, True, 0.5, 13),
    (2, True, 3.0, 13),
    (3, False, 1.0, 13),
    (4, True, 0.0, 13),
    (5, True, 1.0, 5),
    (6, False, 0.5, 5),
]


@pytest.mark.parametrize(("seed", "fit_frame", "truth_off", "motions"), ROTATION_CASES)
def test_rotation_fit_loop_kernel_equals_plain(both, seed, fit_frame, truth_off, motions):
    """The gyro rotation fit's damped Gauss-Newton loop compiled (its evaluations, normal
    equations and damped solves; :func:`imudiag.numba_kernels.rotation_loop`) and what
    follows it (covariance, deletion figures and variances, the robust excess;
    :func:`imudiag.numba_kernels.rotation_post`) against the numpy on simulated sessions (a
    shape within, and beyond, its limits; with and without the frame rotation; motions too
    influential to be left out): the same estimate, covariance, deletion figures and
    prediction within the reports' tolerance of each value or its scale, as the exact fit."""
    from imudiag.diagnosis.gyro_fit import rotation_fit

    gyro, pairs, var, earth = _rotation_case(seed, truth_off)
    assert len(pairs) >= 10
    probe, fitted = pairs[0], pairs[1 : 1 + motions]

    def fit():
        return rotation_fit(gyro, fitted, var, earth, fit_frame=fit_frame, predict=probe)

    calls: dict[str, list[bool]] = {"rotation_loop": [], "rotation_post": []}
    real = {name: getattr(kernels, name) for name in calls}

    def counted(name):
        def call(*args, **kwargs):
            out = real[name](*args, **kwargs)
            calls[name].append(out is not None)
            return out

        return call

    for name in calls:
        setattr(kernels, name, counted(name))
    try:
        plain, fast = both(fit)
    finally:
        for name in calls:
            setattr(kernels, name, real[name])
    assert calls == {"rotation_loop": [True], "rotation_post": [True]}, (
        "the compiled loop and what follows it ran the fit once, and did not give up"
    )
    std = np.sqrt(np.diag(plain.cov))
    finite = np.where(np.isfinite(plain.loo_var), plain.loo_var, 0.0)
    param_std = np.sqrt(np.max(finite, axis=0))  # each parameter's std, frame included
    pairs_scale = {
        "deviation": (plain.deviation, fast.deviation, std),
        "frame": (plain.frame, fast.frame, None),
        "cov": (plain.cov, fast.cov, None),
        "loo": (plain.loo_deviation, fast.loo_deviation, std),
        "point_z": (plain.point_z, fast.point_z, np.nanmax(np.abs(plain.point_z))),
        "rms": (np.array([plain.rms]), np.array([fast.rms]), None),
        "dof": (np.array([plain.dof]), np.array([fast.dof]), None),
        "predicted_z": (np.array([plain.predicted_z]), np.array([fast.predicted_z]), None),
        "loo_params": (plain.loo_params, fast.loo_params, param_std),
        "loo_var": (plain.loo_var, fast.loo_var, None),
        "excess": (np.array([plain.excess_var]), np.array([fast.excess_var]), None),
        "cov_scale": (np.array([plain.cov_scale]), np.array([fast.cov_scale]), None),
        "info": (plain.info, fast.info, np.max(np.abs(plain.info))),
    }
    if motions < 10 and fit_frame:
        assert np.isnan(plain.point_z).any() and not np.isnan(plain.point_z).all()
    for key, (b, a, scale) in pairs_scale.items():
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        tol = RTOL * (np.abs(b) + (0.0 if scale is None else scale))
        assert a.shape == b.shape, key
        with np.errstate(invalid="ignore"):  # inf - inf: a motion left without figures
            bad = ~((np.abs(a - b) <= tol) | (a == b) | (np.isnan(a) & np.isnan(b)))
        assert not bad.any(), f"{key}: {a[bad]} != {b[bad]} (tolerance {tol[bad]})"


@pytest.mark.parametrize("seed", range(3))
def test_attitude_groups_kernel_equals_plain(both, seed):
    """The window's attitude groups (greedy clustering of the intervals' directions) compiled
    against the numpy loop: the same labels, on seeded sets of directions (repeated
    attitudes with noise, directions spread at random, zero and non-finite rows)."""
    from imudiag.diagnosis.window import attitude_groups

    rng = np.random.default_rng(seed)
    for _ in range(200):
        base = rng.normal(size=(int(rng.integers(1, 8)), 3))
        up = base[rng.integers(0, base.shape[0], size=int(rng.integers(1, 40)))]
        up = up + rng.normal(0.0, 10 ** rng.uniform(-4, -0.5), up.shape)
        up /= np.linalg.norm(up, axis=1)[:, None]
        if rng.random() < 0.3:
            up[rng.integers(up.shape[0])] = 0.0
        if rng.random() < 0.3:
            up[rng.integers(up.shape[0]), rng.integers(3)] = np.nan
        plain, fast = both(lambda up=up: attitude_groups(up, 10.0))
        assert fast.dtype == plain.dtype
        np.testing.assert_array_equal(fast, plain)
