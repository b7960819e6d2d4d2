"""The window diagnosis's cost work (issue 14) leaves every number as it was, bit for bit.

The quaternion products of the rotation fit run as a few whole-array operations instead
of one per term; the rotation matrices are filled in place; product plans, the fit's
start at the certificate and each motion's duration, sampling interval and bias variance
are kept and reused. Each is checked here against the arithmetic it replaced (written out
below as it was) or against the same fit with nothing kept.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from test_rotation_jacobian import xsens_windows  # noqa: F401  (the real Xsens windows)

from imudiag.diagnosis.gyro_fit import rotation_fit
from imudiag.rotations import (
    qmul,
    quat_matrix,
    rotvec_quat,
    segment_product_plan,
    segmented_product_of_rotvecs,
)


def _quat_matrix_stacked(q: np.ndarray) -> np.ndarray:
    """quat_matrix as it was (nested np.stack), the reference of the in-place one."""
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


def _rotation_vectors(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Rotation vectors (shape, 3), rad, over many decades of angle, with exact zeros."""
    scale = 10.0 ** rng.uniform(-9, 0.5, size=shape + (1,))
    theta = rng.normal(size=shape + (3,)) * scale
    theta[..., 0][rng.random(shape) < 0.1] = 0.0
    return theta


@pytest.mark.parametrize("sets", [1, 4])
def test_products_equal_qmul_term_for_term(sets):
    """Two-block segments: each product equals qmul of the two quaternions bit for bit
    (signed terms added in qmul's order), for one parameter set and several at once."""
    rng = np.random.default_rng(14)
    theta = _rotation_vectors(rng, (sets, 2 * 300))
    got = segmented_product_of_rotvecs(theta, segment_product_plan(np.full(300, 2)))
    q = rotvec_quat(theta)
    assert np.array_equal(got, qmul(q[:, 0::2], q[:, 1::2]))


def test_rotation_matrices_equal_the_stacked_formula():
    rng = np.random.default_rng(15)
    for shape in [(4,), (7, 4), (3, 5, 4)]:
        q = rng.normal(size=shape) * 10.0 ** rng.uniform(-3, 3, size=shape[:-1] + (1,))
        assert np.array_equal(quat_matrix(q), _quat_matrix_stacked(q))
    for q in (np.array([1, 2, 3, 4]), np.array([0.1, 0.2, 0.3, 0.9], dtype=np.float32)):
        got, want = quat_matrix(q), _quat_matrix_stacked(q)  # integers, single precision
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_plans_are_kept_read_only_and_equal_fresh_ones():
    """One segment's plan is kept by its length (each new motion's, window after window),
    read-only; a plan of several segments is made afresh."""
    single = segment_product_plan(np.array([37]))
    assert segment_product_plan([37]) is single
    assert segment_product_plan(np.array([37], dtype=np.int32)) is single
    levels, where = single
    assert where.tolist() == [0] and not where.flags.writeable
    with pytest.raises(ValueError):
        levels[0][0][0] = 1
    lengths = np.array([5, 0, 1, 8, 3])
    plan = segment_product_plan(lengths)
    assert segment_product_plan(lengths) is not plan
    levels, where = plan
    assert where.tolist() == [0, -1, 1, 2, 3]
    # the products of the padded tree, segment by segment, kept plan or not
    rng = np.random.default_rng(16)
    theta = _rotation_vectors(rng, (2, int(lengths.sum())))
    padded = np.zeros((2, lengths.size, 8, 3))
    start = np.cumsum(lengths) - lengths
    for s, (a, n) in enumerate(zip(start, lengths, strict=True)):
        padded[:, s, :n] = theta[:, a : a + n]
    want = np.ones((2, lengths.size, 4)) * np.array([1.0, 0, 0, 0])
    for s, n in enumerate(lengths):
        if n:
            q = rotvec_quat(padded[:, s])
            while q.shape[1] > 1:
                q = qmul(q[:, 0::2], q[:, 1::2])
            want[:, s] = q[:, 0]
    assert np.array_equal(segmented_product_of_rotvecs(theta, plan), want)
    for s, (a, n) in enumerate(zip(start, lengths, strict=True)):
        alone = segmented_product_of_rotvecs(theta[:, a : a + n], segment_product_plan([n]))
        assert np.array_equal(alone[:, 0], want[:, s])


