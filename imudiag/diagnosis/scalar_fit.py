"""Scalar fits of a triad's 9 parameters: |N^-1 (U - B) / S| = magnitude.

Three solvers, all returning a :class:`TriadFit` in certificate units:

- :func:`exact_fit`: the paper's linear least squares (eqs. 7, 9, 10) as the
  start, refined by Gauss-Newton with step control on the exact model over the
  means of quasi-static intervals, weighted by the noise of each mean, with a
  weak Gaussian prior at the certificate (``prior_factor`` times the limits)
  that keeps unobservable directions at the certificate and gives them a
  posterior standard deviation of about ``prior_factor`` limits, so they are
  reported as undetermined instead of as numbers that look fine (note §4).
- :func:`linear_fit`: the paper's literal linearised solution, per sample
  (F0 of every sample, squares of noisy samples included), no iteration.
- :func:`normal_equation_fit` over :class:`NormalEquations` accumulated from
  every sample with a per-sample magnitude (the moving-base variant, note §6:
  bias regressor ``y_j / |y|^2`` through the un-normalised form).

Parameters inside the fits are dimensionless: ``beta = B / (S m0)`` with m0
the reference magnitude in input units, and the shape ``e_x e_y e_z d1 d2 d3``
of the symmetric part P of N (see :mod:`.gauge`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..certificate import TriadModel
from . import kernels
from .gauge import p_matrix
from .params import TriadFit, TriadForm, std_above_limit, triad_form
from .robust import CHI2_1_MEDIAN, MAX_LEVERAGE, point_diagnostics, reject_outliers

#: Floor of the standard deviation of a normalised residual (model resolution).
RESIDUAL_FLOOR = 1e-7
#: Largest shape deviation from the certificate (relative scale error, rad) a step may reach.
MAX_SHAPE = 0.5


def _regressors(y: np.ndarray) -> np.ndarray:
    """The 9 regressors of the linearised model for corrected vectors y (..., 3)."""
    return np.concatenate(
        [
            y,
            y * y,
            (y[..., 0] * y[..., 1])[..., None],
            (y[..., 0] * y[..., 2])[..., None],
            (y[..., 1] * y[..., 2])[..., None],
        ],
        axis=-1,
    )


def _regressor_jacobian(y: np.ndarray) -> np.ndarray:
    """d h / d y (N, 9, 3) of the 9 regressors at corrected outputs y (N, 3)."""
    n = y.shape[0]
    jac = np.zeros((n, 9, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = jac[:, 2, 2] = 1.0
    jac[:, 3, 0], jac[:, 4, 1], jac[:, 5, 2] = 2 * y[:, 0], 2 * y[:, 1], 2 * y[:, 2]
    jac[:, 6, 0], jac[:, 6, 1] = y[:, 1], y[:, 0]
    jac[:, 7, 0], jac[:, 7, 2] = y[:, 2], y[:, 0]
    jac[:, 8, 1], jac[:, 8, 2] = y[:, 2], y[:, 1]
    return jac


def internal_limits(triad: TriadModel | TriadForm, m0: float) -> np.ndarray:
    """The limits (9,) in the fits' dimensionless units at reference magnitude m0."""
    return triad_form(triad).internal_limits(m0)


def certificate_internal(triad: TriadModel | TriadForm, m0: float) -> tuple[np.ndarray, np.ndarray]:
    """theta_c (9,) = (B / (S m0), shape of P) and the rotation Q (read-only) of the
    certificate's N."""
    form = triad_form(triad)
    return form.internal(m0), form.q


def _finish(
    triad: TriadModel | TriadForm,
    method: str,
    m0: float,
    theta_dev: np.ndarray,
    cov: np.ndarray,
    null: np.ndarray,
    determined_std_ratio: float,
    condition: float,
    points: int,
    rms: float,
) -> TriadFit:
    """Turn internal deviations and covariance into a TriadFit in certificate units."""
    form = triad_form(triad)
    scale = form.scale(m0)
    cert, limit, units = form.certificate, form.limit, form.units
    est = cert + theta_dev * scale
    std = np.sqrt(np.maximum(np.diag(cov), 0.0)) * scale
    std = np.where(null, np.inf, std)
    est = np.where(null, cert, est)
    determined = std <= determined_std_ratio * limit
    std_list, limit_list = std.tolist(), limit.tolist()
    reasons = [
        ""
        if ok
        else (
            "not excited by the data (no information on it)"
            if not math.isfinite(std_list[i])
            else std_above_limit(std_list[i], determined_std_ratio, limit_list[i], units[i])
        )
        for i, ok in enumerate(determined.tolist())
    ]
    return TriadFit(
        triad=form.name,
        method=method,
        estimate=est,
        std=std,
        certificate=cert,
        limit=limit,
        determined=determined,
        reasons=reasons,
        condition=condition,
        points=points,
        rms_residual=rms,
        certificate_std=form.certificate_std,
    )


