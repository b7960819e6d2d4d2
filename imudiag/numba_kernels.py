"""The numba kernels switched by :mod:`imudiag.kernels` (imported by it only when they are
loaded: this module needs numba, the ``fleet`` extra): the window fits
(:func:`exact_fit_kernel`, the loops of :mod:`imudiag.diagnosis.kernels`), the GNSS epoch cut
(:func:`epoch_cut`) and the still detector's passes (:func:`window_rows`,
:func:`window_rates`, :func:`variance_test`, :func:`jump_test`, :func:`drift_within`,
:func:`trailing_spread`), the prefix sums' pass (:func:`chunked_cumsum`, :func:`stack_backs`)
and the monitor's vibration high-pass, stuck scan and noise differences
(:func:`highpass_squares`, :func:`stuck_scan`, :func:`second_diff_squares`). Module-level
functions, so numba's on-disk cache (``cache=True``) serves every later process: a fleet
worker loads them instead of compiling.
Plain arithmetic only, in the order of the numpy paths (no fast-math: no reassociation, no
fused multiply-add); where a kernel solves otherwise (the exact fit's Cholesky and Jacobi
SVD for LAPACK's), it is equal to rounding and says so."""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

#: Smallest |pivot| / largest |pivot| of the Jacobi-scaled damped normal matrix the exact
#: fit's kernel solves itself; below it the plain loop (SVD least squares) runs the fit.
PIVOT_RATIO = 1e-8

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
            c1 = residuals(cand, v, mu, var_v, prior_prec, theta_c, extra, floor2, r1, x1, w1, s1)
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


@jit
def so3_coefficients(a, a2):
    # (1 - cos a) / a^2 and (a - sin a) / a^3 of the rotation vector's length a (a2 = a^2),
    # by their series below 1e-2 rad
    if a < 1e-2:
        c1 = 0.5 - a2 / 24.0 + a2 * a2 / 720.0
        c2 = 1.0 / 6.0 - a2 / 120.0 + a2 * a2 / 5040.0
    else:
        c1 = (1.0 - np.cos(a)) / a**2
        c2 = (a - np.sin(a)) / a**3
    return c1, c2


@jit
def qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    # Hamilton product, each component's terms in qmul's order
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    )


@jit
def product_sensitivity_kernel(theta, inc, lengths):
    s_count = lengths.shape[0]
    out = np.zeros((s_count, 4))
    sens = np.zeros((s_count, 27))
    quat = np.empty((theta.shape[0], 4))
    for k in range(theta.shape[0]):
        x, y, z = theta[k, 0], theta[k, 1], theta[k, 2]
        a2 = x * x + y * y + z * z
        a = np.sqrt(a2)
        half = 0.5 * a
        kk = np.sin(half) / a if a > 1e-4 else 0.5 - a2 / 48.0
        quat[k, 0] = np.cos(half)
        quat[k, 1] = x * kk
        quat[k, 2] = y * kk
        quat[k, 3] = z * kk
    first = 0
    for s in range(s_count):
        n = lengths[s]
        # the suffix after the last block: the identity
        s0, s1, s2, s3 = 1.0, 0.0, 0.0, 0.0
        for k in range(first + n - 1, first - 1, -1):
            # S_k^T J_r(theta_k), S_k the product of the blocks after k
            nq = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3)
            w, qx, qy, qz = s0 / nq, s1 / nq, s2 / nq, s3 / nq
            r00 = 1 - 2 * (qy * qy + qz * qz)
            r01 = 2 * (qx * qy - w * qz)
            r02 = 2 * (qx * qz + w * qy)
            r10 = 2 * (qx * qy + w * qz)
            r11 = 1 - 2 * (qx * qx + qz * qz)
            r12 = 2 * (qy * qz - w * qx)
            r20 = 2 * (qx * qz - w * qy)
            r21 = 2 * (qy * qz + w * qx)
            r22 = 1 - 2 * (qx * qx + qy * qy)
            x, y, z = theta[k, 0], theta[k, 1], theta[k, 2]
            a2 = x * x + y * y + z * z
            a = np.sqrt(a2)
            c1, c2 = so3_coefficients(a, a2)
            dg = 1.0 - c2 * a2
            cx, cy, cz = c1 * x, c1 * y, c1 * z
            gx, gy, gz = c2 * x, c2 * y, c2 * z
            j00, j01, j02 = dg + gx * x, gx * y + cz, gx * z - cy
            j10, j11, j12 = gy * x - cz, dg + gy * y, gy * z + cx
            j20, j21, j22 = gz * x + cy, gz * y - cx, dg + gz * z
            r = ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22))
            jm = ((j00, j01, j02), (j10, j11, j12), (j20, j21, j22))
            i0, i1, i2 = inc[k, 0], inc[k, 1], inc[k, 2]
            for i in range(3):
                for j in range(3):
                    aij = r[0][i] * jm[0][j] + r[1][i] * jm[1][j] + r[2][i] * jm[2][j]
                    base = 9 * i + 3 * j
                    sens[s, base] += aij * i0
                    sens[s, base + 1] += aij * i1
                    sens[s, base + 2] += aij * i2
            s0, s1, s2, s3 = qmul(quat[k, 0], quat[k, 1], quat[k, 2], quat[k, 3], s0, s1, s2, s3)
        out[s, 0], out[s, 1], out[s, 2], out[s, 3] = s0, s1, s2, s3
        first += n
    return out, sens


