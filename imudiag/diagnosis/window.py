"""One window of the diagnosis: both triads' 9 parameters from a run of quasi-static intervals.

Accelerometers: the exact scalar fit (|f| = g) over the interval means.
Gyros: for navigation-grade units (Earth rate observable per the certificate)
the same fit with |w| = Earth rate; otherwise the bias at rest and the shape
from the rotations between consecutive intervals, with the gravity directions
taken from this window's accelerometer estimate (so an accelerometer fault
does not leak into the gyro estimate). ``method="linear"`` runs the paper's
literal linearised solution on both triads instead (eq. 8 for the gyros,
whatever their grade), for comparison.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..certificate import Certificate, TriadModel, misalignment_of_n
from . import kernels
from .changepoint import window_exact_fit
from .config import DiagnosisConfig
from .gauge import p_matrix, shape_of_triad
from .gyro_fit import (
    MAX_STEP_DEG,
    RotationPair,
    earth_rate_observable,
    rest_rotation_fit,
    rotation_fit,
    scale_key,
)
from .intervals import MotionSegment, QuasiStaticInterval, stacked_mean_var
from .known_rate import classify_plateaus
from .params import (
    TriadFit,
    certificate_vector,
    triad_form,
    undetermined_fit,
)
from .predicates import Judgement, held_back, judge
from .scalar_fit import linear_fit


@dataclass
class WindowResult:
    """Estimates of one window, with what the window was made of."""

    index: int  #: running number
    t_start: float  #: s, start of the first interval
    t_end: float  #: s, end of the last interval (the time the window was diagnosed)
    intervals: int
    attitudes: int  #: distinct attitudes (specific-force directions apart by the separation)
    rotations: int  #: usable rotations between consecutive intervals (gyro fit)
    accel: TriadFit
    gyro: TriadFit
    method: str
    candidates: list[dict] = field(default_factory=list)  #: predicates beyond their limits
    #: each fit's :class:`~.predicates.Judgement` as the window left it (for the stream's
    #: tracker: worked out once); not part of the report
    judgements: dict[str, Judgement] = field(default_factory=dict, repr=False, compare=False)

    def fit(self, triad: str) -> TriadFit:
        """The fit of ``gyro`` or ``accel``."""
        return self.gyro if triad == "gyro" else self.accel

    def to_json(self) -> dict:
        """The window as listed in the diagnosis report's ``windows``."""
        return {
            "index": self.index,
            "t_start": round(self.t_start, 6),
            "t_end": round(self.t_end, 6),
            "method": self.method,
            "intervals": self.intervals,
            "attitudes": self.attitudes,
            "rotations": self.rotations,
            "accel": self.accel.to_json(),
            "gyro": self.gyro.to_json(),
            "candidates": self.candidates,
        }


def attitude_groups(up: np.ndarray, separation_deg: float) -> np.ndarray:
    """Attitude number (K,) of each direction (K, 3): greedy clustering in order, a direction
    joins the first centre within ``separation_deg``, else starts a new one; -1 for a
    direction that is not finite or zero."""
    cos_sep = math.cos(math.radians(separation_deg))
    up = np.asarray(up, dtype=float).reshape(-1, 3)
    valid = np.all(np.isfinite(up), axis=1) & np.any(up, axis=1)
    compiled = kernels.kernel("attitude_labels")  # fleet workers: the same greedy clustering
    if compiled is not None:
        out: np.ndarray = compiled(np.ascontiguousarray(up), valid, cos_sep)
        return out
    centres = np.empty_like(up)  # the first k rows: the centres so far
    labels = np.full(up.shape[0], -1, dtype=int)
    k = 0
    for i, (u, ok) in enumerate(zip(up, valid.tolist(), strict=True)):
        if not ok:
            continue
        near = np.flatnonzero(centres[:k] @ u >= cos_sep) if k else np.zeros(0, dtype=int)
        if near.size:
            labels[i] = int(near[0])
        else:
            centres[k] = u
            labels[i] = k
            k += 1
    return labels


def distinct_attitudes(up: np.ndarray, separation_deg: float) -> int:
    """Number of directions (K, 3) at least ``separation_deg`` apart (greedy clustering)."""
    labels = attitude_groups(up, separation_deg)
    return int(labels.max()) + 1 if labels.size else 0


