"""Tail probabilities and significance figures without scipy (runtime deps stay numpy only).

A *significance* in the model-check report is the one-sided standard-normal
equivalent of a p-value: z with P(N(0,1) > z) = p (z = 5 is p = 2.9e-7).
Tails are computed on a log scale so that overwhelming evidence gives a
finite, large z rather than infinity.
"""

from __future__ import annotations

import math

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def log_normal_sf(z: float) -> float:
    """log P(N(0,1) > z), accurate in the far tail."""
    if z < 37.0:  # erfc is representable down to about 1e-300
        return math.log(max(0.5 * math.erfc(z / math.sqrt(2.0)), 1e-300))
    # asymptotic series of the Mills ratio (relative error below 1e-9 here)
    z2 = z * z
    series = 1.0 - 1.0 / z2 + 3.0 / z2**2 - 15.0 / z2**3
    return -0.5 * z2 - math.log(z) - _LOG_SQRT_2PI + math.log(series)


def z_from_log_p(log_p: float) -> float:
    """The z with log P(N(0,1) > z) = log_p (one-sided); 0 for p >= 0.5."""
    if log_p >= math.log(0.5):
        return 0.0
    # start from the asymptotic inverse, then Newton on log_normal_sf
    t = -2.0 * log_p
    z = math.sqrt(max(t - math.log(max(t, 1e-12)) - math.log(2.0 * math.pi), 1e-6))
    for _ in range(30):
        f = log_normal_sf(z) - log_p
        # d/dz log sf = -pdf/sf
        log_pdf = -0.5 * z * z - _LOG_SQRT_2PI
        slope = -math.exp(log_pdf - log_normal_sf(z))
        step = f / slope
        z -= step
        z = max(z, 0.0)
        if abs(step) < 1e-10:
            break
    return z


def log_chi2_sf(x: float, dof: float) -> float:
    """log P(chi2(dof) > x): exact for integer dof up to 40, Wilson-Hilferty beyond."""
    if x <= 0.0:
        return 0.0
    k = float(dof)
    if k == int(k) and 1 <= k <= 40:
        h = 0.5 * x
        terms: list[float] = []
        if int(k) % 2 == 0:  # e^-h sum_{i < k/2} h^i / i!
            terms = [-h + i * math.log(h) - math.lgamma(i + 1) for i in range(int(k) // 2)]
        else:  # erfc(sqrt h) + e^-h sum_{i=1}^{(k-1)/2} h^(i-1/2) / Gamma(i + 1/2)
            terms = [math.log(2.0) + log_normal_sf(math.sqrt(x))]
            terms += [
                -h + (i - 0.5) * math.log(h) - math.lgamma(i + 0.5)
                for i in range(1, (int(k) - 1) // 2 + 1)
            ]
        top = max(terms)
        return min(top + math.log(sum(math.exp(t - top) for t in terms)), 0.0)
    a = 2.0 / (9.0 * k)
    z = ((x / k) ** (1.0 / 3.0) - (1.0 - a)) / math.sqrt(a)
    return log_normal_sf(z)


def chi2_significance(x: float, dof: float, trials: float = 1.0) -> float:
    """Significance z of a chi-square statistic ``x`` with ``dof``, Bonferroni over ``trials``."""
    log_p = log_chi2_sf(x, dof) + math.log(max(trials, 1.0))
    return z_from_log_p(min(log_p, 0.0))


def chi2_ratio_quantile(dof: float, z: float) -> float:
    """Quantile chi2(dof)/dof at the standard-normal quantile z (Wilson-Hilferty)."""
    a = 2.0 / (9.0 * dof)
    return max((1.0 - a + z * math.sqrt(a)) ** 3, 1e-6)


__all__ = [
    "chi2_ratio_quantile",
    "chi2_significance",
    "log_chi2_sf",
    "log_normal_sf",
    "z_from_log_p",
]
