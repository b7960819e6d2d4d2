"""Generalised least squares under a random-walk bias, by Kalman innovations.

A residual series of chunk means is modelled as

    y_i = H_i b(t_i) + X_i beta + e_i,   b a random walk (K^2 per second per state),
                                          e_i white with variance R_i.

The bias state starts diffuse (it absorbs a constant offset per sensor). The
filter is linear, so running it on y and on every regressor column at once
gives innovations ``nu`` whose whitened values ``nu / sqrt(S)`` turn the
correlated problem into ordinary least squares (the GLS of the random-walk
covariance): any subset of regressors is then fitted, tested and cross-
validated from the same innovations. A batch of random-walk coefficients is
filtered together for profile likelihoods. The loop runs over chunks (a few
per second of data), vectorised across columns and the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: an innovation whose state variance is above this fraction of the diffuse prior is
#: "diffuse" (it only sets the initial state) and is left out of fits and likelihoods
DIFFUSE_FRACTION = 1e-4


@dataclass
class Innovations:
    """Filter output: nu (B, n, c), S (B, n), valid (B, n) bool (used and not diffuse)."""

    nu: np.ndarray
    S: np.ndarray
    valid: np.ndarray

    def whitened(self, b: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(rows, w): the valid chunk indices and ``nu / sqrt(S)`` (m, c) of batch member b."""
        rows = np.flatnonzero(self.valid[b])
        return rows, self.nu[b, rows] / np.sqrt(self.S[b, rows])[:, None]


def run_filter(t: np.ndarray, H: np.ndarray, R: np.ndarray, Z: np.ndarray, q: np.ndarray,
               use: np.ndarray | None = None, p0: np.ndarray | None = None) -> Innovations:
    """Innovations of data columns ``Z`` (n, c) under random-walk states.

    t (n,) s; H (n, d); R (n,) white variance; q (B, d) random-walk intensities K^2
    (state units^2 / s); ``use`` (n,) chunks to assimilate (others: time update only,
    for fitting on part of the data); p0 (d,) diffuse prior variance.
    """
    n, d = H.shape
    c = Z.shape[1]
    q = np.atleast_2d(np.asarray(q, dtype=float))
    b = q.shape[0]
    if use is None:
        use = np.ones(n, dtype=bool)
    if p0 is None:
        hh = np.maximum(np.sum(H * H, axis=1), 1e-300)
        p0 = np.full(d, 1e6 * float(np.median(R / hh)))
    x = np.zeros((b, d, c))
    P = np.broadcast_to(np.diag(p0), (b, d, d)).copy()
    nu = np.zeros((b, n, c))
    S = np.full((b, n), np.inf)
    valid = np.zeros((b, n), dtype=bool)
    diag = np.arange(d)
    t_prev = float(t[0]) if n else 0.0
    for i in range(n):  # one step per chunk (not per sample)
        dt = float(t[i]) - t_prev
        t_prev = float(t[i])
        if dt > 0:
            P[:, diag, diag] += q * dt
        if not use[i]:
            continue
        h = H[i]
        ph = P @ h  # (b, d)
        hph = ph @ h  # (b,)
        s = hph + R[i]
        innov = Z[i][None, :] - np.einsum("d,bdc->bc", h, x)
        gain = ph / s[:, None]
        x += gain[:, :, None] * innov[:, None, :]
        P -= gain[:, :, None] * ph[:, None, :]
        nu[:, i] = innov
        S[:, i] = s
        valid[:, i] = hph < DIFFUSE_FRACTION * float(np.dot(h * h, p0))
    return Innovations(nu=nu, S=S, valid=valid)


def orthonormal_basis(a: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis (m, r) of the column space of ``a`` (m, p), numerically rank r."""
    if a.shape[1] == 0:
        return np.zeros((a.shape[0], 0))
    u, s, _vt = np.linalg.svd(a, full_matrices=False)
    if s.shape[0] == 0 or s[0] == 0:
        return np.zeros((a.shape[0], 0))
    return u[:, s > rtol * s[0]]


def profile_loglik(inn: Innovations, cols: list[int] | np.ndarray, mask: np.ndarray | None = None
                   ) -> np.ndarray:
    """Log-likelihood (B,) of column 0 (y) with regressors ``cols`` concentrated out, per batch
    member, over the chunks in ``mask`` (n,) (default: valid for every member). Compare
    likelihoods of different runs only over the same ``mask``."""
    cols = list(cols)
    b = inn.nu.shape[0]
    out = np.empty(b)
    common = np.all(inn.valid, axis=0) if mask is None else (mask & np.isfinite(inn.S).all(0))
    rows = np.flatnonzero(common)
    for k in range(b):  # a few tens of grid points
        s = inn.S[k, rows]
        w = inn.nu[k, rows] / np.sqrt(s)[:, None]
        y = w[:, 0]
        if cols:
            q = orthonormal_basis(w[:, cols])
            y = y - q @ (q.T @ y)
        out[k] = -0.5 * (float(np.sum(np.log(s))) + float(y @ y))
    return out


__all__ = ["DIFFUSE_FRACTION", "Innovations", "orthonormal_basis", "profile_loglik", "run_filter"]
