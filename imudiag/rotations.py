"""Quaternions (w, x, y, z), Hamilton convention: R(a * b) = R(a) R(b).

The helpers the gyro rotation fit (:mod:`imudiag.diagnosis.gyro_fit`) and the model
check's rotation channel (:mod:`imudiag.modelcheck.rotations`) share: products of
quaternion arrays, quaternions of rotation vectors (rad), rotation matrices, and the
ordered product of a sequence by pairwise reduction (no loop over samples).
"""

from __future__ import annotations

import functools

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
    q = np.asarray(q)
    if q.dtype.kind not in "fc":
        q = q.astype(float)  # as np.linalg.norm takes integers
    # np.linalg.norm's arithmetic for a real vector, without its argument handling
    q = q / np.sqrt(np.add.reduce(q * q, axis=-1, keepdims=True))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (3, 3), dtype=q.dtype)
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


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


def _hamilton_terms() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:data:`_HAMILTON` as arrays (4 terms, 4 components): the component of a and of b
    in each term, and its sign (+-1.0)."""
    arr = np.array(_HAMILTON)  # (component, term, (sign, i, j))
    return arr[:, :, 1].T.copy(), arr[:, :, 2].T.copy(), arr[:, :, 0].T.astype(float)


_TERM_A, _TERM_B, _TERM_SIGN = _hamilton_terms()


def _qmul_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of quaternions stored component-major, (4, ...) by (4, ...):
    the arithmetic of :func:`qmul` term for term (the same roundings: the 16 signed
    terms ``(+-a_i) b_j`` are its products exactly, a subtracted term is its negation
    added, and each component adds its four terms in :func:`qmul`'s order), in a handful
    of whole-array operations instead of one per term."""
    terms = a[_TERM_A]  # (4 terms, 4 components, ...)
    terms *= _TERM_SIGN.reshape(_TERM_SIGN.shape + (1,) * (a.ndim - 1))
    terms *= b[_TERM_B]
    out = np.add(terms[0], terms[1])
    out += terms[2]
    out += terms[3]
    return out


#: one level of a segmented pairwise product: (first of each pair, where its product goes,
#: the unpaired last element of each odd segment, where it goes, elements after the level)
ProductLevel = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]


def segment_product_plan(lengths: np.ndarray) -> tuple[list[ProductLevel], np.ndarray]:
    """The levels of the pairwise products of segments of ``lengths`` (S,) laid end to end,
    and where each segment's product ends up (S,; -1: an empty segment, the identity).

    Each level pairs consecutive elements inside each segment, (0, 1), (2, 3), ..., and
    passes an odd segment's last element up unpaired: the tree of :func:`ordered_product`
    over each segment padded to a power of two, without the padding. The plans of one
    segment are kept by its length (the rotation fit asks for each new motion's alone,
    window after window; at most :data:`KEPT_PLANS`, some kB each), read-only.
    """
    n = np.asarray(lengths, dtype=np.intp).reshape(-1)
    if n.size == 1:
        return _single_segment_plan(int(n[0]))
    return _plan(n)


#: most single-segment plans kept (one per motion length in blocks)
KEPT_PLANS = 256


@functools.lru_cache(maxsize=KEPT_PLANS)
def _single_segment_plan(length: int) -> tuple[list[ProductLevel], np.ndarray]:
    """:func:`segment_product_plan` of one segment of ``length`` elements, read-only."""
    levels, where = _plan(np.array([length], dtype=np.intp))
    for level in levels:
        for arr in level[:4]:
            arr.setflags(write=False)
    where.setflags(write=False)
    return levels, where