def model_with(triad: TriadModel, estimate: np.ndarray) -> TriadModel:
    """A copy of ``triad`` with B, E, d of ``estimate`` (certificate units, (9,)).

    The shape comes from the estimate's deviations; the certificate's
    unobservable rotation Q of N = P Q is kept. The fields it does not change are the
    certificate's own objects, not copies (every window makes one: a deep copy of the
    temperature, noise and limit blocks cost more than the window's accelerometer fit).
    """
    import dataclasses

    shape_c, q = shape_of_triad(triad)
    dev = np.asarray(estimate, dtype=float) - certificate_vector(triad)
    shape = shape_c + np.concatenate([dev[3:6] / triad.scale_factor, dev[6:9]])
    n = p_matrix(shape) @ q
    return dataclasses.replace(
        triad,
        bias=np.asarray(estimate[:3], dtype=float).copy(),
        scale_factor_error=(np.diag(n) - 1.0) * triad.scale_factor,
        misalignment=misalignment_of_n(n),
    )


def _interval_label(index: int, t_start: float, t_end: float) -> str:
    """:func:`interval_labels`' name of one interval."""
    return f"interval {index} ({t_start:.2f}-{t_end:.2f} s)"


#: The names made so far (every window of an interval names it again); not for a time of
#: zero, whose sign (``-0.00``) a key equal to ``0.0`` would lose
_interval_label_once = functools.lru_cache(maxsize=4096)(_interval_label)


def interval_labels(intervals: list[QuasiStaticInterval]) -> list[str]:
    """How reports name each interval: running number and time span (s)."""
    return [
        (_interval_label_once if iv.t_start and iv.t_end else _interval_label)(
            iv.index, iv.t_start, iv.t_end
        )
        for iv in intervals
    ]


def motion_labels(pairs: list[RotationPair]) -> list[str]:
    """How reports name each motion of the rotation fit: its time span (s)."""
    return [f"motion {p.t[0]:.2f}-{p.t[-1]:.2f} s" for p in pairs]


def _stack(intervals: list[QuasiStaticInterval], triad: str) -> tuple[np.ndarray, ...]:
    means = np.array([iv.mean(triad) for iv in intervals])
    covs = np.array([iv.cov(triad) for iv in intervals])
    mvar = stacked_mean_var(intervals, triad, covs)
    counts = np.array([iv.n for iv in intervals], dtype=float)
    return means, mvar, covs, counts


def _temperature_corrected(triad: TriadModel, means: np.ndarray, temps: list) -> np.ndarray:
    """Remove the certificate's temperature bias from interval means (output units)."""
    if triad.temperature is None or any(t is None for t in temps):
        return means
    dt = np.array(temps, dtype=float)[:, None] - triad.temperature.reference
    return means - triad.temperature.bias_coefficient * dt


def _with_reason(fit: TriadFit, idx: range, extra: str) -> None:
    for i in idx:
        if not fit.determined[i]:
            fit.reasons[i] = f"{fit.reasons[i]}; {extra}" if fit.reasons[i] else extra


def accel_window_fit(
    cert: Certificate,
    intervals: list[QuasiStaticInterval],
    config: DiagnosisConfig,
    method: str,
    attitudes: int,
) -> TriadFit:
    """The accelerometer fit of one window."""
    tri = cert.accel
    means, mvar, covs, counts = _stack(intervals, "accel")
    means = _temperature_corrected(tri, means, [iv.temp for iv in intervals])
    g_in = cert.gravity / tri.unit_to_si
    if method == "linear":
        fit = linear_fit(
            tri, means, covs, counts, g_in, config.determined_std_ratio, config.prior_factor
        )
    else:
        # outliers rejected unless the window spans a step change (a unit that changed
        # inside it: dropping some of its intervals would leave a mixture that names the
        # wrong parameter); a single interval is kept from making a fault by the
        # influence rule of the predicates
        fit = window_exact_fit(
            triad_form(tri),  # the certificate converted once for the window's fits
            means,
            mvar,
            g_in,
            interval_labels(intervals),
            config.min_dof,
            prior_factor=config.prior_factor,
            determined_std_ratio=config.determined_std_ratio,
        )
    if method != "linear":
        fit.require_redundancy(fit.dof, config.min_dof, range(9), f"{len(intervals)} intervals")
    _with_reason(
        fit,
        range(9),
        f"{attitudes} distinct attitude(s) in the window (at least 9 well-spread needed)",
    )
    return fit