def _estimated_variance(
    triad: TriadForm,
    m0: float,
    jac: np.ndarray,
    noise: np.ndarray,
    prior_diag: np.ndarray,
    cov: np.ndarray,
    null: np.ndarray,
    extra: float,
    cov_scale: float,
) -> np.ndarray:
    """(9,) the part of each parameter's variance the fit estimated from its residuals,
    certificate units^2 (:attr:`.params.TriadFit.estimated_var`): the diagonal of ``cov``
    (with the excess variance ``extra`` and the Birge ratio ``cov_scale``) less that of the
    covariance the points' stated ``noise`` (K,) and the prior alone give. 0 where the fit
    estimated nothing, or where a parameter has no estimate (``null``)."""
    if (extra <= 0.0 and cov_scale <= 1.0) or jac.shape[0] == 0:
        return np.zeros(9)
    known = np.linalg.pinv(jac.T @ (jac / noise[:, None]) + prior_diag)
    return _estimated_part(triad, m0, cov, np.diag(known), null)


def _estimated_part(
    triad: TriadForm, m0: float, cov: np.ndarray, known_diag: np.ndarray, null: np.ndarray
) -> np.ndarray:
    """:func:`_estimated_variance` from the noise-only covariance's diagonal ``known_diag``
    (9,), certificate units^2."""
    part = np.maximum(np.diag(cov) - known_diag, 0.0) * triad.scale(m0) ** 2
    return np.where(null | ~np.isfinite(part), 0.0, part)


def _scaled_condition(info: np.ndarray, lim: np.ndarray) -> float:
    """Condition number of the information matrix with parameters in units of their limits."""
    m = info * np.outer(lim, lim)
    w = np.linalg.eigvalsh(m)
    if w[-1] <= 0:
        return float("inf")
    return float(w[-1] / max(w[0], w[-1] * 1e-300))


# ---------------------------------------------------------------------------
# exact model


#: Component pairs (i, j) of the three off-diagonal shape parameters d1 d2 d3.
_PAIR_I = np.array([0, 0, 1])
_PAIR_J = np.array([1, 2, 2])


