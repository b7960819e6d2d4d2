"""Gyro triad: bias at rest, and scale factor / misalignment from rotations.

A MEMS gyro cannot see Earth rate (design note §5): at rest its output *is*
its bias (plus an Earth-rate term far below its noise, kept as uncertainty).
Its scale factors and misalignment need known rotations: between two
quasi-static intervals the gyro-integrated rotation C (body at the end to body
at the start) must carry the first measured specific-force direction into the
second, ``f_1 = C^T f_0`` (Tedaldi et al., ICRA 2014). The fit finds the shape
(e, d: the symmetric part P of N, see :mod:`.gauge`) that makes it so over all
rotations of a window, by Gauss-Newton with a numerical Jacobian; every
parameter set integrates all segments at once (segments padded, quaternion
products reduced pairwise: no loop over samples).

Navigation-grade gyros see Earth rate; :func:`earth_rate_observable` decides
from the certificate's noise whether the stationary scalar fit with
``|w| = Earth rate`` is meaningful (the paper's eq. 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..certificate import Certificate, TriadModel
from .gauge import p_matrix, shape_of_triad, small_rotation
from .params import limit_vector

#: Floor of the direction residual (rad): integration and modelling resolution.
DIRECTION_FLOOR = 1e-4


# ---------------------------------------------------------------------------
# quaternions (w, x, y, z), Hamilton convention: R(a * b) = R(a) R(b)


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternion arrays (..., 4)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def rotvec_quat(theta: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of rotation vectors (..., 3), rad."""
    a = np.linalg.norm(theta, axis=-1)
    half = 0.5 * a
    # sin(a/2)/a with its series near zero
    k = np.where(a > 1e-8, np.sin(half) / np.where(a > 1e-8, a, 1.0), 0.5 - a * a / 48.0)
    return np.concatenate([np.cos(half)[..., None], theta * k[..., None]], axis=-1)


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def ordered_product(q: np.ndarray) -> np.ndarray:
    """q_0 * q_1 * ... * q_{L-1} along axis -2 of (..., L, 4), by pairwise reduction."""
    length = q.shape[-2]
    size = 1 << max(0, (length - 1).bit_length())
    if size != length:
        pad = np.zeros(q.shape[:-2] + (size - length, 4))
        pad[..., 0] = 1.0
        q = np.concatenate([q, pad], axis=-2)
    while q.shape[-2] > 1:
        q = qmul(q[..., 0::2, :], q[..., 1::2, :])
    return q[..., 0, :]


# ---------------------------------------------------------------------------
# observability of Earth rate


def earth_rate_observable(
    certificate: Certificate, interval_s: float = 10.0, ratio: float = 20.0
) -> bool:
    """Whether the gyros can measure Earth rate (navigation grade) per the certificate.

    True when the white noise of a ``interval_s`` mean is below Earth rate /
    ``ratio`` and the bias limits are below Earth rate, on every axis (both in
    input units). Without a noise density, only the bias-limit test applies,
    tightened tenfold.
    """
    g = certificate.gyro
    omega = certificate.earth_rate / g.unit_to_si  # input units
    bias_lim = g.limits.bias / g.scale_factor
    if g.noise is None or g.noise.density is None:
        return bool(np.all(bias_lim < omega / 10.0))
    # a mean of T seconds of white noise of density n has sigma n / sqrt(2 T)... per output unit
    sigma_mean = g.noise.density / g.scale_factor / math.sqrt(2.0 * interval_s)
    return bool(np.all(sigma_mean < omega / ratio) and np.all(bias_lim < omega))


# ---------------------------------------------------------------------------
# bias at rest


