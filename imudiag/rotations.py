"""Quaternions (w, x, y, z), Hamilton convention: R(a * b) = R(a) R(b).

The helpers the gyro rotation fit (:mod:`imudiag.diagnosis.gyro_fit`) and the model
check's rotation channel (:mod:`imudiag.modelcheck.rotations`) share: products of
quaternion arrays, quaternions of rotation vectors (rad), rotation matrices, and the
ordered product of a sequence by pairwise reduction (no loop over samples).
"""

from __future__ import annotations

import numpy as np


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternion arrays (..., 4)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def rotvec_quat(theta: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of rotation vectors (..., 3), rad."""
    a2 = np.einsum("...i,...i->...", theta, theta)
    a = np.sqrt(a2)
    half = 0.5 * a
    # sin(a/2)/a with its series near zero
    big = a > 1e-4
    k = np.where(big, np.sin(half) / np.where(big, a, 1.0), 0.5 - a2 / 48.0)
    out = np.empty(theta.shape[:-1] + (4,))
    out[..., 0] = np.cos(half)
    out[..., 1:] = theta * k[..., None]
    return out


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def matrix_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (4,) (w, x, y, z), w >= 0, of a rotation matrix (3, 3)
    (the inverse of :func:`quat_matrix`; Shepperd's method, stable at every angle)."""
    r = np.asarray(r, dtype=float)
    tr = float(np.trace(r))
    cands = [tr, r[0, 0], r[1, 1], r[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = [
            w,
            (r[2, 1] - r[1, 2]) / (4 * w),
            (r[0, 2] - r[2, 0]) / (4 * w),
            (r[1, 0] - r[0, 1]) / (4 * w),
        ]
    else:
        j, k = (i % 3), ((i + 1) % 3)
        a = i - 1
        s = 2.0 * np.sqrt(1.0 + 2.0 * r[a, a] - tr)
        q = [0.0] * 4
        q[0] = (r[k, j] - r[j, k]) / s
        q[1 + a] = 0.25 * s
        q[1 + j] = (r[j, a] + r[a, j]) / s
        q[1 + k] = (r[k, a] + r[a, k]) / s
    out = np.array(q, dtype=float)
    out /= np.linalg.norm(out)
    return -out if out[0] < 0 else out


def ordered_product(q: np.ndarray) -> np.ndarray:
    """q_0 * q_1 * ... * q_{L-1} along axis -2 of (..., L, 4), by pairwise reduction."""
    length = q.shape[-2]
    size = 1 << max(0, (length - 1).bit_length())
    if size != length:
        pad = np.zeros(q.shape[:-2] + (size - length, 4))
        pad[..., 0] = 1.0
        q = np.concatenate([q, pad], axis=-2)
    while q.shape[-2] > 1:
        q = qmul(q[..., 0::2, :], q[..., 1::2, :])
    return q[..., 0, :]


def _qmul_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternions stored component-major: (L, 4, M) by (L, 4, M),
    each component a contiguous row of M (the arithmetic of :func:`qmul`, term for term)."""
    aw, ax, ay, az = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    bw, bx, by, bz = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    out = np.empty(a.shape)
    out[:, 0] = aw * bw - ax * bx - ay * by - az * bz
    out[:, 1] = aw * bx + ax * bw + ay * bz - az * by
    out[:, 2] = aw * by - ax * bz + ay * bw + az * bx
    out[:, 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def ordered_product_of_rotvecs(theta: np.ndarray) -> np.ndarray:
    """q(theta_0) * q(theta_1) * ... * q(theta_{L-1}) of rotation vectors (rad) along axis
    -2 of (..., L, 3): quaternions (..., 4), equal to ``ordered_product(rotvec_quat(theta))``
    bit for bit, faster.

    The same pairwise reduction, with the L axis first and each component a contiguous row
    over all the other axes (one product of whole rows per level, not one per strided
    quaternion), and without padding L to a power of two: an element left unpaired at a
    level passes up unchanged, as its product with the identity padding did exactly.
    """
    lead = theta.shape[:-2]
    length = theta.shape[-2]
    if length == 0:
        return np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0]), lead + (4,)).copy()
    rows = np.moveaxis(theta.reshape((-1, length, 3)), 1, 0)  # (L, M, 3), M = prod(lead)
    q = np.moveaxis(rotvec_quat(rows), 2, 1).copy()  # (L, 4, M)
    while q.shape[0] > 1:
        half = q.shape[0] // 2
        prod = _qmul_rows(q[0 : 2 * half : 2], q[1 : 2 * half : 2])
        q = np.concatenate([prod, q[-1:]]) if q.shape[0] % 2 else prod
    return q[0].T.reshape(lead + (4,))


__all__ = [
    "matrix_quat",
    "ordered_product",
    "ordered_product_of_rotvecs",
    "qmul",
    "quat_matrix",
    "rotvec_quat",
]
