"""The gyro rotation fit's fast ordered product equals the plain one bit for bit (issue 14)."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.rotations import ordered_product, ordered_product_of_rotvecs, rotvec_quat


@pytest.mark.parametrize("length", [0, 1, 2, 3, 5, 8, 9, 167])
@pytest.mark.parametrize("lead", [(), (4,), (3, 5)])
def test_equal_to_the_padded_pairwise_product(length, lead):
    rng = np.random.default_rng(1000 + length)
    theta = rng.normal(scale=0.02, size=lead + (length, 3))  # rad, 1 deg blocks
    if length > 2:
        theta[..., -2:, :] = 0.0  # zero padding, as stack_pairs leaves it
        theta[..., 0, :] *= 1e-6  # below the series threshold of rotvec_quat
    fast = ordered_product_of_rotvecs(theta)
    assert fast.shape == lead + (4,)
    if length == 0:
        assert np.array_equal(fast, np.broadcast_to([1.0, 0.0, 0.0, 0.0], lead + (4,)))
        return
    assert np.array_equal(fast, ordered_product(rotvec_quat(theta)))
    assert np.allclose(np.linalg.norm(fast, axis=-1), 1.0, atol=1e-12)
