"""The exact fit in one compiled call (issue 28, :func:`imudiag.numba_kernels.exact_fit_kernel`
behind :func:`imudiag.diagnosis.scalar_fit.exact_fit` where the kernels are on) against the
plain numpy path, which stays the reference: the linear start (a Jacobi SVD for LAPACK's), the
Gauss-Newton loop with its excess-variance refits, the covariance (Cholesky for ``pinv``), the
deletion figures and the robust fit's prediction errors.

Equal within the reports' cross-processor tolerance
(:data:`tests.test_diagnose_frozen_reports.HW_REL_TOL`, 1e-7 relative, of each value or of
its scale), not bit for bit:

- on seeded random windows (attitudes spread, few points, fewer points than parameters, one
  attitude only, an outlier, a start vector, a tighter prior, the prediction of a point left
  out), the compiled call used (it did not give up) in each;
- on every window fit of every real recording shipped (tests/data/real, each with its
  data-sheet-like certificate, as tests/test_one_answer.py) and of the simulated families
  (static, multi-position, a turntable at a known rate, an urban drive with its GNSS): each
  exact fit the plain diagnosis made replayed with and without the kernel;
- whole reports: `imudiag.diagnose` with the kernels against the plain one on every real
  recording (:func:`tests.test_diagnose_frozen_reports.hardware_differences`: every verdict,
  fault, count and string equal). The one float it lets differ beyond 1e-3 is the ``dof``
  of a fit whose points are fitted to rounding: dof = K - tr(C I) is then the difference of
  two nearly equal numbers (3.9e-7 for the MPU-6050's first window of 2 points: its exact
  value, by rational arithmetic, is 3.8709e-7; numpy's ``pinv`` gives 3.8690e-7, the kernel's
  Cholesky 3.8727e-7, and even the exact inverse rounded to float64 3.8746e-7), held here to
  :data:`DOF_ABS` absolute.

tests/test_fleet_real.py holds the fleet's task (kernels on) to ``imudiag diagnose`` (plain)
on the same recordings.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

import imudiag  # noqa: E402
from imudiag import kernels as switch  # noqa: E402
from imudiag.aiding import moving  # noqa: E402
from imudiag.diagnosis import changepoint, kernels, scalar_fit  # noqa: E402
from imudiag.diagnosis.scalar_fit import exact_fit, robust_exact_fit  # noqa: E402
from imudiag.reports import json_text  # noqa: E402
from tests.test_diagnose_frozen_reports import (
    HW_REL_TOL,
    HW_RESIDUAL_KEYS,
    hardware_differences,
)  # noqa: E402
from tests.test_fit_kernels import fit_arrays, random_means  # noqa: E402
from tests.test_one_answer import LIKE, REAL, REAL_CASES  # noqa: E402

#: every real recording shipped, each with its certificate (tests/test_one_answer.py's, and
#: the MPU-6050's still hold with its data-sheet-like one); the x-io MT Manager export needs
#: read options (no time column): diagnosed through a text-table option below
REAL_LOGS = {
    **{k: v for k, v in REAL_CASES.items() if k != "xsens-mtmanager"},
    "mpu6050-static": (REAL / "mpu6050/static.csv.gz", LIKE / "like-mpu6050.yaml"),
}
#: the absolute tolerance of a ``dof`` near zero (a fit of its points to rounding; see above)
DOF_ABS = 1e-8


@pytest.fixture
def counted(monkeypatch):
    """The compiled fit's calls and how many gave up (the plain path ran instead)."""
    tally = {"calls": 0, "gave_up": 0}
    real = scalar_fit._compiled_fit

    def wrapper(*args, **kwargs):
        out = real(*args, **kwargs)
        tally["calls"] += 1
        tally["gave_up"] += out is None
        return out

    monkeypatch.setattr(scalar_fit, "_compiled_fit", wrapper)
    return tally


def both(fn):
    """``fn()`` on the plain path, then with the kernels; the two results."""
    with switch.switched(False):
        plain = fn()
    with switch.switched(True) as on:
        assert on, switch.status()
        fast = fn()
    return plain, fast


