"""The noise judge's counts compiled (issue 28, :func:`imudiag.numba_kernels.beyond_counts`
behind :func:`imudiag.trailing.median_side`, numba from the ``fleet`` extra): the same
comparisons and integer counts as the numpy path, so the same ``above`` and ``below`` flags,
on data made to be hard (whole ADC counts with ties, thresholds equal to data values, NaN,
infinite thresholds) and on the transposed view the noise judge passes."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.trailing import median_side  # noqa: E402


@pytest.mark.parametrize("w", [4, 5, 200, 201])
def test_median_side_kernel_equals_plain(w):
    rng = np.random.default_rng(100 + w)
    raw = np.rint(rng.normal(scale=3.0, size=(6, 5000)))  # whole ADC counts, channel rows
    d2 = np.diff(raw, n=2, axis=1) ** 2
    d2[rng.random(d2.shape) < 0.001] = np.nan
    x = d2.T  # (R, 6), a strided view as the noise judge passes it
    ends = np.sort(rng.integers(w, x.shape[0] + 1, 400))
    thr = np.stack([np.full(6, 4.0), rng.uniform(0.0, 20.0, 6), np.full(6, np.inf)])
    thr[1, 2] = 9.0  # a data value
    was = kernels.enabled()
    try:
        kernels.enable(False)
        plain = median_side(x, ends, w, thr)
        assert kernels.enable(True), kernels.status()
        fast = median_side(x, ends, w, thr)
        fast_c = median_side(np.ascontiguousarray(x), ends, w, thr)
    finally:
        kernels.enable(was)
    assert plain[0].any() and plain[1].any()
    for got in (fast, fast_c):
        for a, b in zip(got, plain, strict=True):
            np.testing.assert_array_equal(a, b)
