"""Tail probabilities and significance figures without scipy (runtime deps stay numpy only).

A *significance* in the model-check report is the one-sided standard-normal
equivalent of a p-value: z with P(N(0,1) > z) = p (z = 5 is p = 2.9e-7).
Tails are computed on a log scale so that overwhelming evidence gives a
finite, large z rather than infinity.
"""

from __future__ import annotations

import math
from functools import lru_cache

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


def _beta_cf(a: float, b: float, x: float) -> float:
    """Continued fraction of the regularised incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 400):
        for num in (
            m * (b - m) * x / ((a + 2 * m - 1.0) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1.0)),
        ):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + num / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def log_betainc(a: float, b: float, x: float) -> float:
    """log of the regularised incomplete beta function I_x(a, b), a, b > 0, 0 <= x <= 1."""
    if x <= 0.0:
        return -math.inf
    if x >= 1.0:
        return 0.0
    log_front = (
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
        + a * math.log(x) + b * math.log1p(-x)
    )  # fmt: skip
    if x < (a + 1.0) / (a + b + 2.0):
        return log_front + math.log(_beta_cf(a, b, x)) - math.log(a)
    tail = math.exp(log_front) * _beta_cf(b, a, 1.0 - x) / b  # I_x = 1 - I_(1-x)(b, a)
    return math.log1p(-tail) if tail < 1.0 else -math.inf


def log_t_two_sided(t: float, dof: float) -> float:
    """log P(|T| > t) for Student's t with ``dof`` (> 0, not necessarily whole) degrees of
    freedom; the normal's for an infinite ``dof``."""
    t = abs(float(t))
    if math.isinf(dof):
        return math.log(2.0) + log_normal_sf(t)
    return log_betainc(0.5 * dof, 0.5, dof / (dof + t * t))


def _log_t_pdf(t: float, dof: float) -> float:
    """log of Student's t density with ``dof`` degrees of freedom at ``t``."""
    return (
        math.lgamma(0.5 * (dof + 1.0)) - math.lgamma(0.5 * dof)
        - 0.5 * math.log(dof * math.pi) - 0.5 * (dof + 1.0) * math.log1p(t * t / dof)
    )  # fmt: skip


@lru_cache(maxsize=4096)
def _t_equivalent(k_sigma: float, dof: float) -> float:
    target = math.log(2.0) + log_normal_sf(k_sigma)
    lo, hi = k_sigma, k_sigma
    while log_t_two_sided(hi, dof) > target:
        lo, hi = hi, hi * 2.0
    # safeguarded Newton on the log tail (d/dt log P(|T| > t) = -2 pdf / P), bisection
    # where a step leaves the bracket; 1e-10 relative
    t = hi if hi == k_sigma else 0.5 * (lo + hi)
    for _ in range(100):
        g = log_t_two_sided(t, dof)
        if g > target:
            lo = t
        else:
            hi = t
        step = (g - target) / -math.exp(math.log(2.0) + _log_t_pdf(t, dof) - g)
        nxt = t - step
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - t) <= 1e-10 * t or hi - lo <= 1e-10 * hi:
            return nxt
        t = nxt
    return t


def t_equivalent(k_sigma: float, dof: float) -> float:
    """The Student-t quantile with the two-sided tail of ``k_sigma`` standard normal sigma,
    for a statistic whose std was estimated with ``dof`` degrees of freedom (``k_sigma``
    itself for an infinite ``dof``; 4 sigma is 5.5 at 15 dof, 17.4 at 4). Fractional
    ``dof`` are rounded to 0.01 (cached); below 0.5 dof the tail is that of 0.5."""
    if not math.isfinite(dof) or dof > 1e6:
        return float(k_sigma)
    return _t_equivalent(float(k_sigma), round(max(float(dof), 0.5), 2))


__all__ = [
    "chi2_ratio_quantile",
    "chi2_significance",
    "log_chi2_sf",
    "log_betainc",
    "log_normal_sf",
    "log_t_two_sided",
    "t_equivalent",
    "z_from_log_p",
]