def assert_fits_close(fast: dict, plain: dict) -> None:
    """Two fits' arrays (:func:`tests.test_fit_kernels.fit_arrays`) equal within
    :data:`HW_REL_TOL` of each value or of its scale (an estimate's: its std), the residual
    figures as the report compares them (:data:`HW_RESIDUAL_KEYS`, 1e-3), a ``dof`` near zero
    to :data:`DOF_ABS`.

    The deletion figures are residual figures: a point's z and its leave-one-out shift are
    proportional to its residual |x| - mu, a difference of nearly equal numbers (1e-5 of
    the magnitude on a simulated board), which the two Gauss-Newton loops, stopping where
    the cost no longer falls by 1e-3, leave equal to about 1e-7 of itself (the parameters
    agree to 1e-9 of their value, 1e-9 of their std); from the same parameters the two
    paths give the same z and shifts to 1e-15 (docs/benchmarks.md)."""
    std = plain["std"]
    finite_std = np.where(np.isfinite(std), std, 0.0)
    est_f, est_p = fast["estimate"], plain["estimate"]
    for key, want in plain.items():
        if want is None:
            assert fast[key] is None, key
            continue
        a, b = np.asarray(fast[key], dtype=float), np.asarray(want, dtype=float)
        assert a.shape == b.shape, key
        if key == "estimate":
            tol = HW_REL_TOL * (np.abs(b) + finite_std)
        elif key == "loo":  # the estimate plus the point's shift, a residual figure
            a, b = a - est_f[None, :], b - est_p[None, :]
            tol = HW_RESIDUAL_KEYS["rms_residual"] * np.abs(b) + HW_REL_TOL * finite_std
        elif key in ("z", "rms"):
            tol = HW_RESIDUAL_KEYS["rms_residual"] * np.abs(b)
        elif key == "dof":
            tol = np.maximum(HW_RESIDUAL_KEYS["dof"] * np.abs(b), DOF_ABS)
        elif key == "estimated_var":  # a difference of variances: at the variance's scale
            tol = HW_RESIDUAL_KEYS["rms_residual"] * (np.abs(b) + finite_std**2)
        else:
            tol = HW_REL_TOL * np.abs(b)
        bad = ~((np.abs(a - b) <= tol) | (a == b) | (np.isnan(a) & np.isnan(b)))
        assert not bad.any(), f"{key}: {a[bad]} != {b[bad]} (tolerance {tol[bad]})"


def assert_predictions_close(fast, plain):
    a = np.asarray(fast.extra.get("predicted_z", []), dtype=float)
    b = np.asarray(plain.extra.get("predicted_z", []), dtype=float)
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=HW_REL_TOL, atol=0.0)


def one_attitude(seed: int, k: int):
    """``k`` means of a single attitude (a drive's stops on level ground): the linear start's
    regressors of rank 1, most directions left at the certificate by the prior."""
    model, means, var, mag = random_means(seed, k)
    means[:] = means[0] + np.random.default_rng(seed).normal(0.0, 0.3, (k, 3))
    return model, means, var, mag


@pytest.mark.parametrize("seed", range(8))
def test_random_windows_compiled_equal_plain(seed, counted):
    k = (3, 5, 8, 9, 12, 20, 35, 60)[seed]
    cases = [random_means(seed, k), one_attitude(seed, max(k, 4))]
    for model, means, var, mag in cases:
        start = np.random.default_rng(seed).normal(0.0, 1e-3, 9)
        for kw in (
            {},
            {"prior_factor": 3.0},
            {"start": "certificate"},
            {"start": start},
            {"scale_by_residual": False},
            {"predict": (means[0] + 5.0, var[0], mag[:1])},
        ):
            plain, fast = both(
                lambda kw=kw, m=model, x=means, v=var, g=mag: exact_fit(m, x, v, g, **kw)
            )
            assert_fits_close(fit_arrays(fast), fit_arrays(plain))
            assert_predictions_close(fast, plain)
            assert fast.reasons == plain.reasons
    assert counted["calls"] == 2 * 6
    assert counted["gave_up"] == 0, "the compiled fit gave up on a random window"


@pytest.mark.parametrize("seed", range(4))
def test_robust_fit_compiled_rejects_what_plain_rejects(seed, counted):
    model, means, var, mag = random_means(100 + seed, 16 + 4 * seed, outlier=True)
    labels = [f"interval {i}" for i in range(means.shape[0])]
    plain, fast = both(lambda: robust_exact_fit(model, means, var, mag, labels=labels))
    assert plain.extra.get("rejected"), "the injected outlier is rejected"
    assert fast.extra.get("rejected") == plain.extra.get("rejected")
    np.testing.assert_array_equal(fast.kept, plain.kept)
    assert_fits_close(fit_arrays(fast), fit_arrays(plain))
    assert counted["calls"] >= 3 and counted["gave_up"] == 0


