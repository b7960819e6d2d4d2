"""Held-out checks of a calibration: does it predict points it was not made from?

One rule for every calibration fit (the accelerometers' |a|/g - 1, a turntable's
|w|/rate - 1, the MEMS gyros' gravity direction after each rotation): each point
(interval, plateau or motion) is predicted by the fit to all the others with the
same pinned parameters, and the calibration generalises when the held-out RMS is
below the uncalibrated RMS (for rotations: beyond what the redundancy explains) and
at most :data:`LOO_RATIO_LIMIT` times the in-sample RMS beyond what the fit's
redundancy explains.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..certificate import Certificate
from .gauge import p_matrix, shape_of_triad, small_rotation
from .gyro_fit import RotationFitResult, RotationPair, predict_end_directions, stack_pairs
from .params import limit_vector

#: How the rotation check names its quantity: the angle between the measured gravity
#: direction after a motion and the one the gyro-integrated rotation predicts.
ROTATION_QUANTITY = "gravity direction after a rotation (rad)"

#: A calibration generalises when its leave-one-out residual is at most this many times
#: its in-sample residual, beyond what its redundancy explains: a correct fit of p
#: effective parameters to n observations already predicts held-out points about
#: n / (n - p) times worse than it fits them (in-sample residuals shrink by 1 - h,
#: held-out ones grow by 1 / (1 - h), h = p / n the mean leverage), 4x for 12 plateaus
#: and 9 parameters
LOO_RATIO_LIMIT = 3.0


def ratio_limit(observations: float, dof: float) -> float:
    """Largest held-out / in-sample RMS ratio accepted: 3 n / dof (dimensionless).

    ``observations`` n the scalar observations of the fit, ``dof`` its effective
    degrees of freedom (n less the parameters the data determine).
    """
    dof = dof if math.isfinite(dof) and dof > 0 else 1.0
    return LOO_RATIO_LIMIT * max(1.0, observations / min(max(dof, 1.0), float(observations)))


def rms(r: np.ndarray) -> float:
    """Root mean square of the finite entries of ``r`` (same unit as ``r``)."""
    return float(np.sqrt(np.nanmean(np.asarray(r, dtype=float) ** 2)))


def judge(
    inside: np.ndarray,
    held: np.ndarray,
    before: np.ndarray,
    observations: float,
    dof: float,
    essential: int,
    quantity: str,
    point: str = "interval",
    what: str = "holds",
    uncalibrated_allowance: bool = False,
) -> dict[str, Any]:
    """The held-out verdict, JSON-ready.

    ``inside`` (K,) in-sample residuals of the calibration, ``held`` (K,) each point's
    residual against the fit to the others (NaN: not held out), ``before`` (K,) the
    uncalibrated residuals, all in the unit of ``quantity``; ``observations`` and
    ``dof`` as :func:`ratio_limit`; ``essential`` points not held out because without
    them a free parameter is unseen. ``point`` / ``what`` name a point and the points
    in the reasons. ``generalises`` is None when fewer than 3 points could be held out.
    ``uncalibrated_allowance``: the held-out RMS may exceed the uncalibrated one by the
    factor n / dof the redundancy explains (when ``like`` is already right, a correct
    fit predicts held-out points that much worse than ``like`` does).
    """
    k = int(np.asarray(inside).shape[0])
    checked = int(np.isfinite(held).sum())
    limit = ratio_limit(observations, dof)
    dof_used = dof if math.isfinite(dof) and dof > 0 else 1.0
    out: dict[str, Any] = {
        "in_sample_rms": rms(inside),
        "leave_one_out_rms": rms(held) if checked else None,
        "uncalibrated_rms": rms(before),
        "held_out": checked,
        "essential": essential,
        "ratio_limit": limit,
        "quantity": quantity,
        "generalises": None,
        "reason": "",
    }
    loo = out["leave_one_out_rms"]
    worse = out["uncalibrated_rms"]
    if uncalibrated_allowance:
        worse *= max(1.0, observations / min(dof_used, float(observations)))
    if checked < 3:
        out["reason"] = (
            f"not checked: {essential} of {k} {point}s are essential (without any one of "
            "them a parameter is unseen), too few redundant ones to hold out"
        )
    elif loo > worse:
        out["generalises"] = False
        out["reason"] = (
            f"held-out {quantity} rms {loo:.3g} is worse than without calibration "
            f"({out['uncalibrated_rms']:.3g}): the fit does not predict {what} it was not "
            "made from"
        )
    elif loo > limit * max(out["in_sample_rms"], 1e-12):
        out["generalises"] = False
        out["reason"] = (
            f"held-out {quantity} rms {loo:.3g} is {loo / out['in_sample_rms']:.1f}x the "
            f"in-sample {out['in_sample_rms']:.3g} (limit {limit:.3g}x: {LOO_RATIO_LIMIT:g}x "
            f"what {observations:g} observations for {observations - dof_used:.1f} parameters "
            f"explain): the fit follows its own {what}"
        )
    else:
        out["generalises"] = True
    worst = int(np.nanargmax(np.abs(held))) if np.isfinite(held).any() else None
    out[f"worst_{point}"] = worst
    return out


def direction_errors(pairs: list[RotationPair], stack: dict, ninv: np.ndarray) -> np.ndarray:
    """Angle (K,) rad between each motion's measured end direction and the one predicted
    with N^-1 ``ninv`` (3, 3) from the increments of :func:`.gyro_fit.stack_pairs`."""
    up0 = np.array([p.up0 for p in pairs])
    up1 = np.array([p.up1 for p in pairs])
    pred = predict_end_directions(stack, ninv[None], up0)[0]
    return np.arctan2(np.linalg.norm(np.cross(pred, up1), axis=1), np.sum(pred * up1, axis=1))


def rotation_leave_one_out(
    like: Certificate,
    pairs: list[RotationPair],
    rot: RotationFitResult,
    free: np.ndarray,
    frame_applied: bool,
    ratio: float,
    ninv: np.ndarray,
    determined: np.ndarray | None = None,
) -> dict[str, Any]:
    """Leave-one-motion-out check of a MEMS gyro calibration from rotations.

    ``rot`` is the calibration's rotation fit to ``pairs`` (the motions it kept),
    ``ninv`` (3, 3) the N^-1 it writes (pinned parameters, ``free`` (9,) False,
    literally at ``like``). Each motion is predicted by the fit to all the others
    (:attr:`.gyro_fit.RotationFitResult.loo_params`: the deletion formula, a
    Newton step from the fit to all, exact for a linear model; checked against
    real refits in the tests), with the frame rotation applied as the calibration
    applied it: the gravity direction after the motion, integrated from the gyros,
    against the one the accelerometers measured (rad). A motion without which a
    free shape parameter is undetermined (std above ``ratio`` limits) is essential
    and not held out (``determined`` (9,): the parameters the calibration determined, when
    a prior decides the others; default ``free``). Verdict by :func:`judge` on 2
    observations per motion.
    """
    gyro = like.gyro
    k = len(pairs)
    stack = stack_pairs(gyro, pairs)
    inside = direction_errors(pairs, stack, ninv)
    before = direction_errors(pairs, stack, np.linalg.inv(gyro.n_matrix()))
    shape_c, q_c = shape_of_triad(gyro)
    scale = np.concatenate([gyro.scale_factor, np.ones(3)])
    free_shape = np.asarray(free, dtype=bool)[3:]
    seen_shape = free_shape if determined is None else np.asarray(determined, dtype=bool)[3:]
    lim = limit_vector(gyro)[3:]
    held = np.full(k, np.nan)
    essential = 0
    if k >= 3 and rot.loo_params is not None and rot.loo_var is not None:
        for i in range(k):
            params, var = rot.loo_params[i], rot.loo_var[i]
            std = np.sqrt(np.maximum(var[:6], 0.0)) * scale
            if not np.all(np.isfinite(params)) or np.any(seen_shape & ~(std <= ratio * lim)):
                essential += 1  # without it a free parameter is unseen: nothing to predict
                continue
            dev = np.where(free_shape, params[:6], 0.0)
            frame = params[6:9] if frame_applied and params.shape[0] >= 9 else np.zeros(3)
            n_i = p_matrix(shape_c + dev) @ small_rotation(frame) @ q_c
            held[i] = direction_errors(
                pairs[i : i + 1], stack_pairs(gyro, pairs[i : i + 1]), np.linalg.inv(n_i)
            )[0]
    return judge(
        inside,
        held,
        before,
        2 * k,
        rot.dof,
        essential,
        ROTATION_QUANTITY,
        point="motion",
        what="motions",
        uncalibrated_allowance=True,
    )


__all__ = [
    "LOO_RATIO_LIMIT",
    "ROTATION_QUANTITY",
    "direction_errors",
    "judge",
    "ratio_limit",
    "rms",
    "rotation_leave_one_out",
]
