"""Outlier rejection in a sliding window that tells a fault onset from isolated outliers.

A window of the diagnosis may span the moment the unit changed (a fault onset):
its older intervals then disagree with the newer ones, and rejecting "outliers"
would keep a mixture that names a wrong parameter. Isolated outliers (a bump in
one hold) are a different thing: the intervals on either side of them agree.

So a window's exact fit first rejects outliers as ``calibrate`` does
(:func:`.scalar_fit.robust_exact_fit`), then asks of the rejected points, in
time order, whether they are a step: the intervals newer than the earliest
rejected one are predicted by the fit to the intervals older than it, and the
intervals older than the latest rejected one by the fit to those newer than it.
After a step, the intervals on the far side are all off (the median of their
prediction errors is beyond :data:`STEP_SIGMA`); around an isolated outlier
they are not (the median ignores the other outliers among them). A step, or a
rejected interval at either end of the window (nothing beyond it to tell), keeps
every interval, and the influence rule of the predicates keeps one interval from
making a fault. Every interval is kept as well where the rejection would leave
another interval the only evidence for a parameter (two holds in one attitude, one of
them off: which one cannot be told, and the one left could make a fault that nothing
holds back). A step is also listed as the fit's ``step_change`` (its first interval of
the unit as it is now): the stream starts its next windows there and withdraws the faults
that the windows mixing both sides raised (:class:`.stream.StreamingDiagnoser`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..certificate import TriadModel
from .params import TriadFit, TriadForm
from .scalar_fit import exact_fit, robust_exact_fit_and_plain

#: Median prediction error (sigma) of the intervals beyond a rejected one, predicted from
#: those before it, above which the window holds a step change (a fault onset), not outliers.
STEP_SIGMA = 3.0


def _median_prediction_z(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    var: np.ndarray,
    mag: np.ndarray,
    fit_rows: np.ndarray,
    predict_rows: np.ndarray,
    kwargs: dict[str, Any],
) -> float:
    """Median prediction error (sigma) of ``predict_rows`` from the fit to ``fit_rows``;
    NaN when either side is empty."""
    if not fit_rows.size or not predict_rows.size:
        return float("nan")
    f = exact_fit(
        triad,
        means[fit_rows],
        var[fit_rows],
        mag[fit_rows],
        predict=(means[predict_rows], var[predict_rows], mag[predict_rows]),
        **kwargs,
    )
    return float(np.median(f.extra.get("predicted_z", [float("nan")])))


def step_change(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    var: np.ndarray,
    mag: np.ndarray,
    rejected: np.ndarray,
    kwargs: dict[str, Any],
) -> tuple[str, int | None]:
    """Why the rejected points (indices, time order of ``means``) look like a step change,
    or "" when they are isolated outliers; with the step's first interval (the first of the
    unit as it is now: the earliest rejected one when the newer intervals are off, the one
    after the latest rejected when the older are), None when there is no step.
    ``kwargs`` as :func:`.scalar_fit.exact_fit`."""
    k = means.shape[0]
    idx = np.arange(k)
    first, last = int(rejected.min()), int(rejected.max())
    if first == k - 1 or last == 0:
        return (
            "the rejected interval is at the end of the window: nothing beyond it to tell a step",
            None,
        )
    newer = _median_prediction_z(triad, means, var, mag, idx[idx < first], idx[idx > first], kwargs)
    older = _median_prediction_z(triad, means, var, mag, idx[idx > last], idx[idx < last], kwargs)
    for z, side, boundary in ((newer, "newer", first), (older, "older", last + 1)):
        if np.isfinite(z) and z > STEP_SIGMA:
            return (
                f"the intervals {side} than the rejected ones are {z:.1f} sigma off (median) "
                f"the fit to the others: a step change, not outliers",
                boundary,
            )
    return "", None


def window_exact_fit(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: float | np.ndarray,
    labels: list[str],
    min_dof: float,
    **kwargs: Any,
) -> TriadFit:
    """The exact fit of one window (``means`` in time order), outliers rejected unless the
    window spans a step change, or when the rejection would leave an interval the only
    evidence for a parameter (then every interval is kept, the points and the reason in
    ``extra["rejection_withheld"]``). Arguments as :func:`.scalar_fit.robust_exact_fit`.
    """
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    var = np.asarray(mean_var, dtype=float).reshape(-1, 3)
    mag = np.broadcast_to(np.asarray(magnitude, dtype=float), (means.shape[0],))
    fit, plain = robust_exact_fit_and_plain(
        triad, means, var, mag, labels=labels, min_dof=min_dof, **kwargs
    )
    if fit.kept is None or bool(np.all(fit.kept)):
        fit.point_labels = list(labels)
        return fit
    # the fit to every interval, made first by the rejection and left untouched by it
    plain.point_labels = list(labels)
    why, boundary = step_change(triad, means, var, mag, np.flatnonzero(~fit.kept), kwargs)
    if not why and _essential(fit) > _essential(plain):
        # two holds in one attitude, one of them off: the data cannot say which, and the
        # one left would be the only evidence for a parameter (a fault nothing can hold back)
        why = (
            "rejecting them would leave an interval the only evidence for a parameter: "
            "which of them is off cannot be told"
        )
    if not why:
        return fit
    plain.extra["rejection_withheld"] = {
        "points": [r["point"] for r in fit.extra.get("rejected", [])],
        "reason": why,
    }
    if boundary is not None:
        # the stream starts its next windows here (:class:`.stream.StreamingDiagnoser`)
        plain.extra["step_change"] = {"first": labels[boundary], "index": boundary}
    return plain


def _essential(fit: TriadFit) -> int:
    """Points of a fit without which some parameter is unseen (NaN rows of its deletion
    shifts, :func:`.robust.point_diagnostics`)."""
    if fit.loo_deviation is None:
        return 0
    return int(np.sum(np.any(~np.isfinite(fit.loo_deviation), axis=1)))


__all__ = ["STEP_SIGMA", "step_change", "window_exact_fit"]