def test_without_a_prior_the_plain_path_fits(counted):
    """No prior on a parameter (``prior_factor`` inf): directions without information are
    ``null``, found by the eigenvectors the kernel does not compute; the plain path runs."""
    model, means, var, mag = random_means(3, 12)
    plain, fast = both(lambda: exact_fit(model, means, var, mag, prior_factor=np.inf))
    assert_fits_close(fit_arrays(fast), fit_arrays(plain))
    assert counted["calls"] == 0


def test_the_linear_start_solves_as_lstsq():
    """The compiled minimum-norm least squares (one-sided Jacobi SVD, rcond 1e-10) against
    ``np.linalg.lstsq`` on full-rank, rank-deficient and short systems."""
    from imudiag import numba_kernels as nk

    rng = np.random.default_rng(11)
    for k, rank in ((40, 9), (12, 9), (20, 4), (5, 5), (3, 3), (30, 1)):
        h = rng.normal(size=(k, rank)) @ rng.normal(size=(rank, 9)) * 10 ** rng.uniform(-3, 3)
        z = rng.normal(size=k)
        out = np.empty(9)
        assert nk.lstsq_min_norm(h, z, 1e-10, out)
        want = np.linalg.lstsq(h, z, rcond=1e-10)[0]
        np.testing.assert_allclose(out, want, rtol=0, atol=1e-9 * np.abs(want).max())


def record_exact_fits(monkeypatch: pytest.MonkeyPatch) -> list[tuple[tuple, dict]]:
    """Every :func:`exact_fit` call of the diagnoses that follow until ``monkeypatch`` is
    undone (the robust fit's, the change-point test's, the moving-base windows'), as (args,
    kwargs)."""
    calls: list[tuple[tuple, dict]] = []

    def recording(*args, **kwargs):
        calls.append((args, dict(kwargs)))
        return exact_fit(*args, **kwargs)

    for module in (scalar_fit, changepoint, moving):
        monkeypatch.setattr(module, "exact_fit", recording)
    return calls


def replay(calls: list[tuple[tuple, dict]]) -> int:
    """Each recorded fit again, plain and compiled: equal within the tolerance; how many."""
    for args, kwargs in calls:
        plain, fast = both(lambda a=args, k=kwargs: exact_fit(*a, **k))
        assert_fits_close(fit_arrays(fast), fit_arrays(plain))
        assert_predictions_close(fast, plain)
        assert fast.reasons == plain.reasons and fast.method == plain.method
    return len(calls)


def diagnose_plain(log, cert, **kw):
    with switch.switched(False):
        return imudiag.diagnose(log, imudiag.api.load_certificate(str(cert)), **kw)


@functools.cache
def plain_real(name: str) -> tuple[list[tuple[tuple, dict]], dict]:
    """The plain diagnosis of a real recording, made once for this module's two tests: its
    exact fits (as :func:`record_exact_fits`) and its report (JSON)."""
    log, cert = REAL_LOGS[name]
    with pytest.MonkeyPatch.context() as mp:
        calls = record_exact_fits(mp)
        report = json.loads(json_text(diagnose_plain(log, cert)))
    return calls, report


@pytest.mark.parametrize("name", sorted(REAL_LOGS))
def test_every_window_fit_of_a_real_recording(name, counted):
    calls, _ = plain_real(name)
    replay(calls)
    assert counted["calls"] == len(calls)  # a fit without a prior would not be counted
    assert counted["gave_up"] <= len(calls) // 10, counted


@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> dict[str, tuple]:
    """The simulated families as (data, certificate, diagnose keywords)."""
    from benchmarks.diagnose_cpu import drive_case, write_board_log
    from imudiag.certificate import default_certificate_path
    from imudiag.logs.options import LogOptions
    from tests.test_known_rate import TABLE_DEG_S, _session, _truth

    d = tmp_path_factory.mktemp("families")
    bundled = default_certificate_path()
    truth = _truth()
    table_cert = d / "table.yaml"
    truth.save(table_cert)
    _session(d / "table.csv", truth.gyro, seed=7)
    samples, track = drive_case(24000, 100.0, 3)
    return {
        "static": (write_board_log(d / "static.npz", "static", 60000, 100.0, 4), bundled, {}),
        "multiposition": (
            write_board_log(d / "multi.npz", "multiposition", 60000, 100.0, 5),
            bundled,
            {},
        ),
        "turntable": (
            d / "table.csv",
            table_cert,
            {
                "config": {"known_rate_rad_s": float(np.radians(TABLE_DEG_S))},
                "log_options": LogOptions(gyro_only=True),
            },
        ),
        "drive": (samples, bundled, {"gnss": track}),
    }