def _plan(n: np.ndarray) -> tuple[list[ProductLevel], np.ndarray]:
    """:func:`segment_product_plan` of the lengths ``n`` (intp), every level at once: a
    segment of n elements has ceil(n / 2^L) at level L (pairs and an odd one passed up)."""
    m = int(n.max()) if n.size else 0
    depth = (m - 1).bit_length() if m > 1 else 0  # levels until every segment is one
    if depth == 0:
        return [], np.where(n > 0, np.cumsum(n) - n, -1)
    div = np.left_shift(1, np.arange(depth + 1, dtype=np.intp))[:, None]
    sizes = -(-n[None, :] // div)  # (depth + 1, S): each segment's elements per level
    starts = np.cumsum(sizes, axis=1) - sizes
    pairs = sizes[:-1] // 2
    odd = (sizes[:-1] % 2).astype(bool)
    per_level = pairs.sum(axis=1)
    flat = pairs.ravel()
    level = np.repeat(np.arange(depth), per_level)  # of each pair, level by level
    seg = np.repeat(np.tile(np.arange(n.size), depth), flat)  # and segment by segment
    rank = np.arange(flat.sum()) - np.repeat(np.cumsum(flat) - flat, flat)
    left = starts[level, seg] + 2 * rank
    to = starts[level + 1, seg] + rank
    odd_level, odd_seg = np.nonzero(odd)
    last = starts[odd_level, odd_seg] + sizes[odd_level, odd_seg] - 1
    last_to = starts[odd_level + 1, odd_seg] + pairs[odd_level, odd_seg]
    cut = np.cumsum(per_level)[:-1]
    odd_cut = np.cumsum(odd.sum(axis=1))[:-1]
    levels: list[ProductLevel] = list(
        zip(
            np.split(left, cut),
            np.split(to, cut),
            np.split(last, odd_cut),
            np.split(last_to, odd_cut),
            sizes[1:].sum(axis=1).tolist(),
            strict=True,
        )
    )
    top = sizes[-1]
    return levels, np.where(top > 0, np.cumsum(top) - top, -1)


def segmented_product_of_rotvecs(
    theta: np.ndarray, plan: tuple[list[ProductLevel], np.ndarray]
) -> np.ndarray:
    """Ordered products of rotation vectors (rad) by segment: ``theta`` (P, K, 3), P sets
    of the K vectors of segments laid end to end as ``plan`` (:func:`segment_product_plan`)
    says; returns (P, S, 4). Bit for bit ``ordered_product(rotvec_quat(.))`` of each segment
    padded with zero vectors (their quaternions are the identity exactly), with neither
    the padding's trigonometry nor its products."""
    levels, where = plan
    q = _rotvec_rows(theta)  # (4, P, K)
    for left, to, last, last_to, size in levels:
        nxt = np.empty(q.shape[:2] + (size,))
        nxt[:, :, to] = _qmul_rows(q.take(left, axis=2), q.take(left + 1, axis=2))
        nxt[:, :, last_to] = q.take(last, axis=2)
        q = nxt
    out = np.zeros((q.shape[1], where.size, 4))
    out[:, :, 0] = 1.0
    full = where >= 0
    out[:, full] = np.moveaxis(q.take(where[full], axis=2), 0, 2)
    return out


def _right_jacobian_coefficients(a2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(1 - cos a) / a^2`` and ``(a - sin a) / a^3`` of squared angles ``a2`` (rad^2), by
    their series below a = 1e-2 (where the closed forms cancel; the series' first omitted
    terms are below 1e-16 there)."""
    a = np.sqrt(a2)
    small = a < 1e-2
    safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0, (1.0 - np.cos(safe)) / safe**2)
    c2 = np.where(small, 1.0 / 6.0 - a2 / 120.0 + a2 * a2 / 5040.0, (safe - np.sin(safe)) / safe**3)
    return c1, c2


def rotvec_right_jacobian(theta: np.ndarray) -> np.ndarray:
    """Right Jacobians (..., 3, 3) of the rotation vectors ``theta`` (..., 3), rad:
    ``R(theta + d) = R(theta) exp([J_r(theta) d]x)`` to first order in d, with
    ``J_r = I - (1 - cos a) / a^2 [theta]x + (a - sin a) / a^3 [theta]x^2``, a = |theta|."""
    theta = np.asarray(theta, dtype=float)
    rows = _right_jacobian_rows(np.moveaxis(theta, -1, 0))
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3): ``skew(v) @ u = v x u``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape + (3,))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def segmented_product_sensitivity(
    theta: np.ndarray,
    inc: np.ndarray,
    lengths: np.ndarray,
    plan: tuple[list[ProductLevel], np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """Ordered products by segment of rotation vectors ``theta = L inc`` (rad) and their
    sensitivity to the matrix L.

    ``theta`` (K, 3) and ``inc`` (K, 3): the vectors of segments of ``lengths`` (S,)
    laid end to end (``plan``: :func:`segment_product_plan` of them), with
    ``theta[k] = L @ inc[k]`` for one 3x3 matrix L. Returns the products (S, 4), equal to
    :func:`segmented_product_of_rotvecs` of ``theta[None]`` bit for bit, and G
    (S, 3, 3, 3): a change dL moves each product by the right perturbation
    ``omega_a = sum_cd G[s, a, c, d] dL[c, d]`` (rad), ``R(L + dL) = R(L) exp([omega]x)``
    to first order. A block k perturbed by ``d_k``
    moves its segment's product by ``S_k^T J_r(theta_k) d_k``, with S_k the product of
    the blocks after it (:func:`rotvec_right_jacobian`); the S_k come down the same
    pairwise tree the products went up (one quaternion product per pair and level), so
    one evaluation serves every parameter.
    """
    levels, where = plan
    q = _rotvec_rows(theta[None])[:, 0]  # (4, K)
    ups = [q]
    for left, to, last, last_to, size in levels:
        nxt = np.empty((4, size))
        nxt[:, to] = _qmul_rows(q.take(left, axis=1), q.take(left + 1, axis=1))
        nxt[:, last_to] = q.take(last, axis=1)
        q = nxt
        ups.append(q)
    # products of what follows each element inside its segment, top down
    suffix: np.ndarray = np.zeros((4, q.shape[1]))
    suffix[0] = 1.0
    for (left, to, last, last_to, _), below in zip(levels[::-1], ups[-2::-1], strict=True):
        down: np.ndarray = np.empty(below.shape)
        parent = suffix.take(to, axis=1)
        down[:, left + 1] = parent
        down[:, left] = _qmul_rows(below.take(left + 1, axis=1), parent)
        down[:, last] = suffix.take(last_to, axis=1)
        suffix = down
    s = where.size
    out = np.zeros((s, 4))
    out[:, 0] = 1.0
    full = where >= 0
    out[full] = q.take(where[full], axis=1).T
    # per block S_k^T J_r(theta_k) (9 rows of K); per segment the sum of its outer products
    # with the block's inc
    rm = _matrix_rows(suffix)
    jr = _right_jacobian_rows(np.ascontiguousarray(theta.T))
    a = np.array(
        [
            rm[0][i] * jr[0][j] + rm[1][i] * jr[1][j] + rm[2][i] * jr[2][j]
            for i in range(3)
            for j in range(3)
        ]
    )
    terms = (a[:, None, :] * np.ascontiguousarray(inc.T)[None]).reshape(27, -1)  # (27, K)
    n = np.asarray(lengths, dtype=np.intp)
    sens = np.zeros((s, 27))
    if terms.shape[1]:
        # each segment summed on its own: the same sums whatever else is in the batch
        sens[n > 0] = np.add.reduceat(terms, (np.cumsum(n) - n)[n > 0], axis=1).T
    return out, sens.reshape(s, 3, 3, 3)


def _matrix_rows(q: np.ndarray) -> list[list[np.ndarray]]:
    """Rotation matrices of unit quaternions stored component-major (4, K), as 3 x 3
    nested lists of (K,) rows (the arithmetic of :func:`quat_matrix`, normalised)."""
    w, x, y, z = q / np.sqrt(np.einsum("ik,ik->k", q, q))
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def _right_jacobian_rows(th: np.ndarray) -> list[list[np.ndarray]]:
    """:func:`rotvec_right_jacobian` of rotation vectors component-major (3, ...), rad, as
    3 x 3 nested lists of (...) rows."""
    a2 = np.einsum("i...,i...->...", th, th)
    c1, c2 = _right_jacobian_coefficients(a2)
    diag = 1.0 - c2 * a2
    x, y, z = th
    cx, cy, cz = c1 * x, c1 * y, c1 * z
    gx, gy, gz = c2 * x, c2 * y, c2 * z
    return [
        [diag + gx * x, gx * y + cz, gx * z - cy],
        [gy * x - cz, diag + gy * y, gy * z + cx],
        [gz * x + cy, gz * y - cx, diag + gz * z],
    ]


__all__ = [
    "matrix_quat",
    "ordered_product",
    "segment_product_plan",
    "segmented_product_of_rotvecs",
    "qmul",
    "quat_matrix",
    "rotvec_quat",
    "rotvec_right_jacobian",
    "segmented_product_sensitivity",
    "skew",
]
