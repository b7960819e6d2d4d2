"""Scalar calibration from a multi-position session: the method the diagnosis rests on.

From all quasi-static intervals of a log (one window, no sliding):

- accelerometers: biases and the symmetric part of N from |f| = g (the exact
  fit, or the paper's linear one, or the moving-base normal equations with
  independent magnitudes);
- gyros: biases at rest, and the shape of N plus the rotation of the gyro
  frame against the accelerometer frame from the rotations between
  intervals (navigation-grade gyros: the Earth-rate scalar fit instead).

Scale factors S, units, limits, the temperature and other extended blocks
come from the ``like`` certificate; the noise density is measured on the
intervals. Parameters the session cannot determine keep the ``like`` value
and are listed as undetermined.

Misalignment gauge (only N N^T is observable for a scalar fit): the
accelerometer N is written symmetric, N = P, i.e. each observable difference
split equally, ``D_xz = d1/2, D_yz = -d1/2`` and so on (see :mod:`.gauge`: exact
to all orders, and the frame it defines is the orthonormal frame nearest to the
accelerometer axes). The gyro N is P_g R where R is the gyro frame's measured
rotation against that accelerometer frame, so gyro-integrated rotations agree
with gravity directions measured by the accelerometers.
"""

from __future__ import annotations

import copy
import datetime as _dt
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..certificate import Certificate, Noise, TriadModel, Uncertainty, misalignment_of_n
from ..reports import CALIBRATION_FORMAT, header
from .config import DiagnosisConfig
from .gauge import n_symmetric, p_matrix, shape_of_triad, small_rotation
from .gyro_fit import (
    RotationFitResult,
    RotationPair,
    earth_rate_observable,
    gyro_sample_var,
    rest_rotation_fit,
    rotation_fit,
    stack_pairs,
)
from .holdout import direction_errors, judge, rms, rotation_leave_one_out
from .intervals import QuasiStaticInterval
from .known_rate import classify_plateaus
from .params import (
    TriadFit,
    certificate_vector,
    limit_vector,
    sensor_of,
    triad_form,
    undetermined_fit,
)
from .robust import reject_outliers
from .scalar_fit import (
    RESIDUAL_FLOOR,
    NormalEquations,
    certificate_internal,
    exact_fit,
    internal_limits,
    linear_fit,
    normal_equation_fit,
    residuals_and_jacobian,
    robust_exact_fit,
)
from .window import (
    attitude_groups,
    count_rotations,
    distinct_attitudes,
    interval_labels,
    motion_labels,
    rotation_pairs,
)

#: Prior standard deviation (in limits) of the calibration fits: practically none.
CALIBRATION_PRIOR = 1e4
#: Effective degrees of freedom a calibration fit keeps: at least one redundant observation
#: (a fit with none reproduces its data exactly and reports a std that nothing checks).
CALIBRATION_MIN_DOF = 1.0
#: Prior standard deviation (in limits) that pins a parameter the session cannot determine.
PINNED_PRIOR = 1e-6


def _pinned_fit(
    fit_once: Callable[[np.ndarray, bool], TriadFit], min_dof: float = 0.0
) -> tuple[TriadFit, np.ndarray]:
    """Fit, pinning at the ``like`` value the parameters the session cannot determine.

    ``fit_once(prior_factor (9,), probe)`` fits with those prior widths (in
    limits); with ``probe`` it only linearises at the ``like`` certificate.
    Without a prior, a parameter the session cannot see makes the others'
    covariance explode through their correlation, and the fit wanders off along
    the unobserved direction. So: first, from the linearisation at ``like``,
    pin the worst parameter (largest std / limit) until the rest are
    determined; then fit, and pin more if the converged fit still leaves some
    undetermined. A fit with fewer than ``min_dof`` effective degrees of
    freedom has no redundancy to check its own standard deviations (6 intervals
    for 9 parameters fit exactly and report a tiny std): its worst shape
    parameter (scale factor or misalignment; a bias only when none is left) is
    pinned too, until the redundancy is there. Pinned parameters are reported
    as undetermined with the reason of the first probe. Returns the fit and the
    prior widths (9,) it was made with.
    """
    pinned = np.zeros(9, dtype=bool)
    dof_reason: dict[int, str] = {}

    def prior(p: np.ndarray) -> np.ndarray:
        return np.where(p, PINNED_PRIOR, CALIBRATION_PRIOR)

    def pin_worst(fit: TriadFit) -> bool:
        und = ~fit.determined & ~pinned
        if not und.any() and np.isfinite(fit.dof) and fit.dof < min_dof - 1e-6:
            und = ~pinned & (np.arange(9) >= 3)
            if not und.any():
                und = ~pinned
            if not und.any():
                return False
            i = int(np.argmax(np.where(und, fit.std / fit.limit, -np.inf)))
            dof_reason[i] = (
                f"{fit.dof:.1f} degrees of freedom left, {min_dof:g} needed to check the fit"
            )
            pinned[i] = True
            return True
        if not und.any():
            return False
        pinned[int(np.argmax(np.where(und, fit.std / fit.limit, -np.inf)))] = True
        return True

    first = fit_once(prior(pinned), True)
    probe = first
    while pin_worst(probe):
        probe = fit_once(prior(pinned), True)
    fit = fit_once(prior(pinned), False)
    while pin_worst(fit):
        fit = fit_once(prior(pinned), False)
    for i in np.flatnonzero(pinned).tolist():
        fit.determined[i] = False
        fit.std[i] = np.inf
        fit.estimate[i] = fit.certificate[i]  # literally the --like value
        why = (
            dof_reason.get(i)
            or first.reasons[i]
            or fit.reasons[i]
            or "correlated with parameters it cannot see"
        )
        fit.reasons[i] = f"not determined by the session ({why}): kept from --like"
    fit.extra["pinned"] = int(pinned.sum())
    return fit, prior(pinned)


#: The parameter classes whose prior width is widened together (:func:`prior_inflation`).
PRIOR_CLASSES = ("bias", "scale_factor", "misalignment")
#: A parameter is "decided by the prior" when the prior carries more than this share of its
#: estimate (posterior variance / prior variance; the prior weight / data information ratio
#: is share / (1 - share)).
PRIOR_DECIDES = 0.5


