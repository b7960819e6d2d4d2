"""The monitor's parts (:mod:`imudiag.monitor`) against their plain definitions, on seeded
random streams cut into random blocks and on the real recordings (issue 30 item 6):

- :class:`~imudiag.monitor.StuckCheck`: after every block, a channel is stuck exactly when
  its last ``stuck_samples`` raw outputs are equal (and its noise is checked), and the
  episodes it counts are the stream's runs of one value that long, however it was cut
  (with the compiled kernels and without);
- :class:`~imudiag.monitor.batching.F0Screen`: its count of samples beyond the F0 limit is
  that of the F0 of each sample corrected with the certificate, and it never counts fewer
  (the bound the gathered reads rely on);
- :meth:`~imudiag.monitor.NoiseCheck.positions`: the checks fall on the stream's multiples
  of the step, once a whole window is there, where calm.
"""

from __future__ import annotations

import numpy as np
import pytest

from imudiag import kernels
from imudiag.certificate import load_default
from imudiag.monitor import MonitorConfig, NoiseCheck, StuckCheck
from imudiag.monitor.batching import F0Screen
from imudiag.scalar import f0
from imudiag.sim import Effects, Fault, multi_position, simulate
from tests.test_detector_equivalence import REAL_NAMES, _real

CERT = load_default()


def _blocks(rng: np.random.Generator, n: int) -> list[tuple[int, int]]:
    out, at = [], 0
    while at < n:
        size = int(rng.choice([rng.integers(1, 8), rng.integers(1, 400)]))
        out.append((at, min(n, at + size)))
        at += size
    return out


def _plain_stuck(raw: np.ndarray, end: int, samples: int) -> np.ndarray:
    """Channels (6,) whose last ``samples`` outputs up to row ``end`` (exclusive) of
    ``raw`` (N, 6) are equal."""
    if end < samples:
        return np.zeros(6, dtype=bool)
    tail = raw[end - samples : end]
    return np.all(tail == tail[-1], axis=0)


def _plain_episodes(raw: np.ndarray, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Per channel of ``raw`` (N, 6): the runs of one value at least ``samples`` long
    (count), and the row completing the first of them (NaN: none)."""
    count = np.zeros(6, dtype=np.int64)
    first = np.full(6, np.nan)
    for c in range(6):
        i = 0
        while i < raw.shape[0]:
            j = i + 1
            while j < raw.shape[0] and raw[j, c] == raw[i, c]:
                j += 1
            if j - i >= samples:
                count[c] += 1
                if np.isnan(first[c]):
                    first[c] = i + samples - 1
            i = j
    return count, first


def _check_stuck(
    raw: np.ndarray, sigma: tuple, seed: int, samples: int = 50, compiled: bool = False
) -> int:
    """The state in force after every block, and the episodes the whole stream raised
    (:attr:`StuckCheck.raised`, also those inside one block), against their definitions;
    ``compiled``: with the kernels (numba, the ``fleet`` extra: the block's scan and its
    episodes, :func:`imudiag.numba_kernels.stuck_episodes`)."""
    rng = np.random.default_rng(seed)
    check = StuckCheck(sigma, 1.0, samples)
    stuck_seen = 0
    for a, b in _blocks(rng, raw.shape[0]):
        with kernels.switched(compiled) as on:
            if compiled and not on:
                pytest.skip(f"the compiled kernels cannot be loaded: {kernels.status()}")
            active = check.update(raw[a:b].T.copy(), np.arange(a, b, dtype=float))
        want = _plain_stuck(raw, b, samples) & check.enabled
        assert np.array_equal(active, want), f"block {a}..{b}"
        stuck_seen += int(active.any())
    count, first = _plain_episodes(raw, samples)
    on = check.enabled  # fixed here: counts (step 1) and a fixed sigma
    np.testing.assert_array_equal(check.raised, np.where(on, count, 0))
    np.testing.assert_array_equal(check.t_first_raised, np.where(on, first, np.nan))
    return stuck_seen


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_stuck_runs_are_their_definition_on_random_streams(seed, compiled):
    rng = np.random.default_rng(500 + seed)
    n = 6000
    raw = np.round(rng.normal(scale=3.0, size=(n, 6)))
    for _ in range(8):  # runs of repeated values of random lengths on random channels
        c, at, length = int(rng.integers(0, 6)), int(rng.integers(0, n)), int(rng.integers(20, 300))
        raw[at : at + length, c] = raw[at, c]
    raw[rng.random((n, 6)) < 0.001] = np.nan  # NaN never equals: it ends a run
    raw[1000:2000, 0] = 7.0  # and one run on a channel checked
    sigma = (np.array([5.0, 0.5, 5.0]), None if seed % 2 else np.array([5.0, 5.0, 5.0]))
    assert _check_stuck(raw, sigma, seed, compiled=compiled) > 0


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("name", REAL_NAMES)
def test_stuck_runs_are_their_definition_on_the_real_recordings(name, compiled):
    block, _cert = _real(name)
    raw = np.concatenate([block.gyro, block.accel], axis=1)[:30_000]
    seed = 600 + REAL_NAMES.index(name)
    _check_stuck(raw, (np.ones(3), np.ones(3)), seed, samples=5, compiled=compiled)


@pytest.mark.parametrize("seed", range(3))
def test_the_f0_screen_counts_what_the_f0_check_fails(seed):
    """The screen's count (folded matrix, or the certificate's inverse) is the count of
    samples whose per-sample F0 exceeds the limit, up to samples within 1e-9 of it,
    which it counts as beyond (a bound never too low)."""
    faults = [Fault("bias", "az", 2.0, 400.0 * (seed + 1)), Fault("scale_factor", "ax", 4.0, 0.02)]
    traj = multi_position(n_attitudes=4, dwell_s=2.0, turn_s=1.0, rate_hz=200, seed=seed)
    block = simulate(CERT, traj, seed=700 + seed, faults=faults, effects=Effects()).samples
    n_inv_t = {name: CERT.triad(name).n_inverse_t() for name in ("gyro", "accel")}
    limit = {name: float(CERT.triad(name).limits.f0) for name in ("gyro", "accel")}
    screen = F0Screen(CERT, n_inv_t, limit)
    accel_si = CERT.accel.inverse(block.accel) * CERT.accel.unit_to_si
    values = np.abs(f0(accel_si / CERT.gravity))
    exact = int(np.count_nonzero(values > limit["accel"]))
    near = int(np.count_nonzero(np.abs(values - limit["accel"]) <= 1e-8 * limit["accel"]))
    rng = np.random.default_rng(seed)
    parts = [block.slice(a, b) for a, b in _blocks(rng, len(block))]
    counted = sum(screen.count(parts[i : i + 7], False)["accel"] for i in range(0, len(parts), 7))
    assert exact > 0
    assert exact <= counted <= exact + near


def test_noise_check_positions_are_the_stream_multiples_once_a_window_is_there():
    cfg = MonitorConfig()
    check = NoiseCheck(CERT, cfg, 200.0)
    rng = np.random.default_rng(9)
    n = 5000
    calm = rng.random(n) > 0.2
    got = []
    for a, b in _blocks(rng, n):
        got.append(a + check.positions(a, a, calm[a:b]))
    pos = np.concatenate(got)
    idx = np.arange(n)
    want = idx[(idx % check.step == 0) & (idx + 1 >= check.window + 2) & calm]
    assert np.array_equal(pos, want)
