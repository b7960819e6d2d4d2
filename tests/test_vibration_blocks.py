"""The vibration meter sums a block's whole windows at once (issue 28: no Python loop per
1-s window): the levels, peak, window counts and the window being filled are bit for bit
those of the former loop over windows, for blocks of any size (random streams, fixed
seeds, with high vibration in some windows and a non-finite output), and on a real
recording (tests/data/real/xsens-mti-multiposition) with its certificate; with the compiled
kernels (numba, the ``fleet`` extra: the high-pass and the windows' sums,
:func:`imudiag.numba_kernels.window_row_sums`) and without."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag import kernels
from imudiag.certificate import load, load_default
from imudiag.logs import read_log
from imudiag.samples import SampleBlock
from imudiag.vibration import VibrationMeter

DATA = Path(__file__).resolve().parent / "data"


class FormerMeter(VibrationMeter):
    """The former loop over windows, kept here as the reference (the high-pass filter is
    the meter's own: only the windowing differs)."""

    def _add_squares(self, sq: np.ndarray) -> None:
        n, pos = sq.shape[0], 0
        while pos < n:
            take = min(n - pos, self.window - self._count)
            self._sumsq += sq[pos : pos + take].sum(axis=0)
            self._count += take
            pos += take
            if self._count == self.window:
                level = np.sqrt(self._sumsq / self.window)
                self.last = level
                self.peak = np.maximum(self.peak, level)
                self.windows += 1
                if float(np.max(level[3:])) > self.limits.accel_high:
                    self.high_windows += 1
                self._sumsq = np.zeros(6)
                self._count = 0


def state(m: VibrationMeter) -> list:
    return [m.last, m.peak, m.windows, m.high_windows, m._sumsq, m._count, m.seen]


def feed_both(
    cert, rate_hz: float, block: SampleBlock, sizes: np.ndarray, compiled: bool = False
) -> VibrationMeter:
    """The meter (``compiled``: with the kernels) and the former loop (plain) fed ``block`` in
    blocks of ``sizes``, their states equal after every block."""
    new, old = VibrationMeter(cert, rate_hz), FormerMeter(cert, rate_hz)
    start = 0
    for size in sizes:
        part = block.slice(start, min(start + int(size), len(block)))
        start += int(size)
        with kernels.switched(compiled) as on:
            if compiled and not on:
                pytest.skip(f"the compiled kernels cannot be loaded: {kernels.status()}")
            new.update(part)
        with kernels.switched(False):
            old.update(part)
        for a, b in zip(state(new), state(old), strict=True):
            np.testing.assert_array_equal(a, b)
        if start >= len(block):
            break
    assert new.windows > 3
    return new


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_whole_windows_at_once_equal_the_former_loop(seed, compiled):
    cert = load_default()
    rng = np.random.default_rng(seed)
    n = 20000
    gyro = rng.normal(0.0, 50.0, (n, 3))
    accel = rng.normal(0.0, 200.0, (n, 3)) + np.array([0.0, 0.0, 8000.0])
    accel[5000:7000] *= 40.0  # a stretch of high vibration
    if seed == 3:
        gyro[1234, 1] = np.nan  # a non-finite output
    block = SampleBlock(t=np.arange(n) / 100.0, gyro=gyro, accel=accel)
    sizes = rng.integers(1, 700, size=n) if seed % 2 else np.full(n, n)
    assert feed_both(cert, 100.0, block, sizes, compiled).high_windows > 0


@pytest.mark.parametrize("compiled", [False, True])
def test_whole_windows_at_once_on_a_real_recording(compiled):
    block = read_log(DATA / "real" / "xsens-mti-multiposition" / "session.csv.gz")
    cert = load(DATA / "diagnosis" / "like-xsens.yaml")
    rate = 1.0 / float(np.median(np.diff(block.t)))
    sizes = np.random.default_rng(9).integers(50, 5000, size=len(block))
    feed_both(cert, rate, block, sizes, compiled)
