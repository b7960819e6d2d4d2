"""A fixed-size numpy ring buffer of recent samples (no allocation per push)."""

from __future__ import annotations

import numpy as np

from .samples import SampleBlock


class SampleRing:
    """The last ``capacity`` samples: t (s), gyro and accel raw outputs (3 each), temp (degC).

    Storage is one preallocated (capacity, 8) float64 array: pushing a block
    copies it in with at most two slice assignments; memory never grows.
    """

    COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az", "temp")

    def __init__(self, capacity: int) -> None:
        if capacity <= 0:
            raise ValueError(f"ring capacity must be > 0 samples, got {capacity}")
        self.capacity = int(capacity)
        self._data = np.full((self.capacity, len(self.COLUMNS)), np.nan)
        self._head = 0  # index of the next write
        self._count = 0
        self.total = 0  #: samples pushed since creation

    def __len__(self) -> int:
        return self._count

    def push(self, block: SampleBlock) -> None:
        """Append a block; only its last ``capacity`` samples are kept."""
        n = len(block)
        if n == 0:
            return
        rows = np.empty((min(n, self.capacity), len(self.COLUMNS)))
        sl = slice(n - rows.shape[0], n)
        rows[:, 0] = block.t[sl]
        rows[:, 1:4] = block.gyro[sl]
        rows[:, 4:7] = block.accel[sl]
        rows[:, 7] = np.nan if block.temp is None else block.temp[sl]
        m = rows.shape[0]
        first = min(m, self.capacity - self._head)
        self._data[self._head : self._head + first] = rows[:first]
        if first < m:
            self._data[: m - first] = rows[first:]
        self._head = (self._head + m) % self.capacity
        self._count = min(self.capacity, self._count + m)
        self.total += n

    def latest(self, n: int | None = None) -> np.ndarray:
        """The last ``n`` samples (all held if None) in time order, as an (n, 8) copy."""
        n = self._count if n is None else min(int(n), self._count)
        if n == 0:
            return np.empty((0, len(self.COLUMNS)))
        start = (self._head - n) % self.capacity
        if start + n <= self.capacity:
            return self._data[start : start + n].copy()
        return np.concatenate([self._data[start:], self._data[: self._head]])

    def latest_block(self, n: int | None = None) -> SampleBlock:
        """The last ``n`` samples as a SampleBlock."""
        rows = self.latest(n)
        temp = rows[:, 7]
        return SampleBlock(
            t=rows[:, 0],
            gyro=rows[:, 1:4],
            accel=rows[:, 4:7],
            temp=None if np.all(np.isnan(temp)) else temp,
        )