@jit
def inv3(a):
    """Inverse of a 3x3 matrix by its adjugate."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    c02 = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    c10 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c11 = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    c12 = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    c20 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    c21 = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    c22 = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    det = a[0, 0] * c00 + a[0, 1] * c10 + a[0, 2] * c20
    out = np.empty((3, 3))
    out[0, 0], out[0, 1], out[0, 2] = c00 / det, c01 / det, c02 / det
    out[1, 0], out[1, 1], out[1, 2] = c10 / det, c11 / det, c12 / det
    out[2, 0], out[2, 1], out[2, 2] = c20 / det, c21 / det, c22 / det
    return out


@jit
def quat_rows(w, x, y, z):
    """Rotation matrix of a quaternion (normalised), as :func:`imudiag.rotations.quat_matrix`."""
    nq = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / nq, x / nq, y / nq, z / nq
    r = np.empty((3, 3))
    r[0, 0] = 1 - 2 * (y * y + z * z)
    r[0, 1] = 2 * (x * y - w * z)
    r[0, 2] = 2 * (x * z + w * y)
    r[1, 0] = 2 * (x * y + w * z)
    r[1, 1] = 1 - 2 * (x * x + z * z)
    r[1, 2] = 2 * (y * z - w * x)
    r[2, 0] = 2 * (x * z - w * y)
    r[2, 1] = 2 * (y * z + w * x)
    r[2, 2] = 1 - 2 * (x * x + y * y)
    return r


@jit
def ninv_derivatives_kernel(shape_c, q_c, x, fit_frame):
    """N^-1 (3, 3) and dN^-1 (npar, 3, 3) of the rotation fit's parameters ``x``, as
    :func:`imudiag.diagnosis.gyro_fit.ninv_derivatives`."""
    npar = x.shape[0]
    s = np.empty(6)
    for i in range(6):
        s[i] = shape_c[i] + x[i]
    p = np.empty((3, 3))
    p[0, 0], p[1, 1], p[2, 2] = 1.0 + s[0], 1.0 + s[1], 1.0 + s[2]
    p[0, 1] = p[1, 0] = 0.5 * s[3]
    p[0, 2] = p[2, 0] = 0.5 * s[4]
    p[1, 2] = p[2, 1] = 0.5 * s[5]
    d_rf = np.zeros((3, 3, 3))
    if fit_frame:
        f0, f1, f2 = x[6], x[7], x[8]
        a2 = f0 * f0 + f1 * f1 + f2 * f2
        a = np.sqrt(a2)
        half = 0.5 * a
        k = np.sin(half) / a if a > 1e-4 else 0.5 - a2 / 48.0
        rf = quat_rows(np.cos(half), f0 * k, f1 * k, f2 * k)
        c1, c2 = so3_coefficients(a, a2)
        dg = 1.0 - c2 * a2
        jr = np.empty((3, 3))
        jr[0, 0], jr[0, 1], jr[0, 2] = (
            dg + c2 * f0 * f0,
            c2 * f0 * f1 + c1 * f2,
            c2 * f0 * f2 - c1 * f1,
        )
        jr[1, 0], jr[1, 1], jr[1, 2] = (
            c2 * f1 * f0 - c1 * f2,
            dg + c2 * f1 * f1,
            c2 * f1 * f2 + c1 * f0,
        )
        jr[2, 0], jr[2, 1], jr[2, 2] = (
            c2 * f2 * f0 + c1 * f1,
            c2 * f2 * f1 - c1 * f0,
            dg + c2 * f2 * f2,
        )
        for j in range(3):
            v0, v1, v2 = jr[0, j], jr[1, j], jr[2, j]  # column j of J_r
            sk = np.zeros((3, 3))
            sk[0, 1], sk[0, 2] = -v2, v1
            sk[1, 0], sk[1, 2] = v2, -v0
            sk[2, 0], sk[2, 1] = -v1, v0
            d_rf[j] = rf @ sk
    else:
        rf = np.eye(3)
    rq = rf @ q_c
    n = p @ rq
    d_n = np.zeros((npar, 3, 3))
    for i in range(min(npar, 6)):
        e = np.zeros((3, 3))
        if i < 3:
            e[i, i] = 1.0
        elif i == 3:
            e[0, 1] = e[1, 0] = 0.5
        elif i == 4:
            e[0, 2] = e[2, 0] = 0.5
        else:
            e[1, 2] = e[2, 1] = 0.5
        d_n[i] = e @ rq
    for j in range(npar - 6):
        d_n[6 + j] = p @ d_rf[j] @ q_c
    ninv = inv3(n)
    dninv = np.empty((npar, 3, 3))
    for i in range(npar):
        dninv[i] = -(ninv @ d_n[i] @ ninv)
    return ninv, dninv


@jit
def predict_kernel(q, sens, dninv, up0):
    """Predicted end directions (n, 3) and their derivatives (n, 3, m), as
    :func:`imudiag.diagnosis.gyro_fit.predict_with_jacobian` after its motion products."""
    n = q.shape[0]
    m = dninv.shape[0]
    pred = np.empty((n, 3))
    d = np.empty((n, 3, m))
    omega = np.empty((3, m))
    for k in range(n):
        c = quat_rows(q[k, 0], q[k, 1], q[k, 2], q[k, 3])
        for i in range(3):
            pred[k, i] = c[0, i] * up0[k, 0] + c[1, i] * up0[k, 1] + c[2, i] * up0[k, 2]
        for a in range(3):
            for mm in range(m):
                acc = 0.0
                for cc in range(3):
                    for dd in range(3):
                        acc += sens[k, a, cc, dd] * dninv[mm, cc, dd]
                omega[a, mm] = acc
        p0, p1, p2 = pred[k, 0], pred[k, 1], pred[k, 2]
        for mm in range(m):
            o0, o1, o2 = omega[0, mm], omega[1, mm], omega[2, mm]
            d[k, 0, mm] = p1 * o2 - p2 * o1
            d[k, 1, mm] = p2 * o0 - p0 * o2
            d[k, 2, mm] = p0 * o1 - p1 * o0
    return pred, d


@jit
def rotation_evaluate(x, turning, lengths, up0, up1, wgt, prior_prec, shape_c, q_c, fit_frame):
    """The gyro rotation fit's evaluation at ``x`` (npar,), as ``evaluate`` in
    :func:`imudiag.diagnosis.gyro_fit.rotation_fit` with the kernels on: residuals (3 n,)
    of the end directions, their Jacobian (3 n, npar) and the cost (the weighted squares and
    the prior's), from N^-1 and its derivatives (:func:`ninv_derivatives_kernel`), each
    block's rotation vector N^-1 inc, the motions' products and sensitivities
    (:func:`product_sensitivity_kernel`) and the predictions (:func:`predict_kernel`)."""
    npar = x.shape[0]
    ninv, dninv = ninv_derivatives_kernel(shape_c, q_c, x, fit_frame)
    kk = turning.shape[0]
    theta = np.empty((kk, 3))
    for k in range(kk):
        t0, t1, t2 = turning[k, 0], turning[k, 1], turning[k, 2]
        for i in range(3):
            theta[k, i] = t0 * ninv[i, 0] + t1 * ninv[i, 1] + t2 * ninv[i, 2]
    q, sens = product_sensitivity_kernel(theta, turning, lengths)
    pred, d = predict_kernel(q, sens.reshape((lengths.shape[0], 3, 3, 3)), dninv, up0)
    n = pred.shape[0]
    r = np.empty(3 * n)
    jac = np.empty((3 * n, npar))
    cost = 0.0
    for k in range(n):
        for i in range(3):
            row = 3 * k + i
            rr = up1[k, i] - pred[k, i]
            r[row] = rr
            cost += rr * rr * wgt[row]
            for p in range(npar):
                jac[row, p] = d[k, i, p]
    prior = 0.0
    for p in range(npar):
        prior += prior_prec[p] * x[p] * x[p]
    return r, jac, cost + prior


@jit
def rotation_loop(
    x0, turning, lengths, up0, up1, wgt, prior_prec, shape_c, q_c, fit_frame, max_iter,
    max_shape,
):  # fmt: skip
    """The gyro rotation fit's damped Gauss-Newton loop (:func:`imudiag.diagnosis.gyro_fit.
    rotation_fit`) from its start ``x0``: the same evaluations (:func:`rotation_evaluate`),
    normal equations, damping, step control (at most 8 tries a step, the shape within
    ``max_shape``) and stopping rule, the damped system solved by :func:`solve` (the plain
    loop: SVD least squares). (ok, x, residuals, Jacobian, cost); ok False where a solve was
    ill-conditioned (the plain loop then runs the fit)."""
    npar = x0.shape[0]
    x = x0.copy()
    res, jac, cost = rotation_evaluate(
        x, turning, lengths, up0, up1, wgt, prior_prec, shape_c, q_c, fit_frame
    )
    nr = res.shape[0]
    lam = 1e-6
    hess = np.empty((npar, npar))
    grad = np.empty(npar)
    a = np.empty((npar, npar))
    step = np.empty(npar)
    cand = np.empty(npar)
    info = np.empty((npar, npar))
    for _ in range(max_iter):
        weighted_info(jac, wgt, prior_prec, info, hess)
        for p in range(npar):
            g = 0.0
            for r in range(nr):
                g += jac[r, p] * (res[r] * wgt[r])
            grad[p] = g - prior_prec[p] * x[p]
        accepted = False
        done = False
        for _try in range(8):
            for p in range(npar):
                for q in range(npar):
                    a[p, q] = hess[p, q]
                a[p, p] += lam * max(hess[p, p], 1e-30)
            if not solve(a, grad, step):
                return False, x, res, jac, cost
            big = 0.0
            for p in range(npar):
                cand[p] = x[p] + step[p]
                if p < 6:
                    big = max(big, abs(cand[p]))
            if big > max_shape:
                lam *= 10.0
                continue
            r1, j1, c1 = rotation_evaluate(
                cand, turning, lengths, up0, up1, wgt, prior_prec, shape_c, q_c, fit_frame
            )
            if np.isfinite(c1) and c1 <= cost:
                done = cost - c1 <= max(1e-3, 1e-9 * cost)
                x = cand.copy()
                res, jac, cost = r1, j1, c1
                lam = max(lam / 10.0, 1e-12)
                accepted = True
                break
            lam *= 10.0
        if not accepted or done:
            break
    return True, x, res, jac, cost


@jit
def _solve_columns(a, b, out):
    """``out`` = a^-1 b, column by column of ``b`` (m, k) by :func:`solve`; False where a
    solve breaks down."""
    col = np.empty(a.shape[0])
    rhs = np.empty(a.shape[0])
    for j in range(b.shape[1]):
        for i in range(a.shape[0]):
            rhs[i] = b[i, j]
        if not solve(a, rhs, col):
            return False
        for i in range(a.shape[0]):
            out[i, j] = col[i]
    return True


@jit
def _below_leverage(h, limit):
    """Whether every eigenvalue of the symmetric ``h`` (m, m) is at most ``limit``: limit I - h
    positive semi-definite, by its Cholesky (a zero pivot: an eigenvalue at the limit)."""
    m = h.shape[0]
    lo = np.zeros((m, m))
    for j in range(m):
        acc = limit - h[j, j]
        for q in range(j):
            acc -= lo[j, q] * lo[j, q]
        if acc < 0.0 or acc != acc:
            return False
        d = np.sqrt(acc)
        lo[j, j] = d
        for i in range(j + 1, m):
            acc = -h[i, j]
            for q in range(j):
                acc -= lo[i, q] * lo[j, q]
            if d > 0.0:
                lo[i, j] = acc / d
            elif acc != 0.0:
                return False
            else:
                lo[i, j] = 0.0
    return True


@jit
def rotation_post(jac, res, wgt, prior_prec, max_leverage, chi2_median):
    """What :func:`imudiag.diagnosis.gyro_fit.rotation_fit` works out after its loop,
    compiled: the information (npar, npar) and the unscaled covariance (:func:`spd_inverse`
    of it with the prior), chi^2, the degrees of freedom, and per motion (its three rows) the
    deletion figures of :func:`imudiag.diagnosis.robust.point_diagnostics` (shift (G, npar),
    z (G,), nan where the motion's leverage exceeds ``max_leverage``; the robust common
    excess) and the deletion variances (G, npar) of ``_deletion_variances`` (inf there). (ok,
    info, cov, chi2, dof, shift, z, excess, loo_var); ok False where the covariance is not
    positive definite or too ill-conditioned, or a 3 x 3 solve breaks down (the plain
    path then works it out)."""
    nr = jac.shape[0]
    npar = jac.shape[1]
    g_count = nr // 3
    info = np.empty((npar, npar))
    hess = np.empty((npar, npar))
    weighted_info(jac, wgt, prior_prec, info, hess)
    cov = np.empty((npar, npar))
    shift = np.full((g_count, npar), np.nan)
    z = np.full(g_count, np.nan)
    loo_var = np.full((g_count, npar), np.inf)
    if not spd_inverse(hess, cov):
        return False, info, cov, 0.0, 0.0, shift, z, 0.0, loo_var
    chi2 = 0.0
    for r in range(nr):
        chi2 += res[r] * res[r] * wgt[r]
    trace = 0.0
    for p in range(npar):
        for q in range(npar):
            trace += cov[p, q] * info[q, p]
    dof = 2.0 * g_count - trace
    sw = np.sqrt(wgt)
    u = np.full(g_count, np.nan)
    nv_mean = np.ones(g_count)
    a = np.empty((3, npar))
    ca = np.empty((npar, 3))
    hk = np.empty((3, 3))
    eye_h = np.empty((3, 3))
    s = np.empty((3, 1))
    sol = np.empty((3, 1))
    sol_m = np.empty((3, npar))
    for g in range(g_count):
        for i in range(3):
            for p in range(npar):
                a[i, p] = jac[3 * g + i, p] * sw[3 * g + i]
        for p in range(npar):  # cov a^T (npar, 3)
            for i in range(3):
                acc = 0.0
                for q in range(npar):
                    acc += cov[p, q] * a[i, q]
                ca[p, i] = acc
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for p in range(npar):
                    acc += a[i, p] * ca[p, j]
                hk[i, j] = acc
        for i in range(3):
            for j in range(i + 1, 3):
                m = 0.5 * (hk[i, j] + hk[j, i])
                hk[i, j] = m
                hk[j, i] = m
        if not _below_leverage(hk, max_leverage):
            continue
        for i in range(3):
            for j in range(3):
                eye_h[i, j] = (1.0 if i == j else 0.0) - hk[i, j]
            # the residual rows of -jac: s = sqrt(w) r, with a of -jac (signs cancel in shift)
            s[i, 0] = sw[3 * g + i] * res[3 * g + i]
        if not _solve_columns(eye_h, s, sol):
            return False, info, cov, chi2, dof, shift, z, 0.0, loo_var
        us = 0.0
        nvw = 0.0
        nv = 0.0
        for i in range(3):
            us += s[i, 0] * sol[i, 0]
            nvw += (1.0 / wgt[3 * g + i]) * wgt[3 * g + i]
            nv += 1.0 / wgt[3 * g + i]
        u[g] = us / (nvw / 3.0)
        nv_mean[g] = nv / 3.0
        for p in range(npar):  # point_diagnostics' a is of -jac: its shift is -(cov a^T) sol
            acc = 0.0
            for i in range(3):
                acc += ca[p, i] * sol[i, 0]
            shift[g, p] = -acc
        # deletion variances: diag(cov) + diag(cov a^T (I - hk)^-1 a cov)
        if not _solve_columns(eye_h, ca.T.copy(), sol_m):
            return False, info, cov, chi2, dof, shift, z, 0.0, loo_var
        for p in range(npar):
            acc = 0.0
            for i in range(3):
                acc += ca[p, i] * sol_m[i, p]
            loo_var[g, p] = cov[p, p] + acc
    excess = common_excess(u, nv_mean, 3.0, chi2_median)
    for g in range(g_count):
        z[g] = np.sqrt(u[g] / (3.0 * (1.0 + excess / nv_mean[g])))
    return True, info, cov, chi2, dof, shift, z, excess, loo_var


@jit
def mean_cov3(x):
    """An interval's mean (3,) and sample covariance (3, 3) of ``x`` (N, 3), N >= 2, as
    :func:`imudiag.diagnosis.intervals.mean_and_cov`: the mean summed down the samples in
    order then divided by N (numpy's reduction along the samples: the same bits), the
    covariance from the centred samples' products times 1 / (N - 1) (numpy's: a BLAS
    product, so equal to rounding)."""
    n = x.shape[0]
    mean = np.empty(3)
    for j in range(3):
        acc = x[0, j]
        for i in range(1, n):
            acc += x[i, j]
        mean[j] = acc / n
    m0, m1, m2 = mean[0], mean[1], mean[2]
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    for i in range(n):
        d0 = x[i, 0] - m0
        d1 = x[i, 1] - m1
        d2 = x[i, 2] - m2
        c00 += d0 * d0
        c01 += d0 * d1
        c02 += d0 * d2
        c11 += d1 * d1
        c12 += d1 * d2
        c22 += d2 * d2
    f = 1.0 / (n - 1)
    cov = np.empty((3, 3))
    cov[0, 0] = c00 * f
    cov[1, 1] = c11 * f
    cov[2, 2] = c22 * f
    cov[0, 1] = cov[1, 0] = c01 * f
    cov[0, 2] = cov[2, 0] = c02 * f
    cov[1, 2] = cov[2, 1] = c12 * f
    return mean, cov


@jit
def attitude_labels(up, valid, cos_sep):
    """:func:`imudiag.diagnosis.window.attitude_groups` compiled: each direction of ``up``
    (K, 3) joins the first centre so far whose dot product with it is at least ``cos_sep``,
    else starts a new one; -1 where not ``valid``. The dot products summed left to right
    (numpy's matrix-vector product may round its last bit otherwise: a label could differ
    only for a direction within a rounding of the separation)."""
    k_all = up.shape[0]
    labels = np.full(k_all, -1, dtype=np.int64)
    centres = np.empty((k_all, 3))
    k = 0
    for i in range(k_all):
        if not valid[i]:
            continue
        u0, u1, u2 = up[i, 0], up[i, 1], up[i, 2]
        found = -1
        for c in range(k):
            if centres[c, 0] * u0 + centres[c, 1] * u1 + centres[c, 2] * u2 >= cos_sep:
                found = c
                break
        if found >= 0:
            labels[i] = found
        else:
            centres[k, 0], centres[k, 1], centres[k, 2] = u0, u1, u2
            labels[i] = k
            k += 1
    return labels


@jit
def epoch_cut(accel, fc, gyro, big, big_mid, start, end, rotate, gyro_sums):
    """Per GNSS epoch k (samples start[k] <= i < end[k], in order), the sums (K, 3) of the
    samples ``fc`` (3, N) rotated to the epoch's mid time by the rotation vector ``big[:, i]
    - big_mid[:, k]`` (rad; Rodrigues, as
    :func:`imudiag.aiding.specific_force._rodrigues_rows`; unrotated when not ``rotate``),
    of ``accel`` (3, N) and, when ``gyro_sums``, of ``gyro`` (3, N): one pass, each bin
    summed from 0 in sample order as ``np.bincount`` sums it."""
    kk = start.shape[0]
    sums = np.zeros((kk, 3))
    plain = np.zeros((kk, 3))
    gsum = np.zeros((kk, 3))
    for k in range(kk):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        p0 = 0.0
        p1 = 0.0
        p2 = 0.0
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        m0 = 0.0
        m1 = 0.0
        m2 = 0.0
        if rotate:
            m0 = big_mid[0, k]
            m1 = big_mid[1, k]
            m2 = big_mid[2, k]
        for i in range(start[k], end[k]):
            x0 = fc[0, i]
            x1 = fc[1, i]
            x2 = fc[2, i]
            if rotate:
                t0 = big[0, i] - m0
                t1 = big[1, i] - m1
                t2 = big[2, i] - m2
                a2 = t0 * t0
                a2 += t1 * t1
                a2 += t2 * t2
                ang = np.sqrt(a2)
                if ang < 1e-12:
                    k0 = 0.0
                    k1 = 0.0
                    k2 = 0.0
                else:
                    k0 = t0 / ang
                    k1 = t1 / ang
                    k2 = t2 / ang
                c = np.cos(ang)
                s = np.sin(ang)
                kd = k0 * x0
                kd += k1 * x1
                kd += k2 * x2
                omc = 1.0 - c
                r0 = x0 * c
                r0 += (k1 * x2 - k2 * x1) * s
                r0 += (k0 * kd) * omc
                r1 = x1 * c
                r1 += (k2 * x0 - k0 * x2) * s
                r1 += (k1 * kd) * omc
                r2 = x2 * c
                r2 += (k0 * x1 - k1 * x0) * s
                r2 += (k2 * kd) * omc
                s0 += r0
                s1 += r1
                s2 += r2
            else:
                s0 += x0
                s1 += x1
                s2 += x2
            p0 += accel[0, i]
            p1 += accel[1, i]
            p2 += accel[2, i]
            if gyro_sums:
                g0 += gyro[0, i]
                g1 += gyro[1, i]
                g2 += gyro[2, i]
        sums[k, 0] = s0
        sums[k, 1] = s1
        sums[k, 2] = s2
        plain[k, 0] = p0
        plain[k, 1] = p1
        plain[k, 2] = p2
        gsum[k, 0] = g0
        gsum[k, 1] = g1
        gsum[k, 2] = g2
    return sums, plain, gsum


@jit
def nan_max(a, b):
    """``np.maximum`` of two floats: nan when either is."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@jit
def nan_min(a, b):
    """``np.minimum`` of two floats: nan when either is."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


@jit
def _history_extremes_scan(d_idx, d_val, d_start, d_max, d_min, old, k, c):
    """Each history's extremes by scanning it (:func:`trailing_spread`): per new kept value
    ``at`` the running ``nan_max`` / ``nan_min`` of its history, the earliest of equal
    values kept (tests/test_stream_kernels.py holds :func:`_history_extremes` to it)."""
    total = d_idx.shape[0]
    for at in range(old, total):
        first = np.searchsorted(d_idx, d_start[at])
        lo = max(at - k + 1, first)
        for j in range(c):
            hi = -np.inf
            low = np.inf
            for q in range(lo, at + 1):
                hi = nan_max(hi, d_val[q, j])
                low = nan_min(low, d_val[q, j])
            d_max[at, j] = hi
            d_min[at, j] = low


@jit
def _history_extremes(d_idx, d_val, d_start, d_max, d_min, old, k, c):
    """:func:`_history_extremes_scan` in time proportional to the kept values, not to them
    times the history: per column a queue of the history's candidates for its maximum
    (values in non-increasing order, the earliest of equal values first) and one for its
    minimum, and the last nan's position (a history holding a nan has nan extremes). A
    history whose first value moves back (a start that is not monotone) rebuilds the
    queues from it. The same elements as the scan's: equal bit for bit."""
    total = d_idx.shape[0]
    qmax = np.empty(total, dtype=np.int64)
    qmin = np.empty(total, dtype=np.int64)
    los = np.empty(total, dtype=np.int64)
    first = 0  # np.searchsorted(d_idx, d_start[at]) (left), moved from the last one's
    for at in range(old, total):
        target = d_start[at]
        while first > 0 and d_idx[first - 1] >= target:
            first -= 1
        while first < total and d_idx[first] < target:
            first += 1
        los[at] = max(at - k + 1, first)
    for j in range(c):
        hmax = 0
        tmax = 0
        hmin = 0
        tmin = 0
        last_nan = -1
        prev_lo = -1  # the last history's first value (-1: none yet)
        nxt = 0  # the next kept value to enter the queues
        for at in range(old, total):
            lo = los[at]
            if prev_lo < 0 or lo < prev_lo:  # (re)build from this history's first value
                hmax = 0
                tmax = 0
                hmin = 0
                tmin = 0
                last_nan = -1
                nxt = lo
            elif nxt < lo:
                nxt = lo
            prev_lo = lo
            for q in range(nxt, at + 1):
                v = d_val[q, j]
                if v != v:
                    last_nan = q
                    continue
                while tmax > hmax and d_val[qmax[tmax - 1], j] < v:
                    tmax -= 1
                qmax[tmax] = q
                tmax += 1
                while tmin > hmin and d_val[qmin[tmin - 1], j] > v:
                    tmin -= 1
                qmin[tmin] = q
                tmin += 1
            if at + 1 > nxt:
                nxt = at + 1
            while hmax < tmax and qmax[hmax] < lo:
                hmax += 1
            while hmin < tmin and qmin[hmin] < lo:
                hmin += 1
            if last_nan >= lo:
                d_max[at, j] = np.nan
                d_min[at, j] = np.nan
            else:
                d_max[at, j] = d_val[qmax[hmax], j] if hmax < tmax else -np.inf
                d_min[at, j] = d_val[qmin[hmin], j] if hmin < tmin else np.inf


@jit
def trailing_spread(d_idx, d_val, d_start, d_max, d_min, old, k0, values, start, step, k):
    """The still detector's trailing spreads (:class:`imudiag.quasistatic.spread.TrailingSpread`,
    its ``update``), compiled: the extremes (into ``d_max``, ``d_min`` (total, C) from
    position ``old`` on) of each new kept value's history (its ``k`` last kept values of
    ``d_val`` (total, >= C) from its first row ``d_start`` on; -inf / inf where none), then
    each row's spread (M, C) of its last kept value's history and its own ``values`` row,
    0 where that kept value is before the row's ``start`` or the spread is not finite.
    Max and min are exact: equal to the numpy path (but for the sign of a zero).
    The histories' extremes by monotonic queues (:func:`_history_extremes`): the same
    values as the scan of each history (:func:`_history_extremes_scan`), bit for bit."""
    total = d_idx.shape[0]
    c = values.shape[1]
    if old < total:
        _history_extremes(d_idx, d_val, d_start, d_max, d_min, old, k, c)
    m = values.shape[0]
    out = np.zeros((m, c))
    # p = old + (r - k0) // step, row by row without a division: ``rem`` is r - k0 modulo step
    p = old + (-k0) // step
    rem = (-k0) % step
    for r in range(m):
        if r:
            rem += 1
            if rem == step:
                rem = 0
                p += 1
        if p < 0 or d_idx[p] < start[r]:
            continue
        for j in range(c):
            v = values[r, j]
            s = nan_max(d_max[p, j], v) - nan_min(d_min[p, j], v)
            if np.isfinite(s):
                out[r, j] = s
    return out


@jit
def quantile_above(v, ok, thr, q):
    """Whether, on every column of ``v`` (M, C) over the rows where ``ok`` (M,), numpy's
    ``q`` quantile (the linear method) is certainly above ``thr`` (C,): at least 10 rows, no
    nan among them, and at most floor((n - 1) q) - 1 of the n values at or below ``thr``
    (one rank of margin): then both order statistics the quantile interpolates are above
    it, and so is the quantile. Counts and comparisons only (the still detector's noise
    estimate, :meth:`imudiag.quasistatic.QuasiStaticDetector._update`, skips a block whose
    window variances cannot lower it)."""
    m = v.shape[0]
    c = v.shape[1]
    n = 0
    for i in range(m):
        if ok[i]:
            n += 1
    if n < 10:
        return False
    limit = int(np.floor((n - 1) * q)) - 1
    if limit < 0:
        return False
    for j in range(c):
        t = thr[j]
        if not (t == t):
            return False
        cnt = 0
        for i in range(m):
            if ok[i]:
                x = v[i, j]
                if x != x:
                    return False
                if not (x > t):
                    cnt += 1
                    if cnt > limit:
                        return False
    return True


@jit
def history_starts(idx, f0, lag0, f1, lag1, f2, lag2, restart, span):
    """The still detector's history starts (:meth:`imudiag.quasistatic.QuasiStaticDetector.
    _starts`) in one pass: per row i the latest restart so far (``restart`` before the
    block; ``idx[i] + lag`` where a flag of (f0, lag0), (f1, lag1), (f2, lag2) (M,) each is
    set), at least ``idx[i] - span``; and the latest restart at the block's end. Integers
    only: the numpy path's values."""
    m = idx.shape[0]
    out = np.empty(m, dtype=np.int64)
    last = restart
    for i in range(m):
        x = idx[i]
        if f0[i] and x + lag0 > last:
            last = x + lag0
        if f1[i] and x + lag1 > last:
            last = x + lag1
        if f2[i] and x + lag2 > last:
            last = x + lag2
        low = x - span
        out[i] = last if last > low else low
    return out, last


@jit
def _prefix_mean_var_rows(x, mean_var, counts, reverse, est, var):
    """:func:`imudiag.diagnosis.gyro_fit._prefix_mean_var` of the rows of ``x`` (K, 3) (the
    means, centred by the caller; taken from the last when ``reverse``) into ``est`` and
    ``var`` (K, 3): the same running sums in the same order, the same operations."""
    k = x.shape[0]
    for j in range(3):
        bw = 0.0
        sw = 0.0
        sn = 0.0
        ss = 0.0
        for r in range(k):
            i = k - 1 - r if reverse else r
            w = counts[i]
            xi = x[i, j]
            bw += w
            sw += w * xi
            sn += w * w * mean_var[i, j]
            ss += w * xi * xi
            e = sw / bw
            noise = sn / (bw * bw)
            scatter = 0.0
            if r > 0:
                scatter = nan_max(ss / bw - e * e, 0.0) / r
            est[r, j] = e
            var[r, j] = nan_max(noise, scatter)


@jit
def rest_step_scores(means, mean_var, counts, lo, hi, min_size):
    """:func:`imudiag.diagnosis.gyro_fit.rest_rate_steps`' scores compiled: per split
    lo..hi (S = hi - lo + 1) and axis, |mean after - mean before| over its std, 0 where the
    step is below ``min_size`` (3,) or the score is not finite (S, 3); ``counts`` (K,) all
    positive. The prefix figures of both parts as the numpy path makes them (its cumulative
    sums run in order too, the means centred on the first): equal bit for bit."""
    k = means.shape[0]
    centred = np.empty((k, 3))
    for i in range(k):
        for j in range(3):
            centred[i, j] = means[i, j] - means[0, j]
    m_old = np.empty((k, 3))
    v_old = np.empty((k, 3))
    m_new = np.empty((k, 3))
    v_new = np.empty((k, 3))
    _prefix_mean_var_rows(centred, mean_var, counts, False, m_old, v_old)
    _prefix_mean_var_rows(centred, mean_var, counts, True, m_new, v_new)
    out = np.zeros((hi - lo + 1, 3))
    for a in range(hi - lo + 1):
        split = lo + a
        for j in range(3):
            step = abs(m_new[k - split - 1, j] - m_old[split - 1, j])
            den = np.sqrt(v_old[split - 1, j] + v_new[k - split - 1, j])
            if step >= min_size[j] and den > 0.0:
                z = step / den
                if np.isfinite(z):
                    out[a, j] = z
    return out


@jit
def _select(buf, n, k):
    """Partition ``buf[:n]`` in place so that ``buf[k]`` is its k-th smallest value (0-based),
    nothing after it smaller and nothing before it larger (Hoare's selection, the middle of
    three as pivot; no nan in ``buf[:n]``). Returns that value."""
    lo = 0
    hi = n - 1
    while hi > lo:
        mid = (lo + hi) >> 1
        a = buf[lo]
        b = buf[mid]
        c = buf[hi]
        if a > b:
            a, b = b, a
        if b > c:
            b = c
            if a > b:
                b = a
        pivot = b
        i = lo
        j = hi
        while i <= j:
            while buf[i] < pivot:
                i += 1
            while buf[j] > pivot:
                j -= 1
            if i <= j:
                t = buf[i]
                buf[i] = buf[j]
                buf[j] = t
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return buf[k]


@jit
def masked_quantile(v, ok, q):
    """numpy's ``np.quantile(v[ok], q, axis=0)`` (the linear method) of ``v`` (M, C) over
    the rows where ``ok`` (M,), and whether it is that: False where no row is kept or a
    kept value is nan (the caller then asks numpy). The two order statistics numpy
    interpolates found by selection, and interpolated with numpy's own operations
    (``_lerp``: from the lower one below half way, from the upper one at or above it), so
    the values are numpy's, bit for bit."""
    m = v.shape[0]
    c = v.shape[1]
    out = np.empty(c)
    n = 0
    for i in range(m):
        if ok[i]:
            n += 1
    if n == 0:
        return out, False
    virtual = (n - 1) * q
    prev = int(np.floor(virtual))
    if virtual >= n - 1:
        prev = n - 1
    gamma = virtual - np.floor(virtual)
    cols = np.empty((c, n))  # the kept values, a contiguous row per column (one pass)
    k = 0
    for i in range(m):
        if ok[i]:
            for j in range(c):
                x = v[i, j]
                if x != x:
                    return out, False
                cols[j, k] = x
            k += 1
    # a low quantile from the few values below a bound: the bound from every s-th value (a
    # rank a little above the quantile's there), the values at or below it gathered (without
    # a branch) and, when they hold both ranks sought, the selection run on them alone (the
    # values below a bound are the lowest ones: their ranks are the whole column's)
    stride = max(1, n // 1024)
    ns = (n + stride - 1) // stride
    rank = min(ns - 1, int(ns * q) + int(3.0 * np.sqrt(ns * q)) + 8)
    sample = np.empty(ns)
    low = np.empty(n)
    need = prev + 2 if prev + 1 < n else prev + 1
    for j in range(c):
        col = cols[j]
        for i in range(ns):
            sample[i] = col[i * stride]
        bound = _select(sample, ns, rank)
        cnt = 0
        for i in range(n):
            x = col[i]
            low[cnt] = x
            cnt += x <= bound
        buf = low
        size = cnt
        if cnt < need:  # too few below the bound: the whole column
            buf = col
            size = n
        a = _select(buf, size, prev)
        if prev + 1 < n and virtual < n - 1:
            b = buf[prev + 1]
            for i in range(prev + 2, size):
                if buf[i] < b:
                    b = buf[i]
        else:
            b = a
        d = b - a
        if gamma >= 0.5:
            out[j] = b - d * (1.0 - gamma)
        else:
            out[j] = a + d * gamma
    return out, True


@jit
def beyond_counts(x, bounds, ends, w):
    """The counts of :func:`imudiag.trailing.median_side`: per window ``x[e - w : e]`` (``e``
    in ``ends``, P, non-decreasing, each at least ``w``) and column of ``x`` (R, C), how many
    values exceed each of ``bounds`` (B, C) and how many are nan: (P, B + 1, C) int32, the
    running counts taken at each window's two ends in one pass (the same comparisons and
    integers as the numpy path's prefix counts: exact)."""
    r = x.shape[0]
    c = x.shape[1]
    nb = bounds.shape[0]
    p = ends.shape[0]
    out = np.zeros((p, nb + 1, c), dtype=np.int32)
    cnt = np.zeros(nb + 1, dtype=np.int32)
    bj = np.empty(nb)
    for j in range(c):  # column by column: a column of the noise judge's x is contiguous
        cnt[:] = 0
        for b in range(nb):
            bj[b] = bounds[b, j]
        lo = 0  # the next window whose start is still ahead
        hi = 0  # the next window whose end is still ahead
        i = 0
        while True:
            while lo < p and ends[lo] - w == i:
                for b in range(nb + 1):
                    out[lo, b, j] -= cnt[b]
                lo += 1
            while hi < p and ends[hi] == i:
                for b in range(nb + 1):
                    out[hi, b, j] += cnt[b]
                hi += 1
            if i == r or hi == p:
                break
            nxt = r  # the rows up to the next window start or end: counted in one run
            if lo < p:
                nxt = min(nxt, ends[lo] - w)
            nxt = min(nxt, ends[hi])
            for ii in range(i, nxt):
                v = x[ii, j]
                for b in range(nb):
                    cnt[b] += v > bj[b]
                cnt[nb] += v != v
            i = nxt
    return out


@jit
def sorted_median(x):
    """The median of ``x`` (n >= 1, numbers), as ``np.median``: the middle value, or the mean
    of the two middle values ((lower + upper) / 2)."""
    s = np.sort(x)
    n = s.shape[0]
    h = n // 2
    if n % 2:
        return s[h]
    return (s[h - 1] + s[h]) / 2.0


@jit
def common_excess(u, nv_mean, m, target):
    """:func:`imudiag.diagnosis.robust._robust_excess` of deletion residuals ``u`` (G,) with
    noise ``nv_mean`` (G,), every point of ``m`` rows: 0 with fewer than 3 finite u or where
    the median of u / m is at most the chi^2_1 median ``target``, else
    :func:`robust_excess` of the finite ones."""
    count = 0
    for g in range(u.shape[0]):
        if np.isfinite(u[g]):
            count += 1
    if count < 3:
        return 0.0
    a_ok = np.empty(count)
    nv_ok = np.empty(count)
    c = 0
    for g in range(u.shape[0]):
        if np.isfinite(u[g]):
            a_ok[c] = u[g] / m
            nv_ok[c] = nv_mean[g]
            c += 1
    if sorted_median(a_ok) > target:
        return robust_excess(a_ok, nv_ok, target)
    return 0.0


@jit
def robust_excess(a, nv, target):
    """The bracketing of :func:`imudiag.diagnosis.robust._robust_excess` after its first
    median test, compiled: ``a`` (n,) = u / m, ``nv`` (n,), the chi^2_1 median ``target``; the
    same trial values, medians (order statistics: exact; nan where a row holds one) and
    comparisons, so the same e."""
    n = a.shape[0]
    mx = a[0] * nv[0]
    for i in range(1, n):
        v = a[i] * nv[i]
        if v > mx or v != v:
            mx = v
    lo = 0.0
    hi = mx + 1e-300
    inv_nv = 1.0 / nv
    row = np.empty(n)
    for _ in range(40):
        span = hi - lo
        k = 15  # the first trial whose median is at or below the target (15: none)
        for q in range(15):
            trial = lo + span * ((q + 1) / 16.0)
            nan = False
            for i in range(n):
                row[i] = a[i] / (1.0 + trial * inv_nv[i])
                if row[i] != row[i]:
                    nan = True
            if not nan and sorted_median(row) <= target:
                k = q
                break
        new_lo = lo + span * (k / 16.0) if k > 0 else lo
        if k < 15:
            hi = lo + span * ((k + 1) / 16.0)
        lo = new_lo
        if hi - lo <= 1e-10 * hi:
            break
    return hi


@jit
def pairwise_block(a, lo, n):
    """``np.sum`` of ``a[lo : lo + n]``, n <= 128, in numpy's order (:func:`pairwise_sum`)."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0 = a[lo]
    r1 = a[lo + 1]
    r2 = a[lo + 2]
    r3 = a[lo + 3]
    r4 = a[lo + 4]
    r5 = a[lo + 5]
    r6 = a[lo + 6]
    r7 = a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@jit
def pairwise_sum(a, lo, n):
    """``np.sum`` of ``a[lo : lo + n]`` (float64) in numpy's order: its pairwise summation
    (below 8 values one by one from -0.0; up to 128 in eight interleaved partial sums joined
    as ((0+1)+(2+3))+((4+5)+(6+7)) and the rest one by one; above, the sum of two halves split
    at a multiple of 8, here walked with a stack: numba's cache does not load recursive
    functions). Held to ``np.sum`` bit for bit by tests/test_fit_bookkeeping_kernels.py."""
    if n <= 128:
        return pairwise_block(a, lo, n)
    s_lo = np.empty(64, dtype=np.int64)
    s_n = np.empty(64, dtype=np.int64)
    s_state = np.zeros(64, dtype=np.int64)  # 0 new, 1 left half pending, 2 right pending
    s_left = np.empty(64)
    sp = 0
    s_lo[0] = lo
    s_n[0] = n
    while True:
        cn = s_n[sp]
        if cn > 128 and s_state[sp] == 0:
            n2 = cn // 2
            n2 -= n2 % 8
            s_state[sp] = 1
            sp += 1
            s_lo[sp] = s_lo[sp - 1]
            s_n[sp] = n2
            s_state[sp] = 0
            continue
        val = pairwise_block(a, s_lo[sp], cn)
        while True:  # hand the value up
            if sp == 0:
                return val
            sp -= 1
            if s_state[sp] == 1:  # the left half: now the right one
                s_left[sp] = val
                s_state[sp] = 2
                n2 = s_n[sp] // 2
                n2 -= n2 % 8
                sp += 1
                s_lo[sp] = s_lo[sp - 1] + n2
                s_n[sp] = s_n[sp - 1] - n2
                s_state[sp] = 0
                break
            val = s_left[sp] + val  # both halves


@jit
def excess_variance(r, sig2, dof):
    """:func:`imudiag.diagnosis.scalar_fit._excess_variance` compiled: the variance e added to
    every point making sum r^2 / (sig2 + e) equal ``dof``, by the same halvings of the same
    bracket, each sum in numpy's order (:func:`pairwise_sum`): the same e."""
    n = r.shape[0]
    r2 = r * r
    mx = r2[0]
    for i in range(1, n):
        if r2[i] > mx or r2[i] != r2[i]:
            mx = r2[i]
    lo = 0.0
    hi = mx * n + 1e-300
    tmp = np.empty(n)
    for _ in range(100):
        b_lo = lo
        b_hi = hi
        mid = 0.5 * (lo + hi)
        for i in range(n):
            tmp[i] = r2[i] / (sig2[i] + mid)
        if pairwise_sum(tmp, 0, n) > dof:
            lo = mid
        else:
            hi = mid
        if lo == b_lo and hi == b_hi:
            break
    return hi


@jit
def jump_test(sums, back_w, back_2w, still, sigma2, w, limit, first):
    """The still detector's jump test (:meth:`imudiag.quasistatic.QuasiStaticDetector._jump`)
    compiled: per window (M,) of the prefix-sum differences ``sums``, ``back_w``,
    ``back_2w`` (M, 13), the same element-wise operations and three-term sums in numpy's
    order (one by one), so the same flags."""
    m = sums.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    thr = 12.0 * limit
    for i in range(m):
        if not still[i] or (first + 1 + i < 2 * w):
            continue
        acc = 0.0
        for c in range(3):
            p1 = back_w[i, 3 + c] - back_2w[i, 3 + c]
            step = (sums[i, 3 + c] - p1) / w
            v = step * step / sigma2[c]
            acc = v if c == 0 else acc + v
        if not acc > thr:
            continue
        acc = 0.0
        for c in range(3):
            p1 = back_w[i, 3 + c] - back_2w[i, 3 + c]
            p_mean = p1 / w
            pv = nan_max((back_w[i, 9 + c] - back_2w[i, 9 + c] - p1 * p_mean) / (w - 1), 0.0)
            v = pv / sigma2[c]
            acc = v if c == 0 else acc + v
        out[i] = acc <= limit
    return out


@jit
def window_moments(sums, w, ref):
    """The still detector's window means and variances (:class:`imudiag.quasistatic.WindowStats`)
    compiled: from the window sums (M, >= 12: outputs 0-5 centred on ``ref`` (6,), their
    squares 6-11) of ``w`` rows, the variances max((S2 - S1 (S1 / w)) / (w - 1), 0) and the
    means S1 / w + ref (M, 6) each, element by element as numpy: the same numbers."""
    m = sums.shape[0]
    var = np.empty((m, 6))
    mean = np.empty((m, 6))
    for i in range(m):
        for j in range(6):
            s1 = sums[i, j]
            mc = s1 / w
            var[i, j] = nan_max((sums[i, 6 + j] - s1 * mc) / (w - 1), 0.0)
            mean[i, j] = mc + ref[j]
    return var, mean


@jit
def chunked_cumsum(rows, last, chunk, out):
    """The prefix sums of :meth:`imudiag.trailing.PrefixSums.update_views`, compiled: ``rows``
    (N, k) summed down the rows chunk by chunk (``chunk`` rows each), each chunk's running
    sum then plus the last prefix sum before it (``last`` (k,), then each chunk's last row),
    into ``out`` (N, k). The same additions in the same order as ``np.cumsum`` of a chunk
    then ``+= last``: equal bit for bit."""
    n = rows.shape[0]
    k = rows.shape[1]
    base = last.copy()
    acc = np.empty(k)
    for a in range(0, n, chunk):
        b = min(n, a + chunk)
        for j in range(k):
            acc[j] = rows[a, j]
            out[a, j] = acc[j] + base[j]
        for i in range(a + 1, b):
            for j in range(k):
                acc[j] = acc[j] + rows[i, j]
                out[i, j] = acc[j] + base[j]
        for j in range(k):
            base[j] = out[b - 1, j]


@jit
def stack_backs(ext, reach, offsets, out):
    """``out[i, j] = ext[reach - offsets[j] + i]`` (N, J, k): the prefix sums ``offsets`` rows
    back of :meth:`imudiag.trailing.PrefixSums.update` stacked (copies: exact)."""
    n = out.shape[0]
    k = out.shape[2]
    for i in range(n):
        for j in range(offsets.shape[0]):
            r = reach - offsets[j] + i
            for c in range(k):
                out[i, j, c] = ext[r, c]


@jit
def highpass_squares(full, n, h, to_si, out):
    """The vibration meter's high-passed squares (:meth:`imudiag.vibration.VibrationMeter.
    update`), compiled: for each of the last ``n`` rows of ``full`` (M, 6) (finite), the row
    minus the mean of the ``h`` rows ending at it (fewer at the stream's start) from the
    prefix sums of the rows centred on the first, times ``to_si`` (6,), squared, into ``out``
    (N, 6). The same operations in the same order as the numpy path: equal bit for bit."""
    highpass_parts(full[: full.shape[0] - n], full[full.shape[0] - n :, :3],
                   full[full.shape[0] - n :, 3:], h, to_si, out)  # fmt: skip


@jit
def highpass_parts(tail, gyro, accel, h, to_si, out):
    """:func:`highpass_squares` of the rows ``tail`` (T, 6) then the block's ``gyro`` and
    ``accel`` (N, 3) side by side, without joining them into one array first."""
    t = tail.shape[0]
    n = gyro.shape[0]
    m = t + n
    k = 6
    first = np.empty(k)
    for j in range(k):
        first[j] = tail[0, j] if t else (gyro[0, j] if j < 3 else accel[0, j - 3])
    c = np.empty((m + 1, k))
    for j in range(k):
        c[0, j] = 0.0
        c[1, j] = first[j] - first[j]
    for i in range(1, m):
        for j in range(k):
            if i < t:
                x = tail[i, j]
            elif j < 3:
                x = gyro[i - t, j]
            else:
                x = accel[i - t, j - 3]
            c[i + 1, j] = c[i, j] + (x - first[j])
    for r in range(n):
        e = m - n + 1 + r
        s = max(e - h, 0)
        d = float(e - s)
        for j in range(k):
            mean = (c[e, j] - c[s, j]) / d + first[j]
            x = gyro[r, j] if j < 3 else accel[r, j - 3]
            hp = (x - mean) * to_si[j]
            out[r, j] = hp * hp


@jit
def window_row_sums(x, pos, whole, w):
    """The sums (whole, C) of ``whole`` consecutive windows of ``w`` rows of ``x`` (N, C) from
    row ``pos`` on, each column summed row by row from 0, as numpy sums a (whole, w, C)
    reshape over its middle axis (the vibration meter's windows): equal bit for bit."""
    c = x.shape[1]
    out = np.zeros((whole, c))
    for q in range(whole):
        r0 = pos + q * w
        for r in range(r0, r0 + w):
            for j in range(c):
                out[q, j] += x[r, j]
    return out


@jit
def stuck_scan(raw, last):
    """The stuck check's scan of a block (:meth:`imudiag.monitor.stuck.StuckCheck.update`),
    compiled: per channel of ``raw`` (6, N) after its ``last`` output (6,), the smallest
    nonzero finite |change| between consecutive outputs (inf: none), the index of the last
    change in the block (-1: none; a non-finite step counts as a change), and how many steps
    are finite and how many are zero. Differences, minima and counts: exact."""
    c = raw.shape[0]
    n = raw.shape[1]
    smallest = np.full(c, np.inf)
    last_change = np.full(c, -1, dtype=np.int64)
    n_valid = np.zeros(c, dtype=np.int64)
    n_same = np.zeros(c, dtype=np.int64)
    for j in range(c):
        prev = last[j]
        for i in range(n):
            x = raw[j, i]
            step = x - prev
            prev = x
            if step == 0.0:
                n_same[j] += 1
                n_valid[j] += 1
                continue
            last_change[j] = i
            if np.isfinite(step):
                n_valid[j] += 1
                a = abs(step)
                if a < smallest[j]:
                    smallest[j] = a
    return smallest, last_change, n_valid, n_same


@jit
def stuck_episodes(raw, last, run, need, active, maybe):
    """The stuck check's new episodes in a block (:meth:`imudiag.monitor.stuck.StuckCheck.
    _episodes`), compiled: per channel of ``raw`` (6, N) where ``maybe``, the runs of equal
    consecutive outputs (``==``, the first against ``last``), each a hit when its equal
    steps, with the ``run`` carried into the block for one at its start, reach ``need``,
    but for a run at the start of a channel ``active`` at the last block's end; returns the
    hits (6,) and the sample index (clipped to the block) where each channel's first hit
    completed ``need`` (-1: none). Comparisons and integers: the numpy path's values."""
    c = raw.shape[0]
    n = raw.shape[1]
    hits = np.zeros(c, dtype=np.int64)
    first = np.full(c, -1, dtype=np.int64)
    for j in range(c):
        if not maybe[j]:
            continue
        prev = last[j]
        start = -1  # the first equal step of the run in progress (-1: none)
        for i in range(n + 1):
            same = False
            if i < n:
                x = raw[j, i]
                same = x == prev
                prev = x
            if same:
                if start < 0:
                    start = i
                continue
            if start >= 0:  # a run of equal steps [start, i) ended
                carried = run[j] if start == 0 else 0
                hit = i - start + carried >= need
                if start == 0 and active[j]:
                    hit = False  # the episode in force at the last block's end goes on
                if hit:
                    if hits[j] == 0:
                        reach = start + need - 1 - carried
                        first[j] = min(max(reach, 0), n - 1)
                    hits[j] += 1
                start = -1
    return hits, first


@jit
def clipped_sigmas(d, mad, mad_to_sigma):
    """The last steps of :func:`imudiag.noise_estimate.second_difference_sigmas`, compiled:
    per chunk and column of the centred second differences ``d`` (K, N, C) with their
    median absolute deviation ``mad`` (K, C), the values within 5 sigma kept (sigma the MAD's,
    or where the MAD is 0 the RMS of all N; all where that is 0 too), and
    sqrt(mean of the kept squares / 6) (K, C). The squares summed along the samples in
    order, as numpy sums them there; the numpy path's values."""
    kk = d.shape[0]
    n = d.shape[1]
    c = d.shape[2]
    out = np.empty((kk, c))
    for k in range(kk):
        for j in range(c):
            m = mad[k, j]
            if m > 0:
                s0 = mad_to_sigma * m
            else:
                tot = 0.0
                for i in range(n):
                    tot += d[k, i, j] * d[k, i, j]
                s0 = np.sqrt(tot / n)
            lim = 5.0 * s0
            keep_all = s0 <= 0  # (not where s0 is nan: then none is kept, as in numpy)
            tot = 0.0
            cnt = 0
            for i in range(n):
                x = d[k, i, j]
                if keep_all or abs(x) <= lim:
                    tot += x * x
                    cnt += 1
            out[k, j] = np.sqrt(tot / cnt / 6.0) if cnt else np.nan
    return out


@jit
def second_diff_squares(chan):
    """The noise judge's squared second differences (:meth:`imudiag.monitor.noise.NoiseCheck.
    judge`), compiled: per row of ``chan`` (C, M), ``((x[i+2] - x[i+1]) - (x[i+1] - x[i]))^2``
    (C, M - 2), the differences of the differences as ``np.diff(n=2)`` takes them: equal bit
    for bit."""
    c = chan.shape[0]
    m = chan.shape[1]
    out = np.empty((c, max(m - 2, 0)))
    for j in range(c):
        for i in range(m - 2):
            d = (chan[j, i + 2] - chan[j, i + 1]) - (chan[j, i + 1] - chan[j, i])
            out[j, i] = d * d
    return out


@jit
def interval_rows(t, gyro, accel, temp, flags, bad_bits, out):
    """The interval collector's rows (N, 9) of a block (:func:`imudiag.diagnosis.intervals.
    _rows`): the time, the outputs, the temperature (nan where ``temp`` is (0,): none) and
    whether a ``bad_bits`` flag is set (``flags`` (N,) int64 or (0,): none), as 1.0 or 0.0.
    Copies and one test per sample: the numpy path's rows."""
    n = t.shape[0]
    has_temp = temp.shape[0] == n
    has_flags = flags.shape[0] == n
    for i in range(n):
        out[i, 0] = t[i]
        out[i, 1] = gyro[i, 0]
        out[i, 2] = gyro[i, 1]
        out[i, 3] = gyro[i, 2]
        out[i, 4] = accel[i, 0]
        out[i, 5] = accel[i, 1]
        out[i, 6] = accel[i, 2]
        out[i, 7] = temp[i] if has_temp else np.nan
        out[i, 8] = 1.0 if has_flags and (flags[i] & bad_bits) != 0 else 0.0


@jit
def window_rows(gyro, accel, flags, bad_bits, cols, ref, rows):
    """The still detector's rows (N, 13) of a block (:meth:`imudiag.quasistatic.windows.
    WindowStage.run`): outputs centred on ``ref`` (0-5, a value that is not finite as 0), their
    squares (6-11) and whether the sample is bad (12: a ``bad_bits`` flag, or a value that is
    not finite in a column of ``cols`` (6,) bool); ``flags`` (N,) int64 or (0,): none. The same
    subtraction and product per element as numpy: the same rows."""
    n = gyro.shape[0]
    has_flags = flags.shape[0] == n
    for i in range(n):
        bad = has_flags and (flags[i] & bad_bits) != 0
        for j in range(6):
            x = gyro[i, j] if j < 3 else accel[i, j - 3]
            if not np.isfinite(x):
                if cols[j]:
                    bad = True
                x = 0.0
            xc = x - ref[j]
            rows[i, j] = xc
            rows[i, 6 + j] = xc * xc
        rows[i, 12] = 1.0 if bad else 0.0


@jit
def window_rates(mean, long_sums, count, ref, g_bias, g_scale, g_ninvt, a_bias, a_scale, a_ninvt):
    """The still detector's rates (:meth:`imudiag.quasistatic.windows.WindowStats.rates`) for a
    certificate without temperature or nonlinearity terms: the gyro rate about the vertical
    (the corrected accelerometer window mean) of the window means and of the longer means
    (``long_sums`` (M, 13) over ``count`` (M,) rows), and the window means' rate magnitude,
    (M,) each, gyro input units. The certificate's inverse and the projections element by
    element: equal to numpy's to rounding (the rate band's comparisons: docs/benchmarks.md)."""
    m = mean.shape[0]
    vertical = np.empty(m)
    vertical_long = np.empty(m)
    magnitude = np.empty(m)
    r = np.empty(3)
    rl = np.empty(3)
    d = np.empty(3)
    for i in range(m):
        for j in range(3):
            r[j] = (mean[i, j] - g_bias[j]) / g_scale[j]
            rl[j] = ((long_sums[i, j] / count[i] + ref[j]) - g_bias[j]) / g_scale[j]
            d[j] = (mean[i, 3 + j] - a_bias[j]) / a_scale[j]
        rate0 = r[0] * g_ninvt[0, 0] + r[1] * g_ninvt[1, 0] + r[2] * g_ninvt[2, 0]
        rate1 = r[0] * g_ninvt[0, 1] + r[1] * g_ninvt[1, 1] + r[2] * g_ninvt[2, 1]
        rate2 = r[0] * g_ninvt[0, 2] + r[1] * g_ninvt[1, 2] + r[2] * g_ninvt[2, 2]
        long0 = rl[0] * g_ninvt[0, 0] + rl[1] * g_ninvt[1, 0] + rl[2] * g_ninvt[2, 0]
        long1 = rl[0] * g_ninvt[0, 1] + rl[1] * g_ninvt[1, 1] + rl[2] * g_ninvt[2, 1]
        long2 = rl[0] * g_ninvt[0, 2] + rl[1] * g_ninvt[1, 2] + rl[2] * g_ninvt[2, 2]
        down0 = d[0] * a_ninvt[0, 0] + d[1] * a_ninvt[1, 0] + d[2] * a_ninvt[2, 0]
        down1 = d[0] * a_ninvt[0, 1] + d[1] * a_ninvt[1, 1] + d[2] * a_ninvt[2, 1]
        down2 = d[0] * a_ninvt[0, 2] + d[1] * a_ninvt[1, 2] + d[2] * a_ninvt[2, 2]
        norm = np.sqrt(down0 * down0 + down1 * down1 + down2 * down2)
        if not norm > 0:
            norm = 1.0
        vertical[i] = (rate0 * down0 + rate1 * down1 + rate2 * down2) / norm
        vertical_long[i] = (long0 * down0 + long1 * down1 + long2 * down2) / norm
        magnitude[i] = np.sqrt(rate0 * rate0 + rate1 * rate1 + rate2 * rate2)
    return vertical, vertical_long, magnitude


@jit
def variance_test(var, var_ref, limit, checked, missing, to_si2, settle_var, ok):
    """The still detector's variance test (:meth:`imudiag.quasistatic.QuasiStaticDetector.
    _update`) compiled: per window of ``var`` (M, 6) the sums over each triad's axes of
    var_j / var_ref_j (M, 2) in numpy's order (one by one), whether each is within ``limit``
    (M, 2), ``ok`` (M,) cleared in place where a triad of ``checked`` (2,) bool is not (all of
    it when ``missing``), and whether the accelerometer variance in SI units exceeds
    ``settle_var`` (M,): the same numbers and flags as the numpy path."""
    m = var.shape[0]
    ratio = np.empty((m, 2))
    still = np.empty((m, 2), dtype=np.bool_)
    settle = np.empty(m, dtype=np.bool_)
    for i in range(m):
        for c in range(2):
            b = 3 * c
            acc = var[i, b] / var_ref[b]
            acc = acc + var[i, b + 1] / var_ref[b + 1]
            acc = acc + var[i, b + 2] / var_ref[b + 2]
            ratio[i, c] = acc
            still[i, c] = acc <= limit
        if missing:
            ok[i] = False
        for c in range(2):
            if checked[c] and not still[i, c]:
                ok[i] = False
        s = var[i, 3] * to_si2[0]
        s = s + var[i, 4] * to_si2[1]
        s = s + var[i, 5] * to_si2[2]
        settle[i] = s > settle_var
    return ratio, still, settle


@jit
def drift_within(spread, to_si, limit, ok):
    """``ok`` (M,) cleared in place where the norm of the drift ``spread`` (M, 3) times
    ``to_si`` exceeds ``limit``, the norm's squares summed as ``np.einsum`` sums three terms
    here ((0 + 2) + 1)."""
    for i in range(spread.shape[0]):
        a0 = spread[i, 0] * to_si[0]
        a1 = spread[i, 1] * to_si[1]
        a2 = spread[i, 2] * to_si[2]
        if not np.sqrt((a0 * a0 + a2 * a2) + a1 * a1) <= limit:
            ok[i] = False


@jit
def turning_rows(now, back2, back3, per_s, m, gate, check_bad):
    """The monitor's turning flags (:meth:`imudiag.monitor.Monitor._slow_stage`) compiled:
    per row of the prefix sums ``now`` and two and three steps back (M, >= 5: the gyro rates
    in 0-2, the bad samples in 4), the angular acceleration |2 (P - P2) - (P - P3)| (its
    squares summed as ``np.einsum`` sums three terms here, ((0 + 2) + 1)) times ``per_s``,
    over ``m``; nan where ``check_bad`` and a bad sample is in the last three steps; turning
    (1.0) where it is not within ``gate``, as the (M, 1) column the numpy path makes: the
    same operations in the same order."""
    n = now.shape[0]
    out = np.empty((n, 1))
    for i in range(n):
        d0 = (now[i, 0] - 2.0 * back2[i, 0]) + back3[i, 0]
        d1 = (now[i, 1] - 2.0 * back2[i, 1]) + back3[i, 1]
        d2 = (now[i, 2] - 2.0 * back2[i, 2]) + back3[i, 2]
        alpha = np.sqrt((d0 * d0 + d2 * d2) + d1 * d1) * per_s / m
        if check_bad and now[i, 4] - back3[i, 4] > 0:
            alpha = np.nan
        out[i, 0] = 0.0 if alpha <= gate else 1.0
    return out


@jit
def rest_rate_rows(now, back0, back1, w, thr, ok, idx, span):
    """The monitor's MEMS rest-rate check (:meth:`imudiag.monitor.Monitor._gyro_rest_rate`)
    compiled: per row of the prefix sums (M, >= 4: the rates in 0-2, the still samples in
    3) the worst axis's |mean rate of the w samples from ``back1`` to ``back0``| over its
    threshold ``thr`` (3,) (nan where an axis's is), and whether the row is usable (``ok``,
    a whole history at stream row ``idx``, and all ``span`` samples still): the numpy
    path's operations in its order."""
    n = now.shape[0]
    worst = np.empty(n)
    usable = np.empty(n, dtype=np.bool_)
    for i in range(n):
        e0 = abs((back0[i, 0] - back1[i, 0]) / w) / thr[0]
        e1 = abs((back0[i, 1] - back1[i, 1]) / w) / thr[1]
        e2 = abs((back0[i, 2] - back1[i, 2]) / w) / thr[2]
        worst[i] = nan_max(nan_max(e0, e1), e2)
        usable[i] = ok[i] and idx[i] + 1 >= span and now[i, 3] - back1[i, 3] == span
    return worst, usable


@jit
def curve_test(spread, to_si, rate_limit, drift_limit, ok):
    """The still detector's curve test in place: ``ok`` (M,) cleared where the rate about the
    vertical drifted beyond ``rate_limit`` (``spread[:, 3]``) and the specific force beyond
    ``drift_limit`` (the norm of ``spread[:, :3]`` times ``to_si``, its squares summed as
    :func:`drift_within` sums them)."""
    for i in range(spread.shape[0]):
        if spread[i, 3] > rate_limit:
            a0 = spread[i, 0] * to_si[0]
            a1 = spread[i, 1] * to_si[1]
            a2 = spread[i, 2] * to_si[2]
            if np.sqrt((a0 * a0 + a2 * a2) + a1 * a1) > drift_limit:
                ok[i] = False


#: Largest 1-norm condition number of the information matrix (with its prior) the exact fit's
#: kernel inverts itself (Cholesky); above it the plain path (``np.linalg.pinv``, whose
#: cut-off at 1e-15 of the largest singular value may then matter) runs the fit.
COV_CONDITION = 1e12


@jit
def spd_inverse(a, out):
    """The inverse of the symmetric positive definite ``a`` (m, m) into ``out``, by Cholesky
    of the Jacobi-scaled D^-1/2 a D^-1/2; False (``out`` undefined) when ``a`` is not
    positive definite, not numbers, or its 1-norm condition exceeds :data:`COV_CONDITION`."""
    m = a.shape[0]
    s = np.empty(m)
    for i in range(m):
        if not (a[i, i] > 0.0 and a[i, i] < np.inf):
            return False
        s[i] = 1.0 / np.sqrt(a[i, i])
    lo = np.zeros((m, m))
    for j in range(m):
        acc = a[j, j] * s[j] * s[j]
        for q in range(j):
            acc -= lo[j, q] * lo[j, q]
        if not acc > 0.0:
            return False
        d = np.sqrt(acc)
        lo[j, j] = d
        for i in range(j + 1, m):
            acc = a[i, j] * s[i] * s[j]
            for q in range(j):
                acc -= lo[i, q] * lo[j, q]
            lo[i, j] = acc / d
    li = np.zeros((m, m))  # L^-1, lower triangular
    for j in range(m):
        li[j, j] = 1.0 / lo[j, j]
        for i in range(j + 1, m):
            acc = 0.0
            for q in range(j, i):
                acc -= lo[i, q] * li[q, j]
            li[i, j] = acc / lo[i, i]
    for i in range(m):
        for j in range(i + 1):
            acc = 0.0
            for q in range(i, m):
                acc += li[q, i] * li[q, j]
            out[i, j] = acc * s[i] * s[j]
            out[j, i] = out[i, j]
    norm_a = 0.0
    norm_inv = 0.0
    for j in range(m):
        ca = 0.0
        ci = 0.0
        for i in range(m):
            ca += abs(a[i, j])
            ci += abs(out[i, j])
        norm_a = max(norm_a, ca)
        norm_inv = max(norm_inv, ci)
    return norm_a * norm_inv <= COV_CONDITION


@jit
def lstsq_min_norm(h, z, rcond, out):
    """``np.linalg.lstsq(h, z, rcond)[0]`` into ``out``: the minimum-norm least-squares
    solution, singular values at or below ``rcond`` times the largest treated as zero, by a
    one-sided Jacobi SVD (Hestenes) of ``h`` (k, n) instead of LAPACK's divide and conquer;
    False when its sweeps did not converge or the data are not numbers."""
    k, n = h.shape
    a = h.copy()
    vm = np.eye(n)
    # a column rotated down to rounding noise (rank below n) is left alone: its singular
    # value is far below any rcond cut-off, and rotating noise against noise never settles
    tiny = 0.0
    for i in range(k):
        for j in range(n):
            tiny += a[i, j] * a[i, j]
    tiny *= 1e-30
    converged = False
    for _sweep in range(60):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                alpha = 0.0
                beta = 0.0
                gamma = 0.0
                for i in range(k):
                    alpha += a[i, p] * a[i, p]
                    beta += a[i, q] * a[i, q]
                    gamma += a[i, p] * a[i, q]
                if alpha <= tiny or beta <= tiny or not abs(gamma) > 1e-15 * np.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = 1.0 / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                if zeta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(1.0 + t * t)
                sn = c * t
                for i in range(k):
                    ap = a[i, p]
                    aq = a[i, q]
                    a[i, p] = c * ap - sn * aq
                    a[i, q] = sn * ap + c * aq
                for i in range(n):
                    vp = vm[i, p]
                    vq = vm[i, q]
                    vm[i, p] = c * vp - sn * vq
                    vm[i, q] = sn * vp + c * vq
        if not rotated:
            converged = True
            break
    if not converged:
        return False
    sv = np.empty(n)
    big = 0.0
    for j in range(n):
        acc = 0.0
        for i in range(k):
            acc += a[i, j] * a[i, j]
        sv[j] = np.sqrt(acc)
        if not sv[j] < np.inf:
            return False
        big = max(big, sv[j])
    for i in range(n):
        out[i] = 0.0
    for j in range(n):
        if sv[j] > rcond * big:
            acc = 0.0
            for i in range(k):
                acc += a[i, j] * z[i]
            coef = acc / (sv[j] * sv[j])
            for i in range(n):
                out[i] += coef * vm[i, j]
    return True


@jit
def linear_start(theta_c, v, mu, out):
    """:func:`imudiag.diagnosis.scalar_fit._linear_start` into ``out`` (the deviation from
    the certificate by the linearised model): the certificate-corrected outputs, the 9
    regressors over mu^2 and the minimum-norm solution (:func:`lstsq_min_norm`, rcond 1e-10);
    False when that failed."""
    k = v.shape[0]
    p = np.empty((3, 3))
    p[0, 0], p[1, 1], p[2, 2] = 1.0 + theta_c[3], 1.0 + theta_c[4], 1.0 + theta_c[5]
    p[0, 1] = p[1, 0] = 0.5 * theta_c[6]
    p[0, 2] = p[2, 0] = 0.5 * theta_c[7]
    p[1, 2] = p[2, 1] = 0.5 * theta_c[8]
    pinv = inv3(p)
    h = np.empty((k, 9))
    z = np.empty(k)
    for n in range(k):
        a0 = v[n, 0] - theta_c[0]
        a1 = v[n, 1] - theta_c[1]
        a2 = v[n, 2] - theta_c[2]
        y0 = a0 * pinv[0, 0] + a1 * pinv[0, 1] + a2 * pinv[0, 2]
        y1 = a0 * pinv[1, 0] + a1 * pinv[1, 1] + a2 * pinv[1, 2]
        y2 = a0 * pinv[2, 0] + a1 * pinv[2, 1] + a2 * pinv[2, 2]
        m2 = mu[n] * mu[n]
        h[n, 0] = y0 / m2
        h[n, 1] = y1 / m2
        h[n, 2] = y2 / m2
        h[n, 3] = y0 * y0 / m2
        h[n, 4] = y1 * y1 / m2
        h[n, 5] = y2 * y2 / m2
        h[n, 6] = y0 * y1 / m2
        h[n, 7] = y0 * y2 / m2
        h[n, 8] = y1 * y2 / m2
        z[n] = 0.5 * ((y0 * y0 + y1 * y1 + y2 * y2) / m2 - 1.0)
    return lstsq_min_norm(h, z, 1e-10, out)


@jit
def weighted_info(jac, wgt, prior_prec, info, hess):
    """J^T diag(wgt) J (m, m) of the Jacobian ``jac`` (K, m) into ``info`` and the same plus
    diag(prior_prec) into ``hess``."""
    k = jac.shape[0]
    m = jac.shape[1]
    for i in range(m):
        for j in range(i + 1):
            acc = 0.0
            for n in range(k):
                acc += jac[n, i] * (jac[n, j] * wgt[n])
            info[i, j] = acc
            info[j, i] = acc
    for i in range(m):
        for j in range(m):
            hess[i, j] = info[i, j]
        hess[i, i] += prior_prec[i]


@jit
def _failed(k, npred):
    """The result of :func:`exact_fit_kernel` when it gave up (ok False, the rest unused)."""
    e9 = np.empty(9)
    e99 = np.empty((9, 9))
    ek = np.empty(k)
    return (
        False, e9, ek, e99, e99, 0.0, 0.0, 0.0, 0.0, np.empty((k, 9)), ek, 0.0, np.empty(npred),
        np.full(9, np.nan),
    )  # fmt: skip


@jit
def exact_fit_kernel(
    theta0, linear, v, var_v, mu, theta_c, prior_prec, max_iter, max_shape, floor2,
    scale_by_residual, max_leverage, chi2_median, pv, pvar, pmu,
):  # fmt: skip
    """The exact fit of :func:`imudiag.diagnosis.scalar_fit.exact_fit` after its set-up, in
    one call: the linear start (``linear``; else ``theta0``), the damped Gauss-Newton loop
    (:func:`gauss_newton`) with the excess-variance refits, the covariance (Cholesky,
    :func:`spd_inverse`, for ``np.linalg.pinv``), chi^2, dof and the Birge ratio, the
    one-row deletion figures of :func:`imudiag.diagnosis.robust.point_diagnostics` with their
    robust excess, and the prediction errors of the points ``pv`` (J, 3), ``pvar``, ``pmu``
    not in the fit (J = 0: none). Returns (ok, theta, r, info, cov, dof, cov_scale,
    extra_used, rms, shift, z, robust excess, predicted z, the diagonal of the covariance
    the points' noise alone and the prior give where the fit estimated an excess or a
    Birge ratio (``_estimated_variance``; nan where not, or where its solve broke down));
    ok False when a solve broke down (the caller runs the plain path)."""
    k = v.shape[0]
    theta = theta0.copy()
    if linear:
        lin = np.empty(9)
        if not linear_start(theta_c, v, mu, lin):
            return _failed(k, pv.shape[0])
        finite = True
        far = 0.0
        for i in range(9):
            if not np.isfinite(lin[i]):
                finite = False
            if i >= 3:
                far = max(far, abs(lin[i]))
        if finite and far <= max_shape:
            for i in range(9):
                theta[i] = theta_c[i] + lin[i]
    extra = 0.0
    extra_used = 0.0
    info = np.empty((9, 9))
    hess = np.empty((9, 9))
    cov = np.empty((9, 9))
    wgt = np.empty(k)
    chi2 = 0.0
    dof = 0.0
    n_outer = 4 if scale_by_residual else 1
    ok, th, r, jac, sig2 = gauss_newton(
        theta.copy(), extra, v, mu, var_v, prior_prec, theta_c, max_iter, max_shape, floor2
    )
    for outer in range(n_outer):
        if outer > 0:
            ok, th, r, jac, sig2 = gauss_newton(
                theta.copy(), extra, v, mu, var_v, prior_prec, theta_c, max_iter, max_shape,
                floor2,
            )  # fmt: skip
        if not ok:
            return _failed(k, pv.shape[0])
        for n in range(k):
            wgt[n] = 1.0 / sig2[n]
        weighted_info(jac, wgt, prior_prec, info, hess)
        if not spd_inverse(hess, cov):
            return _failed(k, pv.shape[0])
        extra_used = extra
        chi2 = 0.0
        for n in range(k):
            chi2 += r[n] * r[n] * wgt[n]
        tr = 0.0
        for i in range(9):
            for j in range(9):
                tr += cov[i, j] * info[j, i]
        dof = k - tr
        if not scale_by_residual or dof < 1.0 or chi2 <= 1.5 * dof:
            break
        noise = np.empty(k)
        for n in range(k):
            noise[n] = sig2[n] - extra
        extra = excess_variance(r, noise, dof)
    cov_scale = 1.0
    cov_out = cov.copy()
    if dof > 0.5 and scale_by_residual:
        cov_scale = max(1.0, chi2 / dof)
        for i in range(9):
            for j in range(9):
                cov_out[i, j] = cov[i, j] * cov_scale
    acc = 0.0
    for n in range(k):
        acc += r[n] * r[n]
    rms = np.sqrt(acc / k)
    # the deletion figures, one row per point (robust.point_diagnostics without groups)
    shift = np.empty((k, 9))
    u = np.empty(k)
    nv_mean = np.empty(k)
    noise_var = np.empty(k)
    ac = np.empty(9)
    for n in range(k):
        noise_var[n] = sig2[n] - extra_used
        sw = np.sqrt(wgt[n])
        for j in range(9):
            acc = 0.0
            for i in range(9):
                acc += jac[n, i] * sw * cov[i, j]
            ac[j] = acc
        h = 0.0
        for j in range(9):
            h += ac[j] * (jac[n, j] * sw)
        s_n = sw * r[n]
        if h <= max_leverage:
            sol = s_n / (1.0 - h)
            u[n] = s_n * sol / (noise_var[n] * wgt[n])
            nv_mean[n] = noise_var[n]
        else:
            sol = np.nan
            u[n] = np.nan
            nv_mean[n] = 1.0
        for j in range(9):
            shift[n, j] = ac[j] * sol
    excess = common_excess(u, nv_mean, 1.0, chi2_median)
    z = np.empty(k)
    for n in range(k):
        z[n] = np.sqrt(u[n] / (1.0 + excess / nv_mean[n]))
    # prediction errors of the points left out (the robust fit's probes)
    npred = pv.shape[0]
    zp = np.empty(npred)
    if npred:
        w_rob = np.empty(k)
        for n in range(k):
            w_rob[n] = 1.0 / (noise_var[n] + excess)
        info_rob = np.empty((9, 9))
        hess_rob = np.empty((9, 9))
        cov_rob = np.empty((9, 9))
        weighted_info(jac, w_rob, prior_prec, info_rob, hess_rob)
        if not spd_inverse(hess_rob, cov_rob):
            return _failed(k, npred)
        rp = np.empty(npred)
        xp = np.empty((npred, 3))
        wp = np.empty((npred, 3))
        sp = np.empty(npred)
        jp = np.empty((npred, 9))
        residuals(th, pv, pmu, pvar, prior_prec, theta_c, 0.0, floor2, rp, xp, wp, sp)
        jacobian(xp, wp, jp)
        for n in range(npred):
            par = 0.0
            for i in range(9):
                acc = 0.0
                for j in range(9):
                    acc += cov_rob[i, j] * jp[n, j]
                par += jp[n, i] * acc
            total = sp[n] + excess + max(par, 0.0)
            zp[n] = abs(rp[n]) / np.sqrt(total)
    known_diag = np.full(9, np.nan)
    if extra_used > 0.0 or cov_scale > 1.0:
        w_known = np.empty(k)
        for n in range(k):
            w_known[n] = 1.0 / noise_var[n]
        info_k = np.empty((9, 9))
        hess_k = np.empty((9, 9))
        weighted_info(jac, w_known, prior_prec, info_k, hess_k)
        known = np.empty((9, 9))
        if spd_inverse(hess_k, known):
            for i in range(9):
                known_diag[i] = known[i, i]
    return (
        True, th, r, info, cov_out, dof, cov_scale, extra_used, rms, shift, z, excess, zp,
        known_diag,
    )  # fmt: skip


def warm_up(part: int | None = None) -> dict[str, Any]:
    """Run each kernel once (compiling it, or loading it from numba's cache); the kernels by
    name. ``part`` 0 or 1: only the exact fit's kernels (its Gauss-Newton loop, excess
    variances, robust excess: one chain, compiled together), or the others (the rotation
    fit's products, the streams' detectors, meters and cuts): two processes of about the
    same compile time, side by side into numba's cache (``.ci/suite.py``'s warm-up); None:
    all."""
    rng = np.random.default_rng(0)
    q_c = np.eye(3)
    if part in (None, 0):  # the exact fit and what it calls (one chain: one process)
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
        robust_excess(np.array([3.0, 1.0, 2.0, 5.0]), np.ones(4), 0.45)
        excess_variance(rng.normal(size=300), np.ones(300), 100.0)
        for start, probes in ((True, 0), (False, 1)):
            exact_fit_kernel(
                np.zeros(9), start, v, np.full((12, 3), 1e-8), np.ones(12), np.zeros(9),
                np.ones(9), 20, 0.5, 1e-14, True, 0.99, 0.45, v[:probes].copy(),
                np.full((probes, 3), 1e-8), np.ones(probes),
            )  # fmt: skip
    if part in (None, 1):  # the rotation fit's products; the streams' detectors, meters, cuts
        product_sensitivity_kernel(
            rng.normal(size=(7, 3)), rng.normal(size=(7, 3)), np.array([3, 0, 4])
        )
        for npar, frame in ((6, False), (9, True)):
            ninv, dninv = ninv_derivatives_kernel(np.zeros(6), q_c, np.full(npar, 1e-3), frame)
            frozen = dninv.copy()
            frozen.setflags(write=False)  # the rotation fit's cached derivatives are read-only
            for d in (dninv, frozen):
                predict_kernel(
                    np.array([[1.0, 0.0, 0.0, 0.0]]), np.zeros((1, 3, 3, 3)), d, np.ones((1, 3))
                )
        turning = rng.normal(size=(7, 3)) * 0.1
        lengths = np.array([3, 4], dtype=np.int64)
        ups = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
        for npar, frame in ((6, False), (9, True)):
            _ok, _x, res, jac, _c = rotation_loop(
                np.zeros(npar), turning, lengths, ups, ups, np.ones(6), np.ones(npar),
                np.zeros(6), q_c, frame, 6, 0.5,
            )  # fmt: skip
            rotation_post(jac, res, np.ones(6), np.ones(npar), 0.99, 0.45)
        rows = rng.normal(size=(3, 8))
        bounds = np.array([0, 3], dtype=np.int64), np.array([3, 8], dtype=np.int64)
        for rotate in (True, False):
            # the epochs' mid rotations as a slice and as an array of their own (a drive's)
            for mid in (rows[:, :3], rows[:, :3].copy()):
                epoch_cut(rows, rows, rows, rows, mid, *bounds, rotate, rotate)
        d_idx = np.array([0, 2, 4], dtype=np.int64)
        d_max = np.zeros((3, 2))
        for vals in (rows.T[:5, :2].copy(), np.zeros((5, 6))[:, 3:5]):  # C and a strided view
            trailing_spread(
                d_idx, rows.T[:3, :4].copy(), d_idx, d_max, d_max.copy(), 0, 0, vals,
                np.zeros(5, dtype=np.int64), 2, 3,
            )  # fmt: skip
        attitude_labels(rng.normal(size=(5, 3)), np.ones(5, dtype=np.bool_), 0.98)
        r14 = rng.normal(size=(9, 14))
        mean_cov3(r14[:, 1:4])  # a strided view (the interval collector's rows)
        mean_cov3(r14[:, 1:4].copy())
        xv = rng.random(size=(20, 6))
        quantile_above(xv[:, 0:3], np.ones(20, dtype=np.bool_), np.zeros(3), 0.05)  # strided
        masked_quantile(xv[:, 0:3], np.ones(20, dtype=np.bool_), 0.05)
        rest_step_scores(xv[:12, :3].copy(), xv[:12, 3:6].copy(), np.ones(12), 5, 7, np.zeros(3))
        flags = np.zeros(20, dtype=np.bool_)
        history_starts(np.arange(20, dtype=np.int64), flags, 3, flags, 0, flags, 5, 0, 7)
        masked_quantile(xv[:, 0:3].copy(), np.ones(20, dtype=np.bool_), 0.05)
        x = rng.normal(size=(12, 6))
        for layout in (x, x.T.copy().T):  # C-contiguous and strided (a transposed view)
            beyond_counts(layout, np.zeros((4, 6)), np.array([3, 12], dtype=np.int64), 3)
        x13 = rng.normal(size=(6, 13))
        jump_test(x13, x13 * 0.5, x13 * 0.25, np.ones(6, dtype=np.bool_), np.ones(3), 2, 3.0, 10)
        jump_test(x13, x13[:, :], x13.T.copy().T, np.ones(6, dtype=np.bool_), np.ones(3), 2, 3.0, 0)
        window_moments(x13, 2, np.zeros(6))
        window_moments(x13[1:], 2, np.zeros(6))
        x26 = rng.normal(size=(6, 26))
        window_moments(x26[:, ::2], 2, np.zeros(6))  # strided (diagnose's prefix-sum views)
        jump_test(x26[:, ::2], x26[:, 1::2], x26[:, ::2], np.ones(6, dtype=np.bool_), np.ones(3), 2,
                  3.0, 0)  # fmt: skip
        g6 = rng.normal(size=(5, 3))
        rows6 = np.empty((5, 13))
        g12 = rng.normal(size=(5, 12))
        for fl in (np.zeros(5, dtype=np.int64), np.zeros(0, dtype=np.int64)):
            # time and temperature contiguous or columns of a wider array (a CSV block's)
            for tt, tmp in ((np.zeros(5), np.zeros(5)), (g12[:, 3], g12[:, 4]), (g6[:, 0], None)):
                tmp = np.zeros(0) if tmp is None else tmp
                for gy, ac in ((g6, g6.copy()), (g12[:, 0:3], g12[:, 6:9])):
                    interval_rows(tt, gy, ac, tmp, fl, 7, np.empty((5, 9)))
                    interval_rows(tt, gy, ac, np.zeros(0), fl, 7, np.empty((5, 9)))
            for gy, ac in ((g6, g6.copy()), (g12[:, 0:3], g12[:, 6:9])):  # C and strided
                window_rows(gy, ac, fl, 7, np.ones(6, dtype=np.bool_), np.zeros(6), rows6)
        window_rates(
            x13[:, :6].copy(), x13, np.ones(6), np.zeros(6), np.zeros(3), np.ones(3), q_c,
            np.zeros(3), np.ones(3), q_c,
        )  # fmt: skip
        ok6 = np.ones(6, dtype=np.bool_)
        variance_test(
            x13[:, :6].copy(), np.ones(6), 3.0, ok6[:2].copy(), False, np.ones(3), 1.0, ok6
        )
        drift_within(x13[:, :3].copy(), np.ones(3), 1.0, ok6)
        # the prefix sums contiguous or views, now and back alike or not (a block's own
        # array and the carried sums' views)
        for now5 in (x13[:, :5].copy(), x13[:, 2:7]):
            for back5 in (x13[:, :5].copy(), x13[:, 2:7]):
                turning_rows(now5, back5, back5, 1.0, 2, 0.5, True)
                rest_rate_rows(
                    now5, back5, back5, 3, np.ones(3), ok6, np.arange(6, dtype=np.int64), 2
                )
        curve_test(x13[:, :4].copy(), np.ones(3), 0.5, 1.0, ok6)
        ext = np.zeros((9, 13))
        chunked_cumsum(x13, x13[0].copy(), 4, ext[3:])  # C rows into a C slice of ext
        stack_backs(ext, 3, np.array([1, 3], dtype=np.int64), np.empty((6, 2, 13)))
        highpass_squares(x13[:, :6].copy(), 4, 3, np.ones(6), np.empty((4, 6)))
        for g3, a3 in ((x13[:, :3].copy(), x13[:, 3:6].copy()), (x13[:, :3], x13[:, 3:6])):
            highpass_parts(np.zeros((2, 6)), g3, a3, 3, np.ones(6), np.empty((6, 6)))
            highpass_parts(np.zeros((0, 6)), g3, a3, 3, np.ones(6), np.empty((6, 6)))
        window_row_sums(x13[:, :6].copy(), 1, 2, 2)
        stuck_scan(x13[:, :6].T.copy(), np.full(6, np.nan))  # a C-contiguous (6, N) block
        second_diff_squares(x13[:, :6].T.copy())
        clipped_sigmas(rng.normal(size=(2, 5, 6)), np.array([[1.0] * 6, [0.0] * 6]), 1.48)
        stuck_scan(np.empty((6, 9))[:, 2:], np.full(6, np.nan))  # a slice after the history
        for raw6 in (x13[:, :6].T.copy(), np.empty((6, 9))[:, 2:]):  # C and a slice, as the scan
            stuck_episodes(
                raw6, np.zeros(6), np.zeros(6, dtype=np.int64), 3, np.zeros(6, dtype=np.bool_),
                np.ones(6, dtype=np.bool_),
            )  # fmt: skip
    return {
        "chunked_cumsum": chunked_cumsum,
        "stack_backs": stack_backs,
        "highpass_squares": highpass_squares,
        "highpass_parts": highpass_parts,
        "window_row_sums": window_row_sums,
        "stuck_scan": stuck_scan,
        "stuck_episodes": stuck_episodes,
        "second_diff_squares": second_diff_squares,
        "clipped_sigmas": clipped_sigmas,
        "variance_test": variance_test,
        "drift_within": drift_within,
        "window_rows": window_rows,
        "interval_rows": interval_rows,
        "window_rates": window_rates,
        "exact_fit": exact_fit_kernel,
        "beyond_counts": beyond_counts,
        "window_moments": window_moments,
        "jump_test": jump_test,
        "excess_variance": excess_variance,
        "pairwise_sum": pairwise_sum,
        "robust_excess": robust_excess,
        "epoch_cut": epoch_cut,
        "trailing_spread": trailing_spread,
        "exact_gauss_newton": gauss_newton,
        "product_sensitivity": product_sensitivity_kernel,
        "ninv_derivatives": ninv_derivatives_kernel,
        "predict": predict_kernel,
        "rotation_loop": rotation_loop,
        "rotation_post": rotation_post,
        "mean_cov3": mean_cov3,
        "attitude_labels": attitude_labels,
        "curve_test": curve_test,
        "turning_rows": turning_rows,
        "rest_rate_rows": rest_rate_rows,
        "quantile_above": quantile_above,
        "masked_quantile": masked_quantile,
        "history_starts": history_starts,
        "rest_step_scores": rest_step_scores,
    }
