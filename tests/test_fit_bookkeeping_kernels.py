"""The window fits' bookkeeping compiled (issue 28, numba from the ``fleet`` extra), each equal
to its numpy path to the bit:

- the common excess variance of the deletion figures
  (:func:`imudiag.numba_kernels.robust_excess` behind
  :func:`imudiag.diagnosis.robust._robust_excess`): the same trial values, the same medians
  (order statistics, exact) and comparisons, on seeded random deletion figures (points of one
  to three rows, equal and unequal noise, a point that is not a number);
- the exact fit's excess variance (:func:`imudiag.numba_kernels.excess_variance` behind
  :func:`imudiag.diagnosis.scalar_fit._excess_variance`): the same halvings, each sum in
  numpy's pairwise order (:func:`imudiag.numba_kernels.pairwise_sum`, held to ``np.sum`` on
  values of every magnitude, so a numpy that sums otherwise fails here first)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.diagnosis.robust import _robust_excess  # noqa: E402
from imudiag.diagnosis.scalar_fit import _excess_variance  # noqa: E402


@pytest.mark.parametrize("seed", range(4))
def test_robust_excess_kernel_equals_plain(seed):
    rng = np.random.default_rng(seed)
    was = kernels.enabled()
    bracketed = 0
    try:
        for case in range(300):
            n = int(rng.integers(3, 60))
            u = rng.chisquare(1, n) * rng.uniform(0.5, 20.0)  # mostly scattered beyond the noise
            if case % 7 == 0:
                u[rng.integers(0, n)] = np.nan
            nv = rng.uniform(0.1, 10.0, n)
            if case % 11 == 0:
                nv[:] = nv[0]
            m = rng.integers(1, 4, n).astype(float)
            kernels.enable(False)
            plain = _robust_excess(u, nv, m)
            assert kernels.enable(True), kernels.status()
            fast = _robust_excess(u, nv, m)
            assert fast == plain, (case, fast, plain)
            bracketed += plain > 0
    finally:
        kernels.enable(was)
    assert bracketed > 200  # the brackets ran, not only the early return


def test_pairwise_sum_is_numpys_sum():
    assert kernels.load(), kernels.status()
    pairwise = kernels._KERNELS["pairwise_sum"]
    rng = np.random.default_rng(3)
    for _ in range(3000):
        n = int(rng.integers(1, 700))
        x = rng.normal(size=n) * 10.0 ** rng.uniform(-12.0, 12.0, n)
        assert pairwise(x, 0, n) == np.sum(x)


@pytest.mark.parametrize("seed", range(3))
def test_excess_variance_kernel_equals_plain(seed):
    rng = np.random.default_rng(10 + seed)
    was = kernels.enabled()
    try:
        for _ in range(300):
            k = int(rng.integers(1, 200))
            sig2 = rng.uniform(0.1, 2.0, k) * 10.0 ** rng.uniform(-3.0, 3.0)
            r = rng.normal(size=k) * np.sqrt(sig2) * rng.uniform(1.0, 30.0)
            dof = float(rng.uniform(0.5, k))
            kernels.enable(False)
            plain = _excess_variance(r, sig2, dof)
            assert kernels.enable(True), kernels.status()
            fast = _excess_variance(r, sig2, dof)
            assert fast == plain, (k, fast, plain)
    finally:
        kernels.enable(was)