def certificate_prior(like: TriadModel) -> tuple[np.ndarray, list[str]]:
    """The ``--like`` certificate's own stated uncertainty as a Gaussian prior: its std (9,)
    in units of the limits and where each comes from (``uncertainty``: the certificate's
    ``uncertainty`` block, a calibration's; ``limit``: none stated, the limit taken as 1
    sigma, the widest deviation the certificate calls healthy)."""
    lim = limit_vector(like)
    stated = like.uncertainty.vector() if like.uncertainty is not None else np.full(9, np.nan)
    ok = np.isfinite(stated) & (stated > 0) & (lim > 0)
    width = np.where(ok, stated / np.where(lim > 0, lim, 1.0), 1.0)
    return width, ["uncertainty" if o else "limit" for o in ok.tolist()]


#: Prior scales tried per class by :func:`prior_inflation` (from the certificate's own width
#: to 10^4 times it, ratio 1.06 between neighbours).
INFLATION_GRID = np.geomspace(1.0, 1.0e4, 161)


def prior_inflation(
    like: TriadModel,
    data: tuple[np.ndarray, np.ndarray, float],
    fit: TriadFit,
    width: np.ndarray,
) -> np.ndarray:
    """Factor (3,) >= 1 per parameter class (bias, scale factor, misalignment) by which the
    data show the certificate's stated width ``width`` (9,) in limits too narrow: the
    type-II maximum likelihood (empirical Bayes) scale of each class's prior.

    The parameters of one class are exchangeable under the certificate (each deviates from
    ``--like`` by about its stated width times the class's scale tau). The data
    ``(means (K, 3) output units, their variances (K, 3), reference magnitude in input
    units)`` of the exact fit are linearised at ``fit``'s estimate (with its excess
    scatter) and the marginal likelihood of the data under the prior N(like, (width tau
    limit)^2) is maximised over the three tau (coordinate ascent on
    :data:`INFLATION_GRID`): a class whose deviations the stated width explains keeps 1
    (the certificate is not trusted beyond what it states); a class the data do not see
    leaves the likelihood flat and keeps 1; the parameters of a class are pooled, so a
    class member the data barely see gets the scale its determined siblings show. This
    replaced (issue 29) a moment estimate with a chi^2 gate that a nominal certificate's
    one 2.3 % scale error could widen 3-4 fold for every axis. Left out by attitude inside
    each recording (benchmarks/calibration_prior.py) it predicts imucal's faces 1.4x better
    (44 -> 31 mg), the Xsens session alike and the MPU-6050 within 4 %.
    """
    means, mvar, magnitude = data
    if fit.kept is not None and fit.kept.shape[0] == means.shape[0]:
        means, mvar = means[fit.kept], mvar[fit.kept]
    form = triad_form(like)
    m0 = float(magnitude)
    s = form.scale_factor
    theta_c, _ = certificate_internal(form, m0)
    lim = internal_limits(form, m0)
    theta = theta_c + np.where(
        np.isfinite(fit.estimate), (fit.estimate - fit.certificate) / form.scale(m0), 0.0
    )
    v = np.asarray(means, dtype=float) / (s * m0)
    r, jac, w = residuals_and_jacobian(theta, v, np.ones(v.shape[0]))
    var_v = np.asarray(mvar, dtype=float) / (s * m0) ** 2
    wgt = 1.0 / (np.einsum("kj,kj->k", w * w, var_v) + RESIDUAL_FLOOR**2 + fit.excess_var)
    z0 = r + jac @ (theta_c - theta)  # residuals at --like, linearised
    info = jac.T @ (jac * wgt[:, None])
    b = jac.T @ (wgt * z0)
    ok = np.isfinite(info).all() and np.isfinite(b).all() and np.all(width * lim > 0)
    tau = np.ones(3)
    if not ok:
        return tau

    def log_evidence(t: np.ndarray) -> np.ndarray:
        """Log marginal likelihood (nats, up to a constant) of each row of scales t (G, 3)."""
        prec = 1.0 / (width * np.repeat(t, 3, axis=1) * lim) ** 2  # (G, 9)
        a = info[None, :, :] + prec[:, :, None] * np.eye(9)[None, :, :]
        try:
            sol = np.linalg.solve(a, np.broadcast_to(b, prec.shape)[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            return np.full(t.shape[0], -np.inf)
        _, logdet = np.linalg.slogdet(np.eye(9)[None, :, :] + info[None, :, :] / prec[:, :, None])
        return 0.5 * (sol @ b) - 0.5 * logdet

    for _sweep in range(3):
        before = tau.copy()
        for c in range(3):
            trial = np.repeat(tau[None, :], INFLATION_GRID.shape[0], axis=0)
            trial[:, c] = INFLATION_GRID
            tau[c] = INFLATION_GRID[int(np.argmax(log_evidence(trial)))]
        if np.array_equal(tau, before):
            break
    return tau


def _regularised_fit(
    fit_once: Callable[[np.ndarray, bool], TriadFit],
    like: TriadModel,
    data: tuple[np.ndarray, np.ndarray, float],
    min_dof: float = 0.0,
) -> tuple[TriadFit, np.ndarray]:
    """Fit with a Gaussian prior at the ``--like`` certificate (issue 29), so parameters the
    session determines weakly are decided by data and certificate in proportion to what
    each knows, instead of being pinned at ``--like``.

    The prior's std is the certificate's stated uncertainty, else its limit
    (:func:`certificate_prior`), widened per class by what the determined parameters show
    (:func:`prior_inflation` on ``data``: the fit's means (K, 3), their variances (K, 3),
    output units, and the reference magnitude, input units, linearised at the fit of
    :func:`_pinned_fit`). Every parameter
    carries it, and its posterior std (the calibration's std) includes it. A fit still
    short of ``min_dof`` degrees of freedom pins its worst shape parameter as
    :func:`_pinned_fit` does. The fit's ``extra["prior"]`` lists the widths (certificate
    units), where they come from, the inflation, the parameter names and each one's prior
    share (the prior's weight in its estimate, posterior / prior variance) and
    ``prior_to_data`` (share / (1 - share): the prior's weight against the data's
    information); parameters the prior decides (share above
    :data:`PRIOR_DECIDES`) are named in ``decided_by_prior`` and their reason says so.
    Returns the fit and the prior widths (9,) in limits it was made with.
    """
    first, _ = _pinned_fit(fit_once, min_dof)
    base, source = certificate_prior(like)
    tau = prior_inflation(like, data, first, base)
    width = base * np.repeat(tau, 3)
    pinned = np.zeros(9, dtype=bool)
    fit = fit_once(np.where(pinned, PINNED_PRIOR, width), False)
    while np.isfinite(fit.dof) and fit.dof < min_dof - 1e-6:
        cand = ~pinned & (np.arange(9) >= 3)
        if not cand.any():
            cand = ~pinned
        if not cand.any():
            break
        pinned[int(np.argmax(np.where(cand, fit.std / fit.limit, -np.inf)))] = True
        fit = fit_once(np.where(pinned, PINNED_PRIOR, width), False)
    sigma = width * fit.limit
    # posterior over prior variance, before the covariance was scaled for the residual
    # scatter (that scaling widens the std, not the prior's weight)
    var = fit.std**2 / max(fit.cov_scale, 1.0)
    share = np.where(
        np.isfinite(fit.std), np.minimum(1.0, var / np.where(sigma > 0, sigma, 1.0) ** 2), 1.0
    )
    names = [f"{sensor_of(like.name, i)} {PRIOR_CLASSES[i // 3]}" for i in range(9)]
    decided = []
    for i in range(9):
        if pinned[i]:
            fit.determined[i] = False
            fit.std[i] = np.inf
            fit.estimate[i] = fit.certificate[i]  # literally the --like value
            fit.reasons[i] = (
                f"not determined by the session ({fit.dof:.1f} degrees of freedom left, "
                f"{min_dof:g} needed to check the fit): kept from --like"
            )
            share[i] = 1.0
        elif not fit.determined[i]:
            why = fit.reasons[i] or "correlated with parameters it cannot see"
            fit.reasons[i] = (
                f"not determined by the session ({why}): regularised toward --like, the prior "
                f"{share[i]:.0%} of the estimate"
            )
        if share[i] > PRIOR_DECIDES:
            decided.append(names[i])
    fit.extra["pinned"] = int(pinned.sum())
    fit.extra["prior"] = {
        "std": [float(x) for x in sigma],
        "source": source,
        "inflation": {c: float(t) for c, t in zip(PRIOR_CLASSES, tau, strict=True)},
        "parameters": names,
        "share": [float(x) for x in share],
        # the prior's weight against the data's information (null: the data add none)
        "prior_to_data": [float(x / (1.0 - x)) if x < 1.0 else None for x in share],
        "decided_by_prior": decided,
    }
    return fit, np.where(pinned, PINNED_PRIOR, width)


def state_uncertainty(triad: TriadModel, fit: TriadFit) -> None:
    """Write the calibration's own std into ``triad.uncertainty`` (the certificate it
    writes): the fit's std for each parameter it determined or regularised toward
    ``--like`` (the posterior std), the ``--like`` value's stated std (NaN: none) for each
    it kept; a diagnosis against this certificate adds it to the
    std of each deviation (:mod:`.predicates`)."""
    kept = triad.uncertainty.vector() if triad.uncertainty is not None else np.full(9, np.nan)
    # a fit regularised toward --like (:func:`_regularised_fit`) states the posterior std of
    # every parameter, the prior's included; a fit without a prior only those it determined
    own = np.asarray(fit.determined, dtype=bool) | ("prior" in fit.extra)
    std = np.where(own & np.isfinite(fit.std), fit.std, kept)
    triad.uncertainty = (
        Uncertainty(std[:3].copy(), std[3:6].copy(), std[6:9].copy())
        if np.any(np.isfinite(std))
        else None
    )


@dataclass
class CalibrationResult:
    """A calibrated certificate and how well the session determined it."""

    certificate: Certificate
    method: str
    intervals: int
    attitudes: int
    rotations: int
    accel: TriadFit
    gyro: TriadFit
    accel_spread_before: dict[str, float] | None  #: None: accelerometers not calibrated
    accel_spread_after: dict[str, float] | None
    rotation_rms_before_deg: float | None = None
    rotation_rms_after_deg: float | None = None
    undetermined: list[dict] = field(default_factory=list)
    #: held-out check (:func:`_leave_one_out`) of the accelerometers (of the gyros with a known
    #: rate), None where not run
    generalisation: dict[str, Any] | None = None
    #: held-out check of the MEMS gyros' rotation calibration
    #: (:func:`.holdout.rotation_leave_one_out`), None where not run
    gyro_generalisation: dict[str, Any] | None = None
    #: the known-rate route: rate (rad/s), plateaus used and set aside, |w|/rate - 1 spreads
    known_rate: dict[str, Any] | None = None
    #: the unit's white noise measured from the recording beside the certificate's (the
    #: reports' ``noise`` object), where the caller measured it
    noise: dict[str, Any] | None = None
    #: per-point residuals behind the spreads, for plots: ``accel_norm`` (|f|/g - 1 of each
    #: interval, dimensionless), ``rotation`` (gravity direction after each rotation, deg),
    #: ``gyro_norm`` (known rate: |w|/rate - 1 of each plateau); each holds ``t`` (s, the
    #: interval's middle or the rotation's end), ``before`` (with --like) and ``after``
    residuals: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    #: the still runs of the recording: ``found``, ``used`` and ``dropped`` ({why: count}),
    #: where the caller collected them (:func:`.session.collect_intervals`)
    holds: dict[str, Any] | None = None
    #: the stuck outputs of the recording (the monitor's check, :func:`..monitor.stuck.
    #: stuck_faults`), where the caller looked for them: each a reason to refuse
    stuck: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        for fit in (self.accel, self.gyro):
            state_uncertainty(self.certificate.triad(fit.triad), fit)

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary of the calibration."""
        return {
            **header(CALIBRATION_FORMAT),
            "method": self.method,
            "intervals": self.intervals,
            "attitudes": self.attitudes,
            "rotations": self.rotations,
            "accel_norm_spread": {
                "before": self.accel_spread_before,
                "after": self.accel_spread_after,
            },
            "rotation_residual_rms_deg": {
                "before": self.rotation_rms_before_deg,
                "after": self.rotation_rms_after_deg,
            },
            "accel": self.accel.to_json(),
            "gyro": self.gyro.to_json(),
            "undetermined": self.undetermined,
            "rejected": self.rejected(),
            "generalisation": self.generalisation,
            "gyro_generalisation": self.gyro_generalisation,
            "known_rate": self.known_rate,
            "holds": self.holds,
            "stuck": self.stuck,
        }

    def refusals(self) -> list[str]:
        """Why the calibration is refused: a stuck output of the recording, the held-out
        checks that failed; or []."""
        from ..monitor.stuck import stuck_words  # the monitor's, loaded by the pass

        stuck = [
            f"{f['triad']} {f['sensor']} stuck ({stuck_words(f)}): a stuck output cannot be "
            "calibrated"
            for f in self.stuck
        ]
        return stuck + [
            c["reason"]
            for c in (self.generalisation, self.gyro_generalisation)
            if c is not None and c.get("generalises") is False
        ]

    def rejected(self) -> list[dict]:
        """Intervals (or motions) the fits rejected as outliers, with the triad and why."""
        out = []
        for fit in (self.accel, self.gyro):
            for r in fit.extra.get("plateaus_set_aside", []):
                out.append(dict(r, triad=fit.triad))
            for r in fit.extra.get("rejected", []):
                out.append(dict(r, triad=fit.triad))
            if fit.extra.get("outliers"):
                out.append({"triad": fit.triad, "point": None, "reason": fit.extra["outliers"]})
        return out


def fields_from_n(n: np.ndarray, scale_factor: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
    """Certificate fields (E (3,) output per input unit, misalignment dict rad) of a general N."""
    e = (np.diag(n) - 1.0) * scale_factor
    return e, misalignment_of_n(n)


def _set_from_fit(out: TriadModel, like: TriadModel, fit: TriadFit) -> None:
    """Write a fit's bias and N (the certificate's rotation kept, the fitted symmetric
    shape applied) into the certificate triad ``out``."""
    shape_c, q = shape_of_triad(like)
    dev = fit.estimate - certificate_vector(like)
    shape = shape_c + np.concatenate([dev[3:6] / like.scale_factor, dev[6:9]])
    out.bias = fit.estimate[:3].copy()
    out.scale_factor_error, out.misalignment = fields_from_n(p_matrix(shape) @ q, like.scale_factor)


def spread(r: np.ndarray) -> dict[str, float]:
    """RMS, std, peak-to-peak and largest magnitude of residuals ``r`` (their unit)."""
    return {
        "rms": float(np.sqrt(np.mean(r * r))),
        "std": float(np.std(r)),
        "peak_to_peak": float(np.ptp(r)),
        "max_abs": float(np.max(np.abs(r))),
    }


def accel_norm_residuals(
    accel: TriadModel, intervals: list[QuasiStaticInterval], gravity: float
) -> np.ndarray:
    """|f| / g - 1 of each interval mean with ``accel``'s correction (dimensionless)."""
    means = np.array([iv.accel_mean for iv in intervals])
    return np.asarray(np.linalg.norm(accel.inverse_si(means), axis=1) / gravity - 1.0)


def accel_norm_spread(
    accel: TriadModel, intervals: list[QuasiStaticInterval], gravity: float
) -> dict[str, float]:
    """Spread of |f| / g - 1 over the interval means with ``accel``'s correction (dimensionless)."""
    return spread(accel_norm_residuals(accel, intervals, gravity))


def rotation_residuals_deg(gyro: TriadModel, pairs: list[RotationPair]) -> np.ndarray:
    """Angle (deg) between the gravity direction measured after each rotation and the one
    predicted by integrating the rotation with ``gyro``'s correction (the held-out check's
    measure, :func:`.holdout.direction_errors`)."""
    if not pairs:
        return np.zeros(0)
    ninv = np.linalg.inv(gyro.n_matrix())
    return np.degrees(direction_errors(pairs, stack_pairs(gyro, pairs), ninv))


def _rotation_rms_deg(gyro: TriadModel, pairs: list[RotationPair]) -> float | None:
    """RMS angle (deg) between the measured and the gyro-predicted gravity direction after
    each motion, with ``gyro``'s correction; None without motions."""
    if not pairs:
        return None
    return math.degrees(rms(np.radians(rotation_residuals_deg(gyro, pairs))))


def _noise_density(
    triad: TriadModel,
    intervals: list[QuasiStaticInterval],
    rate_hz: float,
    measured: dict[str, np.ndarray] | None = None,
) -> np.ndarray:
    """White-noise density (3,) output units/sqrt(Hz) to write: the one measured from the log
    (``measured[triad]``, :mod:`imudiag.noise_estimate`, the figure every command uses) where
    given and finite, else from the interval sample variances (which also hold bias wander
    and residual motion: 2x the white noise on the MPU-6050's gyros)."""
    m = None if measured is None else measured.get(triad.name)
    if m is not None and np.all(np.isfinite(m)) and np.all(np.asarray(m) > 0):
        return np.asarray(m, dtype=float)
    var = np.median(np.array([np.diag(iv.cov(triad.name)) for iv in intervals]), axis=0)
    return np.sqrt(var) / math.sqrt(rate_hz / 2.0)


def _undetermined(fit: TriadFit) -> list[dict]:
    return [
        {
            "triad": fit.triad,
            "sensor": sensor_of(fit.triad, i),
            "cause": ("bias", "scale_factor", "misalignment")[i // 3],
            "reason": fit.reasons[i],
        }
        for i in range(9)
        if not fit.determined[i]
    ]


def calibrate(
    intervals: list[QuasiStaticInterval],
    like: Certificate,
    method: str = "exact",
    rate_hz: float | None = None,
    moving: dict[str, tuple[NormalEquations, float]] | None = None,
    config: DiagnosisConfig | None = None,
    source: str = "",
    noise_density: dict[str, np.ndarray] | None = None,
) -> CalibrationResult:
    """Calibrate from ``intervals`` (time order); returns the new certificate and figures.

    ``method``: exact | linear | moving-base (``moving`` then holds each triad's
    normal equations and reference magnitude m0 in input units). ``noise_density``:
    the white noise measured from the log per triad (output units/sqrt(Hz)), written
    to the certificate. The steps: the accelerometer fit (and its held-out check), the
    gyro fit on the calibrated accelerometers (Earth rate, or the rest biases and the
    rotations between holds), the note of how, the residuals before and after.
    """
    cfg = config or DiagnosisConfig()
    rate = float(rate_hz or like.sample_rate)
    if not intervals:
        raise ValueError("no quasi-static interval in the session: nothing to calibrate from")
    acc_fit, generalisation = _accel_calibration(intervals, like, method, moving, cfg)
    new = like.copy()
    new.sample_rate = rate
    acc = new.accel
    acc_like = like.accel
    shape_c, _ = shape_of_triad(acc_like)
    dev = acc_fit.estimate - certificate_vector(acc_like)
    acc_shape = shape_c + np.concatenate([dev[3:6] / acc_like.scale_factor, dev[6:9]])
    acc.bias = acc_fit.estimate[:3].copy()
    acc.scale_factor_error, acc.misalignment = n_symmetric(acc_like, acc_shape)
    acc.noise = _with_density(
        acc_like.noise, _noise_density(acc_like, intervals, rate, noise_density)
    )
    gyr = new.gyro
    gyr_fit, pairs, used_pairs, gyro_generalisation = _gyro_calibration(
        intervals, like, acc, gyr, method, moving, cfg
    )
    gyr_like = like.gyro
    gyr.noise = _with_density(
        gyr_like.noise, _noise_density(gyr_like, intervals, rate, noise_density)
    )
    rotations = count_rotations(pairs, cfg.attitude_separation_deg)
    new.device = _calibration_note(like, method, source, intervals, cfg, rotations)
    new.source = None
    residuals = _calibration_residuals(like, acc, gyr, intervals, used_pairs)
    return CalibrationResult(
        certificate=new,
        method=method,
        intervals=len(intervals),
        attitudes=distinct_attitudes(
            np.array([iv.up for iv in intervals]), cfg.attitude_separation_deg
        ),
        rotations=rotations,
        accel=acc_fit,
        gyro=gyr_fit,
        accel_spread_before=spread(residuals["accel_norm"]["before"]),
        accel_spread_after=spread(residuals["accel_norm"]["after"]),
        rotation_rms_before_deg=_rotation_rms_deg(gyr_like, used_pairs),
        rotation_rms_after_deg=_rotation_rms_deg(gyr, used_pairs),
        undetermined=_undetermined(acc_fit) + _undetermined(gyr_fit),
        generalisation=generalisation,
        residuals=residuals,
        gyro_generalisation=gyro_generalisation,
    )


def _accel_calibration(
    intervals: list[QuasiStaticInterval],
    like: Certificate,
    method: str,
    moving: dict[str, tuple[NormalEquations, float]] | None,
    cfg: DiagnosisConfig,
) -> tuple[TriadFit, dict[str, Any] | None]:
    """The accelerometers' fit (``method``, as :func:`calibrate`'s) and, for the exact
    fit, its held-out check by attitude groups (else None)."""
    ratio = cfg.determined_std_ratio
    acc_like = like.accel
    g_in = like.gravity / acc_like.unit_to_si
    means = np.array([iv.accel_mean for iv in intervals])
    mvar = np.array([iv.mean_var("accel") for iv in intervals])
    covs = np.array([iv.accel_cov for iv in intervals])
    counts = np.array([iv.n for iv in intervals], dtype=float)
    labels = interval_labels(intervals)
    if method == "moving-base":
        if not moving or "accel" not in moving:
            raise ValueError("the moving-base calibration needs independent accel magnitudes")
        ne, m0 = moving["accel"]
        acc_fit = normal_equation_fit(
            acc_like, ne, m0, "moving-base", ratio, prior_factor=CALIBRATION_PRIOR
        )
    elif method == "linear":
        acc_fit = linear_fit(acc_like, means, covs, counts, g_in, ratio, CALIBRATION_PRIOR)
    else:
        acc_fit, acc_prior = _regularised_fit(
            lambda pf, probe: (
                exact_fit(
                    acc_like,
                    means,
                    mvar,
                    g_in,
                    prior_factor=pf,
                    determined_std_ratio=ratio,
                    max_iter=0,
                    start="certificate",
                    scale_by_residual=False,
                )
                if probe
                else robust_exact_fit(
                    acc_like,
                    means,
                    mvar,
                    g_in,
                    labels=labels,
                    min_dof=CALIBRATION_MIN_DOF,
                    prior_factor=pf,
                    determined_std_ratio=ratio,
                    max_iter=100,
                )
            ),
            acc_like,
            (means, mvar, g_in),
            CALIBRATION_MIN_DOF,
        )
    generalisation = None
    if method == "exact":
        kept = acc_fit.kept if acc_fit.kept is not None else np.ones(len(means), dtype=bool)
        ups = np.array([iv.up for iv in intervals])[kept]
        generalisation = _leave_one_out(
            acc_like,
            means[kept],
            mvar[kept],
            g_in,
            acc_fit,
            acc_prior,
            ratio,
            groups=attitude_groups(ups, cfg.attitude_separation_deg),
        )
    return acc_fit, generalisation


def _gyro_calibration(
    intervals: list[QuasiStaticInterval],
    like: Certificate,
    acc: TriadModel,
    gyr: TriadModel,
    method: str,
    moving: dict[str, tuple[NormalEquations, float]] | None,
    cfg: DiagnosisConfig,
) -> tuple[TriadFit, list[RotationPair], list[RotationPair], dict[str, Any] | None]:
    """The gyros' fit, written into ``gyr`` (the new certificate's gyro), the accelerometers
    ``acc`` already calibrated: moving-base, Earth rate (navigation grade), or the rest
    biases and the rotations between holds (MEMS). Returns the fit, the rotation pairs,
    those the fit kept, and the rotations' held-out check (None where not run)."""
    ratio = cfg.determined_std_ratio
    counts = np.array([iv.n for iv in intervals], dtype=float)
    labels = interval_labels(intervals)
    gyr_like = like.gyro
    gmeans = np.array([iv.gyro_mean for iv in intervals])
    gmvar = np.array([iv.mean_var("gyro") for iv in intervals])
    gcovs = np.array([iv.gyro_cov for iv in intervals])
    w_in = like.earth_rate / gyr_like.unit_to_si
    pairs = rotation_pairs(like, acc, intervals)
    used_pairs = pairs
    gyro_generalisation = None
    mode = cfg.gyro_mode
    if mode == "auto":
        mode = "earth-rate" if earth_rate_observable(like) else "rotation"
    if method == "moving-base" and moving and "gyro" in moving:
        ne, m0 = moving["gyro"]
        gyr_fit = normal_equation_fit(
            gyr_like, ne, m0, "moving-base", ratio, prior_factor=CALIBRATION_PRIOR
        )
        _set_from_fit(gyr, gyr_like, gyr_fit)
    elif mode == "earth-rate":
        if method == "linear":
            gyr_fit = linear_fit(gyr_like, gmeans, gcovs, counts, w_in, ratio, CALIBRATION_PRIOR)
        else:
            gyr_fit, _ = _regularised_fit(
                lambda pf, probe: (
                    exact_fit(
                        gyr_like,
                        gmeans,
                        gmvar,
                        w_in,
                        prior_factor=pf,
                        determined_std_ratio=ratio,
                        max_iter=0,
                        method="exact-earth-rate",
                        start="certificate",
                        scale_by_residual=False,
                    )
                    if probe
                    else robust_exact_fit(
                        gyr_like,
                        gmeans,
                        gmvar,
                        w_in,
                        labels=labels,
                        min_dof=CALIBRATION_MIN_DOF,
                        prior_factor=pf,
                        determined_std_ratio=ratio,
                        max_iter=100,
                        method="exact-earth-rate",
                    )
                ),
                gyr_like,
                (gmeans, gmvar, w_in),
                CALIBRATION_MIN_DOF,
            )
        _set_from_fit(gyr, gyr_like, gyr_fit)
    else:
        gyr_fit, used_pairs, gyro_generalisation = _rest_rotation_calibration(
            like, gyr, intervals, pairs, cfg
        )
    return gyr_fit, pairs, used_pairs, gyro_generalisation


def _rest_rotation_calibration(
    like: Certificate,
    gyr: TriadModel,
    intervals: list[QuasiStaticInterval],
    pairs: list[RotationPair],
    cfg: DiagnosisConfig,
) -> tuple[TriadFit, list[RotationPair], dict[str, Any] | None]:
    """The MEMS gyros' route, written into ``gyr``: the rest biases and the rotations
    between holds (:func:`_gyro_rest_rotation`, pinned where the session cannot tell).
    Returns the fit, the rotation pairs it kept and their held-out check (None where not
    run)."""
    ratio = cfg.determined_std_ratio
    gyr_like = like.gyro
    gyro_generalisation = None
    n_holder: dict[str, np.ndarray] = {}
    rot_holder: dict[str, RotationFitResult] = {}

    def once(pf: np.ndarray, probe: bool) -> TriadFit:
        fit, n_holder["n"], n_holder["kept"], rot = _gyro_rest_rotation(
            like, gyr_like, intervals, pairs, cfg, pf, probe
        )
        if rot is not None:
            rot_holder["rot"] = rot
        return fit

    # pinned, not regularised: the rotation fit's shape is fitted with the frame rotation
    # free, and the frame is dropped where the rotations do not determine it, so a
    # regularised shape would carry what the frame took (30-60 mrad on 6 rotations)
    gyr_fit, gprior = _pinned_fit(once, CALIBRATION_MIN_DOF)
    n_g = n_holder["n"]
    used_pairs = [p for p, k in zip(pairs, n_holder["kept"], strict=True) if k]
    if gyr_fit.extra.get("frame_rad") is not None:
        # N from the final estimates, so pinned parameters are literally the --like values
        shape_c, q_c = shape_of_triad(gyr_like)
        scale = np.concatenate([gyr_like.scale_factor, np.ones(3)])
        dev = (gyr_fit.estimate[3:] - gyr_fit.certificate[3:]) / scale
        frame = np.asarray(gyr_fit.extra["frame_rad"]) if gyr_fit.extra["frame_applied"] else 0
        n_g = p_matrix(shape_c + dev) @ small_rotation(np.zeros(3) + frame) @ q_c
    gyr.bias = gyr_fit.estimate[:3].copy()
    gyr.scale_factor_error, gyr.misalignment = fields_from_n(n_g, gyr_like.scale_factor)
    if gyr_fit.extra.get("frame_rad") is not None and "rot" in rot_holder:
        gyro_generalisation = rotation_leave_one_out(
            like,
            used_pairs,
            rot_holder["rot"],
            gprior != PINNED_PRIOR,
            bool(gyr_fit.extra["frame_applied"]),
            ratio,
            np.linalg.inv(n_g),
            determined=np.asarray(gyr_fit.determined, dtype=bool),
        )
    return gyr_fit, used_pairs, gyro_generalisation


def _calibration_note(
    like: Certificate,
    method: str,
    source: str,
    intervals: list[QuasiStaticInterval],
    cfg: DiagnosisConfig,
    rotations: int,
) -> dict[str, Any]:
    """The new certificate's ``device`` (:func:`calibrated_device`) after a multi-position
    calibration."""
    return _calibrated_device(
        like,
        f"imudiag calibrate --method {method}"
        + (f" from {source}" if source else "")
        + f": {len(intervals)} quasi-static intervals, "
        f"{distinct_attitudes(np.array([iv.up for iv in intervals]), cfg.attitude_separation_deg)}"
        f" attitudes, {rotations} rotations",
    )


def _calibrated_device(like: Certificate, how: str) -> dict[str, Any]:
    """The ``device`` of a certificate calibrated from ``like``: ``like``'s, with the date
    and ``how`` it was made (``calibration``). A data-sheet ``like`` (``--like auto`` on an
    autopilot's log, or a file of config/datasheets) gives a calibration of this unit, no
    longer the part's typical figures: its ``datasheet`` key is dropped (the status would
    call the certificate a data sheet) and named in ``calibration``."""
    device = dict(like.device)
    sheet = device.pop("datasheet", None)
    device["calibrated"] = _dt.date.today().isoformat()
    device["calibration"] = how + (f"; like the data sheet {sheet}" if sheet else "")
    return device


def _calibration_residuals(
    like: Certificate,
    acc: TriadModel,
    gyr: TriadModel,
    intervals: list[QuasiStaticInterval],
    used_pairs: list[RotationPair],
) -> dict[str, dict[str, np.ndarray]]:
    """Per-point residuals before (``like``) and after (``acc``, ``gyr``): each interval's
    |f|/g - 1, and the gravity direction after each rotation kept (deg)."""
    mid_t = np.array([0.5 * (iv.t_start + iv.t_end) for iv in intervals])
    residuals: dict[str, dict[str, np.ndarray]] = {
        "accel_norm": {
            "t": mid_t,
            "before": accel_norm_residuals(like.accel, intervals, like.gravity),
            "after": accel_norm_residuals(acc, intervals, like.gravity),
        }
    }
    if used_pairs:  # the motions the calibration kept (rejected ones are listed apart)
        residuals["rotation"] = {
            "t": np.array([float(p.t[-1]) for p in used_pairs]),
            "before": rotation_residuals_deg(like.gyro, used_pairs),
            "after": rotation_residuals_deg(gyr, used_pairs),
        }
    return residuals


def _norm_residuals(triad: TriadModel, means: np.ndarray, magnitude_in: float) -> np.ndarray:
    """|x| / magnitude - 1 of interval means with ``triad``'s correction (dimensionless)."""
    return np.asarray(np.linalg.norm(triad.inverse(means), axis=1) / magnitude_in - 1.0)


def calibrate_known_rate(
    intervals: list[QuasiStaticInterval],
    like: Certificate,
    rate_rad_s: float,
    rate_hz: float | None = None,
    config: DiagnosisConfig | None = None,
    source: str = "",
    noise_density: dict[str, np.ndarray] | None = None,
) -> CalibrationResult:
    """Calibrate the gyros from turntable plateaus at a known rate (rad/s); the
    accelerometers are kept from ``like`` (a turntable adds centripetal acceleration, and
    the log may have no accelerometer columns).

    ``intervals``: plateaus found by a detector with :data:`.known_rate.PLATEAU_DETECTOR`.
    Plateaus off the rate (stopped, another speed) are set aside with the reason; the
    rest go through the outlier rejection and the pinning of :func:`calibrate`, and the
    held-out check is made on |w| / rate - 1.
    """
    cfg = config or DiagnosisConfig()
    rate = float(rate_hz or like.sample_rate)
    ratio = cfg.determined_std_ratio
    gyr_like = like.gyro
    rate_in = rate_rad_s / gyr_like.unit_to_si
    keep, set_aside = classify_plateaus(gyr_like, intervals, rate_in)
    plateaus = [iv for iv, k in zip(intervals, keep, strict=True) if k]
    if len(plateaus) < 2:
        raise ValueError(
            f"{len(plateaus)} plateau(s) at the known rate {rate_in:.4g} {gyr_like.input_unit} "
            f"among {len(intervals)} constant-rate intervals: nothing to calibrate from"
        )
    gmeans = np.array([iv.gyro_mean for iv in plateaus])
    gmvar = np.array([iv.mean_var("gyro") for iv in plateaus])
    labels = interval_labels(plateaus)
    gyr_fit, gprior = _regularised_fit(
        lambda pf, probe: (
            exact_fit(
                gyr_like,
                gmeans,
                gmvar,
                rate_in,
                prior_factor=pf,
                determined_std_ratio=ratio,
                max_iter=0,
                start="certificate",
                scale_by_residual=False,
                method="exact-known-rate",
            )
            if probe
            else robust_exact_fit(
                gyr_like,
                gmeans,
                gmvar,
                rate_in,
                labels=labels,
                min_dof=CALIBRATION_MIN_DOF,
                prior_factor=pf,
                determined_std_ratio=ratio,
                max_iter=100,
                method="exact-known-rate",
            )
        ),
        gyr_like,
        (gmeans, gmvar, rate_in),
        CALIBRATION_MIN_DOF,
    )
    if set_aside:
        gyr_fit.extra["plateaus_set_aside"] = set_aside
    kept = gyr_fit.kept if gyr_fit.kept is not None else np.ones(len(plateaus), dtype=bool)
    # the turntable's "attitude" is the mounting: plateaus whose rate points the same way in
    # the body share its errors, and another session of the unit is a new set of mountings
    axes = gyr_like.inverse(gmeans[kept])
    axes = axes / np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-300)
    generalisation = _leave_one_out(
        gyr_like,
        gmeans[kept],
        gmvar[kept],
        rate_in,
        gyr_fit,
        gprior,
        ratio,
        quantity="|w|/rate - 1",
        groups=attitude_groups(axes, cfg.attitude_separation_deg),
    )
    new = like.copy()
    new.sample_rate = rate
    gyr = new.gyro
    _set_from_fit(gyr, gyr_like, gyr_fit)
    gyr.noise = _with_density(
        gyr_like.noise, _noise_density(gyr_like, plateaus, rate, noise_density)
    )
    acc_fit = undetermined_fit(
        like.accel,
        "kept",
        "known-rate session: the accelerometers are not calibrated from turntable plateaus "
        "(centripetal acceleration; the log may have none)",
    )
    unit = gyr_like.input_unit
    new.device = _calibrated_device(
        like,
        f"imudiag calibrate --known-rate {rate_in:.6g} {unit}"
        + (f" from {source}" if source else "")
        + f": {len(plateaus)} plateaus ({len(set_aside)} set aside)",
    )
    new.source = None
    used = gmeans[kept]
    known = {
        "rate_rad_s": rate_rad_s,
        "rate": rate_in,
        "unit": unit,
        "plateaus": int(kept.sum()),
        "set_aside": len(set_aside),
        "norm_spread": {},
    }
    used_t = np.array(
        [0.5 * (iv.t_start + iv.t_end) for iv, k in zip(plateaus, kept, strict=True) if k]
    )
    gyro_norm = {
        "t": used_t,
        "before": _norm_residuals(gyr_like, used, rate_in),
        "after": _norm_residuals(gyr, used, rate_in),
    }
    known["norm_spread"] = {k: spread(gyro_norm[k]) for k in ("before", "after")}
    return CalibrationResult(
        certificate=new,
        method="exact-known-rate",
        intervals=len(intervals),
        attitudes=0,
        rotations=0,
        accel=acc_fit,
        gyro=gyr_fit,
        accel_spread_before=None,
        accel_spread_after=None,
        undetermined=_undetermined(acc_fit) + _undetermined(gyr_fit),
        generalisation=generalisation,
        known_rate=known,
        residuals={"gyro_norm": gyro_norm},
    )


def _leave_one_out(
    like: TriadModel,
    means: np.ndarray,
    mvar: np.ndarray,
    g_in: float,
    fit: TriadFit,
    prior: np.ndarray,
    ratio: float,
    quantity: str = "|a|/g - 1",
    groups: np.ndarray | None = None,
) -> dict[str, Any]:
    """Held-out check of a calibration (dimensionless ``quantity``: |a|/g - 1, or
    |w|/rate - 1 on a turntable; ``g_in`` the reference magnitude, input units).

    With ``groups`` (K,) (each interval's attitude, :func:`.window.attitude_groups`) the
    check leaves one attitude out at a time: all its intervals are predicted by the fit to
    the other attitudes (same prior ``prior``, in limits, and the same pinned parameters;
    a fold that leaves a parameter the whole session determines to the prior alone is
    essential and not held out), which is what another session of the unit
    asks of the calibration (intervals of one attitude share its errors, and an interval
    left out beside its siblings is predicted far too well). Where fewer than 3 attitudes
    can be left out (each is essential: without it a free parameter is unseen), the check
    falls back to leaving one interval out, and says so (``by``). The calibration
    generalises by the rule of :func:`.holdout.judge` (below the uncalibrated RMS, at most
    3 n / dof times the in-sample RMS, n the attitudes or intervals held out); a fit that
    only reproduces the holds it was made from fails, with the reason.
    """
    k = means.shape[0]

    def norm_err(triad: TriadModel, m: np.ndarray) -> np.ndarray:
        return np.linalg.norm(triad.inverse(m), axis=1) / g_in - 1.0

    def model_of(f: TriadFit) -> TriadModel:
        t = copy.deepcopy(like)
        shape_c, _ = shape_of_triad(like)
        dev = f.estimate - certificate_vector(like)
        t.bias = f.estimate[:3].copy()
        t.scale_factor_error, t.misalignment = n_symmetric(
            like, shape_c + np.concatenate([dev[3:6] / like.scale_factor, dev[6:9]])
        )
        return t

    inside = norm_err(model_of(fit), means)
    before = norm_err(like, means)
    # a fold is essential when it leaves a parameter the whole session determines undetermined
    # (decided by the prior alone it predicts nothing about the session)
    free = np.asarray(fit.determined, dtype=bool) & (prior != PINNED_PRIOR)

    def held_out(labels: np.ndarray) -> tuple[np.ndarray, int, int]:
        held = np.full(k, np.nan)
        essential = 0
        names = np.unique(labels)
        if names.size < 3:
            return held, 0, int(names.size)
        for name in names.tolist():
            out = labels == name
            if (~out).sum() < 3:
                essential += 1
                continue
            f = exact_fit(
                like,
                means[~out],
                mvar[~out],
                g_in,
                prior_factor=prior,
                determined_std_ratio=ratio,
                max_iter=100,
            )
            if np.any(free & ~f.determined):
                essential += 1  # without it a free parameter is unseen: nothing to predict
                continue
            held[out] = norm_err(model_of(f), means[out])
        return held, essential, int(names.size)

    by = "attitude"
    if groups is not None and k >= 3:
        labels = np.asarray(groups)
        held, essential, n_groups = held_out(labels)
        checked = np.unique(labels[np.isfinite(held)]).size
        if checked >= 3:
            # the observations of the rule are the attitudes, the redundancy theirs
            params = k - fit.dof if np.isfinite(fit.dof) else float(k)
            out = judge(
                inside,
                held,
                before,
                n_groups,
                n_groups - params,
                essential,
                quantity,
                point="attitude",
                uncalibrated_allowance=True,
            )
            worst = out.pop("worst_attitude")
            out["worst_attitude"] = None if worst is None else int(labels[worst])
            out["by"] = by
            out["attitudes"] = n_groups
            out["attitudes_held_out"] = int(checked)
            return out
        note = (
            f"{essential} of {n_groups} attitudes are essential (without any one of them a "
            "parameter is unseen): checked by leaving one interval out instead, which "
            "predicts another session of the unit less well"
        )
    else:
        note = ""
    by = "interval"
    held, essential, _ = held_out(np.arange(k)) if k >= 3 else (np.full(k, np.nan), 0, k)
    out = judge(inside, held, before, k, fit.dof, essential, quantity, uncalibrated_allowance=True)
    out["by"] = by
    if note:
        out["note"] = note
    return out


def _with_density(noise: Noise | None, density: np.ndarray) -> Noise:
    out = copy.deepcopy(noise) if noise is not None else Noise()
    out.density = np.asarray(density, dtype=float)
    return out


def _gyro_rest_rotation(
    like: Certificate,
    gyr_like: TriadModel,
    intervals: list[QuasiStaticInterval],
    pairs: list[RotationPair],
    cfg: DiagnosisConfig,
    prior_factor: np.ndarray,
    probe: bool = False,
) -> tuple[TriadFit, np.ndarray, np.ndarray, RotationFitResult | None]:
    """MEMS gyro calibration: rest bias, then shape and frame from the rotations.

    ``prior_factor`` (9,): prior std in limits per parameter (the bias entries unused).
    Unless ``probe``, motions that the fit to the others does not predict are rejected
    (:func:`.robust.reject_outliers`, as the intervals of the exact fits) and listed in
    the fit's ``extra["rejected"]``. Returns the fit, N (3, 3), the mask (pairs,) of
    the motions it kept and the rotation fit to them (None without rotations).
    """
    ratio = cfg.determined_std_ratio
    shape_c, q_c = shape_of_triad(gyr_like)
    n_g = gyr_like.n_matrix()
    extra: dict = {}
    kept = np.ones(len(pairs), dtype=bool)
    rot: RotationFitResult | None = None
    if count_rotations(pairs, cfg.attitude_separation_deg) > 0:
        sample_var = gyro_sample_var(intervals)

        def once(
            keep: np.ndarray, probe_i: int | None
        ) -> tuple[RotationFitResult, np.ndarray | None, float, float]:
            r = rotation_fit(
                gyr_like,
                [p for p, k in zip(pairs, keep, strict=True) if k],
                sample_var,
                like.earth_rate,
                prior_factor=prior_factor[3:],
                fit_frame=True,
                max_iter=0 if probe else 30,
                scale_by_residual=not probe,
                predict=None if probe_i is None else pairs[probe_i],
            )
            return r, r.point_z, r.dof, r.predicted_z

        rejected: list[dict] = []
        note = ""
        if probe:
            rfit = once(kept, None)[0]
        else:
            rfit, kept, rejected, note = reject_outliers(
                once, len(pairs), motion_labels(pairs), CALIBRATION_MIN_DOF
            )
        assert rfit.frame_cov is not None  # fit_frame=True: the frame rotation was fitted
        frame_std = np.sqrt(np.maximum(np.diag(rfit.frame_cov), 0.0))
        # the frame rotation goes into N only where the rotations determine it as well as a
        # misalignment must be (a rotation fitted from 2 turns would be written as 0.3 rad)
        frame_ok = bool(np.all(frame_std <= ratio * gyr_like.limits.misalignment))
        frame = rfit.frame if frame_ok else np.zeros(3)
        n_g = p_matrix(shape_c + rfit.deviation) @ small_rotation(frame) @ q_c
        extra = {
            "frame_rad": [float(v) for v in rfit.frame],
            "frame_std_rad": [float(v) for v in frame_std],
            "frame_applied": frame_ok,
            "rotation_rms_rad": rfit.rms,
            "motions": int(kept.sum()),
        }
        if rejected:
            extra["rejected"] = rejected
        if note:
            extra["outliers"] = note
        rot = rfit
    fit = rest_rotation_fit(
        gyr_like,
        np.array([iv.gyro_mean for iv in intervals]),
        np.array([iv.mean_var("gyro") for iv in intervals]),
        np.array([iv.n for iv in intervals], dtype=float),
        like.earth_rate,
        rot,
        ratio,
    )
    fit.extra = extra
    return fit, n_g, kept, rot


__all__ = [
    "CalibrationResult",
    "accel_norm_residuals",
    "accel_norm_spread",
    "calibrate",
    "fields_from_n",
    "rotation_residuals_deg",
    "spread",
]
