"""k-of-n persistence with hysteresis, vectorised over a block of check outcomes."""

from __future__ import annotations

import numpy as np


class Persistence:
    """Declares a condition active when ``k`` of the last ``n`` checks failed.

    It clears again when at most ``k_clear`` of the last ``n`` checks failed
    (hysteresis; default 0: a full window of passes). Only checks that were
    made count: samples where a check was not applicable are left out.
    """

    def __init__(self, k: int, n: int, k_clear: int = 0) -> None:
        if not 1 <= k <= n:
            raise ValueError(f"persistence needs 1 <= k <= n, got k={k}, n={n}")
        if not 0 <= k_clear < k:
            raise ValueError(f"persistence needs 0 <= k_clear < k, got k_clear={k_clear}")
        self.k, self.n, self.k_clear = int(k), int(n), int(k_clear)
        self._tail = np.zeros(0, dtype=bool)
        self._tail_failures = 0
        self.active = False
        self.t_first: float | None = None  #: sample time (s) the condition last became active
        self.raised = 0  #: times the condition became active (even set and cleared in one block)
        self.t_first_raised: float | None = None  #: sample time (s) it first became active

    @property
    def tail_failures(self) -> int:
        """Failures among the last ``n - 1`` checks: an inactive condition cannot become
        active before this plus the failures still to come reaches ``k``."""
        return self._tail_failures

    def reset(self) -> None:
        """Forget all history."""
        self._tail = np.zeros(0, dtype=bool)
        self._tail_failures = 0
        self.active = False
        self.t_first = None
        self.raised = 0
        self.t_first_raised = None

    def update(self, failed: np.ndarray, t: np.ndarray) -> bool:
        """Feed check outcomes (True = failed) at sample times ``t`` (s); returns ``active``."""
        failed = np.asarray(failed, dtype=bool)
        if failed.size == 0:
            return self.active
        if not self.active and not failed.any() and not self._tail.any():
            # nothing failed within the window: the state cannot change (the common case,
            # taken by every check on every daemon turn; the general path costs ~10x more)
            keep = min(self._tail.size + failed.size, self.n - 1)
            if keep != self._tail.size:
                self._tail = np.zeros(keep, dtype=bool)
            return False
        seq = np.concatenate([self._tail, failed])
        c = np.concatenate([[0], np.cumsum(seq, dtype=np.int64)])
        idx = np.arange(len(self._tail), len(seq))  # positions of the new checks
        count = c[idx + 1] - c[np.maximum(idx + 1 - self.n, 0)]
        sets = np.flatnonzero(count >= self.k)
        clears = np.flatnonzero(count <= self.k_clear)
        self._count_raises(sets, clears, t)
        last_set = sets[-1] if sets.size else -1
        last_clear = clears[-1] if clears.size else -1
        if last_set > last_clear:
            if not self.active:
                # first set after the last clear that precedes it
                earlier_clears = clears[clears < last_set]
                start = earlier_clears[-1] if earlier_clears.size else -1
                first_set = sets[np.searchsorted(sets, start + 1)]
                self.t_first = float(t[first_set])
            elif last_clear >= 0:
                # cleared and set again inside this block
                first_set = sets[np.searchsorted(sets, last_clear + 1)]
                self.t_first = float(t[first_set])
            self.active = True
        elif last_clear > last_set:
            self.active = False
        self._tail = seq[-(self.n - 1) :] if self.n > 1 else np.zeros(0, dtype=bool)
        self._tail_failures = int(np.count_nonzero(self._tail))
        return self.active

    def _count_raises(self, sets: np.ndarray, clears: np.ndarray, t: np.ndarray) -> None:
        """Count inactive -> active transitions among this block's set/clear positions."""
        if not sets.size:
            return
        pos = np.concatenate([sets, clears])
        kind = np.concatenate([np.ones(sets.size, np.int8), -np.ones(clears.size, np.int8)])
        order = np.argsort(pos, kind="stable")
        pos, kind = pos[order], kind[order]
        prev = np.concatenate([[1 if self.active else -1], kind[:-1]])
        rises = np.flatnonzero((kind == 1) & (prev == -1))
        if rises.size:
            self.raised += int(rises.size)
            if self.t_first_raised is None:
                self.t_first_raised = float(t[pos[rises[0]]])
