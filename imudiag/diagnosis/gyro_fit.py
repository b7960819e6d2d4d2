"""Gyro triad: bias at rest, and scale factor / misalignment from rotations.

A MEMS gyro cannot see Earth rate (design note §5): at rest its output *is*
its bias (plus an Earth-rate term far below its noise, kept as uncertainty).
Its scale factors and misalignment need known rotations: between two
quasi-static intervals the gyro-integrated rotation C (body at the end to body
at the start) must carry the first measured specific-force direction into the
second, ``f_1 = C^T f_0`` (Tedaldi et al., ICRA 2014). The fit finds the shape
(e, d: the symmetric part P of N, see :mod:`.gauge`) that makes it so over all
rotations of a window, by Gauss-Newton with an analytic Jacobian (the
derivatives carried through the product of each motion's rotations,
:func:`predict_with_jacobian`); all segments are integrated at once (each
segment's blocks only, quaternion products reduced pairwise: no loop over
samples or segments).

Navigation-grade gyros see Earth rate; :func:`earth_rate_observable` decides
from the certificate's noise whether the stationary scalar fit with
``|w| = Earth rate`` is meaningful (the paper's eq. 8).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..certificate import SENSOR_NAMES, Certificate, TriadModel
from ..rotations import (
    quat_matrix,
    rotvec_quat,
    rotvec_right_jacobian,
    segment_product_plan,
    segmented_product_of_rotvecs,
    segmented_product_sensitivity,
    skew,
)
from . import kernels
from .gauge import p_matrix, shape_of_triad
from .intervals import QuasiStaticInterval
from .params import (
    TriadFit,
    certificate_std_vector,
    certificate_vector,
    limit_vector,
    parameter_units,
    std_above_limit,
)
from .robust import MAX_LEVERAGE, group_leverages, point_diagnostics

#: Floor of the direction residual (rad): integration and modelling resolution.
DIRECTION_FLOOR = 1e-4
#: Relative floor of the direction residual per rad of rotation (timing, sampling).
ROTATION_REL_FLOOR = 1e-3
#: Largest rotation between two samples (deg) that the rotation check integrates: faster
#: motions are sampled too coarsely for the gyro integral to be trusted.
MAX_STEP_DEG = 3.0
#: Largest shape deviation (relative scale error, misalignment in rad) a fit may reach:
#: beyond it the model is not a small-error model any more and the step is refused.
MAX_SHAPE = 0.5


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


#: A step in a gyro's rest rate inside a window (a bias shift: a shock, a power cycle):
#: the means of the intervals after it differ from those before by more than this many
#: sigma (each side's std the larger of its noise and its scatter, as :func:`rest_bias`).
#: The best split of a window is searched, so the threshold stands well above the maximum
#: of a score over ~20 splits of white noise (about 3 sigma).
REST_STEP_SIGMA = 6.0
#: Fewest intervals on each side of a rest-rate step: the side after it gives the bias,
#: its scatter the std (fewer points would make that std itself a guess).
REST_STEP_MIN_SIDE = 5
#: Smallest rest-rate step split, in bias limits: a smaller one cannot move the bias
#: across its limit by itself, and the slow wander of a real unit's rest rate can score
#: as a step (the MPU-6050's 449-s hold: 1.1 counts, 0.008 limits, at 6.1 sigma).
REST_STEP_MIN_LIMITS = 0.5


def _rest_parts(
    means: np.ndarray, mean_var: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count-weighted mean of interval means (K, d), the variance of that mean from their
    white noise, and the variance from their scatter (bias wander; 0 for one interval),
    per column."""
    w = np.asarray(counts, dtype=float)
    w = w / w.sum()
    est = w @ means
    white = (w * w) @ mean_var
    k = means.shape[0]
    scatter = (w @ (means - est) ** 2) * k / (k - 1) / k if k > 1 else np.zeros_like(white)
    return est, white, scatter


