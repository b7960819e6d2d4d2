"""The gyro rotation fit's fast ordered product equals the plain one bit for bit (issue 14)."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.rotations import (
    ordered_product,
    rotvec_quat,
    segment_product_plan,
    segmented_product_of_rotvecs,
)


def _segmented(padded: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The segmented product of the first ``lengths`` vectors of each row of ``padded``
    (P, S, L, 3)."""
    width = padded.shape[2]
    row, block = np.nonzero(np.arange(width)[None, :] < lengths[:, None])
    return segmented_product_of_rotvecs(padded[:, row, block], segment_product_plan(lengths))


@pytest.mark.parametrize(
    "lengths",
    [[29, 101, 0, 67, 166, 1, 2], [1], [0], [5, 3], [0, 0], [2, 2, 2], [8, 9, 7, 16, 17]],
)
def test_equal_to_the_padded_pairwise_product(lengths):
    """Only the blocks each segment has are turned and multiplied; the result is the
    padded product's (ordered_product of rotvec_quat), bit for bit, for every set."""
    rng = np.random.default_rng(1000 + sum(lengths))
    lengths = np.array(lengths)
    n_sets, width = 4, max(int(lengths.max()), 1)
    padded = np.zeros((n_sets, len(lengths), width, 3))
    for r, n in enumerate(lengths):
        padded[:, r, :n] = rng.normal(scale=0.02, size=(n_sets, n, 3))  # rad, 1 deg blocks
        if n > 2:
            padded[:, r, 0] *= 1e-6  # below the series threshold of rotvec_quat
    got = _segmented(padded, lengths)
    assert got.shape == (n_sets, len(lengths), 4)
    assert np.array_equal(got, ordered_product(rotvec_quat(padded)))
    assert np.allclose(np.linalg.norm(got, axis=-1), 1.0, atol=1e-12)
    empty = lengths == 0
    assert np.array_equal(got[:, empty], np.broadcast_to([1.0, 0, 0, 0], got[:, empty].shape))


def test_the_plan_pairs_neighbours_inside_each_segment():
    levels, where = segment_product_plan(np.array([3, 0, 2]))
    left, to, last, last_to, size = levels[0]
    assert left.tolist() == [0, 3] and to.tolist() == [0, 2]  # (0, 1) and (3, 4)
    assert last.tolist() == [2] and last_to.tolist() == [1] and size == 3
    assert len(levels) == 2 and where.tolist() == [0, -1, 1]


def test_predicted_directions_do_not_depend_on_the_padding():
    """predict_end_directions with each motion's block count equals the fully padded
    evaluation (a stack without ``blocks``) exactly."""
    from imudiag.certificate import load_default
    from imudiag.diagnosis.gyro_fit import RotationPair, predict_end_directions, stack_pairs

    gyro = load_default().gyro
    rng = np.random.default_rng(8)
    pairs = []
    for m in (40, 300, 150):  # samples of each motion at 200 Hz
        t = np.arange(m) / 200.0
        rate = rng.normal(scale=0.8, size=3)  # rad/s
        raw = rate / gyro.unit_to_si * gyro.scale_factor + rng.normal(scale=3.0, size=(m, 3))
        up0 = rng.normal(size=3)
        pairs.append(
            RotationPair(t, raw, np.zeros(3), up0 / np.linalg.norm(up0), up0, 1e-8, np.ones(3))
        )
    stack = stack_pairs(gyro, pairs)
    assert len(set(stack["blocks"].tolist())) == 3
    ninv = np.linalg.inv(gyro.n_matrix())[None] + rng.normal(scale=1e-3, size=(5, 3, 3))
    up0 = np.array([p.up0 for p in pairs])
    fast = predict_end_directions(stack, ninv, up0)
    full = predict_end_directions({"inc": stack["inc"]}, ninv, up0)
    assert fast.shape == (5, 3, 3)
    assert np.array_equal(fast, full)


def test_a_motion_memo_follows_the_gyro_scale():
    """The increments kept on a motion are reused for the same scale and recomputed for a
    gyro model whose scale factors changed (in place too)."""
    import copy

    from imudiag.certificate import load_default
    from imudiag.diagnosis.gyro_fit import RotationPair, stack_pairs

    gyro = load_default().gyro
    rng = np.random.default_rng(9)
    t = np.arange(200) / 200.0
    raw = rng.normal(scale=2000.0, size=(200, 3))
    memo: dict = {}

    def pair(m):
        return RotationPair(t, raw, np.zeros(3), np.eye(3)[2], np.eye(3)[2], 1e-8, np.ones(3), m)

    first = stack_pairs(gyro, [pair(memo)])["inc"]
    assert len(memo) == 1
    again = stack_pairs(copy.deepcopy(gyro), [pair(memo)])["inc"]  # same scale: kept
    assert len(memo) == 1 and np.array_equal(again, first)
    other = copy.deepcopy(gyro)
    other.scale_factor = other.scale_factor * 1.01
    changed = stack_pairs(other, [pair(memo)])["inc"]
    assert len(memo) == 2
    assert np.array_equal(changed, stack_pairs(other, [pair(None)])["inc"])
    assert not np.array_equal(changed, first)
    other.scale_factor[0] *= 1.01  # changed in place: a new key, not the stale entry
    in_place = stack_pairs(other, [pair(memo)])["inc"]
    assert len(memo) == 3
    assert np.array_equal(in_place, stack_pairs(other, [pair(None)])["inc"])
