"""WHY THIS FILE STAYS (issue 30 item 6): a part of the reference of
``tests/test_monitor_equivalence.py``; the note at the top of ``old_monitor.py`` says why
it is kept. Do not edit.

Trailing-window sums over a stream of rows, carried across blocks (vectorised)."""

from __future__ import annotations

import numpy as np


class TrailingSum:
    """Sum of the last ``window`` rows ending at each new row, for a stream fed in blocks.

    Rows are (N, k) arrays (or (N,) vectors). The first ``window - 1`` rows of
    the stream have shorter windows; :meth:`update` returns the row count of
    each window alongside the sums so callers can require full windows.
    """

    def __init__(self, window: int, width: int | None = None) -> None:
        if window < 1:
            raise ValueError(f"trailing window must be >= 1 row, got {window}")
        self.window = int(window)
        shape = (0,) if width is None else (0, width)
        self._tail = np.zeros(shape)

    def update(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sums, counts) for each row of ``rows``: sums has the rows' shape, counts (N,)."""
        rows = np.asarray(rows, dtype=float)
        seq = np.concatenate([self._tail, rows]) if self._tail.size else rows
        zero = np.zeros((1,) + seq.shape[1:])
        c = np.concatenate([zero, np.cumsum(seq, axis=0)])
        idx = np.arange(seq.shape[0] - rows.shape[0], seq.shape[0])
        lo = np.maximum(idx + 1 - self.window, 0)
        self._tail = seq[seq.shape[0] - min(self.window - 1, seq.shape[0]) :]
        return c[idx + 1] - c[lo], idx + 1 - lo
