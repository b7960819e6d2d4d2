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


def _half_angle(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos(a/2), sin(a/2)/a) of rotation vectors (..., 3), rad, a = |theta| (the second
    by its series near zero): a quaternion is (cos(a/2), theta sin(a/2)/a)."""
    a2 = np.einsum("...i,...i->...", theta, theta)
    a = np.sqrt(a2)
    half = 0.5 * a
    # sin(a/2)/a with its series near zero
    big = a > 1e-4
    k = np.where(big, np.sin(half) / np.where(big, a, 1.0), 0.5 - a2 / 48.0)
    return np.cos(half), k


def rotvec_quat(theta: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of rotation vectors (..., 3), rad."""
    c, k = _half_angle(theta)
    out = np.empty(theta.shape[:-1] + (4,))
    out[..., 0] = c
    out[..., 1:] = theta * k[..., None]
    return out


def _rotvec_rows(theta: np.ndarray) -> np.ndarray:
    """:func:`rotvec_quat` component-major: (4, ...) of rotation vectors (..., 3), rad."""
    c, k = _half_angle(theta)
    out = np.empty((4,) + theta.shape[:-1])
    out[0] = c
    for i in range(3):
        np.multiply(theta[..., i], k, out=out[i + 1])
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


#: the terms of each component of a Hamilton product a * b, in the order :func:`qmul` adds
#: them: (sign, component of a, component of b)
_HAMILTON = (
    ((1, 0, 0), (-1, 1, 1), (-1, 2, 2), (-1, 3, 3)),
    ((1, 0, 1), (1, 1, 0), (1, 2, 3), (-1, 3, 2)),
    ((1, 0, 2), (-1, 1, 3), (1, 2, 0), (1, 3, 1)),
    ((1, 0, 3), (1, 1, 2), (-1, 2, 1), (1, 3, 0)),
)


def _qmul_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternions stored component-major, (4, L, M) by (4, L, M):
    the arithmetic of :func:`qmul` term for term (the same roundings), on whole rows and
    into two buffers (no temporary array per term)."""
    out = np.empty(a.shape)
    term = np.empty(a.shape[1:])
    for c, terms in enumerate(_HAMILTON):
        acc = out[c]
        (_, i0, j0), *rest = terms
        np.multiply(a[i0], b[j0], out=acc)
        for sign, i, j in rest:
            np.multiply(a[i], b[j], out=term)
            (np.add if sign > 0 else np.subtract)(acc, term, out=acc)
    return out


def ordered_product_rows(q: np.ndarray) -> np.ndarray:
    """q_0 * q_1 * ... * q_{L-1} of quaternions stored component-major (4, L, M): (4, M).

    :func:`ordered_product` bit for bit, faster: the same pairwise reduction, each
    component a contiguous row over M (one product of whole rows per level, not one per
    strided quaternion), and without padding L to a power of two (an element left unpaired
    at a level passes up unchanged, as its product with the identity padding did exactly).
    """
    if q.shape[1] == 0:
        out = np.zeros((4, q.shape[2]))
        out[0] = 1.0
        return out
    while q.shape[1] > 1:
        half = q.shape[1] // 2
        prod = _qmul_rows(q[:, 0 : 2 * half : 2], q[:, 1 : 2 * half : 2])
        q = np.concatenate([prod, q[:, -1:]], axis=1) if q.shape[1] % 2 else prod
    return q[:, 0]


def ordered_product_of_rotvecs(theta: np.ndarray) -> np.ndarray:
    """q(theta_0) * q(theta_1) * ... * q(theta_{L-1}) of rotation vectors (rad) along axis
    -2 of (..., L, 3): quaternions (..., 4), ``ordered_product(rotvec_quat(theta))`` bit for
    bit (:func:`ordered_product_rows`)."""
    lead = theta.shape[:-2]
    length = theta.shape[-2]
    m = int(np.prod(lead, dtype=np.int64))
    rows = np.moveaxis(theta.reshape((m, length, 3)), 1, 0)  # (L, M, 3)
    return ordered_product_rows(_rotvec_rows(rows)).T.reshape(lead + (4,))


def ragged_product_of_rotvecs(
    theta: np.ndarray, block: np.ndarray, row: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """Ordered products of rotation vectors (rad) given only where they may be non-zero.

    ``theta`` (P, K, 3): for each of P sets, the K vectors at (``block[k]``, ``row[k]``)
    of a (L, R) = ``shape`` grid of blocks by rows whose other vectors are zero (the
    padding of rows shorter than L); ``block`` must be non-decreasing. Returns (P, R, 4),
    equal bit for bit to :func:`ordered_product_of_rotvecs` of the padded (P, R, L, 3)
    (a zero vector's quaternion is the identity exactly): the trigonometry runs on the K
    vectors only.
    """
    n_sets = theta.shape[0]
    length, n_rows = shape
    width = n_sets * n_rows
    q = np.zeros((4, length, width))
    q[0] = 1.0
    flat = (block * width + row)[None, :] + (np.arange(n_sets) * n_rows)[:, None]  # (P, K)
    vals = _rotvec_rows(theta)  # (4, P, K)
    for c in range(4):
        np.put(q[c], flat, vals[c])
    return ordered_product_rows(q).T.reshape(n_sets, n_rows, 4)


__all__ = [
    "matrix_quat",
    "ordered_product",
    "ordered_product_of_rotvecs",
    "ordered_product_rows",
    "ragged_product_of_rotvecs",
    "qmul",
    "quat_matrix",
    "rotvec_quat",
]
