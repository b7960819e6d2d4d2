"""What one interval (or one motion) does to a fit: outlier rejection and influence.

Two questions are asked of every weighted least-squares fit of the diagnosis.
Both start from the converged fit alone (one Newton step, exact for a linear
model); a suspected outlier is then confirmed against a real refit without it:

- *Is a point an outlier?* Its deletion residual, the residual it would have
  against the fit to all the others, standardised by the noise of the point
  and a common excess scatter estimated robustly (the median of the squared
  standardised residuals, so one gross outlier cannot hide itself by inflating
  the scale the way the chi^2 / dof scale would). A bump during a hold, a
  stopped turntable plateau or a clipped turn stands out at many sigma;
  :func:`reject_outliers` checks the worst such point against the fit to the
  others and drops it when it is beyond :data:`REJECT_SIGMA` there, and
  repeats, within a budget (:data:`MAX_REJECT_FRACTION` of the
  points, and never below the redundancy the fit needs), and lists what it
  rejected and why.
- *Does one point make a fault?* The parameter change its removal would cause
  (the deletion formula of regression diagnostics, the group form for the
  three residuals of a motion): a fault candidate must stay a candidate with
  any single point left out (:func:`imudiag.diagnosis.predicates.candidates`).

For a fit with residuals ``r`` (n,), Jacobian ``J = dr/dtheta`` (n, p),
weights ``w`` (n,) and the unscaled posterior covariance ``C`` (the inverse of
J^T W J plus the prior precision), leaving out the rows ``g`` of one point
moves the estimate by ``C A^T (I - H)^-1 s`` with ``A = W_g^1/2 J_g``,
``s = W_g^1/2 r_g`` and ``H = A C A^T`` (its leverage); that is a Newton step
from the optimum of the full fit, exact when the model is linear near it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from ..kernels import kernel
from ..noise_estimate import medians

T = TypeVar("T")

#: A point whose prediction error from the fit to the others exceeds this (sigma) is rejected.
REJECT_SIGMA = 5.0
#: A point whose deletion figure in the fit to all points exceeds this (sigma) is checked.
SCREEN_SIGMA = 3.0
#: Points checked per round: the ones with the largest deletion figures (when the fit
#: scatters more than its noise, these are checked even below SCREEN_SIGMA: an outlier
#: pulls the fit to all points towards itself and inflates the scale, so the screening
#: figure understates it).
PROBES = 3
#: At most this fraction of a fit's points is rejected; more outliers than that is not a
#: few bad points but a model that does not fit, and is reported as such.
MAX_REJECT_FRACTION = 0.25
#: Leverage above which a point is the only evidence for some direction: it cannot be
#: judged an outlier (nothing predicts it), and its shift is NaN (an essential point,
#: which the predicates do not let hold a fault back).
MAX_LEVERAGE = 0.99
#: Median of a chi^2 variable with one degree of freedom.
CHI2_1_MEDIAN = 0.454936423119572


@dataclass
class PointDiagnostics:
    """Per-point figures of a converged fit (internal parameter units)."""

    z: np.ndarray  #: (G,) robustly standardised deletion residuals, sigma (NaN: cannot judge)
    shift: np.ndarray  #: (G, p) parameter change when the point is left out (NaN: unseen)
    excess_var: float  #: robust common excess variance added to every residual


def group_leverages(
    a_all: np.ndarray, cov: np.ndarray, groups: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """For groups of rows all of one size m: (rows (G, m), their weighted Jacobian rows
    a (G, m, p), hat blocks a cov a^T (G, m, m) symmetrised, and whether each group can be
    left out (G,): its largest leverage at most :data:`MAX_LEVERAGE`); None for groups of
    different sizes. ``a_all`` (n, p) weighted Jacobian, ``cov`` (p, p) unscaled covariance.
    """
    sizes = {len(g) for g in groups}
    if len(sizes) > 1:
        return None
    rows = np.asarray(groups, dtype=np.intp).reshape(len(groups), -1)
    a = a_all[rows]
    hk = a @ cov[None] @ np.swapaxes(a, 1, 2)
    hk = 0.5 * (hk + np.swapaxes(hk, 1, 2))
    judged = np.linalg.eigvalsh(hk)[:, -1] <= MAX_LEVERAGE if rows.shape[1] else np.ones(0, bool)
    return rows, a, hk, judged


def point_diagnostics(
    jac: np.ndarray,
    r: np.ndarray,
    noise_var: np.ndarray,
    cov: np.ndarray,
    groups: Sequence[np.ndarray] | None = None,
    weights: np.ndarray | None = None,
) -> PointDiagnostics:
    """Deletion residuals, leverages and parameter shifts of every point of a fit.

    ``jac`` (n, p) = dr/dtheta, ``r`` (n,) residuals, ``noise_var`` (n,) the
    variance of each residual from the data's noise alone, ``cov`` (p, p) the
    unscaled posterior covariance the fit was solved with, ``weights`` (n,) the
    weights it used (default ``1 / noise_var``). ``groups``: the rows of each
    point (default one row each).
    """
    w = 1.0 / noise_var if weights is None else weights
    sw = np.sqrt(w)
    a_all = jac * sw[:, None]
    s_all = sw * r
    if groups is None:
        # one row per point: the same formulas with scalars, vectorised (every window fit)
        h = np.einsum("ij,jk,ik->i", a_all, cov, a_all)
        ok = h <= MAX_LEVERAGE
        sol = np.where(ok, s_all / np.where(ok, 1.0 - h, 1.0), np.nan)
        shift = (a_all @ cov) * sol[:, None]
        u = np.where(ok, s_all * sol, np.nan) / (noise_var * w)
        m_rows = np.ones(r.shape[0])
        nv_mean = np.where(ok, noise_var, 1.0)
    else:
        g_count, p = len(groups), cov.shape[0]
        shift = np.full((g_count, p), np.nan)
        u = np.full(g_count, np.nan)  # squared deletion residual in units of the noise
        m_rows = np.array([len(g) for g in groups], dtype=float)
        nv_mean = np.ones(g_count)
        blocks = group_leverages(a_all, cov, groups)
        if blocks is not None and g_count:
            # groups of one size (every motion's three direction components): all at once
            rows, a, hk, judged = blocks
            rows, a, hk = rows[judged], a[judged], hk[judged]
            s = s_all[rows]
            sol = np.linalg.solve(np.eye(rows.shape[1])[None] - hk, s[:, :, None])[:, :, 0]
            shift[judged] = ((cov[None] @ np.swapaxes(a, 1, 2)) @ sol[:, :, None])[:, :, 0]
            u[judged] = np.sum(s * sol, axis=1) / np.mean(noise_var[rows] * w[rows], axis=1)
            nv_mean[judged] = np.mean(noise_var[rows], axis=1)
        else:
            for k, rows in enumerate(groups):
                a = a_all[rows]
                hk = a @ cov @ a.T
                hk = 0.5 * (hk + hk.T)
                if np.linalg.eigvalsh(hk)[-1] > MAX_LEVERAGE:
                    continue
                s = s_all[rows]
                sol_k = np.linalg.solve(np.eye(len(rows)) - hk, s)
                shift[k] = cov @ a.T @ sol_k
                # squared standardised deletion residual s^T (I - H)^-1 s, in weight units,
                # rescaled to the noise-only variance
                u[k] = float(s @ sol_k) / float(np.mean(noise_var[rows] * w[rows]))
                nv_mean[k] = float(np.mean(noise_var[rows]))
    excess = _robust_excess(u, nv_mean, m_rows)
    z = np.sqrt(u / (m_rows * (1.0 + excess / nv_mean)))
    return PointDiagnostics(z=z, shift=shift, excess_var=excess)


def _robust_excess(u: np.ndarray, nv: np.ndarray, m: np.ndarray) -> float:
    """Common excess variance e making the median of u / (m (1 + e / nv)) the chi^2_1 median."""
    ok = np.isfinite(u)
    if ok.sum() < 3:
        return 0.0
    u, nv, m = u[ok], nv[ok], m[ok]

    a = u / m
    if float(np.median(a)) <= CHI2_1_MEDIAN:
        return 0.0
    compiled = kernel("robust_excess")  # the same brackets compiled (exact: order statistics)
    if compiled is not None:
        return float(
            compiled(
                np.ascontiguousarray(a, dtype=float),
                np.ascontiguousarray(nv, dtype=float),
                CHI2_1_MEDIAN,
            )
        )
    # the median falls as e grows: bracket the crossing, 15 trial values per round in one
    # median call (16x narrower a round), to 1e-10 of the answer (was 80 medians one by one)
    lo, hi = 0.0, float(np.max(a * nv)) + 1e-300
    steps = np.arange(1, 16) / 16.0
    inv_nv = 1.0 / nv
    for _ in range(40):
        trial = lo + (hi - lo) * steps
        below = medians(a / (1.0 + trial[:, None] * inv_nv)) <= CHI2_1_MEDIAN
        k = int(np.argmax(below)) if below.any() else trial.size
        if k > 0:
            lo = float(trial[k - 1])
        if k < trial.size:
            hi = float(trial[k])
        if hi - lo <= 1e-10 * hi:
            break
    return hi


def reject_outliers(
    fit_once: Callable[[np.ndarray, int | None], tuple[T, np.ndarray | None, float, float]],
    count: int,
    labels: Sequence[str],
    min_dof: float = 3.0,
) -> tuple[T, np.ndarray, list[dict], str]:
    """Fit; while a point looks off, confirm it against the fit to the others and drop it.

    ``fit_once(keep, probe)`` fits the points where the boolean mask ``keep``
    (count,) is true and returns the fit, the screening figures of the kept
    points (:attr:`PointDiagnostics.z`; None when it cannot judge them), its
    effective degrees of freedom and, when ``probe`` is a point index, that
    point's prediction error in sigma against this fit (its noise, the common
    excess scatter and the fit's own uncertainty). A point is screened when its
    deletion figure exceeds :data:`SCREEN_SIGMA`, or is among the :data:`PROBES`
    largest when the fit scatters more than its noise (``fit.excess_var > 0``),
    and rejected when its prediction error from the others
    exceeds :data:`REJECT_SIGMA`. A rejection never leaves fewer than ``min_dof``
    degrees of freedom nor drops more than :data:`MAX_REJECT_FRACTION` of the
    points. Returns the last fit, the mask, the rejected points (label, sigma,
    reason) and a note when confirmed outliers were left in, else "".
    """
    keep = np.ones(count, dtype=bool)
    fit, z, dof, _ = fit_once(keep, None)
    rejected: list[dict] = []
    note = ""
    budget = int(np.floor(MAX_REJECT_FRACTION * count))
    while z is not None and z.size and dof - 1.0 >= min_dof:
        zz = np.where(np.isfinite(z), z, -np.inf)
        order = [int(j) for j in np.argsort(-zz)[:PROBES] if np.isfinite(zz[j])]
        if not order:
            break
        scatter = bool(getattr(fit, "excess_var", 0.0) > 0.0)
        if not scatter:
            order = [j for j in order if zz[j] > SCREEN_SIGMA]
        best: tuple[int, tuple[T, np.ndarray | None, float, float], np.ndarray] | None = None
        for j in order:
            i = int(np.flatnonzero(keep)[j])
            trial_keep = keep.copy()
            trial_keep[i] = False
            probe = fit_once(trial_keep, i)
            if probe[3] > REJECT_SIGMA and (best is None or probe[3] > best[1][3]):
                best = (i, probe, trial_keep)
        if best is None:
            break
        i, (trial, tz, tdof, zp), trial_keep = best
        if len(rejected) + 1 > budget:
            note = (
                f"{labels[i]} is {zp:.1f} sigma off the fit to the others after "
                f"{len(rejected)} rejected and is left in: more outliers than "
                f"{MAX_REJECT_FRACTION:.0%} of the points is not a few bad points but a model "
                "that does not fit these data"
            )
            break
        rejected.append(
            {
                "point": labels[i],
                "sigma": round(float(zp), 2),
                "reason": f"{float(zp):.1f} sigma off the fit to the others (beyond "
                f"{REJECT_SIGMA:g}): a bump in the hold, a wrong reference magnitude, "
                "a clipped or interrupted motion",
            }
        )
        keep, fit, z, dof = trial_keep, trial, tz, tdof
    return fit, keep, rejected, note


__all__ = [
    "MAX_LEVERAGE",
    "MAX_REJECT_FRACTION",
    "PointDiagnostics",
    "REJECT_SIGMA",
    "SCREEN_SIGMA",
    "point_diagnostics",
    "reject_outliers",
]