#: Smallest rotation (path length, deg) of a motion the rotation fit uses.
MIN_ROTATION_DEG = 5.0
#: Largest condition number (dimensionless) of the gyro rotation fit's limit-scaled
#: information matrix that is reported: above it the smallest eigenvalue is within about
#: a hundred roundings of zero (rounding noise of the Jacobian), and the window is singular
CONDITION_RESOLUTION = 1.0 / (100.0 * float(np.finfo(float).eps))


def clipped(raw: np.ndarray, rest: np.ndarray, sigma: np.ndarray, min_repeat: int = 3) -> bool:
    """Whether a gyro channel sat at its extreme value (clipping: the range was exceeded).

    ``raw`` (M, 3) outputs of a motion, ``rest`` (3,) the rest output, ``sigma``
    (3,) the per-sample noise (output units). Clipped when a channel's largest
    or smallest value, far from rest (over 20 sigma), occurs ``min_repeat``
    times or more: a noisy signal does not repeat its extreme exactly.
    """
    for extreme in (raw.max(axis=0), raw.min(axis=0)):
        hits = np.sum(raw == extreme, axis=0)
        if np.any((hits >= min_repeat) & (np.abs(extreme - rest) > 20.0 * sigma)):
            return True
    return False


def _usable_key(gyro: TriadModel, max_step: float, min_path: float) -> tuple:
    """The memo key of a motion's screening (:func:`_motion_usable`) for a gyro model and
    its limits (rad per sample, rad)."""
    return ("usable", max_step, min_path, *scale_key(gyro))


def _motion_usable(
    gyro: TriadModel,
    prev: QuasiStaticInterval,
    seg: MotionSegment,
    max_step: float,
    min_path: float,
    key: tuple | None = None,
) -> bool:
    """Whether a motion after interval ``prev`` turned slowly enough (``max_step`` rad per
    sample at most), far enough (``min_path`` rad) and never clipped; kept in the motion's
    memo per gyro scale (the same motion is screened again in every window of its
    interval). ``key``: :func:`_usable_key` made once by a caller that screens many."""
    key = key or _usable_key(gyro, max_step, min_path)
    if key in seg.memo:
        return bool(seg.memo[key])
    rate = (seg.gyro - prev.gyro_mean) / gyro.scale_factor * gyro.unit_to_si
    steps = np.linalg.norm(rate[:-1], axis=1) * np.diff(seg.t)
    usable = not (np.max(steps) > max_step or np.sum(steps) < min_path)
    if usable:
        sigma = np.sqrt(np.maximum(np.diag(prev.gyro_cov), 1e-30))
        usable = not clipped(seg.gyro, prev.gyro_mean, sigma)
    seg.memo[key] = usable
    return usable


def rotation_pairs(
    cert: Certificate, accel: TriadModel, intervals: list[QuasiStaticInterval]
) -> list[RotationPair]:
    """Usable motions between consecutive intervals of the window, as rotation-fit input.

    A motion is skipped when it turned less than ``MIN_ROTATION_DEG`` (it says
    nothing about scale or misalignment), when the stream broke inside it, when it was longer
    than the collector keeps, when a sample was flagged saturated, when a gyro
    channel clipped, or when it turned faster than ``MAX_STEP_DEG`` per sample
    (the gyro integral of so coarse a sampling cannot be trusted).
    """
    pairs: list[RotationPair] = []
    g_in = cert.gravity / accel.unit_to_si
    gyro = cert.gyro
    max_step = math.radians(MAX_STEP_DEG)
    min_path = math.radians(MIN_ROTATION_DEG)
    screened = _usable_key(gyro, max_step, min_path)
    # every interval's unit specific force in this window's accelerometer model, and
    # whether it has one (a zero vector has no direction)
    ups: np.ndarray | None = None
    positive: list[bool] = []
    key: tuple | None = None  # the direction variance's memo key (this accelerometer scale)
    for i, (prev, cur) in enumerate(zip(intervals[:-1], intervals[1:], strict=True)):
        seg = cur.before
        if seg is None or not seg.usable or cur.index != prev.index + 1 or seg.t.shape[0] < 2:
            continue
        usable = seg.memo.get(screened)  # (screened in an earlier window of its interval)
        if usable is None:
            usable = _motion_usable(gyro, prev, seg, max_step, min_path, screened)
        if not usable:
            continue
        if ups is None:
            f_all = accel.inverse(np.array([iv.accel_mean for iv in intervals]))
            nf = np.linalg.norm(f_all, axis=1)
            positive = (nf > 0).tolist()
            ups = np.divide(f_all, nf[:, None], out=np.zeros_like(f_all), where=nf[:, None] > 0)
        if not (positive[i] and positive[i + 1]):
            continue
        if "pair" not in seg.memo:  # the two intervals' figures, the same in every window
            seg.memo["pair"] = (
                0.5 * (prev.gyro_mean + cur.gyro_mean),
                0.25 * (prev.mean_var("gyro") + cur.mean_var("gyro")),
                (prev.mean_var("accel") + cur.mean_var("accel")) / 2.0,
            )
        bias, bias_var, accel_var = seg.memo["pair"]
        if key is None:
            key = ("dir_var", float(g_in), np.asarray(accel.scale_factor, dtype=float).tobytes())
        if key not in seg.memo:  # the same accelerometer scale in every window
            seg.memo[key] = float(np.mean(accel_var / accel.scale_factor**2)) / g_in**2
        pairs.append(
            RotationPair(
                t=seg.t,
                raw=seg.gyro,
                bias=bias,
                up0=ups[i],
                up1=ups[i + 1],
                dir_var=seg.memo[key],
                bias_var=bias_var,
                memo=seg.memo,
            )
        )
    return pairs