def _residuals(
    theta: np.ndarray, v: np.ndarray, mu: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals |P^-1 (v - beta)| - mu (K,), x = P^-1 (v - beta) (K, 3) and
    w = P^-1 x_hat (K, 3): :func:`residuals_and_jacobian` without the Jacobian."""
    beta = theta[:3]
    p = p_matrix(theta[3:])
    pinv = np.linalg.inv(p)
    x = (v - beta) @ pinv.T
    nx = np.sqrt((x * x).sum(axis=1))  # np.linalg.norm's own sum, without its wrapper
    xh = x / nx[:, None]
    w = xh @ pinv.T  # P^-1 symmetric
    return nx - mu, x, w


def _jacobian(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The Jacobian (K, 9) of :func:`_residuals` from its x and w."""
    jac = np.empty((x.shape[0], 9))
    jac[:, 0:3] = -w
    jac[:, 3:6] = -w * x
    # columns 6-8: -0.5 (w_i x_j + w_j x_i) for (i, j) = (0, 1), (0, 2), (1, 2), in one pass
    jac[:, 6:9] = -0.5 * (w[:, _PAIR_I] * x[:, _PAIR_J] + w[:, _PAIR_J] * x[:, _PAIR_I])
    return jac


def residuals_and_jacobian(
    theta: np.ndarray, v: np.ndarray, mu: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals |P^-1 (v - beta)| - mu (K,), Jacobian (K, 9) and w = P^-1 x_hat (K, 3)."""
    r, x, w = _residuals(theta, v, mu)
    return r, _jacobian(x, w), w


def exact_fit(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: float | np.ndarray,
    prior_factor: float | np.ndarray = 10.0,
    determined_std_ratio: float = 0.5,
    max_iter: int = 20,
    method: str = "exact",
    start: np.ndarray | str = "linear",
    scale_by_residual: bool = True,
    predict: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> TriadFit:
    """Fit B, E, d of ``triad`` to interval means on the exact scalar model.

    ``means`` (K, 3) mean raw outputs (output units); ``mean_var`` (K, 3) their
    variances (output units^2); ``magnitude`` the true input magnitude at each
    mean (input units, scalar or (K,)). ``prior_factor``: prior standard
    deviation at the certificate in limits, scalar or per parameter (9,)
    (``inf``: no prior). ``start``: ``linear`` (the linearised solution),
    ``certificate``, or an internal starting point (9,). ``max_iter=0`` with
    ``start="certificate"`` gives the covariance of the linearisation at the
    certificate (what the data can determine, whatever the estimate), best
    with ``scale_by_residual=False`` (no chi^2 / dof inflation of the covariance).
    ``predict``: (means (J, 3), variances (J, 3), magnitudes (J,)) of points not
    in the fit; their prediction errors in sigma (their noise, the fit's excess
    scatter and its parameter uncertainty) go to ``fit.extra["predicted_z"]``.
    ``triad``: the certificate's model or its internal form (:func:`.params.triad_form`,
    made once by a caller that fits many windows).
    """
    triad = triad_form(triad)
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    k = means.shape[0]
    mag = np.broadcast_to(np.asarray(magnitude, dtype=float), (k,))
    if not k:
        m0 = 1.0
    elif (low := float(mag.min())) == float(mag.max()):
        m0 = low  # one magnitude for all (no nan): np.median of equal values is that value
    else:
        m0 = float(np.median(mag))
    s = triad.scale_factor
    v = means / (s * m0)
    var_v = np.asarray(mean_var, dtype=float).reshape(-1, 3) / (s * m0) ** 2
    mu = mag / m0
    theta_c, _ = certificate_internal(triad, m0)
    lim = internal_limits(triad, m0)
    pf = np.broadcast_to(np.asarray(prior_factor, dtype=float), (9,))
    prior_prec = np.where(np.isfinite(pf), 1.0 / (pf * lim) ** 2, 0.0)
    prior_diag = np.diag(prior_prec)
    shape_c = theta_c[3:]

    if isinstance(start, str) and start not in ("linear", "certificate"):
        raise ValueError(f"start must be linear, certificate or a vector, got {start!r}")
    if k and max_iter > 0 and np.all(np.isfinite(pf)) and kernels.enabled():
        # the whole fit compiled (fleet workers); None where one of its solves gave up
        compiled = _compiled_fit(
            triad, method, m0, v, var_v, mu, theta_c, lim, prior_prec, start, max_iter,
            determined_std_ratio, scale_by_residual, predict,
        )  # fmt: skip
        if compiled is not None:
            return compiled
    if isinstance(start, str):
        theta = theta_c.copy()
        if start == "linear":
            lin = _linear_start(theta_c, v, mu)
            if np.all(np.isfinite(lin)) and np.max(np.abs(lin[3:])) <= MAX_SHAPE:
                theta = theta_c + lin
    else:
        theta = np.asarray(start, dtype=float).copy()

    def cost(
        th: np.ndarray, extra: float
    ) -> tuple[float, np.ndarray, tuple[np.ndarray, np.ndarray], np.ndarray]:
        """(cost, residuals, (x, w) for the Jacobian, variances): the Jacobian is made
        (:func:`_jacobian`) only for a step that is taken; most tries are not."""
        r, x, w = _residuals(th, v, mu)
        sig2 = np.einsum("kj,kj->k", w * w, var_v) + RESIDUAL_FLOOR**2 + extra
        c = float((r * r / sig2).sum() + (prior_prec * (th - theta_c) ** 2).sum())
        return c, r, (x, w), sig2

    def gauss_newton(
        theta: np.ndarray, extra: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if kernels.enabled():  # the same loop compiled (fleet workers), None if it gave up
            out = kernels.exact_gauss_newton(
                theta,
                extra,
                v,
                mu,
                var_v,
                prior_prec,
                theta_c,
                max_iter,
                MAX_SHAPE,
                RESIDUAL_FLOOR**2,
            )
            if out is not None:
                return out
        c0, r, xw, sig2 = cost(theta, extra)
        jac = _jacobian(*xw)
        lam = 1e-6
        for _ in range(max_iter):
            wgt = 1.0 / sig2
            hess = jac.T @ (jac * wgt[:, None]) + prior_diag
            damp = np.diag(np.maximum(hess.diagonal(), 1e-30))
            grad = jac.T @ (r * wgt) + prior_prec * (theta - theta_c)
            c_before = c0
            accepted = False
            for _try in range(16):
                step = -np.linalg.lstsq(hess + lam * damp, grad, rcond=None)[0]
                cand = theta + step
                if abs(cand[3:] - shape_c).max() > MAX_SHAPE:
                    lam *= 10.0
                    continue
                c1, r1, xw1, s1 = cost(cand, extra)
                if np.isfinite(c1) and c1 <= c0:
                    theta, c0, r, jac, sig2 = cand, c1, r1, _jacobian(*xw1), s1
                    lam = max(lam / 10.0, 1e-12)
                    accepted = True
                    break
                lam *= 10.0
            if not accepted or (c_before - c0) <= max(1e-3, 1e-9 * c0):
                break
        return theta, r, jac, sig2

    # Real data scatter more than the white noise of the means (bias wander,
    # temperature, placement): estimate that excess variance, common to every
    # mean, by the method of moments (chi^2 = dof) and refit with it, so the
    # prior keeps its intended weight against the data.
    extra = 0.0
    for _outer in range(4 if scale_by_residual else 1):
        theta_fit, r, jac, sig2 = gauss_newton(theta.copy(), extra)
        wgt = 1.0 / sig2
        info = jac.T @ (jac * wgt[:, None])
        hess = info + prior_diag
        cov = np.linalg.pinv(hess)
        cov_unscaled = cov
        extra_used = extra
        chi2 = float((r * r * wgt).sum())
        dof = k - float((cov @ info).trace())
        if not scale_by_residual or dof < 1.0 or chi2 <= 1.5 * dof:
            break
        extra = _excess_variance(r, sig2 - extra, dof)
    theta = theta_fit
    cov_scale = 1.0
    if dof > 0.5 and scale_by_residual:
        # what the excess variance did not absorb: Birge ratio
        cov_scale = max(1.0, chi2 / dof)
        cov = cov * cov_scale
    null = ~np.isfinite(np.diag(cov))
    if not np.all(np.isfinite(pf)):
        # without a prior, directions with no information have no meaningful estimate
        ev, evec = np.linalg.eigh(info * np.outer(lim, lim))
        weak = ev < ev[-1] * 1e-12 if ev[-1] > 0 else np.ones(9, dtype=bool)
        null |= np.sum(evec[:, weak] ** 2, axis=1) > 1e-3
    rms = float(np.sqrt(np.mean(r * r))) if k else float("nan")
    fit = _finish(
        triad,
        method,
        m0,
        theta - theta_c,
        cov,
        null,
        determined_std_ratio,
        _scaled_condition(info, lim),
        k,
        rms,
    )
    fit.dof = dof
    fit.cov_scale = cov_scale
    fit.excess_var = float(extra_used)
    fit.estimated_var = _estimated_variance(
        triad, m0, jac, sig2 - extra_used, prior_diag, cov, null, extra_used, cov_scale
    )
    if k and max_iter > 0:
        diag = point_diagnostics(jac, r, sig2 - extra_used, cov_unscaled, weights=wgt)
        scale = triad.scale(m0)
        loo = (theta - theta_c)[None, :] + diag.shift
        fit.loo_deviation = np.where(null[None, :], 0.0, loo * scale[None, :])
        fit.point_z = diag.z
    if predict is not None:
        # the scatter of the points about this fit, measured robustly (the median, so
        # other outliers still in cannot mask the probed one by inflating it)
        noise = sig2 - extra_used
        e_rob = diag.excess_var if k and max_iter > 0 else extra_used
        w_rob = 1.0 / (noise + e_rob)
        cov_rob = np.linalg.pinv(jac.T @ (jac * w_rob[:, None]) + prior_diag)
        pm, pv, pmag = (np.asarray(x, dtype=float) for x in predict)
        rp, jp, wp = residuals_and_jacobian(
            theta, pm.reshape(-1, 3) / (s * m0), np.atleast_1d(pmag) / m0
        )
        nvp = np.einsum("kj,kj->k", wp * wp, pv.reshape(-1, 3) / (s * m0) ** 2)
        parvar = np.maximum(np.einsum("ki,ij,kj->k", jp, cov_rob, jp), 0.0)
        total = nvp + RESIDUAL_FLOOR**2 + e_rob + parvar
        fit.extra["predicted_z"] = [float(x) for x in np.abs(rp) / np.sqrt(total)]
    return fit


def _compiled_fit(
    triad: TriadForm,
    method: str,
    m0: float,
    v: np.ndarray,
    var_v: np.ndarray,
    mu: np.ndarray,
    theta_c: np.ndarray,
    lim: np.ndarray,
    prior_prec: np.ndarray,
    start: np.ndarray | str,
    max_iter: int,
    determined_std_ratio: float,
    scale_by_residual: bool,
    predict: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
) -> TriadFit | None:
    """:func:`exact_fit` after its set-up in one compiled call
    (:func:`imudiag.numba_kernels.exact_fit_kernel`: linear start, Gauss-Newton with the
    excess-variance refits, covariance, deletion figures, predictions), for a fit of at
    least one point with a finite prior on every parameter; None when the kernels are off
    or a solve gave up (the plain path then runs the fit). Equal to the plain path within
    rounding (tests/test_exact_fit_kernel.py)."""
    fit_kernel = kernels.kernel("exact_fit")
    if fit_kernel is None:
        return None
    linear = isinstance(start, str) and start == "linear"
    theta0 = theta_c if isinstance(start, str) else np.asarray(start, dtype=float)
    s = triad.scale_factor
    if predict is not None:
        pm, pv, pmag = (np.asarray(x, dtype=float) for x in predict)
        p_v = pm.reshape(-1, 3) / (s * m0)
        p_var = pv.reshape(-1, 3) / (s * m0) ** 2
        p_mu = np.atleast_1d(pmag) / m0
    else:
        p_v, p_var, p_mu = np.empty((0, 3)), np.empty((0, 3)), np.empty(0)
    ok, theta, _r, info, cov, dof, cov_scale, extra_used, rms, shift, z, _e, zp, known = fit_kernel(
        np.ascontiguousarray(theta0, dtype=float),
        linear,
        np.ascontiguousarray(v),
        np.ascontiguousarray(var_v),
        np.ascontiguousarray(mu, dtype=float),
        np.ascontiguousarray(theta_c),
        np.ascontiguousarray(prior_prec),
        int(max_iter),
        MAX_SHAPE,
        RESIDUAL_FLOOR**2,
        bool(scale_by_residual),
        MAX_LEVERAGE,
        CHI2_1_MEDIAN,
        np.ascontiguousarray(p_v),
        np.ascontiguousarray(p_var),
        np.ascontiguousarray(p_mu, dtype=float),
    )
    if not ok:
        return None
    null = np.zeros(9, dtype=bool)  # a finite prior: no direction without information
    fit = _finish(
        triad,
        method,
        m0,
        theta - theta_c,
        cov,
        null,
        determined_std_ratio,
        _scaled_condition(info, lim),
        v.shape[0],
        float(rms),
    )
    fit.dof = float(dof)
    fit.cov_scale = float(cov_scale)
    fit.excess_var = float(extra_used)
    if (extra_used > 0.0 or cov_scale > 1.0) and np.all(np.isfinite(known)):
        # a part of each variance estimated from the residuals; the noise-only covariance's
        # diagonal from the kernel
        fit.estimated_var = _estimated_part(triad, m0, cov, known, null)
    elif extra_used > 0.0 or cov_scale > 1.0:  # the kernel's solve broke down: numpy's
        _r0, x0, w0 = _residuals(theta, v, mu)
        fit.estimated_var = _estimated_variance(
            triad,
            m0,
            _jacobian(x0, w0),
            np.einsum("kj,kj->k", w0 * w0, var_v) + RESIDUAL_FLOOR**2,
            np.diag(prior_prec),
            cov,
            null,
            float(extra_used),
            float(cov_scale),
        )
    fit.loo_deviation = ((theta - theta_c)[None, :] + shift) * triad.scale(m0)[None, :]
    fit.point_z = z
    if predict is not None:
        fit.extra["predicted_z"] = [float(x) for x in zp]
    return fit


def robust_exact_fit(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: float | np.ndarray,
    labels: list[str] | None = None,
    min_dof: float = 3.0,
    **kwargs: Any,
) -> TriadFit:
    """:func:`exact_fit` with outlier points rejected (:func:`.robust.reject_outliers`).

    Same arguments as :func:`exact_fit` plus ``labels`` (one per mean, for the
    report) and ``min_dof`` (the redundancy a rejection must leave). The fit's
    ``extra`` lists what was rejected and why (``rejected``) and, when outliers
    were too many to reject, says so (``outliers``); ``kept`` is the mask of the
    means it used.
    """
    return robust_exact_fit_and_plain(
        triad, means, mean_var, magnitude, labels=labels, min_dof=min_dof, **kwargs
    )[0]


def robust_exact_fit_and_plain(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: float | np.ndarray,
    labels: list[str] | None = None,
    min_dof: float = 3.0,
    **kwargs: Any,
) -> tuple[TriadFit, TriadFit]:
    """:func:`robust_exact_fit` and the plain :func:`exact_fit` to every mean it started
    from (the same object when nothing was rejected; else untouched by the rejection), so
    a caller that falls back to keeping every point need not fit them again."""
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    var = np.asarray(mean_var, dtype=float).reshape(-1, 3)
    k = means.shape[0]
    mag = np.broadcast_to(np.asarray(magnitude, dtype=float), (k,))
    names = labels if labels is not None else [f"point {i}" for i in range(k)]

    def once(
        keep: np.ndarray, probe: int | None
    ) -> tuple[TriadFit, np.ndarray | None, float, float]:
        pr = None if probe is None else (means[probe], var[probe], mag[probe : probe + 1])
        f = exact_fit(triad, means[keep], var[keep], mag[keep], predict=pr, **kwargs)
        zp = f.extra.pop("predicted_z", [float("nan")])[0]
        if probe is None:
            plain.append(f)  # reject_outliers fits every point first, and only then
        return f, f.point_z, f.dof, zp

    plain: list[TriadFit] = []
    fit, keep, rejected, note = reject_outliers(once, k, names, min_dof)
    fit.kept = keep
    fit.point_labels = [x for x, kept in zip(names, keep, strict=True) if kept]
    if rejected:
        fit.extra["rejected"] = rejected
    if note:
        fit.extra["outliers"] = note
    return fit, plain[0]


def _excess_variance(r: np.ndarray, sig2: np.ndarray, dof: float) -> float:
    """Variance e added to every point that makes sum r^2 / (sig2 + e) equal ``dof``
    (compiled where the kernels are on: the same halvings and sums, the same e)."""
    compiled = kernels.kernel("excess_variance")
    if compiled is not None and r.shape[0] > 0:
        return float(
            compiled(
                np.ascontiguousarray(r, dtype=float),
                np.ascontiguousarray(np.broadcast_to(sig2, r.shape), dtype=float),
                float(dof),
            )
        )
    lo, hi = 0.0, float(np.max(r * r)) * len(r) + 1e-300
    r2 = r * r
    for _ in range(100):
        before = (lo, hi)
        mid = 0.5 * (lo + hi)
        if np.sum(r2 / (sig2 + mid)) > dof:
            lo = mid
        else:
            hi = mid
        if (lo, hi) == before:
            # a halving is a function of (lo, hi) alone: once one leaves them as they were
            # (adjacent floats), every later one would, and 100 would end here too
            break
    return hi


def _linear_start(theta_c: np.ndarray, v: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Deviation from the certificate by the linearised model (eqs. 7, 9, 10), internal units."""
    p = p_matrix(theta_c[3:])
    y = (v - theta_c[:3]) @ np.linalg.inv(p).T
    h = _regressors(y) / (mu**2)[:, None]
    z = 0.5 * (np.einsum("kj,kj->k", y, y) / mu**2 - 1.0)
    # minimum-norm solution: directions the attitudes do not excite stay at the certificate
    return np.linalg.lstsq(h, z, rcond=1e-10)[0]


# ---------------------------------------------------------------------------
# literal linearised solution and the moving-base normal equations


class NormalEquations:
    """Accumulated normal equations of the linearised scalar model (internal units).

    Each sample contributes z = 1/2 (|y|^2 - mu^2) against the 9 regressors of
    y, the certificate-corrected output normalised by m0, with weight w:
    ``A += w h h^T``, ``b += w h z``, ``zz += w z^2``.
    """

    def __init__(self) -> None:
        self.a = np.zeros((9, 9))
        self.b = np.zeros(9)
        self.zz = 0.0
        self.n = 0

    def add(
        self,
        h: np.ndarray,
        z: np.ndarray,
        w: np.ndarray,
        y: np.ndarray | None = None,
        noise_var: np.ndarray | None = None,
    ) -> None:
        """Add samples: regressors h (N, 9), targets z (N,), weights w (N,).

        With the samples' corrected outputs ``y`` (N, 3) and their white-noise
        variance ``noise_var`` (3,), the errors-in-variables terms are removed:
        noise in the regressors correlates with noise in z and, summed over
        many samples, poses as information in directions the motion does not
        excite (corrected least squares, first order in the noise).
        """
        hw = h * w[:, None]
        self.a += hw.T @ h
        self.b += hw.T @ z
        self.zz += float(np.sum(w * z * z))
        self.n += int(h.shape[0])
        if y is not None and noise_var is not None and h.shape[0]:
            jac = _regressor_jacobian(y)  # (N, 9, 3)
            jv = jac * np.asarray(noise_var, dtype=float)  # J V
            self.a -= np.einsum("n,nia,nja->ij", w, jv, jac)
            self.b -= np.einsum("n,nia,na->i", w, jv, y)

    def __iadd__(self, other: NormalEquations) -> NormalEquations:
        self.a += other.a
        self.b += other.b
        self.zz += other.zz
        self.n += other.n
        return self


def corrected_normalised(triad: TriadModel | TriadForm, raw: np.ndarray, m0: float) -> np.ndarray:
    """Certificate-corrected outputs (N, 3) in units of ``m0`` (input units)."""
    theta_c, q = certificate_internal(triad, m0)
    p = p_matrix(theta_c[3:])
    return (np.asarray(raw, dtype=float) / (triad.scale_factor * m0) - theta_c[:3]) @ np.linalg.inv(
        p
    ).T


def sample_rows(
    triad: TriadModel | TriadForm,
    raw: np.ndarray,
    magnitude: np.ndarray,
    m0: float,
    noise_var: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Per-sample rows (h (N, 9), z (N,), w (N,), y (N, 3), noise_var) of the moving-base
    variant, the arguments of :meth:`NormalEquations.add`.

    ``raw`` (N, 3) outputs; ``magnitude`` (N,) the input magnitude per sample in
    input units, independent of the triad (another sensor, a known
    trajectory); ``noise_var`` (3,) per-sample variance of the corrected output
    in units of m0^2, subtracted from the squares (note §3). z = 1/2 (|y|^2 -
    mu^2) with y in units of m0: dividing by mu^2 gives F0 against regressors
    ``y_j / mu^2`` for the constant B / S (note §6). Weights: the inverse
    variance of z from the white noise, ``1 / (mu^2 s + s^2)`` with s the mean
    noise variance (1e-6 when unknown), so the normal equations are in chi^2 units.
    """
    y = corrected_normalised(triad, raw, m0)
    mu = np.asarray(magnitude, dtype=float) / m0
    h = _regressors(y)
    z = 0.5 * (np.einsum("ij,ij->i", y, y) - mu * mu)
    s2 = 1e-6
    if noise_var is not None:
        nv = np.asarray(noise_var, dtype=float)
        h[:, 3:6] -= nv
        z -= 0.5 * float(np.sum(nv))
        s2 = max(float(np.mean(nv)), 1e-30)
    w = 1.0 / (mu * mu * s2 + s2 * s2)
    return h, z, w, y, None if noise_var is None else np.asarray(noise_var, dtype=float)


def samples_normal_equations(
    triad: TriadModel | TriadForm,
    raw: np.ndarray,
    magnitude: np.ndarray,
    m0: float,
    noise_var: np.ndarray | None = None,
) -> NormalEquations:
    """Normal equations of the moving-base variant over samples (see :func:`sample_rows`)."""
    ne = NormalEquations()
    ne.add(*sample_rows(triad, raw, magnitude, m0, noise_var))
    return ne


def interval_normal_equations(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    covs: np.ndarray,
    counts: np.ndarray,
    magnitude: float | np.ndarray,
    m0: float,
) -> NormalEquations:
    """The paper's literal per-sample normal equations, from interval moments.

    Every sample of interval i enters with F0 of the noisy sample, i.e. the
    regressors and target are averages of squares (mean^2 + variance), not
    squares of averages: what a literal per-sample implementation computes.
    Each sample is weighted by the inverse variance of its F0 (chi^2 units).
    """
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    k = means.shape[0]
    mu = np.broadcast_to(np.asarray(magnitude, dtype=float), (k,)) / m0
    y = corrected_normalised(triad, means, m0)
    theta_c, _ = certificate_internal(triad, m0)
    pinv = np.linalg.inv(p_matrix(theta_c[3:]))
    scale = 1.0 / (triad.scale_factor * m0)
    cy = pinv @ (np.asarray(covs) * np.outer(scale, scale)) @ pinv.T  # (K, 3, 3)
    m2 = np.einsum("ki,kj->kij", y, y) + cy
    mu2 = (mu * mu)[:, None]
    h = (
        np.concatenate(
            [
                y,
                np.stack(
                    [m2[:, 0, 0], m2[:, 1, 1], m2[:, 2, 2], m2[:, 0, 1], m2[:, 0, 2], m2[:, 1, 2]],
                    axis=1,
                ),
            ],
            axis=1,
        )
        / mu2
    )
    z = 0.5 * (np.trace(m2, axis1=1, axis2=2) / mu2[:, 0] - 1.0)
    n = np.asarray(counts, dtype=float)
    # variance of one sample's F0 about its interval mean
    f0_var = np.einsum("ki,kij,kj->k", y, cy, y) / mu2[:, 0] ** 2
    f0_var = np.maximum(f0_var, RESIDUAL_FLOOR**2)
    ne = NormalEquations()
    ne.add(h, z, n / f0_var)
    # the per-sample scatter of F0 about the interval mean adds to the residual sum
    ne.zz += float(np.sum(n))
    ne.n = int(n.sum())
    return ne


def normal_equation_fit(
    triad: TriadModel | TriadForm,
    ne: NormalEquations,
    m0: float,
    method: str,
    determined_std_ratio: float = 0.5,
    points: int | None = None,
    prior_factor: float = 10.0,
) -> TriadFit:
    """Least squares from normal equations in chi^2 units, with the same weak prior at the
    certificate as the exact fit (``prior_factor`` limits), covariance scaled by
    chi^2 / dof when above 1."""
    lim = internal_limits(triad, m0)
    if ne.n <= 9 or not np.any(ne.a):
        from .params import undetermined_fit

        return undetermined_fit(triad, method, "too few samples for the 9-parameter fit")
    d = lim
    a_s = ne.a * np.outer(d, d)
    # the errors-in-variables correction can leave small negative eigenvalues where
    # the data carry no information: no information is zero, not negative
    ev, evec = np.linalg.eigh(0.5 * (a_s + a_s.T))
    a_s = (evec * np.maximum(ev, 0.0)) @ evec.T
    hess = a_s + np.eye(9) / prior_factor**2
    inv_s = np.linalg.pinv(hess)
    delta = d * (inv_s @ (ne.b * d))
    chi2 = ne.zz - 2.0 * float(delta @ ne.b) + float((delta / d) @ a_s @ (delta / d))
    dof = ne.n - float(np.trace(inv_s @ a_s))
    ratio = max(chi2, 0.0) / dof if dof > 0.5 else 1.0
    cov = np.outer(d, d) * inv_s * max(1.0, ratio)
    ev = np.linalg.eigvalsh(a_s)
    cond = float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")
    fit = _finish(
        triad,
        method,
        m0,
        delta,
        cov,
        np.zeros(9, dtype=bool),
        determined_std_ratio,
        cond,
        int(points if points is not None else ne.n),
        float(np.sqrt(max(ratio, 0.0))),
    )
    fit.dof = dof
    return fit


def linear_fit(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    covs: np.ndarray,
    counts: np.ndarray,
    magnitude: float | np.ndarray,
    determined_std_ratio: float = 0.5,
    prior_factor: float = 10.0,
) -> TriadFit:
    """The paper's literal linearised least squares over the samples of the intervals."""
    mag = np.asarray(magnitude, dtype=float)
    m0 = float(np.median(mag)) if mag.ndim else float(mag)
    ne = interval_normal_equations(triad, means, covs, counts, magnitude, m0)
    return normal_equation_fit(
        triad,
        ne,
        m0,
        "linear",
        determined_std_ratio,
        points=len(np.atleast_2d(means)),
        prior_factor=prior_factor,
    )


__all__ = [
    "exact_fit",
    "robust_exact_fit",
    "robust_exact_fit_and_plain",
    "linear_fit",
    "NormalEquations",
    "samples_normal_equations",
    "sample_rows",
    "interval_normal_equations",
    "normal_equation_fit",
    "corrected_normalised",
    "RESIDUAL_FLOOR",
]