def _rest_mean_var(
    means: np.ndarray, mean_var: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Count-weighted mean of interval means (K, d) and its variance: the larger of the
    white noise of the means and their scatter (bias wander), per column."""
    est, white, scatter = _rest_parts(means, mean_var, counts)
    return est, np.maximum(white, scatter)


def _rest_scatter_part(
    means: np.ndarray, mean_var: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, float]:
    """The part (3,) of :func:`_rest_mean_var`'s variance measured from the means' own
    scatter (where it exceeds their white noise; 0 elsewhere), output units^2, and the
    degrees of freedom it was measured with (intervals - 1)."""
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    if means.shape[0] < 2:
        return np.zeros(3), float("nan")
    _est, white, scatter = _rest_parts(
        means, np.asarray(mean_var, dtype=float).reshape(-1, 3), counts
    )
    return np.where(scatter > white, scatter, 0.0), float(means.shape[0] - 1)


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
    est, var = _rest_mean_var(means, np.asarray(mean_var, dtype=float).reshape(-1, 3), counts)
    return est, np.sqrt(var + _earth_var(gyro, earth_rate_si))


def _earth_var(gyro: TriadModel, earth_rate_si: float) -> np.ndarray:
    """Variance (3,) of the Earth-rate term of unknown direction at rest, output units^2."""
    earth = gyro.scale_factor * earth_rate_si / gyro.unit_to_si
    return earth**2 / 3.0


@dataclass(frozen=True)
class RestStep:
    """A step of one gyro's rest rate inside a window (:func:`rest_rate_steps`)."""

    axis: int  #: 0, 1, 2 for x, y, z
    index: int  #: first interval after the step (row of the window's means)
    before: float  #: rest rate before the step, output units
    after: float  #: rest rate after it, output units
    after_var: float  #: variance of ``after`` (as :func:`rest_bias` takes it), output units^2
    z: float  #: the step over its std (sigma)

    def to_json(self, t_after: float) -> dict:
        """As the window's gyro fit lists it (``rest_step``); ``t_after`` the start (s) of
        the first interval after the step."""
        return {
            "sensor": SENSOR_NAMES["gyro"][self.axis],
            "t_after": round(t_after, 6),
            "before": self.before,
            "after": self.after,
            "sigma": round(self.z, 3),
        }


def _prefix_mean_var(
    means: np.ndarray, mean_var: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_rest_mean_var` of every leading part ``[:n]``, n = 1..K, at once: rows (K, d)
    from prefix sums (``means`` centred by the caller, so no large squares cancel)."""
    w = counts[:, None]
    big_w = np.cumsum(w, axis=0)
    est = np.cumsum(w * means, axis=0) / big_w
    noise = np.cumsum(w * w * mean_var, axis=0) / big_w**2
    n = np.arange(1, means.shape[0] + 1, dtype=float)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        spread = np.cumsum(w * means * means, axis=0) / big_w - est * est
        scatter = np.where(n > 1, np.maximum(spread, 0.0) / (n - 1), 0.0)
    return est, np.maximum(noise, scatter)


def rest_rate_steps(
    means: np.ndarray,
    mean_var: np.ndarray,
    counts: np.ndarray,
    min_size: np.ndarray | float = 0.0,
) -> list[RestStep]:
    """Steps of the gyros' rest rates in a window (interval means (K, 3) in time order,
    their white-noise variances and sample counts): per axis, the split of the window into
    an older and a newer part whose means differ most for their std (each part's mean and
    variance as :func:`rest_bias` takes them); a step where that is beyond
    :data:`REST_STEP_SIGMA`, with :data:`REST_STEP_MIN_SIDE` intervals on each side and a
    size of at least ``min_size`` (output units, per axis or one for all). Every split is
    scored at once from prefix sums (tests/test_rest_step.py holds it to the split-by-split
    definition).
    """
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    mean_var = np.asarray(mean_var, dtype=float).reshape(-1, 3)
    counts = np.asarray(counts, dtype=float)
    k = means.shape[0]
    lo, hi = REST_STEP_MIN_SIDE, k - REST_STEP_MIN_SIDE  # splits lo..hi
    if hi < lo:
        return []
    splits = np.arange(lo, hi + 1)
    scores = kernels.kernel("rest_step_scores") if bool(np.all(counts > 0)) else None
    if scores is not None:  # (fleet workers) the same sums and scores compiled: exact
        z = scores(
            np.ascontiguousarray(means), np.ascontiguousarray(mean_var), counts, lo, hi,
            np.array(np.broadcast_to(np.asarray(min_size, dtype=float), (3,))),  # (writable)
        )  # fmt: skip
    else:
        centred = means - means[0]
        m_old, v_old = _prefix_mean_var(centred, mean_var, counts)
        m_new, v_new = _prefix_mean_var(centred[::-1], mean_var[::-1], counts[::-1])
        m0, v0 = m_old[splits - 1], v_old[splits - 1]  # parts [:split]
        m1, v1 = m_new[k - splits - 1], v_new[k - splits - 1]  # parts [split:]
        step = np.abs(m1 - m0)
        z = step / np.sqrt(v0 + v1)
        z[~(step >= min_size) | ~np.isfinite(z)] = 0.0
    out = []
    for a in range(3):
        best = int(np.argmax(z[:, a]))
        if z[best, a] > REST_STEP_SIGMA:
            split = int(splits[best])
            before, _ = _rest_mean_var(means[:split], mean_var[:split], counts[:split])
            after, var = _rest_mean_var(means[split:], mean_var[split:], counts[split:])
            out.append(
                RestStep(
                    a, split, float(before[a]), float(after[a]), float(var[a]), float(z[best, a])
                )
            )
    return out


def rest_rotation_fit(
    gyro: TriadModel,
    means: np.ndarray,
    mean_var: np.ndarray,
    counts: np.ndarray,
    earth_rate_si: float,
    rotation: RotationFitResult | None,
    determined_std_ratio: float,
    rotation_note: str = "",
    starts: np.ndarray | None = None,
) -> TriadFit:
    """The MEMS gyro fit, the one place it is assembled: the bias at rest (:func:`rest_bias`
    of the interval means (K, 3), output units) and the shape from ``rotation`` (the
    :func:`rotation_fit` of the motions between the intervals, None without rotations).

    With ``starts`` (the intervals' start times, s: a window of the diagnosis, which
    judges the unit as it is now) an axis whose rest rate steps inside the window
    (:func:`rest_rate_steps`) takes its bias from the intervals after the step; each step
    is listed in ``extra["rest_step"]``. Without (a calibration), the bias is that of every
    interval.

    Estimates and std in certificate units; a parameter is determined where its std is at
    most ``determined_std_ratio`` of its limit. ``rotation_note`` is added to the reason of
    an undetermined shape parameter when there were rotations. The caller adds what its
    use wants (``extra``, condition, leave-one-out rows).
    """
    cert = certificate_vector(gyro)
    limit = limit_vector(gyro)
    units = parameter_units(gyro)
    est = cert.copy()
    std = np.full(9, np.inf)
    est[:3], std[:3] = rest_bias(gyro, means, mean_var, counts, earth_rate_si)
    # what the std holds of a scatter measured on the window's own points (the Student-t
    # threshold of .predicates): the rest rates' scatter, the rotation fit's Birge ratio
    est_var, est_dof = np.zeros(9), np.full(9, np.nan)
    est_var[:3], est_dof[:3] = _rest_scatter_part(means, mean_var, counts)
    extra: dict = {}
    if starts is not None:
        steps = rest_rate_steps(means, mean_var, counts, REST_STEP_MIN_LIMITS * limit[:3])
        earth_var = _earth_var(gyro, earth_rate_si)
        for step in steps:  # the bias after the step, as rest_bias takes it
            est[step.axis] = step.after
            std[step.axis] = math.sqrt(step.after_var + earth_var[step.axis])
            part, dof = _rest_scatter_part(
                means[step.index :], mean_var[step.index :], counts[step.index :]
            )
            est_var[step.axis], est_dof[step.axis] = part[step.axis], dof
        if steps:
            extra["rest_step"] = [s.to_json(float(starts[s.index])) for s in steps]
    if rotation is not None:
        scale = np.concatenate([gyro.scale_factor, np.ones(3)])
        est[3:] = cert[3:] + rotation.deviation * scale
        std[3:] = np.sqrt(np.maximum(np.diag(rotation.cov), 0.0)) * scale
        finite = np.isfinite(std[3:])
        est_var[3:][finite] = std[3:][finite] ** 2 * (1.0 - 1.0 / rotation.cov_scale)
    determined = std <= determined_std_ratio * limit
    reasons = [""] * 9
    for i in range(9):
        if determined[i]:
            continue
        if i >= 3 and rotation is None:
            reasons[i] = "no rotation between static poses"
        else:
            reasons[i] = std_above_limit(std[i], determined_std_ratio, limit[i], units[i])
            if i >= 3:
                reasons[i] += rotation_note
    return TriadFit(
        triad="gyro",
        method="rest+rotation",
        estimate=est,
        std=std,
        certificate=cert,
        limit=limit,
        determined=determined,
        reasons=reasons,
        points=len(np.asarray(means).reshape(-1, 3)),
        dof=rotation.dof if rotation is not None else float("nan"),
        certificate_std=certificate_std_vector(gyro),
        extra=extra,
        estimated_var=est_var,
        estimated_dof=est_dof,
    )


def gyro_sample_var(intervals: list[QuasiStaticInterval]) -> np.ndarray:
    """Per-sample gyro output variance (3,) of a session, output units^2: the median over
    its still intervals (a calibration's motions are weighted with it)."""
    return np.median(np.array([np.diag(iv.gyro_cov) for iv in intervals]), axis=0)


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
    #: the motion's :attr:`.intervals.MotionSegment.memo` (its increments are kept there
    #: per gyro scale, :func:`scale_key`: the same motion is in many windows), or None
    memo: dict | None = None


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
    dof: float = float("nan")  #: effective degrees of freedom
    frame_cov: np.ndarray | None = None  #: (3, 3) covariance of ``frame``, rad^2 (fit_frame only)
    #: (pairs, 6) ``deviation`` with each motion left out (NaN where it alone carries one)
    loo_deviation: np.ndarray | None = None
    #: (pairs,) robustly standardised deletion residual of each motion, sigma (:mod:`.robust`)
    point_z: np.ndarray | None = None
    #: robust excess variance of a direction component beyond the motions' noise, rad^2
    excess_var: float = 0.0
    #: factor (>= 1) ``cov`` was scaled by for a scatter beyond the motions' noise (chi^2 /
    #: dof, the Birge ratio); 1 where it was not
    cov_scale: float = 1.0
    #: prediction error of the ``predict`` motion against this fit, sigma (NaN: not asked)
    predicted_z: float = float("nan")
    #: (pairs, npar) all fitted parameters (shape, frame) with each motion left out, by the
    #: deletion formula of :mod:`.robust`; NaN rows: the motion alone carries a direction
    loo_params: np.ndarray | None = None
    #: (pairs, npar) their variances (scaled as ``cov``); inf where the row is NaN
    loo_var: np.ndarray | None = None


def _block_increments(inc: np.ndarray, block_rad: float) -> np.ndarray:
    """Sum consecutive increments (M, 3) into blocks of at most about ``block_rad`` of turn.

    The increments are linear in the raw outputs, so N^-1 applies to the sums
    exactly; only the order of rotations inside a block is lost (a coning
    error below (block / 2)^2 / 2 rad per block), and a turn costs the same
    whatever the sample rate.
    """
    path = np.cumsum(np.linalg.norm(inc, axis=1))
    ids = np.floor(path / block_rad).astype(np.int64)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(ids)) + 1])
    return np.add.reduceat(inc, starts, axis=0)


def scale_key(gyro: TriadModel) -> tuple[float, bytes]:
    """What a motion's screening and increments depend on in a gyro model (its nominal
    scale factors and unit), as a memo key: a model changed in place is a new key."""
    return float(gyro.unit_to_si), np.asarray(gyro.scale_factor, dtype=float).tobytes()


def _pair_increments(gyro: TriadModel, p: RotationPair, block_deg: float) -> np.ndarray:
    """One motion's blocked rotation increments before N^-1 (rad), kept in its memo per
    gyro scale (the window diagnosis refits each motion in every window of its interval)."""
    key = ("increments", block_deg, *scale_key(gyro))
    if p.memo is not None and key in p.memo:
        return p.memo[key]
    y = (p.raw - p.bias) / gyro.scale_factor * gyro.unit_to_si
    inc = 0.5 * (y[1:] + y[:-1]) * np.diff(p.t)[:, None]
    out = _block_increments(inc, math.radians(block_deg)) if inc.shape[0] else inc
    if p.memo is not None:
        p.memo[key] = out
    return out


def stack_pairs(
    gyro: TriadModel, pairs: list[RotationPair], block_deg: float = 1.0
) -> dict[str, np.ndarray]:
    """Rotation increments of every motion before N^-1 (trapezoid rule, rad), padded.

    ``inc`` (n, B, 3): per motion, blocks of at most about ``block_deg`` of turn
    (zero padding is the identity); ``path`` (n,): each motion's path length, rad;
    ``blocks`` (n,): each motion's number of blocks (the rest of its row is padding).
    """
    blocks = [_pair_increments(gyro, p, block_deg) for p in pairs]
    b = max(max(x.shape[0] for x in blocks), 1)
    out = np.zeros((len(pairs), b, 3))
    for i, x in enumerate(blocks):
        out[i, : x.shape[0]] = x
    path = np.sum(np.linalg.norm(out, axis=2), axis=1)
    return {"inc": out, "path": path, "blocks": np.array([x.shape[0] for x in blocks])}


def predict_end_directions(
    stack: dict[str, np.ndarray], ninv: np.ndarray, up0: np.ndarray
) -> np.ndarray:
    """Predicted end directions (P, n, 3) for parameter sets with N^-1 (P, 3, 3).

    The rotation of each motion is the ordered product of its blocks' quaternions
    (:func:`.rotations.segmented_product_of_rotvecs`: only the blocks a motion has, not
    the padding to the longest, go through N^-1, the trigonometry and the products; the
    plan of the products is kept in ``stack``, which every evaluation of a fit shares).
    """
    _product_plan(stack)
    theta = np.matmul(stack["turning"][None], np.swapaxes(ninv, 1, 2))  # (P, K, 3)
    q = segmented_product_of_rotvecs(theta, stack["plan"])  # type: ignore[arg-type]
    c = quat_matrix(q)  # body at end -> body at start
    return np.einsum("pnji,nj->pni", c, up0)


def _turning_blocks(stack: dict[str, np.ndarray]) -> None:
    """Keep in ``stack`` the blocks that turn, motion by motion (``turning`` (K, 3), rad) and
    each motion's number of them (``lengths``)."""
    if "turning" in stack:
        return
    inc = stack["inc"]
    n, b, _ = inc.shape
    lengths = stack.get("blocks")
    if lengths is None:  # a stack made by hand: every block may turn
        lengths = np.full(n, b)
    row, block = np.nonzero(np.arange(b)[None, :] < np.asarray(lengths)[:, None])
    stack["turning"] = inc[row, block]  # (K, 3): motion by motion, blocks in order
    stack["lengths"] = np.asarray(lengths)


def _product_plan(stack: dict[str, np.ndarray]) -> None:
    """Keep in ``stack`` the blocks that turn, motion by motion, and the plan of their
    products (every evaluation of a fit shares them)."""
    if "plan" in stack:
        return
    _turning_blocks(stack)
    stack["plan"] = segment_product_plan(stack["lengths"])  # type: ignore[assignment]


def motion_sensitivities(
    stack: dict[str, np.ndarray], ninv: np.ndarray, memos: list[dict | None] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Each motion's rotation (n, 4) for one N^-1 (3, 3) and its sensitivity to N^-1
    (n, 3, 3, 3; :func:`.rotations.segmented_product_sensitivity`).

    ``memos`` (one per motion, or None): where each motion's pair is kept, keyed by N^-1
    and the motion's increments (every window starts its fit at the certificate's N^-1,
    and a motion is in every window of its interval); when all are there, nothing is
    computed.
    """
    _turning_blocks(stack)
    turning = stack["turning"]
    lengths = stack["lengths"]
    if memos is None or any(m is None for m in memos):
        theta = np.matmul(turning[None], ninv.T[None])[0]  # (K, 3)
        fast = kernels.product_sensitivity(theta, turning, lengths)  # fleet workers
        if fast is not None:
            return fast
        _product_plan(stack)
        return segmented_product_sensitivity(
            theta,
            turning,
            lengths,
            stack["plan"],  # type: ignore[arg-type]
        )
    first = np.cumsum(lengths) - lengths
    parts = [turning[a : a + n] for a, n in zip(first, lengths, strict=True)]
    keys = [("sensitivity", ninv.tobytes(), part.tobytes()) for part in parts]
    missing = [i for i, (m, k) in enumerate(zip(memos, keys, strict=True)) if k not in m]  # type: ignore[operator]
    if missing:
        sub = np.concatenate([parts[i] for i in missing])
        sub_lengths = lengths[missing]
        sub_theta = np.matmul(sub[None], ninv.T[None])[0]
        fast = kernels.product_sensitivity(sub_theta, sub, sub_lengths)  # fleet workers
        q, sens = (
            fast
            if fast is not None
            else segmented_product_sensitivity(
                sub_theta, sub, sub_lengths, segment_product_plan(sub_lengths)
            )
        )
        for j, i in enumerate(missing):
            memos[i][keys[i]] = (q[j], sens[j])  # type: ignore[index]
    kept = [m[k] for m, k in zip(memos, keys, strict=True)]  # type: ignore[index]
    return np.array([v[0] for v in kept]), np.array([v[1] for v in kept])


def predict_with_jacobian(
    stack: dict[str, np.ndarray],
    ninv: np.ndarray,
    dninv: np.ndarray,
    up0: np.ndarray,
    memos: list[dict | None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted end directions (n, 3) for one N^-1 (3, 3), and their derivatives
    (n, 3, m) with respect to m parameters whose derivatives of N^-1 are ``dninv``
    (m, 3, 3) (per parameter unit).

    The analytic Jacobian of :func:`predict_end_directions`: each block's rotation
    vector ``N^-1 inc`` moves by ``dN^-1 inc``, which moves each motion's rotation C by
    a right perturbation omega (:func:`.rotations.segmented_product_sensitivity`: one
    pass down the product tree serves every parameter), and the prediction ``C^T up0``
    by ``pred x omega``. The prediction itself is :func:`predict_end_directions`'s.
    ``memos``: as :func:`motion_sensitivities`.
    """
    q, sens = motion_sensitivities(stack, ninv, memos)
    fast = kernels.predict_directions(q, sens, dninv, up0)  # fleet workers
    if fast is not None:
        return fast
    omega = np.einsum("nacd,mcd->nam", sens, dninv)  # (n, 3, m), rad per parameter unit
    c = quat_matrix(q)  # body at end -> body at start
    pred = np.einsum("nji,nj->ni", c, up0)
    return pred, np.cross(pred[:, :, None], omega, axis=1)


#: (6, 3, 3): dP per shape parameter (:func:`.gauge.p_matrix` is affine in the shape)
_D_P = p_matrix(np.eye(6)) - np.eye(3)[None]
_D_P.setflags(write=False)


def ninv_derivatives(
    shape_c: np.ndarray, q_c: np.ndarray, x: np.ndarray, fit_frame: bool
) -> tuple[np.ndarray, np.ndarray]:
    """N^-1 (3, 3) of the rotation fit's parameters ``x`` (npar,) and its derivatives
    (npar, 3, 3) per parameter unit (shape parameters dimensionless or rad, frame rad).

    ``N = P(shape_c + x[:6]) [R(x[6:9])] Q_c`` (:func:`.gauge.p_matrix`; the frame
    rotation when ``fit_frame``), and ``dN^-1 = -N^-1 dN N^-1``.
    """
    fast = kernels.ninv_derivatives(shape_c, q_c, x, fit_frame)  # fleet workers
    if fast is not None:
        return fast
    npar = x.shape[0]
    p = p_matrix(shape_c + x[:6])
    d_p = _D_P
    if fit_frame:
        phi = x[6:9]
        rf = quat_matrix(rotvec_quat(phi))
        # dR/dphi_j = R [J_r(phi) e_j]x
        d_rf = rf[None] @ skew(rotvec_right_jacobian(phi).T)  # (3, 3, 3)
    else:
        rf = np.eye(3)
        d_rf = np.zeros((0, 3, 3))
    n = p @ rf @ q_c
    d_n = np.concatenate([d_p @ (rf @ q_c)[None], (p[None] @ d_rf @ q_c[None])])[:npar]
    ninv = np.linalg.inv(n)
    return ninv, -ninv[None] @ d_n @ ninv[None]


@functools.lru_cache(maxsize=32)
def _ninv_at_certificate(
    shape_c: bytes, q_c: bytes, npar: int, compiled: bool
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ninv_derivatives` at x = 0 (the certificate) of the shape and rotation whose
    bytes are given, kept (read-only): every window's fit starts there. ``compiled``:
    whether the kernels are on (:mod:`.kernels`), so each path keeps its own figures."""
    # copies: a bytes object's buffer need not be aligned, and an unaligned operand takes
    # another matmul loop than the one the fit's other evaluations go through
    out = ninv_derivatives(
        np.frombuffer(shape_c).copy(),
        np.frombuffer(q_c).reshape(3, 3).copy(),
        np.zeros(npar),
        npar == 9,
    )
    for arr in out:
        arr.setflags(write=False)
    return out


def direction_var(
    gyro: TriadModel,
    pairs: list[RotationPair],
    path: np.ndarray,
    gyro_sample_var: np.ndarray,
    earth_rate_si: float,
) -> np.ndarray:
    """Variance (n,) of each component of a motion's end direction from noise alone, rad^2.

    ``path`` (n,) the motions' rotation path lengths (rad); the rest as :func:`rotation_fit`.
    """
    figures = np.array([_motion_figures(gyro, p) for p in pairs]).reshape(-1, 3)
    durations, mean_dt, bias_rad2 = figures.T
    s_rad2 = float(np.mean(gyro_sample_var / gyro.scale_factor**2)) * gyro.unit_to_si**2
    return (
        (ROTATION_REL_FLOOR * path) ** 2
        + np.array([p.dir_var for p in pairs]) * 2.0
        + s_rad2 * mean_dt * durations
        + bias_rad2 * durations**2
        + (earth_rate_si * durations) ** 2
        + DIRECTION_FLOOR**2
    )


def _motion_figures(gyro: TriadModel, p: RotationPair) -> tuple[float, float, float]:
    """A motion's duration (s), mean sampling interval (s) and bias variance (rad/s)^2 (the
    mean over the axes), kept in its memo per gyro scale (the same in every window)."""
    key = ("figures", *scale_key(gyro))
    if p.memo is not None and key in p.memo:
        return p.memo[key]
    out = (
        float(p.t[-1] - p.t[0]),
        float(np.mean(np.diff(p.t))) if p.t.shape[0] > 1 else 0.0,
        float(np.mean(p.bias_var / gyro.scale_factor**2)) * gyro.unit_to_si**2,
    )
    if p.memo is not None:
        p.memo[key] = out
    return out


def rotation_fit(
    gyro: TriadModel,
    pairs: list[RotationPair],
    gyro_sample_var: np.ndarray,
    earth_rate_si: float = 7.292115e-5,
    prior_factor: float | np.ndarray = 10.0,
    fit_frame: bool = False,
    max_iter: int = 6,
    scale_by_residual: bool = True,
    predict: RotationPair | None = None,
) -> RotationFitResult:
    """Fit the gyro shape (and with ``fit_frame`` its rotation against the accelerometers).

    ``gyro_sample_var`` (3,) per-sample output variance (output units^2).
    Prior: ``prior_factor`` limits (scalar or per shape parameter (6,)) around the
    certificate's shape; the frame rotation has a prior of 0.1 rad.
    ``scale_by_residual``: inflate the covariance by chi^2 / dof when above 1.
    ``max_iter=0`` gives the covariance of the linearisation at the certificate.
    ``predict``: a motion not in the fit; its prediction error in sigma (its noise, the
    robust excess scatter of the fitted motions and the fit's uncertainty) goes to
    ``predicted_z``, on the scale of :attr:`RotationFitResult.point_z`.
    """
    shape_c, q_c = shape_of_triad(gyro)
    lim = limit_vector(gyro)[3:] / np.concatenate([gyro.scale_factor, np.ones(3)])
    npar = 9 if fit_frame else 6
    prior_sd = np.concatenate([np.broadcast_to(prior_factor, (6,)) * lim, np.full(3, 0.1)])
    prior_prec = 1.0 / prior_sd[:npar] ** 2
    stack = stack_pairs(gyro, pairs)
    up0 = np.array([p.up0 for p in pairs])
    up1 = np.array([p.up1 for p in pairs])
    # per-pair variance of a direction component
    var = direction_var(gyro, pairs, stack["path"], gyro_sample_var, earth_rate_si)
    wgt = np.repeat(1.0 / var, 3)

    memos = [p.memo for p in pairs]

    def evaluate(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Residuals (3 n,), Jacobian of the prediction (3 n, npar, analytic), cost at x."""
        at_certificate = not x.any()  # every fit's start: what depends on x alone is kept
        pred, d_pred = predict_with_jacobian(
            stack,
            *(
                _ninv_at_certificate(shape_c.tobytes(), q_c.tobytes(), npar, kernels.enabled())
                if at_certificate
                else ninv_derivatives(shape_c, q_c, x, fit_frame)
            ),
            up0,
            # and so is each motion's rotation
            memos=memos if at_certificate else None,
        )
        r = (up1 - pred).ravel()
        j = d_pred.reshape(-1, npar)
        return r, j, float(np.sum(r * r * wgt) + np.sum(prior_prec * x * x))

    x = np.zeros(npar)
    compiled = None
    if max_iter > 0 and pairs and kernels.enabled():  # the loop compiled (fleet workers)
        _turning_blocks(stack)  # (the compiled products need no plan)
        compiled = kernels.rotation_loop(
            x, stack, up0, up1, wgt, prior_prec, shape_c, q_c, fit_frame, max_iter, MAX_SHAPE
        )
    if compiled is not None:
        x, res, jac, cost = compiled
    else:
        res, jac, cost = evaluate(x)
        lam = 1e-6
        done = False
        for _ in range(max_iter):
            info = jac.T @ (jac * wgt[:, None])
            hess = info + np.diag(prior_prec)
            grad = jac.T @ (res * wgt) - prior_prec * x
            accepted = False
            for _try in range(8):
                a = hess + lam * np.diag(np.maximum(np.diag(hess), 1e-30))
                step = np.linalg.lstsq(a, grad, rcond=None)[0]
                cand = x + step
                if np.max(np.abs(cand[:6])) > MAX_SHAPE:
                    lam *= 10.0
                    continue
                r1, j1, c1 = evaluate(cand)
                if np.isfinite(c1) and c1 <= cost:
                    # a chi^2 change far below 1 is statistically nothing
                    done = cost - c1 <= max(1e-3, 1e-9 * cost)
                    x, res, jac, cost = cand, r1, j1, c1
                    lam = max(lam / 10.0, 1e-12)
                    accepted = True
                    break
                lam *= 10.0
            if not accepted or done:
                break
    shift = loo = loo_params = loo_var = None
    point_z = None
    excess = 0.0
    post = kernels.rotation_post(jac, res, wgt, prior_prec) if compiled is not None else None
    if post is not None:  # what follows, compiled (fleet workers)
        info, cov, chi2, dof, shift, point_z, excess, loo_var = post
    else:
        info = jac.T @ (jac * wgt[:, None])
        hess = info + np.diag(prior_prec)
        cov = np.linalg.pinv(hess)
        chi2 = float(np.sum(res * res * wgt))
        # two observations per motion (a direction), less the parameters the data determine
        dof = 2 * len(pairs) - float(np.trace(cov @ info))
        if pairs and max_iter > 0:
            groups = [np.arange(3 * i, 3 * i + 3) for i in range(len(pairs))]
            diag = point_diagnostics(-jac, res, 1.0 / wgt, cov, groups=groups, weights=wgt)
            shift, point_z, excess = diag.shift, diag.z, diag.excess_var
            loo_var = _deletion_variances(jac * np.sqrt(wgt)[:, None], cov, groups)
    if shift is not None and loo_var is not None:  # each motion left out
        loo = x[None, :6] + shift[:, :6]
        loo_params = x[None, :] + shift
        if dof > 0.5 and scale_by_residual:
            loo_var = loo_var * max(1.0, chi2 / dof)
    predicted_z = float("nan")
    if predict is not None:
        predicted_z = _prediction_z(
            gyro,
            predict,
            ninv_derivatives(shape_c, q_c, x, fit_frame),
            jac,
            1.0 / wgt,
            excess,
            prior_prec,
            (gyro_sample_var, earth_rate_si),
        )
    cov_scale = max(1.0, chi2 / dof) if dof > 0.5 and scale_by_residual else 1.0
    cov = cov * cov_scale
    ang = [math.degrees(math.acos(min(max(float(np.dot(p.up0, p.up1)), -1.0), 1.0))) for p in pairs]
    return RotationFitResult(
        deviation=x[:6],
        cov=cov[:6, :6],
        info=info[:6, :6],
        frame=x[6:9] if fit_frame else np.zeros(3),
        pairs=len(pairs),
        rms=float(np.sqrt(np.mean(res * res))),
        max_angle_deg=max(ang) if ang else 0.0,
        dof=dof,
        frame_cov=cov[6:9, 6:9] if fit_frame else None,
        loo_deviation=loo,
        point_z=point_z,
        excess_var=excess,
        cov_scale=cov_scale,
        predicted_z=predicted_z,
        loo_params=loo_params,
        loo_var=loo_var,
    )


def _deletion_variances(a_all: np.ndarray, cov: np.ndarray, groups: list[np.ndarray]) -> np.ndarray:
    """Diagonal (G, p) of the unscaled covariance with each group of rows left out.

    ``a_all`` (n, p) the weighted Jacobian, ``cov`` (p, p) the unscaled covariance of the
    fit to all rows: removing rows A gives C + C A^T (I - A C A^T)^-1 A C (Woodbury);
    inf where the group's leverage exceeds :data:`.robust.MAX_LEVERAGE`.
    """
    out = np.full((len(groups), cov.shape[0]), np.inf)
    blocks = group_leverages(a_all, cov, groups) if groups else None
    if blocks is not None:
        # every motion's three components at once
        rows, a, hk, judged = blocks
        a, hk = a[judged], hk[judged]
        m = cov[None] @ np.swapaxes(a, 1, 2)  # (G, p, 3)
        sol = np.linalg.solve(np.eye(rows.shape[1])[None] - hk, np.swapaxes(m, 1, 2))
        out[judged] = np.diag(cov)[None] + np.einsum("gij,gji->gi", m, sol)
        return out
    for k, rows in enumerate(groups):
        a = a_all[rows]
        hk = a @ cov @ a.T
        hk = 0.5 * (hk + hk.T)
        if np.linalg.eigvalsh(hk)[-1] > MAX_LEVERAGE:
            continue
        m = cov @ a.T
        out[k] = np.diag(cov) + np.einsum(
            "ij,ji->i", m, np.linalg.solve(np.eye(len(rows)) - hk, m.T)
        )
    return out


def _prediction_z(
    gyro: TriadModel,
    pair: RotationPair,
    ninv: tuple[np.ndarray, np.ndarray],
    jac: np.ndarray,
    noise_var: np.ndarray,
    excess: float,
    prior_prec: np.ndarray,
    noise: tuple[np.ndarray, float],
) -> float:
    """Prediction error (sigma) of a motion left out of the fit whose N^-1 and its
    derivatives are ``ninv`` (:func:`ninv_derivatives`).

    Its end-direction residual (3,) against the covariance of its noise, the
    robust ``excess`` scatter (rad^2) and the fit's parameter uncertainty (the
    fitted motions weighted with that excess too), scaled per component as the
    deletion residuals of :func:`.robust.point_diagnostics` are.
    """
    stack = stack_pairs(gyro, [pair])
    pred, d_pred = predict_with_jacobian(stack, *ninv, pair.up0[None])
    r = pair.up1 - pred[0]
    jp = d_pred[0]  # (3, npar)
    w_rob = 1.0 / (noise_var + excess)
    cov_rob = np.linalg.pinv(jac.T @ (jac * w_rob[:, None]) + np.diag(prior_prec))
    nv = float(direction_var(gyro, [pair], stack["path"], *noise)[0])
    total = (nv + excess) * np.eye(3) + jp @ cov_rob @ jp.T
    u = float(r @ np.linalg.solve(total, r))
    return math.sqrt(max(u, 0.0) / 3.0)


__all__ = [
    "RotationPair",
    "RotationFitResult",
    "direction_var",
    "gyro_sample_var",
    "motion_sensitivities",
    "ninv_derivatives",
    "predict_end_directions",
    "predict_with_jacobian",
    "rotation_fit",
    "scale_key",
    "rest_bias",
    "earth_rate_observable",
    "stack_pairs",
]