def rest_bias(
    gyro: TriadModel,
    means: np.ndarray,
    mean_var: np.ndarray,
    counts: np.ndarray,
    earth_rate_si: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Bias estimate (3,) and std (3,), output units, from interval gyro means (K, 3).

    Count-weighted mean of the interval means; the std is the larger of the
    white noise of the means and their scatter (bias wander), plus the Earth
    rate term of unknown direction (S * Omega / sqrt(3) per axis).
    """
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    w = np.asarray(counts, dtype=float)
    w = w / w.sum()
    est = w @ means
    noise_var = (w * w) @ np.asarray(mean_var, dtype=float).reshape(-1, 3)
    k = means.shape[0]
    if k > 1:
        scatter = (w @ (means - est) ** 2) * k / (k - 1) / k
        noise_var = np.maximum(noise_var, scatter)
    earth = gyro.scale_factor * earth_rate_si / gyro.unit_to_si
    return est, np.sqrt(noise_var + earth**2 / 3.0)


# ---------------------------------------------------------------------------
# rotations between quasi-static intervals


@dataclass
class RotationPair:
    """One motion between two still intervals, as the rotation fit needs it."""

    t: np.ndarray  #: (M,) s, from the last sample of the first interval to the first of the next
    raw: np.ndarray  #: (M, 3) raw gyro outputs
    bias: np.ndarray  #: (3,) gyro bias during the motion, output units
    up0: np.ndarray  #: (3,) unit specific force at the first interval (body axes)
    up1: np.ndarray  #: (3,) unit specific force at the second interval
    dir_var: float  #: variance of each direction component from accelerometer noise, rad^2
    bias_var: np.ndarray  #: (3,) variance of the bias, output units^2


@dataclass
class RotationFitResult:
    """Shape deviation from the certificate (internal units) and its covariance."""

    deviation: np.ndarray  #: (6,) e_x e_y e_z d1 d2 d3 minus the certificate's
    cov: np.ndarray  #: (6, 6)
    info: np.ndarray  #: (6, 6) data information matrix
    frame: np.ndarray  #: (3,) rotation of the gyro frame against the accelerometers, rad
    pairs: int
    rms: float  #: rad
    max_angle_deg: float  #: largest rotation among the pairs


def _stack_pairs(gyro: TriadModel, pairs: list[RotationPair]) -> dict[str, np.ndarray]:
    m = max(p.t.shape[0] for p in pairs)
    n = len(pairs)
    y = np.zeros((n, m, 3))
    dt = np.zeros((n, m - 1))
    for i, p in enumerate(pairs):
        k = p.t.shape[0]
        y[i, :k] = (p.raw - p.bias) / gyro.scale_factor * gyro.unit_to_si
        y[i, k:] = y[i, k - 1]
        dt[i, : k - 1] = np.diff(p.t)
    return {"y": y, "dt": dt}


def _predict(
    stack: dict[str, np.ndarray], ninv: np.ndarray, up0: np.ndarray
) -> np.ndarray:
    """Predicted end directions (P, n, 3) for parameter sets with N^-1 (P, 3, 3)."""
    omega = np.einsum("pij,nmj->pnmi", ninv, stack["y"])
    theta = 0.5 * (omega[:, :, 1:] + omega[:, :, :-1]) * stack["dt"][None, :, :, None]
    q = ordered_product(rotvec_quat(theta))
    c = quat_matrix(q)  # body at end -> body at start
    return np.einsum("pnji,nj->pni", c, up0)


def rotation_fit(
    gyro: TriadModel,
    pairs: list[RotationPair],
    gyro_sample_var: np.ndarray,
    earth_rate_si: float = 7.292115e-5,
    prior_factor: float = 10.0,
    fit_frame: bool = False,
    max_iter: int = 6,
) -> RotationFitResult:
    """Fit the gyro shape (and with ``fit_frame`` its rotation against the accelerometers).

    ``gyro_sample_var`` (3,) per-sample output variance (output units^2).
    Prior: ``prior_factor`` limits around the certificate's shape (frame: 0.1 rad).
    """
    shape_c, q_c = shape_of_triad(gyro)
    lim = limit_vector(gyro)[3:] / np.concatenate([gyro.scale_factor, np.ones(3)])
    npar = 9 if fit_frame else 6
    prior_sd = np.concatenate([prior_factor * lim, np.full(3, 0.1)])[:npar]
    prior_prec = 1.0 / prior_sd**2 if np.isfinite(prior_factor) else np.zeros(npar)
    if not np.isfinite(prior_factor) and fit_frame:
        prior_prec[6:] = 0.0
    stack = _stack_pairs(gyro, pairs)
    up0 = np.array([p.up0 for p in pairs])
    up1 = np.array([p.up1 for p in pairs])
    durations = np.array([p.t[-1] - p.t[0] for p in pairs])
    # per-pair variance of a direction component
    s_rad2 = float(np.mean(gyro_sample_var / gyro.scale_factor**2)) * gyro.unit_to_si**2
    mean_dt = np.array([np.mean(np.diff(p.t)) if p.t.shape[0] > 1 else 0.0 for p in pairs])
    bias_rad2 = np.array(
        [float(np.mean(p.bias_var / gyro.scale_factor**2)) * gyro.unit_to_si**2 for p in pairs]
    )
    var = (
        np.array([p.dir_var for p in pairs]) * 2.0
        + s_rad2 * mean_dt * durations
        + bias_rad2 * durations**2
        + (earth_rate_si * durations) ** 2
        + DIRECTION_FLOOR**2
    )
    wgt = np.repeat(1.0 / var, 3)

    def ninv_of(x: np.ndarray) -> np.ndarray:
        """N^-1 (P, 3, 3) for parameter sets x (P, npar) (deviations from the certificate)."""
        p = p_matrix(shape_c + x[:, :6])
        if fit_frame:
            r = np.array([small_rotation(v) for v in x[:, 6:9]])
            n = p @ r @ q_c
        else:
            n = p @ q_c
        return np.linalg.inv(n)

    x = np.zeros(npar)
    h = 1e-6
    jac = np.zeros((3 * len(pairs), npar))
    res = np.zeros(3 * len(pairs))
    for _ in range(max_iter):
        sets = np.vstack([x, x + h * np.eye(npar)])
        pred = _predict(stack, ninv_of(sets), up0)
        res = (up1 - pred[0]).ravel()
        jac = ((pred[1:] - pred[0][None]) / h).reshape(npar, -1).T  # d pred / d x
        info = jac.T @ (jac * wgt[:, None])
        grad = jac.T @ (res * wgt) - prior_prec * x
        try:
            step = np.linalg.solve(info + np.diag(prior_prec), grad)
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(info + np.diag(prior_prec), grad, rcond=None)[0]
        x = x + step
        if np.max(np.abs(step)) < 1e-9:
            break
    pred = _predict(stack, ninv_of(x[None]), up0)
    res = (up1 - pred[0]).ravel()
    info = jac.T @ (jac * wgt[:, None])
    hess = info + np.diag(prior_prec)
    cov = np.linalg.pinv(hess)
    chi2 = float(np.sum(res * res * wgt))
    dof = 2 * len(pairs) - npar
    if dof > 0:
        cov = cov * max(1.0, chi2 / dof)
    ang = [
        math.degrees(math.acos(float(np.clip(np.dot(p.up0, p.up1), -1.0, 1.0)))) for p in pairs
    ]
    return RotationFitResult(
        deviation=x[:6],
        cov=cov[:6, :6],
        info=info[:6, :6],
        frame=x[6:9] if fit_frame else np.zeros(3),
        pairs=len(pairs),
        rms=float(np.sqrt(np.mean(res * res))),
        max_angle_deg=max(ang) if ang else 0.0,
    )


__all__ = [
    "RotationPair",
    "RotationFitResult",
    "rotation_fit",
    "rest_bias",
    "earth_rate_observable",
    "qmul",
    "rotvec_quat",
    "quat_matrix",
    "ordered_product",
]
