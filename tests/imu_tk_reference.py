"""Reference implementation of imu_tk's multi-position calibration (a test oracle, not shipped).

A. Tedaldi, A. Pretto, E. Menegatti, "A Robust and Easy to Implement Method for IMU
Calibration without External Equipments", ICRA 2014; the algorithm as imu_tk
(github.com/Kyle-ak/imu_tk, ``MultiPosCalibration``) publishes it, written here from the
paper and a reading of that code (nothing copied):

- still detector: the norm of the per-axis accelerometer variance over a centred window of
  ``win`` samples (101) below a threshold, the threshold a multiple 2..10 of the same norm
  over the initial still period (``init_s``, 50 s in imu_tk's example);
- accelerometers: for each multiple, the intervals of at least ``interval_n`` samples (100)
  give their first ``interval_n`` samples (or their means), and the 9 parameters (3
  misalignments of an upper-triangular T, 3 scales K, 3 biases b) minimise
  sum (g - |T K (a - b)|)^2; the multiple with the least final cost wins; fewer than
  ``min_intervals`` (12) intervals: no calibration at that multiple;
- gyroscopes: the bias is the mean over the initial still period; 6 misalignments and 3
  scales minimise, over consecutive still intervals, |R^T u0 - u1|^2, R the rotation
  integrated (RK4 on the quaternion) from the calibrated rates between the end of one
  interval and the start of the next, u0, u1 the calibrated gravity directions.

Units: the raw outputs are whatever the log holds; the calibrated accelerometer output is in
the unit of ``g_mag`` (m/s^2 here), the calibrated gyro output in the unit its initial scale
gives (rad/s here).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

#: imu_tk's defaults (MultiPosCalibration_ constructor and staticIntervalsDetector)
WIN = 101
MIN_INTERVALS = 12
INTERVAL_N = 100
THRESHOLD_MULTIPLES = range(2, 11)


def local_variance(x: np.ndarray, win: int = WIN) -> np.ndarray:
    """Per-axis sample variance (ddof 1) over a centred window of ``win`` samples (N, 3);
    NaN where the window does not fit."""
    win = max(11, win | 1)
    h = win // 2
    n = x.shape[0]
    out = np.full(x.shape, np.nan)
    if n <= win:
        return out
    xc = x - x.mean(axis=0)
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(xc, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(xc * xc, axis=0)])
    s1 = c1[win:] - c1[:-win]
    s2 = c2[win:] - c2[:-win]
    out[h : n - h] = (s2 - s1 * s1 / win) / (win - 1)
    return out


def static_intervals(x: np.ndarray, threshold: float, win: int = WIN) -> list[tuple[int, int]]:
    """Still intervals (start, end inclusive sample indices) where the variance norm of the
    centred window is below ``threshold`` (imu_tk's ``staticIntervalsDetector``)."""
    norm = np.linalg.norm(local_variance(x, win), axis=1)
    still = np.isfinite(norm) & (norm < threshold)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def init_variance_norm(t: np.ndarray, x: np.ndarray, init_s: float) -> float:
    """Norm of the per-axis variance over the first ``init_s`` seconds (the threshold unit)."""
    sel = t <= t[0] + init_s
    return float(np.linalg.norm(np.var(x[sel], axis=0, ddof=1)))


@dataclass
class AccCalibration:
    """imu_tk's accelerometer triad: calibrated = T K (raw - b)."""

    mis: np.ndarray  #: (3,) yz, zy, zx, rad
    scale: np.ndarray  #: (3,) output unit per raw unit
    bias: np.ndarray  #: (3,) raw units
    threshold_multiple: int = 0
    intervals: list[tuple[int, int]] = field(default_factory=list)
    cost: float = float("nan")

    def matrix(self) -> np.ndarray:
        """T K (3, 3)."""
        yz, zy, zx = self.mis
        t = np.array([[1.0, -yz, zy], [0.0, 1.0, -zx], [0.0, 0.0, 1.0]])
        return t @ np.diag(self.scale)

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """Calibrated outputs (N, 3) of raw ones (N, 3)."""
        return (np.atleast_2d(raw) - self.bias) @ self.matrix().T


def _acc_from(p: np.ndarray) -> AccCalibration:
    return AccCalibration(mis=p[:3].copy(), scale=p[3:6].copy(), bias=p[6:9].copy())


def fit_acc(
    points: np.ndarray, g_mag: float, scale0: np.ndarray, bias0: np.ndarray
) -> tuple[AccCalibration, float]:
    """The accelerometer cost on ``points`` (M, 3 raw): returns the fit and its final cost
    (ceres' convention, half the sum of squared residuals, output unit^2)."""
    p0 = np.concatenate([np.zeros(3), scale0, bias0])

    def res(p: np.ndarray) -> np.ndarray:
        return g_mag - np.linalg.norm(_acc_from(p).apply(points), axis=1)

    sol = least_squares(res, p0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
    return _acc_from(sol.x), float(sol.cost)


def interval_points(
    x: np.ndarray, intervals: list[tuple[int, int]], n: int = INTERVAL_N, means: bool = False
) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """imu_tk's ``extractIntervalsSamples``: intervals of at least ``n`` samples give their
    first ``n`` samples (or their whole mean with ``means``)."""
    kept = [iv for iv in intervals if iv[1] - iv[0] + 1 >= n]
    if means:
        pts = [x[a : b + 1].mean(axis=0) for a, b in kept]
    else:
        pts = [x[a : a + n] for a, _ in kept]
    if not kept:
        return np.zeros((0, 3)), kept
    return (np.array(pts) if means else np.concatenate(pts)), kept


def calibrate_acc(
    t: np.ndarray,
    acc: np.ndarray,
    g_mag: float,
    scale0: np.ndarray,
    bias0: np.ndarray,
    init_s: float,
    min_intervals: int = MIN_INTERVALS,
    interval_n: int = INTERVAL_N,
    use_means: bool = False,
) -> AccCalibration | None:
    """imu_tk's ``calibrateAcc``: the threshold multiple with the least cost; None when no
    multiple finds ``min_intervals`` intervals (imu_tk: "Can't obtain any calibration")."""
    norm_th = init_variance_norm(t, acc, init_s)
    best: AccCalibration | None = None
    for mult in THRESHOLD_MULTIPLES:
        ivs = static_intervals(acc, mult * norm_th)
        pts, kept = interval_points(acc, ivs, interval_n, use_means)
        if len(kept) < min_intervals:
            continue
        cal, cost = fit_acc(pts, g_mag, scale0, bias0)
        if best is None or cost < best.cost:
            cal.threshold_multiple, cal.intervals, cal.cost = mult, kept, cost
            best = cal
    return best


@dataclass
class GyroCalibration:
    """imu_tk's gyro triad: calibrated = T K (raw - b), T with 6 misalignments."""

    mis: np.ndarray  #: (6,) yz, zy, zx, xz, xy, yx, rad
    scale: np.ndarray  #: (3,)
    bias: np.ndarray  #: (3,) raw units
    cost: float = float("nan")

    def matrix(self) -> np.ndarray:
        """T K (3, 3)."""
        yz, zy, zx, xz, xy, yx = self.mis
        t = np.array([[1.0, -yz, zy], [xz, 1.0, -zx], [-xy, yx, 1.0]])
        return t @ np.diag(self.scale)

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """Calibrated rates (N, 3) of raw ones (N, 3)."""
        return (np.atleast_2d(raw) - self.bias) @ self.matrix().T


def _omega_matrix(w: np.ndarray) -> np.ndarray:
    """(K, 4, 4) quaternion-rate matrices of rates (K, 3), q = [w, x, y, z], dq = 0.5 W q."""
    x, y, z = w[:, 0], w[:, 1], w[:, 2]
    o = np.zeros(w.shape[:1])
    return np.stack(
        [
            np.stack([o, -x, -y, -z], -1),
            np.stack([x, o, z, -y], -1),
            np.stack([y, -z, o, x], -1),
            np.stack([z, y, -x, o], -1),
        ],
        -2,
    )


def integrate(segments: list[np.ndarray], dt: float) -> np.ndarray:
    """Rotation matrices (K, 3, 3) integrated (RK4 on the quaternion, rates interpolated
    linearly between samples, as imu_tk's ``quatIntegrationStepRK4``) over each segment of
    calibrated rates (M_k, 3); all segments advance together, padded with zero rate."""
    k = len(segments)
    m = max(s.shape[0] for s in segments)
    w = np.zeros((k, m, 3))
    for i, s in enumerate(segments):
        w[i, : s.shape[0]] = s
    q = np.zeros((k, 4))
    q[:, 0] = 1.0
    for j in range(m - 1):
        w0, w1 = w[:, j], w[:, j + 1]
        wm = 0.5 * (w0 + w1)
        o0, om, o1 = _omega_matrix(w0), _omega_matrix(wm), _omega_matrix(w1)
        k1 = 0.5 * np.einsum("kij,kj->ki", o0, q)
        k2 = 0.5 * np.einsum("kij,kj->ki", om, q + 0.5 * dt * k1)
        k3 = 0.5 * np.einsum("kij,kj->ki", om, q + 0.5 * dt * k2)
        k4 = 0.5 * np.einsum("kij,kj->ki", o1, q + dt * k3)
        q = q + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
    a, b, c, d = q.T
    return np.stack(
        [
            np.stack([a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)], -1),
            np.stack([2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)], -1),
            np.stack([2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d], -1),
        ],
        -2,
    )


