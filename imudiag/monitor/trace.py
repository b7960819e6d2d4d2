"""Every F0 check of a triad kept for plots, thinned to a bounded number of points."""

from __future__ import annotations

import numpy as np


class Thinned:
    """(t, value) pairs kept for a plot: every ``stride``-th, the stride doubling whenever
    more than ``max_points`` are held (so a day-long log costs a bounded memory)."""

    def __init__(self, max_points: int) -> None:
        self.max_points = max_points
        self.stride = 1
        self.seen = 0  #: pairs given, kept or not
        self._t: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self._held = 0

    def add(self, t: np.ndarray, v: np.ndarray) -> None:
        keep = (self.seen + np.arange(t.size)) % self.stride == 0
        self.seen += int(t.size)
        if not np.any(keep):
            return
        self._t.append(np.asarray(t, dtype=float)[keep])
        self._v.append(np.asarray(v, dtype=float)[keep])
        self._held += int(np.count_nonzero(keep))
        while self._held > self.max_points:
            t_all, v_all = self.arrays()
            self._t, self._v = [t_all[::2]], [v_all[::2]]
            self._held = int(self._t[0].size)
            self.stride *= 2

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Times (s) and values kept, in the order given."""
        if not self._t:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(self._t), np.concatenate(self._v)


class F0Trace:
    """Every F0 check of one triad for plots: its time (s, the last sample's), its value
    (F0, dimensionless; for the MEMS gyro rest-rate check the ratio of the worst axis' mean
    rate to its threshold) and whether it failed. Passing and failing checks are each
    thinned to at most ``max_points`` (every k-th kept, k a power of 2)."""

    def __init__(self, check: str, limit: float, max_points: int = 50_000) -> None:
        self.check = check  #: ``f0`` or ``rest_rate``
        self.limit = limit  #: a check fails beyond this (dimensionless)
        self.passed = Thinned(max_points)
        self.failed = Thinned(max_points)

    def add(self, t: np.ndarray, values: np.ndarray, failed: np.ndarray) -> None:
        """Checks at times ``t`` (s) with ``values`` and their failed flags."""
        self.passed.add(t[~failed], values[~failed])
        self.failed.add(t[failed], values[failed])

    @property
    def checks(self) -> int:
        """Checks given (kept or thinned away)."""
        return self.passed.seen + self.failed.seen
