"""Optional compiled kernels of the window fits (numba, the ``fleet`` extra; issue 28).

The exact fit (:func:`.scalar_fit.exact_fit`) runs a small damped Gauss-Newton loop once or
more per window and per outlier probe: 10-50 interval means, 9 parameters, 10-30 cost
evaluations, each a handful of numpy calls on arrays of a few hundred numbers, so numpy's
per-call overhead is most of its CPU. :func:`exact_gauss_newton` is the same loop compiled by
numba: the same residuals, weights, cost, Jacobian, damping, step control and stopping rule,
in the same order. Its 9x9 damped normal equations are solved by Gaussian elimination with
partial pivoting on the Jacobi-scaled matrix instead of LAPACK's SVD least squares
(``np.linalg.lstsq``), so its floats differ from the plain loop's by rounding. Where that
elimination breaks down (no pivot, or one below :data:`imudiag.numba_kernels.PIVOT_RATIO` of the
largest: singular even after the damping, or not numbers) the kernel gives up and the plain
loop runs the fit instead. ``tests/test_fit_kernels.py`` holds the two to each other, and
whole reports made with the kernels to the frozen ones within the cross-processor tolerance
(the rounding of a near-singular window differs there as between processors).

Beyond the loop, :func:`imudiag.numba_kernels.exact_fit_kernel` runs the whole exact fit after
its set-up in one call (linear start, the loop with its excess-variance refits, covariance,
deletion figures, predictions: :func:`.scalar_fit.exact_fit` calls it where the kernels are on
and falls back to the plain path where it gives up); ``tests/test_exact_fit_kernel.py``.

The gyro rotation fit evaluates each motion's rotation and its sensitivity to N^-1
(:func:`imudiag.rotations.segmented_product_sensitivity`, a pairwise product tree in numpy)
once per try; :func:`product_sensitivity` is the same figures compiled, the products taken
along each motion in order, so again equal to rounding; so are N^-1 and its derivatives
(:func:`ninv_derivatives`) and the predicted directions with theirs
(:func:`predict_directions`).

The kernels themselves are in :mod:`imudiag.numba_kernels`, their switch (on or off, per
process or per thread, :func:`enable`, :func:`switched`, :func:`enabled`, :func:`load`,
:func:`status`) in :mod:`imudiag.kernels` (the ground floor, so that the still detector and
the GNSS epoch cut below and beside this floor use the same switch); both re-exported here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..kernels import available, enable, enabled, kernel, load, status, switched


def exact_gauss_newton(
    theta: np.ndarray,
    extra: float,
    v: np.ndarray,
    mu: np.ndarray,
    var_v: np.ndarray,
    prior_prec: np.ndarray,
    theta_c: np.ndarray,
    max_iter: int,
    max_shape: float,
    floor2: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The exact fit's damped Gauss-Newton loop, compiled: (theta (9,), residuals (K,),
    Jacobian (K, 9), residual variances (K,)), all in the fit's dimensionless units, as the
    plain loop of :func:`.scalar_fit.exact_fit`; None when the kernels are off or a solve was
    ill-conditioned (the caller runs the plain loop)."""
    loop: Callable[..., Any] | None = kernel("exact_gauss_newton")
    if loop is None:
        return None
    ok, th, r, jac, sig2 = loop(
        np.ascontiguousarray(theta, dtype=float),
        float(extra),
        np.ascontiguousarray(v, dtype=float),
        np.ascontiguousarray(mu, dtype=float),
        np.ascontiguousarray(var_v, dtype=float),
        np.ascontiguousarray(prior_prec, dtype=float),
        np.ascontiguousarray(theta_c, dtype=float),
        int(max_iter),
        float(max_shape),
        float(floor2),
    )
    if not ok:
        return None
    return th, r, jac, sig2


def product_sensitivity(
    theta: np.ndarray, inc: np.ndarray, lengths: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`imudiag.rotations.segmented_product_sensitivity` compiled: the ordered products
    (S, 4) of the rotation vectors ``theta`` (K, 3), rad, by segment of ``lengths`` (S,), and
    their sensitivity (S, 3, 3, 3) to L where ``theta = L inc``; None when the kernels are
    off. Each segment's product is taken left to right and its suffixes right to left (the
    plain path multiplies pairwise up and down a tree): equal to rounding."""
    compiled = kernel("product_sensitivity")
    if compiled is None:
        return None
    q, sens = compiled(
        np.ascontiguousarray(theta, dtype=float),
        np.ascontiguousarray(inc, dtype=float),
        np.ascontiguousarray(lengths, dtype=np.int64),
    )
    return q, sens.reshape(-1, 3, 3, 3)


def ninv_derivatives(
    shape_c: np.ndarray, q_c: np.ndarray, x: np.ndarray, fit_frame: bool
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`.gyro_fit.ninv_derivatives` compiled (N^-1 (3, 3) and its derivatives (npar,
    3, 3) per parameter unit); None when the kernels are off."""
    compiled = kernel("ninv_derivatives")
    if compiled is None:
        return None
    out: tuple[np.ndarray, np.ndarray] = compiled(
        np.ascontiguousarray(shape_c, dtype=float),
        np.ascontiguousarray(q_c, dtype=float),
        np.ascontiguousarray(x, dtype=float),
        bool(fit_frame),
    )
    return out


