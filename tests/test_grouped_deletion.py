"""The rotation fit's per-motion deletion figures, all motions at once, equal the per-motion
loop (issue 14): shifts, standardised residuals, excess scatter and deletion variances."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.diagnosis import gyro_fit, robust


def _problem(seed: int, n_groups: int = 23, p: int = 9):
    """A weighted least-squares problem with 3-row groups, one of them of leverage ~1."""
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(3 * n_groups, p))
    jac[:3] *= 1e4  # the first motion alone carries the parameters: not judged
    noise_var = rng.uniform(0.5, 2.0, size=3 * n_groups) * 1e-6  # rad^2
    w = 1.0 / noise_var
    cov = np.linalg.pinv(jac.T @ (jac * w[:, None]) + np.eye(p))
    r = rng.normal(size=3 * n_groups) * np.sqrt(noise_var) * 1.5
    groups = [np.arange(3 * i, 3 * i + 3) for i in range(n_groups)]
    return jac, r, noise_var, w, cov, groups


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_all_groups_at_once_equal_the_loop(seed, monkeypatch):
    jac, r, noise_var, w, cov, groups = _problem(seed)
    fast = robust.point_diagnostics(-jac, r, noise_var, cov, groups=groups, weights=w)
    fast_var = gyro_fit._deletion_variances(jac * np.sqrt(w)[:, None], cov, groups)
    # the same functions through their loop over groups (the path of unequal groups)
    monkeypatch.setattr(robust, "group_leverages", lambda *a: None)
    monkeypatch.setattr(gyro_fit, "group_leverages", lambda *a: None)
    slow = robust.point_diagnostics(-jac, r, noise_var, cov, groups=groups, weights=w)
    slow_var = gyro_fit._deletion_variances(jac * np.sqrt(w)[:, None], cov, groups)
    assert np.isnan(fast.z[0]) and np.all(np.isnan(fast.shift[0])) and np.isinf(fast_var[0, 0])
    assert np.isfinite(fast.z[1:]).all() and np.isfinite(fast_var[1:]).all()
    np.testing.assert_allclose(fast.z, slow.z, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(fast.shift, slow.shift, rtol=1e-10, atol=0, equal_nan=True)
    assert fast.excess_var == pytest.approx(slow.excess_var, rel=1e-10, abs=0.0)
    np.testing.assert_allclose(fast_var, slow_var, rtol=1e-12)


def test_groups_of_different_sizes_take_the_loop():
    jac, r, noise_var, w, cov, _ = _problem(4)
    groups = [np.arange(0, 2), np.arange(2, 6)] + [np.arange(i, i + 3) for i in range(6, 69, 3)]
    assert robust.group_leverages(jac, cov, groups) is None
    d = robust.point_diagnostics(-jac, r, noise_var, cov, groups=groups, weights=w)
    assert d.z.shape == (len(groups),) and np.isfinite(d.z[2:]).all()