def count_rotations(pairs: list[RotationPair], separation_deg: float) -> int:
    """Motions that turned the gravity direction by more than ``separation_deg``."""
    c = math.cos(math.radians(separation_deg))
    return int(sum(1 for p in pairs if np.dot(p.up0, p.up1) < c))


def gyro_window_fit(
    cert: Certificate,
    intervals: list[QuasiStaticInterval],
    config: DiagnosisConfig,
    method: str,
    accel_model: TriadModel,
    attitudes: int,
) -> tuple[TriadFit, int]:
    """The gyro fit of one window and the number of rotations it used."""
    tri = cert.gyro
    means, mvar, covs, counts = _stack(intervals, "gyro")
    means = _temperature_corrected(tri, means, [iv.temp for iv in intervals])
    w_in = cert.earth_rate / tri.unit_to_si
    mode = config.gyro_mode
    if mode == "auto":
        mode = "earth-rate" if earth_rate_observable(cert) else "rotation"
    if method == "linear":
        fit = linear_fit(
            tri, means, covs, counts, w_in, config.determined_std_ratio, config.prior_factor
        )
        _with_reason(fit, range(9), f"{attitudes} distinct attitude(s); |w| = Earth rate (eq. 8)")
        return fit, 0
    if mode == "earth-rate":
        fit = window_exact_fit(
            triad_form(tri),
            means,
            mvar,
            w_in,
            interval_labels(intervals),
            config.min_dof,
            prior_factor=config.prior_factor,
            determined_std_ratio=config.determined_std_ratio,
            method="exact-earth-rate",
        )
        fit.require_redundancy(fit.dof, config.min_dof, range(9), f"{len(intervals)} intervals")
        _with_reason(
            fit,
            range(9),
            f"{attitudes} distinct attitude(s) in the window (at least 9 well-spread needed)",
        )
        return fit, 0

    pairs = rotation_pairs(cert, accel_model, intervals)
    rotations = count_rotations(pairs, config.attitude_separation_deg)
    rot = None
    if rotations:
        # the mean of the intervals' per-axis variances (the same sums in the same order as
        # np.mean of their diagonals stacked)
        sample_var = covs.diagonal(axis1=1, axis2=2).mean(axis=0)
        rot = rotation_fit(
            tri,
            pairs,
            sample_var,
            cert.earth_rate,
            prior_factor=config.prior_factor,
            fit_frame=True,
        )
    fit = rest_rotation_fit(
        tri,
        means,
        mvar,
        counts,
        cert.earth_rate,
        rot,
        config.determined_std_ratio,
        f"; {rotations} rotation(s) between static poses in the window",
        starts=np.array([iv.t_start for iv in intervals]),
    )
    rot_dof = fit.dof
    if rot is not None:
        scale = np.concatenate([tri.scale_factor, np.ones(3)])
        lim_int = fit.limit[3:] / scale
        m = rot.info * np.outer(lim_int, lim_int)
        ev = np.linalg.eigvalsh(m)
        # beyond CONDITION_RESOLUTION the smallest eigenvalue is rounding noise (a window
        # whose motions leave a direction unseen): singular, reported as null
        resolved = ev[0] > ev[-1] / CONDITION_RESOLUTION
        fit.condition = float(ev[-1] / ev[0]) if resolved else float("inf")
        fit.rms_residual = rot.rms
        fit.extra.update({"rotation_rms_rad": rot.rms, "frame_rad": [float(v) for v in rot.frame]})
        if rot.loo_deviation is not None:
            # each motion left out: the shape moves, the rest biases do not
            loo = np.tile(fit.estimate - fit.certificate, (len(pairs), 1))
            loo[:, 3:] = rot.loo_deviation * scale
            fit.loo_deviation = loo
            fit.point_labels = motion_labels(pairs)
    if rotations:
        fit.require_redundancy(rot_dof, config.min_dof, range(3, 9), f"{len(pairs)} motions")
    return fit, rotations


