"""The exact fit's excess variance (:func:`imudiag.diagnosis.scalar_fit._excess_variance`)
stops its bisection once a halving leaves the bracket unchanged (issue 28): the answer is
bit for bit that of the full 100 halvings, on random residuals and variances (fixed seed)
spanning 14 decades."""

from __future__ import annotations

import numpy as np

from imudiag.diagnosis.scalar_fit import _excess_variance


def hundred_halvings(r: np.ndarray, sig2: np.ndarray, dof: float) -> float:
    """The plain bisection: always 100 halvings."""
    lo, hi = 0.0, float(np.max(r * r)) * len(r) + 1e-300
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if np.sum(r * r / (sig2 + mid)) > dof:
            lo = mid
        else:
            hi = mid
    return hi


def test_early_stop_is_bit_for_bit_the_full_bisection():
    rng = np.random.default_rng(28)
    for _ in range(1000):
        k = int(rng.integers(3, 40))
        r = rng.normal(size=k) * 10 ** rng.uniform(-12, 2)
        sig2 = 10 ** rng.uniform(-14, 1, size=k)
        dof = float(rng.uniform(0.5, k))
        assert _excess_variance(r, sig2, dof) == hundred_halvings(r, sig2, dof)
