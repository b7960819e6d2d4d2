"""Vectorised noise processes that continue across chunks (state carried by the caller)."""

from __future__ import annotations

import math

import numpy as np

#: largest growth factor a**-k allowed inside one Gauss-Markov block (keeps full precision)
_MAX_GROWTH_LOG = 100.0 * math.log(10.0)


def random_walk(increments: np.ndarray, carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Running sums ``carry + cumsum(increments)`` along axis 0 and the new carry."""
    if increments.shape[0] == 0:
        return increments.copy(), carry
    walk = np.cumsum(increments, axis=0) + carry
    return walk, walk[-1].copy()


def gauss_markov(drive: np.ndarray, a: float, x_prev: float) -> np.ndarray:
    """First-order recursion ``x_k = a x_{k-1} + drive_k`` (0 < a < 1) for all k at once.

    Exact closed form ``x_k = a^(k+1) x_prev + a^k sum_{j<=k} a^-j drive_j``, evaluated
    in blocks short enough that ``a^-j`` stays below 1e100 (no loop per sample).
    """
    n = drive.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    if a <= 0.0:
        return drive.astype(float).copy()
    neg_log_a = -math.log(a)
    block = n if neg_log_a == 0 else max(1, min(n, int(_MAX_GROWTH_LOG / neg_log_a)))
    x = float(x_prev)
    for start in range(0, n, block):
        w = drive[start : start + block]
        k = np.arange(w.shape[0], dtype=float)
        grow = np.exp(k * neg_log_a)  # a^-k
        shrink = np.exp(-k * neg_log_a)  # a^k
        seg = shrink * (a * x + np.cumsum(w * grow))
        out[start : start + block] = seg
        x = float(seg[-1])
    return out


def flicker_components(
    band_s: tuple[float, float], per_decade: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """First-order Gauss-Markov processes whose sum has a flat Allan variance over the
    cluster times ``band_s`` (low, high) s: the flicker floor (bias instability) of IEEE
    Std 952 approximated over a band of tau.

    Returns correlation times T_k (s) and weights w_k with
    sum_k w_k shape(tau / T_k) = 1 within 1 % over the band (shape: the Allan variance of a
    unit Gauss-Markov process); a floor B gets sigma_k = 0.664 B sqrt(w_k). Correlation
    times span band/4 .. 2 band at ``per_decade`` per decade; weights by least squares on a
    log-spaced tau grid.
    """
    from ..certificate import markov_allan_shape

    lo, hi = float(band_s[0]), float(band_s[1])
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ValueError(f"flicker band must be 0 < low < high s, got {band_s}")
    k = int(round(math.log10(8.0 * hi / lo) * per_decade)) + 1
    tc = np.logspace(math.log10(lo / 4.0), math.log10(2.0 * hi), k)
    tau = np.logspace(math.log10(lo), math.log10(hi), 10 * k)
    a = markov_allan_shape(tau[:, None] / tc[None, :])
    w = np.linalg.lstsq(a, np.ones(tau.shape[0]), rcond=None)[0]
    w = np.clip(w, 0.0, None)
    w *= 1.0 / math.exp(float(np.mean(np.log(a @ w))))
    return tc, w