def predict_directions(
    q: np.ndarray, sens: np.ndarray, dninv: np.ndarray, up0: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The rotation fit's predicted end directions (n, 3) and their derivatives (n, 3, m)
    from the motions' rotations ``q`` (n, 4), sensitivities ``sens`` (n, 3, 3, 3), dN^-1
    (m, 3, 3) and start directions ``up0`` (n, 3), compiled; None when the kernels are off."""
    compiled = kernel("predict")
    if compiled is None:
        return None
    out: tuple[np.ndarray, np.ndarray] = compiled(
        np.ascontiguousarray(q, dtype=float),
        np.ascontiguousarray(sens, dtype=float),
        np.ascontiguousarray(dninv, dtype=float),
        np.ascontiguousarray(up0, dtype=float),
    )
    return out


def rotation_loop(
    x: np.ndarray,
    stack: dict[str, np.ndarray],
    up0: np.ndarray,
    up1: np.ndarray,
    wgt: np.ndarray,
    prior_prec: np.ndarray,
    shape_c: np.ndarray,
    q_c: np.ndarray,
    fit_frame: bool,
    max_iter: int,
    max_shape: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """The gyro rotation fit's damped Gauss-Newton loop compiled
    (:func:`imudiag.numba_kernels.rotation_loop`) from ``x`` (npar,), its evaluations
    compiled too: (x, residuals (3 n,), Jacobian (3 n, npar), cost) at its end, as the plain
    loop of :func:`.gyro_fit.rotation_fit`, equal to rounding; None when the kernels are
    off or a damped solve was ill-conditioned (the caller runs the plain loop). ``stack``:
    the motions' turning blocks (``turning`` (K, 3) rad) and each motion's count of them
    (``lengths``)."""
    loop: Callable[..., Any] | None = kernel("rotation_loop")
    if loop is None:
        return None
    ok, x1, r1, j1, c1 = loop(
        np.ascontiguousarray(x, dtype=float),
        np.ascontiguousarray(stack["turning"], dtype=float),
        np.ascontiguousarray(stack["lengths"], dtype=np.int64),
        np.ascontiguousarray(up0, dtype=float),
        np.ascontiguousarray(up1, dtype=float),
        np.ascontiguousarray(wgt, dtype=float),
        np.ascontiguousarray(prior_prec, dtype=float),
        np.ascontiguousarray(shape_c, dtype=float),
        np.ascontiguousarray(q_c, dtype=float),
        bool(fit_frame),
        int(max_iter),
        float(max_shape),
    )
    if not ok:
        return None
    return x1, r1, j1, float(c1)


def rotation_post(
    jac: np.ndarray, res: np.ndarray, wgt: np.ndarray, prior_prec: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float, np.ndarray, np.ndarray, float, np.ndarray] | None:
    """What the gyro rotation fit works out after its loop, compiled
    (:func:`imudiag.numba_kernels.rotation_post`): (information, unscaled covariance, chi^2,
    degrees of freedom, each motion's deletion shift (G, npar), z (G,), the robust excess,
    the deletion variances (G, npar)), as :func:`.gyro_fit.rotation_fit`'s numpy with
    :func:`.robust.point_diagnostics`, equal to rounding; None when the kernels are off or
    the covariance or a motion's solve is ill-conditioned (the caller runs the numpy)."""
    from .robust import CHI2_1_MEDIAN, MAX_LEVERAGE

    post: Callable[..., Any] | None = kernel("rotation_post")
    if post is None:
        return None
    ok, info, cov, chi2, dof, shift, z, excess, loo_var = post(
        np.ascontiguousarray(jac, dtype=float),
        np.ascontiguousarray(res, dtype=float),
        np.ascontiguousarray(wgt, dtype=float),
        np.ascontiguousarray(prior_prec, dtype=float),
        float(MAX_LEVERAGE),
        float(CHI2_1_MEDIAN),
    )
    if not ok:
        return None
    return info, cov, float(chi2), float(dof), shift, z, float(excess), loo_var


__all__ = [
    "available",
    "enable",
    "enabled",
    "exact_gauss_newton",
    "kernel",
    "load",
    "ninv_derivatives",
    "predict_directions",
    "product_sensitivity",
    "rotation_loop",
    "rotation_post",
    "status",
    "switched",
]
