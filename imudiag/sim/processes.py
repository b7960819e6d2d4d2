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
        w = drive[start:start + block]
        k = np.arange(w.shape[0], dtype=float)
        grow = np.exp(k * neg_log_a)  # a^-k
        shrink = np.exp(-k * neg_log_a)  # a^k
        seg = shrink * (a * x + np.cumsum(w * grow))
        out[start:start + block] = seg
        x = float(seg[-1])
    return out
