"""Optional compiled kernels of the window fits (numba, the ``fleet`` extra; issue 28).

The exact fit (:func:`.scalar_fit.exact_fit`) runs a small damped Gauss-Newton loop once or
more per window and per outlier probe: 10-50 interval means, 9 parameters, 10-30 cost
evaluations, each a handful of numpy calls on arrays of a few hundred numbers, so numpy's
per-call overhead is most of its CPU. :func:`exact_gauss_newton` is the same loop compiled by
numba: the same residuals, weights, cost, Jacobian, damping, step control and stopping rule,
in the same order. Its 9x9 damped normal equations are solved by Gaussian elimination with
partial pivoting on the Jacobi-scaled matrix instead of LAPACK's SVD least squares
(``np.linalg.lstsq``), so its floats differ from the plain loop's by rounding; where that
matrix is ill-conditioned (a pivot below :data:`PIVOT_RATIO` of the largest), the kernel gives
up and the plain loop runs instead, so rounding is never amplified beyond that of a
well-conditioned solve (``tests/test_fit_kernels.py`` holds the two to each other).

The plain numpy loop stays the reference and the default. :func:`enable` switches the kernel
on in this process where numba is installed: the fleet's workers do it once (the JIT compile,
or the load of numba's on-disk cache, is paid by the worker's first task, outside that log's
CPU figure); ``imudiag diagnose`` and the daemon keep the plain loop unless
``IMUDIAG_KERNELS=numba`` is set in the environment.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np

#: Smallest |pivot| / largest |pivot| of the Jacobi-scaled damped normal matrix the kernel
#: solves itself; below it the plain loop (SVD least squares) runs the fit instead.
PIVOT_RATIO = 1e-8

#: "on": None until the first :func:`enabled` reads ``IMUDIAG_KERNELS``
_STATE: dict[str, Any] = {"on": None, "kernel": None, "error": None}


def available() -> bool:
    """Whether numba can be imported here (the ``fleet`` extra installs it)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def enable(on: bool = True) -> bool:
    """Use the compiled kernels in this process from now on (``on``), or the plain loops;
    returns whether the kernels are in use. The first enable compiles them (or loads numba's
    cache) and runs them once; without numba, or when that fails, the plain loops stay and
    :func:`status` says why."""
    if not on:
        _STATE["on"] = False
        return False
    if _STATE["kernel"] is None:
        try:
            _STATE["kernel"] = _compile()
        except Exception as exc:  # noqa: BLE001 - no numba, or a failed compile: plain loops
            _STATE["error"] = f"{type(exc).__name__}: {exc}"
            _STATE["on"] = False
            return False
    _STATE["on"] = True
    return True


def enabled() -> bool:
    """Whether the compiled kernels are in use in this process (the first call switches them
    on when ``IMUDIAG_KERNELS=numba`` is set in the environment)."""
    if _STATE["on"] is None:
        _STATE["on"] = False
        if os.environ.get("IMUDIAG_KERNELS", "").strip().lower() == "numba":
            enable(True)
    return bool(_STATE["on"])