def calibrate_gyro(
    t: np.ndarray,
    gyro: np.ndarray,
    acc_cal: AccCalibration,
    acc: np.ndarray,
    scale0: np.ndarray,
    init_s: float,
) -> GyroCalibration:
    """imu_tk's gyro step of ``calibrateAccGyro`` (bias from the initial still period, not
    optimised): the 9 parameters that carry each still interval's gravity direction into
    the next one's."""
    bias = gyro[t <= t[0] + init_s].mean(axis=0)
    ivs = acc_cal.intervals
    ups = [acc_cal.apply(acc[a : b + 1]).mean(axis=0) for a, b in ivs]
    ups = [u / np.linalg.norm(u) for u in ups]
    segs = [(ivs[i][1], ivs[i + 1][0] - 1) for i in range(len(ivs) - 1)]
    dt = float(np.median(np.diff(t)))
    u0 = np.array(ups[:-1])
    u1 = np.array(ups[1:])

    def cal_of(p: np.ndarray) -> GyroCalibration:
        return GyroCalibration(mis=p[:6].copy(), scale=p[6:9].copy(), bias=bias)

    def res(p: np.ndarray) -> np.ndarray:
        c = cal_of(p)
        r = integrate([c.apply(gyro[a : b + 1]) for a, b in segs], dt)
        return (np.einsum("kji,kj->ki", r, u0) - u1).ravel()

    p0 = np.concatenate([np.zeros(6), scale0])
    sol = least_squares(res, p0, method="lm", x_scale="jac", xtol=1e-10, ftol=1e-10)
    out = cal_of(sol.x)
    out.cost = float(sol.cost)
    return out


__all__ = [
    "AccCalibration",
    "GyroCalibration",
    "calibrate_acc",
    "calibrate_gyro",
    "fit_acc",
    "interval_points",
    "static_intervals",
]
