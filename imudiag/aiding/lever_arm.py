"""The antenna-IMU lever arm from the mismatch of the two specific-force magnitudes.

The GNSS velocity is the antenna's, so the GNSS specific force is the antenna's:
f_ant = f_imu + A l with A = [omega']x + [omega]x [omega]x (body axes), the
tangential and centripetal terms of a lever arm l (m, body, IMU to antenna).
With u = f_imu / |f_imu| and the epoch mean of A, to first order

    |f_gnss| - |f_imu| = u^T A l + c,

one row per GNSS epoch, solved for l by weighted least squares with the
variance of each epoch's magnitudes (GNSS velocity noise and IMU white noise).
``c`` (m/s^2) is a nuisance offset: an accelerometer bias or scale error along
gravity, which a level vehicle sees as a constant |f| offset, is not taken for a
lever arm. The standard deviations come from the normal matrix, inflated by the
fit's chi^2/dof where the data scatter more than the noise model.

Observability: A l needs rotation, and only its part along f counts. In a car
(yaw turns, f near the body vertical) u^T A l ~ (v omega / g) omega^2 l_y: the
horizontal components show in turns (more in tight, fast ones), the vertical
one hardly ever (pitch rates are small); an axis is *determined* when its std
is at most ``determined_std_m``. Straight driving determines nothing.

The estimate is conditional on the GNSS latency used: a latency error shifts |f|
in time, d|f|/dt x error, which in pull-ups and braking mimics the tangential
term of the longitudinal component (on the simulated aircraft the two cannot be
solved for together: the x std grows from 0.12 to 2 m). Configure the latency
where it is known; the |f| correlation that estimates it is itself pulled by an
unmodelled lever arm of a metre (0.12 s true, 0.07-0.10 s estimated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..rotations import skew
from .specific_force import ImuSeries


@dataclass
class LeverArmEstimate:
    """The lever arm estimate (m, body axes, IMU to antenna) and its standard deviations."""

    lever_arm_m: np.ndarray  #: (3,) m; nan where nothing could be solved
    std_m: np.ndarray  #: (3,) m, 1 sigma
    determined: np.ndarray  #: (3,) bool: std at most the threshold
    offset_m_s2: float  #: the nuisance |f| offset, m/s^2
    epochs: int  #: epochs used
    chi2_dof: float  #: the fit's chi^2 per degree of freedom
    reason: str  #: why no axis is determined ("" when one is)

    def used(self) -> np.ndarray:
        """The lever arm to apply (m): the estimate on determined axes, 0 elsewhere."""
        return np.where(self.determined, np.nan_to_num(self.lever_arm_m), 0.0)

    def to_json(self) -> dict:
        """The estimate as reported (diagnosis report, daemon status)."""

        def r(x: float, nd: int = 3) -> float | None:
            return round(float(x), nd) if math.isfinite(x) else None

        return {
            "estimate_m": [r(x) for x in self.lever_arm_m],
            "std_m": [r(x) for x in self.std_m],
            "determined": [bool(x) for x in self.determined],
            "offset_m_s2": r(self.offset_m_s2, 5),
            "epochs": self.epochs,
            "chi2_dof": r(self.chi2_dof, 2),
            "reason": self.reason,
        }


def lever_arm_rows(
    t: np.ndarray,
    gyro_si: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    imu_mean_si: np.ndarray,
    latency_s: float = 0.0,
    series: ImuSeries | None = None,
) -> np.ndarray:
    """Regressor rows u^T mean(A) (K, 3), s^-2, of the epochs [t0, t1) - latency (s):
    t (N,) s, gyro_si (N, 3) rad/s corrected, imu_mean_si (K, 3) the IMU's epoch means
    (m/s^2) that give u. The centripetal part is the epoch mean of [w]x[w]x over the
    samples; the angular acceleration is the central difference of the neighbouring
    epochs' mean rates (the derivative of single MEMS samples is mostly noise, and a
    noisy regressor pulls the estimate towards 0). Epochs without samples or without
    both neighbours (contiguous) get NaN rows. ``series``: the record of t and gyro_si made
    once (:class:`.ImuSeries`), its epochs' samples and [w]x [w]x reused (the same sums)."""
    t = np.asarray(t, dtype=float)
    w = np.asarray(gyro_si, dtype=float)
    a = np.asarray(t0, dtype=float) - latency_s
    b = np.asarray(t1, dtype=float) - latency_s
    kk = a.shape[0]
    cen = series.centripetal() if series is not None else None
    if series is not None and cen is not None:
        # only the samples from the first epoch's to the last one's, each in its epoch
        idx, lo, hi, count = series.bins(t0, t1, latency_s)
        cen, w = cen[lo:hi], w[lo:hi]
    else:
        j = np.searchsorted(a, t, side="right") - 1
        inside = (j >= 0) & (j < kk)
        inside[inside] &= t[inside] < b[j[inside]]
        idx = np.where(inside, j, kk)
        count = np.bincount(idx, minlength=kk + 1)[:kk]
        sw = skew(w)
        cen = (sw @ sw).reshape(-1, 9)
    sums = np.stack([np.bincount(idx, cen[:, c], minlength=kk + 1)[:kk] for c in range(9)], 1)
    wsum = np.stack([np.bincount(idx, w[:, c], minlength=kk + 1)[:kk] for c in range(3)], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_c = (sums / count[:, None]).reshape(kk, 3, 3)
        w_mean = wsum / count[:, None]
        u = imu_mean_si / np.linalg.norm(imu_mean_si, axis=1)[:, None]
    wdot = np.full((kk, 3), np.nan)
    if kk >= 3:
        mid = 0.5 * (a + b)
        contiguous = (np.abs(a[2:] - b[1:-1]) < 1e-6) & (np.abs(a[1:-1] - b[:-2]) < 1e-6)
        d = (w_mean[2:] - w_mean[:-2]) / (mid[2:] - mid[:-2])[:, None]
        wdot[1:-1] = np.where(contiguous[:, None], d, np.nan)
    mat = skew(wdot) + mean_c
    return np.einsum("ki,kij->kj", u, mat)


def row_noise_variance(gyro_sigma_si: float, samples_per_epoch: float, epoch_s: float) -> float:
    """Variance per axis (rad/s^2)^2 of an epoch's angular acceleration from white gyro
    noise ``gyro_sigma_si`` (rad/s per sample): the central difference of two epoch
    means of ``samples_per_epoch`` samples, ``2 epoch_s`` apart (as :func:`lever_arm_rows`)."""
    return 2.0 * gyro_sigma_si**2 / max(samples_per_epoch, 1.0) / (2.0 * epoch_s) ** 2


def row_noise_correction(
    unit_f: np.ndarray, weights: np.ndarray, row_noise_var: float
) -> np.ndarray:
    """What the noise of the lever-arm rows adds to the normal matrix (3, 3): a row's
    noise is u x delta with delta the angular-acceleration noise (variance
    ``row_noise_var`` (rad/s^2)^2 per axis), covariance s^2 (I - u u^T); ``weights``
    (K,) the epochs' weights, 1 / (m/s^2)^2."""
    proj = np.eye(3)[None] - unit_f[:, :, None] * unit_f[:, None, :]
    return row_noise_var * np.einsum("k,kij->ij", weights, proj)


def weighted_solve(
    h: np.ndarray, y: np.ndarray, var: np.ndarray, correction: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Weighted least squares y = h x with variances ``var`` (K,): (x, cov, std,
    chi^2/dof); ``correction`` is subtracted from the normal matrix (noisy regressors).
    A pseudo-inverse keeps unexcited directions at 0 (a straight drive has no rotation
    terms); their parameters get an infinite std. The covariance is inflated by
    chi^2/dof when the data scatter more than ``var`` says."""
    wts = 1.0 / var
    normal = h.T @ (h * wts[:, None])
    if correction is not None:
        normal -= correction
    rhs = h.T @ (y * wts)
    scale = np.sqrt(np.maximum(np.diag(normal), 1e-300))
    ns = normal / np.outer(scale, scale)
    evals, evecs = np.linalg.eigh(ns)
    keep = evals > 1e-9 * max(float(evals.max()), 1e-300)
    inv = (evecs[:, keep] / evals[keep]) @ evecs[:, keep].T / np.outer(scale, scale)
    x = inv @ rhs
    res = y - h @ x
    dof = max(y.size - int(np.sum(keep)), 1)
    chi2_dof = float(np.sum(res * res * wts)) / dof
    cov = inv * max(chi2_dof, 1.0)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # an eigen-direction dropped as unexcited leaves its parameters undetermined
    weak = ~keep
    if np.any(weak):
        unexcited = np.any(np.abs(evecs[:, weak]) > 0.1, axis=1)
        std = np.where(unexcited, np.inf, std)
    return x, cov, std, chi2_dof


def solve_lever_arm(
    rows: np.ndarray,
    mismatch: np.ndarray,
    variance: np.ndarray,
    unit_f: np.ndarray | None = None,
    row_noise_var: float = 0.0,
    determined_std_m: float = 0.15,
    min_epochs: int = 30,
) -> LeverArmEstimate:
    """Weighted least squares for the lever arm (module doc): rows (K, 3) s^-2,
    mismatch |f_gnss| - |f_imu| (K,) m/s^2 with the IMU taken without a lever arm,
    variance (K,) (m/s^2)^2 of each mismatch. The rows are noisy (the angular
    acceleration from a MEMS gyro): with the directions of f ``unit_f`` (K, 3) and the
    angular-acceleration noise variance per axis ``row_noise_var`` (rad/s^2)^2, the
    normal matrix is corrected for it (a row's noise is u x delta, covariance
    s^2 (I - u u^T)): a noisy regressor otherwise pulls the estimate towards 0."""
    rows = np.asarray(rows, dtype=float)
    y = np.asarray(mismatch, dtype=float)
    var = np.asarray(variance, dtype=float)
    ok = np.all(np.isfinite(rows), axis=1) & np.isfinite(y) & np.isfinite(var) & (var > 0)
    n = int(np.sum(ok))
    nan3 = np.full(3, np.nan)
    if n < min_epochs:
        return LeverArmEstimate(
            nan3, nan3, np.zeros(3, bool), math.nan, n, math.nan,
            f"{n} usable GNSS epochs, {min_epochs} needed",
        )  # fmt: skip
    h = np.column_stack([rows[ok], np.ones(n)])
    correction = None
    if unit_f is not None and row_noise_var > 0:
        correction = np.zeros((4, 4))
        correction[:3, :3] = row_noise_correction(
            np.asarray(unit_f, dtype=float)[ok], 1.0 / var[ok], row_noise_var
        )
    x, cov, std, chi2_dof = weighted_solve(h, y[ok], var[ok], correction)
    lever, lever_std = x[:3], std[:3]
    determined = lever_std <= determined_std_m
    reason = undetermined_reason(lever_std, determined_std_m)
    return LeverArmEstimate(lever, lever_std, determined, float(x[3]), n, chi2_dof, reason)


def undetermined_reason(lever_std: np.ndarray, determined_std_m: float) -> str:
    """Why no axis of a lever arm with stds ``lever_std`` (3,) m is determined (an axis is
    when its std is at most ``determined_std_m``, m); "" when one is."""
    if np.any(lever_std <= determined_std_m):
        return ""
    return (
        f"the drive's turns do not determine it (std {', '.join(f'{s:.2g}' for s in lever_std)}"
        f" m, above {determined_std_m:g} m)"
    )


__all__ = [
    "LeverArmEstimate",
    "lever_arm_rows",
    "row_noise_correction",
    "solve_lever_arm",
    "undetermined_reason",
    "weighted_solve",
]