def status() -> str:
    """``numba`` when the kernels are in use, else ``plain`` and why."""
    if _STATE["on"]:
        return "numba"
    return "plain" + (f" ({_STATE['error']})" if _STATE["error"] else "")


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
    kernel: Callable[..., Any] | None = _STATE["kernel"] if enabled() else None
    if kernel is None:
        return None
    ok, th, r, jac, sig2 = kernel(
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


def _compile() -> Callable[..., Any]:
    """The numba kernel of :func:`exact_gauss_newton`, compiled (cached on disk) and run once."""
    import numba

    jit = numba.njit(cache=True, nogil=True)

    @jit
    def residuals(th, v, mu, var_v, prior_prec, theta_c, extra, floor2, r, x, w, sig2):
        # P (symmetric) of the shape th[3:9] and its inverse (adjugate / determinant)
        p00 = 1.0 + th[3]
        p11 = 1.0 + th[4]
        p22 = 1.0 + th[5]
        p01 = 0.5 * th[6]
        p02 = 0.5 * th[7]
        p12 = 0.5 * th[8]
        c00 = p11 * p22 - p12 * p12
        c01 = p02 * p12 - p01 * p22
        c02 = p01 * p12 - p02 * p11
        c11 = p00 * p22 - p02 * p02
        c12 = p01 * p02 - p00 * p12
        c22 = p00 * p11 - p01 * p01
        det = p00 * c00 + p01 * c01 + p02 * c02
        i00 = c00 / det
        i01 = c01 / det
        i02 = c02 / det
        i11 = c11 / det
        i12 = c12 / det
        i22 = c22 / det
        k = v.shape[0]
        cost = 0.0
        for n in range(k):
            a0 = v[n, 0] - th[0]
            a1 = v[n, 1] - th[1]
            a2 = v[n, 2] - th[2]
            x0 = i00 * a0 + i01 * a1 + i02 * a2
            x1 = i01 * a0 + i11 * a1 + i12 * a2
            x2 = i02 * a0 + i12 * a1 + i22 * a2
            nx = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            h0 = x0 / nx
            h1 = x1 / nx
            h2 = x2 / nx
            w0 = i00 * h0 + i01 * h1 + i02 * h2
            w1 = i01 * h0 + i11 * h1 + i12 * h2
            w2 = i02 * h0 + i12 * h1 + i22 * h2
            x[n, 0] = x0
            x[n, 1] = x1
            x[n, 2] = x2
            w[n, 0] = w0
            w[n, 1] = w1
            w[n, 2] = w2
            rn = nx - mu[n]
            r[n] = rn
            s2 = w0 * w0 * var_v[n, 0] + w1 * w1 * var_v[n, 1] + w2 * w2 * var_v[n, 2]
            s2 = s2 + floor2 + extra
            sig2[n] = s2
            cost += rn * rn / s2
        for i in range(9):
            d = th[i] - theta_c[i]
            cost += prior_prec[i] * d * d
        return cost

    @jit
    def jacobian(x, w, jac):
        for n in range(x.shape[0]):
            jac[n, 0] = -w[n, 0]
            jac[n, 1] = -w[n, 1]
            jac[n, 2] = -w[n, 2]
            jac[n, 3] = -w[n, 0] * x[n, 0]
            jac[n, 4] = -w[n, 1] * x[n, 1]
            jac[n, 5] = -w[n, 2] * x[n, 2]
            jac[n, 6] = -0.5 * (w[n, 0] * x[n, 1] + w[n, 1] * x[n, 0])
            jac[n, 7] = -0.5 * (w[n, 0] * x[n, 2] + w[n, 2] * x[n, 0])
            jac[n, 8] = -0.5 * (w[n, 1] * x[n, 2] + w[n, 2] * x[n, 1])

    @jit
    def solve(a, b, out):
        # Gaussian elimination with partial pivoting on D^-1/2 A D^-1/2 (D = diag A > 0);
        # False when a pivot is below PIVOT_RATIO of the largest (ill-conditioned)
        m = a.shape[0]
        s = np.empty(m)
        for i in range(m):
            s[i] = 1.0 / np.sqrt(a[i, i])
        aa = np.empty((m, m))
        bb = np.empty(m)
        for i in range(m):
            bb[i] = b[i] * s[i]
            for j in range(m):
                aa[i, j] = a[i, j] * s[i] * s[j]
        big = 0.0
        small = np.inf
        for c in range(m):
            piv = c
            best = abs(aa[c, c])
            for i in range(c + 1, m):
                if abs(aa[i, c]) > best:
                    best = abs(aa[i, c])
                    piv = i
            if piv != c:
                for j in range(m):
                    t = aa[c, j]
                    aa[c, j] = aa[piv, j]
                    aa[piv, j] = t
                t = bb[c]
                bb[c] = bb[piv]
                bb[piv] = t
            big = max(big, best)
            small = min(small, best)
            if not best > 0.0:
                return False
            for i in range(c + 1, m):
                f = aa[i, c] / aa[c, c]
                if f != 0.0:
                    for j in range(c, m):
                        aa[i, j] -= f * aa[c, j]
                    bb[i] -= f * bb[c]
        if not small >= PIVOT_RATIO * big:
            return False
        for i in range(m - 1, -1, -1):
            acc = bb[i]
            for j in range(i + 1, m):
                acc -= aa[i, j] * out[j]
            out[i] = acc / aa[i, i]
        for i in range(m):
            out[i] *= s[i]
        return True

    @jit
    def gauss_newton(theta, extra, v, mu, var_v, prior_prec, theta_c, max_iter, max_shape, floor2):
        k = v.shape[0]
        th = theta.copy()
        r = np.empty(k)
        x = np.empty((k, 3))
        w = np.empty((k, 3))
        sig2 = np.empty(k)
        r1 = np.empty(k)
        x1 = np.empty((k, 3))
        w1 = np.empty((k, 3))
        s1 = np.empty(k)
        jac = np.empty((k, 9))
        hess = np.empty((9, 9))
        a = np.empty((9, 9))
        grad = np.empty(9)
        step = np.empty(9)
        cand = np.empty(9)
        c0 = residuals(th, v, mu, var_v, prior_prec, theta_c, extra, floor2, r, x, w, sig2)
        jacobian(x, w, jac)
        lam = 1e-6
        wgt = np.empty(k)
        for _ in range(max_iter):
            for n in range(k):
                wgt[n] = 1.0 / sig2[n]
            for i in range(9):
                for j in range(9):
                    acc = 0.0
                    for n in range(k):
                        acc += jac[n, i] * (jac[n, j] * wgt[n])
                    hess[i, j] = acc
                hess[i, i] += prior_prec[i]
                acc = 0.0
                for n in range(k):
                    acc += jac[n, i] * (r[n] * wgt[n])
                grad[i] = acc + prior_prec[i] * (th[i] - theta_c[i])
            c_before = c0
            accepted = False
            for _try in range(16):
                for i in range(9):
                    for j in range(9):
                        a[i, j] = hess[i, j]
                    a[i, i] = hess[i, i] + lam * max(hess[i, i], 1e-30)
                if not solve(a, grad, step):
                    return False, th, r, jac, sig2
                far = 0.0
                for i in range(9):
                    cand[i] = th[i] - step[i]
                    if i >= 3:
                        far = max(far, abs(cand[i] - theta_c[i]))
                if far > max_shape:
                    lam *= 10.0
                    continue
                c1 = residuals(
                    cand, v, mu, var_v, prior_prec, theta_c, extra, floor2, r1, x1, w1, s1
                )
                if np.isfinite(c1) and c1 <= c0:
                    th[:] = cand
                    c0 = c1
                    r[:] = r1
                    x[:, :] = x1
                    w[:, :] = w1
                    sig2[:] = s1
                    jacobian(x, w, jac)
                    lam = max(lam / 10.0, 1e-12)
                    accepted = True
                    break
                lam *= 10.0
            if not accepted or (c_before - c0) <= max(1e-3, 1e-9 * c0):
                break
        return True, th, r, jac, sig2

    # compile (or load the cache) now: the worker's first task pays it, not a log
    rng = np.random.default_rng(0)
    v = rng.normal(size=(12, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    gauss_newton(
        np.zeros(9),
        0.0,
        v,
        np.ones(12),
        np.full((12, 3), 1e-8),
        np.ones(9),
        np.zeros(9),
        20,
        0.5,
        1e-14,
    )
    return gauss_newton
