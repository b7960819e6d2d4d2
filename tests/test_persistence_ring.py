"""Persistence (k of n with hysteresis) and the sample ring buffer."""

import numpy as np
import pytest

from imudiag.persistence import Persistence
from imudiag.ringbuffer import SampleRing
from imudiag.samples import SampleBlock


def _reference(failed: np.ndarray, k: int, n: int, k_clear: int) -> list[bool]:
    """Per-sample state machine written the slow, obvious way."""
    state, out = False, []
    for i in range(len(failed)):
        count = int(failed[max(0, i - n + 1) : i + 1].sum())
        if count >= k:
            state = True
        elif count <= k_clear:
            state = False
        out.append(state)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_persistence_matches_reference_under_any_blocking(seed):
    rng = np.random.default_rng(seed)
    # bursts of failures so that the state flips several times
    failed = np.repeat(rng.random(60) < 0.4, rng.integers(1, 30, 60))
    t = np.arange(failed.size) * 0.005
    k, n, k_clear = 5, 12, 1
    ref = _reference(failed, k, n, k_clear)
    p = Persistence(k, n, k_clear)
    cuts = np.sort(rng.choice(np.arange(1, failed.size), 15, replace=False))
    states = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, failed.size], strict=True):
        p.update(failed[a:b], t[a:b])
        states.append((b - 1, p.active))
    for i, active in states:
        assert active == ref[i], f"sample {i}"
    assert any(ref) and not all(ref)


def test_persistence_reports_first_time():
    p = Persistence(3, 5)
    failed = np.array([0, 0, 1, 0, 1, 1, 1, 1], dtype=bool)
    t = np.arange(8) * 0.1
    assert p.update(failed, t)
    assert p.t_first == pytest.approx(0.5)  # third failure within 5 checks at index 5


def test_persistence_rejects_bad_settings():
    with pytest.raises(ValueError, match="k <= n"):
        Persistence(6, 5)


def test_ring_keeps_last_samples_in_order():
    ring = SampleRing(10)
    t = np.arange(27, dtype=float)
    g = np.c_[t, t + 100, t + 200]
    for a in range(0, 27, 4):
        b = min(27, a + 4)
        ring.push(SampleBlock(t=t[a:b], gyro=g[a:b], accel=-g[a:b]))
    rows = ring.latest()
    assert len(ring) == 10 and ring.total == 27
    np.testing.assert_array_equal(rows[:, 0], t[-10:])
    np.testing.assert_array_equal(rows[:, 1:4], g[-10:])
    blk = ring.latest_block(3)
    np.testing.assert_array_equal(blk.accel, -g[-3:])
    # a block larger than the ring keeps only its tail
    ring.push(SampleBlock(t=np.arange(100, 125.0), gyro=np.zeros((25, 3)), accel=np.zeros((25, 3))))
    np.testing.assert_array_equal(ring.latest()[:, 0], np.arange(115, 125.0))


def test_trailing_sum_matches_direct_windows_under_any_blocking():
    from imudiag.trailing import TrailingSum

    rng = np.random.default_rng(7)
    x = rng.normal(size=(500, 3))
    w = 37
    direct = np.array([x[max(0, i - w + 1) : i + 1].sum(axis=0) for i in range(len(x))])
    ts = TrailingSum(w, 3)
    got, counts = [], []
    for a, b in [(0, 1), (1, 20), (20, 21), (21, 300), (300, 500)]:
        s, c = ts.update(x[a:b])
        got.append(s)
        counts.append(c)
    np.testing.assert_allclose(np.concatenate(got), direct, atol=1e-12)
    np.testing.assert_array_equal(np.concatenate(counts), np.minimum(np.arange(1, 501), w))


def test_prefix_sums_give_every_window_exactly_under_any_blocking():
    """Whole-number rows, so every sum is exact: the windows ``offsets`` back from each row
    equal the direct sums (zero before the stream's start), through the ring's wraps, blocks
    longer than it holds, and the shift back to zero every 2^20 rows."""
    from imudiag.trailing import PrefixSums

    rng = np.random.default_rng(8)
    n = (1 << 20) + 5000
    x = rng.integers(-50, 50, size=(n, 2)).astype(float)
    p = np.concatenate([np.zeros((1, 2)), np.cumsum(x, axis=0)])  # p[i]: the first i rows
    offsets = np.array([1, 37, 500])
    ps = PrefixSums(2, 500)
    start = 0
    # small reads through every alignment of the ring's slots, then any size
    sizes = [1 + i % 7 for i in range(3000)] + [250, 3000, 499]
    sizes += list(rng.integers(1, 20000, size=200))
    k = 0
    while start < n:
        size = int(sizes[k % len(sizes)])
        k += 1
        rows = x[start : start + size]
        now, back, idx = ps.update(rows, offsets)
        m = len(rows)
        np.testing.assert_array_equal(idx, np.arange(start, start + m))
        ends = idx + 1  # rows of the stream up to and including each new row
        for j, off in enumerate(offsets):
            window = p[ends] - p[np.maximum(ends - off, 0)]
            np.testing.assert_array_equal(now - back[:, j], window)
        start += m
    assert ps.depth < n  # the ring wrapped