def known_rate_window_fit(
    cert: Certificate, intervals: list[QuasiStaticInterval], config: DiagnosisConfig
) -> TriadFit:
    """The gyro fit of one window of turntable plateaus at ``config.known_rate_rad_s``.

    Plateaus off the rate (stopped, another speed) are left out and listed
    (``plateaus_set_aside``); the others are fitted with the table rate as the
    magnitude (outliers rejected unless the window spans a step change, as in
    :func:`accel_window_fit`).
    """
    tri = cert.gyro
    assert config.known_rate_rad_s is not None
    rate_in = config.known_rate_rad_s / tri.unit_to_si
    keep, set_aside = classify_plateaus(tri, intervals, rate_in)
    plateaus = [iv for iv, k in zip(intervals, keep, strict=True) if k]
    if len(plateaus) < 2:
        fit = undetermined_fit(
            tri,
            "exact-known-rate",
            f"{len(plateaus)} plateau(s) at the known rate in the window (2 or more needed)",
        )
    else:
        means, mvar, _covs, _counts = _stack(plateaus, "gyro")
        means = _temperature_corrected(tri, means, [iv.temp for iv in plateaus])
        fit = window_exact_fit(
            tri,
            means,
            mvar,
            rate_in,
            interval_labels(plateaus),
            config.min_dof,
            prior_factor=config.prior_factor,
            determined_std_ratio=config.determined_std_ratio,
            method="exact-known-rate",
        )
        fit.require_redundancy(fit.dof, config.min_dof, range(9), f"{len(plateaus)} plateaus")
        _with_reason(fit, range(9), f"{len(plateaus)} plateau(s) at the known rate")
    if set_aside:
        fit.extra["plateaus_set_aside"] = set_aside
    return fit


def diagnose_window(
    cert: Certificate,
    intervals: list[QuasiStaticInterval],
    config: DiagnosisConfig,
    index: int = 0,
) -> WindowResult:
    """Both triads' fits over ``intervals`` (in time order) with ``config.method``."""
    method = config.method
    if not intervals:
        raise ValueError("a window needs at least one interval")
    if config.known_rate_rad_s is not None:
        attitudes, rotations = 0, 0
        acc = undetermined_fit(
            cert.accel,
            "kept",
            "known-rate session: the accelerometers are not diagnosed on a turntable",
        )
        gyr = known_rate_window_fit(cert, intervals, config)
    else:
        attitudes = distinct_attitudes(
            np.array([iv.up for iv in intervals]), config.attitude_separation_deg
        )
        acc = accel_window_fit(cert, intervals, config, method, attitudes)
        accel_model = model_with(cert.accel, acc.estimate)
        gyr, rotations = gyro_window_fit(cert, intervals, config, method, accel_model, attitudes)
    judgements = {}
    for name, fit in (("accel", acc), ("gyro", gyr)):
        judgements[name] = judge(fit, config.k_sigma)
        hb = held_back(fit, config.k_sigma, fit.point_labels or [], judgements[name])
        if hb:
            fit.extra["held_back"] = hb
    return WindowResult(
        index=index,
        t_start=intervals[0].t_start,
        t_end=intervals[-1].t_end,
        intervals=len(intervals),
        attitudes=attitudes,
        rotations=rotations,
        accel=acc,
        gyro=gyr,
        method=method,
        judgements=judgements,
    )


__all__ = [
    "WindowResult",
    "attitude_groups",
    "diagnose_window",
    "distinct_attitudes",
    "model_with",
    "rotation_pairs",
]
