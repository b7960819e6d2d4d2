"""An interval's mean and covariance (:func:`imudiag.diagnosis.intervals.mean_and_cov`, issue
28: np.cov's steps without its argument handling, its mean kept) equal ``x.mean(axis=0)``
and ``np.cov(x, rowvar=False)`` bit for bit, on the collector's own layout (columns of its
(N, 14) rows) and on contiguous samples of every scale (seeded)."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.diagnosis.intervals import mean_and_cov


@pytest.mark.parametrize("seed", range(4))
def test_mean_and_cov_equal_numpy_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    for _ in range(60):
        n = int(rng.integers(2, 7000))
        rows = rng.normal(size=(n, 14)) * 10 ** rng.uniform(-4, 5) + rng.normal() * 3e4
        for x in (rows[:, 1:4], rows[:, 4:7], np.ascontiguousarray(rows[:, 4:7])):
            mean, cov = mean_and_cov(x)
            assert mean.tobytes() == x.mean(axis=0).tobytes()
            assert cov.tobytes() == np.cov(x, rowvar=False).tobytes()


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_moments_equal_numpy(seed):
    """The fleet workers' compiled moments (:func:`imudiag.numba_kernels.mean_cov3`): the mean
    bit for bit (the same sums down the samples, in order), the covariance to rounding (a
    BLAS product in numpy: within 1e-12 of the variances' scale)."""
    pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")
    from imudiag.numba_kernels import mean_cov3

    rng = np.random.default_rng(100 + seed)
    for _ in range(60):
        n = int(rng.integers(2, 7000))
        rows = rng.normal(size=(n, 14)) * 10 ** rng.uniform(-4, 5) + rng.normal() * 3e4
        for x in (rows[:, 1:4], np.ascontiguousarray(rows[:, 4:7])):
            mean, cov = mean_cov3(x)
            want_mean, want_cov = mean_and_cov(x)
            assert mean.tobytes() == want_mean.tobytes()
            scale = np.sqrt(np.outer(np.diag(want_cov), np.diag(want_cov)))
            np.testing.assert_array_less(np.abs(cov - want_cov), 1e-12 * scale + 1e-300)


def test_a_windows_mean_gyro_variance_is_numpys_mean_of_the_diagonals():
    """The gyro rotation fit's per-sample variance of a window (``gyro_window_fit``: the
    intervals' covariance diagonals averaged from the stacked covariances) equals np.mean of
    the diagonals listed, bit for bit (the same sums down the intervals)."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        k = int(rng.integers(1, 60))
        a = rng.normal(size=(k, 3, 3)) * 10 ** rng.uniform(-6, 6)
        covs = a @ np.swapaxes(a, 1, 2)
        want = np.mean([np.diag(c) for c in covs], axis=0)
        assert covs.diagonal(axis1=1, axis2=2).mean(axis=0).tobytes() == want.tobytes()


@pytest.mark.parametrize("seed", range(3))
def test_the_collectors_rows_equal_with_the_kernels(seed):
    """The interval collector's rows of a block (:func:`imudiag.diagnosis.intervals._rows`:
    time, outputs, temperature, bad flag), compiled (:func:`imudiag.numba_kernels.
    interval_rows`) and not: the same bytes, for blocks with and without temperature and
    flags (bad bits and others), contiguous and as the columns of a CSV block's array."""
    pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")
    from imudiag import kernels
    from imudiag.diagnosis.intervals import _rows
    from imudiag.samples import SampleBlock

    rng = np.random.default_rng(300 + seed)
    for _ in range(20):
        n = int(rng.integers(1, 5000))
        wide = rng.normal(size=(n, 10)) * 1e3
        wide[:, 0] = np.cumsum(rng.uniform(0.001, 0.02, n))
        wide[rng.random((n, 10)) < 0.001] = np.nan
        flags = rng.integers(0, 1 << 12, n).astype(np.uint16) if rng.random() < 0.7 else None
        temp = wide[:, 7] if rng.random() < 0.5 else None
        for t, gyro, accel in (
            (wide[:, 0], wide[:, 1:4], wide[:, 4:7]),  # columns of one array (strided)
            (wide[:, 0].copy(), wide[:, 1:4].copy(), wide[:, 4:7].copy()),
        ):
            block = SampleBlock(t=t, gyro=gyro, accel=accel, temp=temp, flags=flags)
            got = []
            for on in (False, True):
                with kernels.switched(on) as active:
                    assert active == on, kernels.status()
                    got.append(_rows(block).tobytes())
            assert got[0] == got[1]