@pytest.mark.parametrize("family", ["static", "multiposition", "turntable", "drive"])
def test_every_window_fit_of_a_simulated_family(family, simulated, counted):
    data, cert, kw = simulated[family]
    with pytest.MonkeyPatch.context() as mp:
        calls = record_exact_fits(mp)
        plain = diagnose_plain(data, cert, **kw)
    assert calls, f"{family}: no exact fit made"
    replay(calls)
    assert counted["calls"] == len(calls) and counted["gave_up"] <= len(calls) // 10, counted
    with switch.switched(True):
        fast = imudiag.diagnose(data, imudiag.api.load_certificate(str(cert)), **kw)
    assert_reports_agree(json.loads(json_text(fast)), json.loads(json_text(plain)))


def assert_reports_agree(fast: dict, plain: dict) -> None:
    """Within the cross-processor tolerance (:func:`hardware_differences`), an estimate also
    within :data:`HW_REL_TOL` of its parameter's std (a parameter that did not move from
    zero, 4e-9 rad, has no relative accuracy), a ``dof`` near zero to :data:`DOF_ABS`; the
    verdicts, named faults and their causes identical."""
    diff = []
    for d in hardware_differences(fast, plain):
        path, _, values = d.partition(": ")
        left, _, right = values.partition(" != ")
        a, b = float(left), float(right)
        if path.endswith(".dof") and abs(a - b) <= DOF_ABS:
            continue
        if ".estimate[" in path:
            std = lookup(plain, path.replace(".estimate[", ".std["))
            if std is not None and abs(a - b) <= HW_REL_TOL * (abs(b) + abs(std)):
                continue
        diff.append(d)
    assert not diff, f"{len(diff)} differences, first: " + "; ".join(diff[:6])
    for key in ("accel", "gyro"):
        assert fast["verdict"][key] == plain["verdict"][key]
    named = [
        [(f["triad"], f.get("sensor"), f["cause"]) for f in r["verdict"]["faults"]]
        for r in (fast, plain)
    ]
    assert named[0] == named[1]


@pytest.mark.parametrize("name", sorted(REAL_LOGS))
def test_whole_reports_of_the_real_recordings(name):
    log, cert = REAL_LOGS[name]
    _, plain = plain_real(name)
    with switch.switched(True):
        fast = json.loads(json_text(imudiag.diagnose(log, imudiag.api.load_certificate(str(cert)))))
    assert_reports_agree(fast, plain)


def lookup(report: dict, path: str) -> float | None:
    """The number at ``path`` (``report.windows[3].accel.bias.std[1]``) of a report, or None."""
    node: object = report
    for part in path.split(".")[1:]:
        name, _, rest = part.partition("[")
        if not isinstance(node, dict) or name not in node:
            return None
        node = node[name]
        for index in rest.rstrip("]").split("][") if rest else []:
            if not isinstance(node, list):
                return None
            node = node[int(index)]
    return float(node) if isinstance(node, (int, float)) and node is not None else None


def test_the_mtmanager_export_read_as_a_table():
    """The 12th recording, the Xsens MT Manager export (no time column, no units in it): read
    with the options its golden file names, both paths give the same report."""
    from imudiag.logs.options import options_from_query
    from tests.test_one_answer import READ_AS

    log, cert = REAL_CASES["xsens-mtmanager"]
    query = READ_AS["xsens-mtmanager"].split("&")
    opts = options_from_query(dict(kv.split("=", 1) for kv in query))
    plain = json.loads(json_text(diagnose_plain(log, cert, log_options=opts)))
    with switch.switched(True):
        fast = imudiag.diagnose(log, imudiag.api.load_certificate(str(cert)), log_options=opts)
    assert_reports_agree(json.loads(json_text(fast)), plain)


def test_kernels_module_switch_is_the_one_switch():
    assert kernels.enabled is switch.enabled and kernels.switched is switch.switched