def _plan_level_by_level(lengths: np.ndarray) -> tuple[list, np.ndarray]:
    """segment_product_plan as it was made, one level after the other (the reference)."""
    n = np.asarray(lengths, dtype=np.intp)
    levels = []
    while n.size and n.max() > 1:
        start = np.cumsum(n) - n
        pairs = n // 2
        odd = (n % 2).astype(bool)
        new_n = pairs + odd
        new_start = np.cumsum(new_n) - new_n
        seg = np.repeat(np.arange(n.size), pairs)
        rank = np.arange(seg.size) - np.repeat(np.cumsum(pairs) - pairs, pairs)
        levels.append(
            (
                start[seg] + 2 * rank,
                new_start[seg] + rank,
                start[odd] + n[odd] - 1,
                new_start[odd] + pairs[odd],
                int(new_n.sum()),
            )
        )
        n = new_n
    return levels, np.where(n > 0, np.cumsum(n) - n, -1)


def test_plans_equal_the_level_by_level_construction():
    """Every level made at once gives the plan made level after level: every index array
    (values and type) and every size, on 600 random sets of lengths (empty segments, ones,
    up to 300 blocks) and the edge cases."""
    rng = np.random.default_rng(17)
    cases = [[], [0], [1], [2], [0, 0], [1, 1], [3, 0, 2], [5, 0, 1, 8, 3], [256], [257]]
    cases += [rng.integers(0, 300, size=rng.integers(1, 30)).tolist() for _ in range(500)]
    cases += [rng.integers(0, 3, size=rng.integers(1, 10)).tolist() for _ in range(100)]
    for lengths in cases:
        levels, where = segment_product_plan(np.array(lengths, dtype=np.intp))
        ref_levels, ref_where = _plan_level_by_level(np.array(lengths, dtype=np.intp))
        assert where.dtype == ref_where.dtype and np.array_equal(where, ref_where), lengths
        assert len(levels) == len(ref_levels), lengths
        for got, want in zip(levels, ref_levels, strict=True):
            for a, b in zip(got[:4], want[:4], strict=True):
                assert a.dtype == b.dtype and np.array_equal(a, b), lengths
            assert got[4] == want[4] and isinstance(got[4], int), lengths


def _fields(fit) -> dict:
    return {k: v for k, v in vars(fit).items() if v is not None}


def test_rotation_fits_with_kept_figures_equal_fits_without(xsens_windows):  # noqa: F811
    """Every window of the real Xsens recording, fitted in order with each motion's memo
    (kept rotations, figures and the certificate's start, filled by the earlier windows),
    equals the same fit with nothing kept, every field bit for bit."""
    cert, windows = xsens_windows
    gyro = cert.gyro
    memos: dict[int, dict] = {}
    kept_any = 0
    for pairs in windows:
        with_memo = [copy.copy(p) for p in pairs]
        for p in with_memo:
            p.memo = memos.setdefault(id(p.memo), {})
        kept_any += sum(bool(p.memo) for p in with_memo)
        plain = [copy.copy(p) for p in pairs]
        for p in plain:
            p.memo = None
        # a per-sample output variance (output units^2): the motions' bias variance (that
        # of a mean of some 10^3 samples) times 10^3
        var = np.full(3, 1e3 * float(np.median([np.mean(p.bias_var) for p in pairs])))
        a = rotation_fit(gyro, with_memo, var, cert.earth_rate, fit_frame=True)
        b = rotation_fit(gyro, plain, var, cert.earth_rate, fit_frame=True)
        fa, fb = _fields(a), _fields(b)
        assert fa.keys() == fb.keys()
        for key in fa:
            assert np.array_equal(fa[key], fb[key], equal_nan=True), key
    assert kept_any > 0  # later windows did start from what earlier ones kept
