"""The noise check's medians (``imudiag.noise_estimate.medians``) equal ``np.median``'s,
value for value: even and odd lengths, ties (whole counts), NaN and infinities, any
leading shape."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.noise_estimate import medians


@pytest.mark.parametrize("n", [1, 2, 3, 200, 999, 1000])
def test_medians_equal_numpys(n):
    rng = np.random.default_rng(n)
    cases = [
        rng.normal(size=(6, 3, n)) ** 2,  # squared second differences
        np.round(rng.normal(scale=3.0, size=(4, n))) ** 2,  # whole counts: many ties
        rng.normal(size=(n,)),
    ]
    with_nan = rng.normal(size=(5, n))
    with_nan[1, n // 2] = np.nan
    with_nan[3, 0] = np.nan
    with_inf = rng.normal(size=(3, n))
    with_inf[0, -1] = np.inf
    with_inf[2, 0] = -np.inf
    if n > 1:
        with_inf[1, :2] = [np.inf, -np.inf]
    cases += [with_nan, with_inf]
    for x in cases:
        # a row whose middle values are inf and -inf has the median NaN (inf - inf): numpy
        # and medians both say so with an "invalid value" warning, expected here
        with np.errstate(invalid="ignore"):
            want = np.median(x.copy(), axis=-1)
            got = medians(x.copy())
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)  # NaN where numpy has NaN, else equal


def test_empty_rows_as_numpy():
    x = np.zeros((2, 0))
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        want = np.median(x.copy(), axis=-1)
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        got = medians(x.copy())
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("n", [2, 4, 198, 200])
def test_even_rows_of_ties_and_signed_zeros_as_numpy(n):
    """An even row's lower middle value is the largest below the upper one (one partition):
    rows of few distinct values, of zeros of either sign, and of a run of equal middles."""
    rng = np.random.default_rng(100 + n)
    x = np.stack(
        [
            rng.integers(-2, 3, n).astype(float),
            np.where(rng.random(n) < 0.5, -0.0, 0.0),
            np.sort(rng.integers(0, 2, n).astype(float)),
            np.full(n, 7.0),
            rng.normal(size=n),
        ]
    )
    want = np.median(x.copy(), axis=-1)
    got = medians(x.copy())
    np.testing.assert_array_equal(got, want)
    assert got[1] == 0.0  # zeros: the sign may differ from numpy's, the value does not
