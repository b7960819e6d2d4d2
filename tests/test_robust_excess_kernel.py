"""The fits' common excess variance compiled (issue 28, :func:`imudiag.numba_kernels.robust_excess`
behind :func:`imudiag.diagnosis.robust._robust_excess`, numba from the ``fleet`` extra): the
same trial values, the same medians (order statistics, exact) and comparisons as the numpy
brackets, so the same excess variance to the bit, on seeded random deletion figures (points
of one to three rows, equal and unequal noise, a point that is not a number)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.diagnosis.robust import _robust_excess  # noqa: E402


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
