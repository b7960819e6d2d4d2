"""Trailing spread (per-column max - min) of a stream's values over a history that can
restart: the drift tests of the still detector (:mod:`imudiag.quasistatic.detector`), kept
cheap per call (one comparison per row between kept values, a sparse table of maxima on
long blocks). ``tests/test_quasistatic_paths.py`` checks it against the plain definition
(:func:`plain_spread`). Where the compiled kernels are on (:mod:`imudiag.kernels`) the
extremes and the rows' spreads are one compiled pass
(:func:`imudiag.numba_kernels.trailing_spread`): max and min are exact, so the spreads are
the same numbers and the detector's flags the same (tests/test_detector_kernels.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..kernels import kernel

#: block rows from which :class:`TrailingSpread` repeats each kept value's extremes over its
#: rows instead of gathering them (the same values; a gather costs more on long blocks)
_REPEAT_ROWS = 4096


class TrailingSpread:
    """Per-column spread (max - min) of a stream's values over a trailing history: the
    drift test of :class:`QuasiStaticDetector`.

    Values are kept every ``step`` stream rows (absolute row index a multiple of
    ``step``); the spread at row i covers the kept values from its history's first
    row (given) up to i, and row i's own value. Results depend on the absolute row
    indices only, not on the blocks. Each kept value's extremes over its own history
    are worked out once, when it is kept (every ``step`` rows), so the rows between
    cost one comparison with the last kept value's.
    """

    def __init__(self, columns: int, step: int, span: int) -> None:
        self.columns = int(columns)
        self.step = max(1, int(step))
        self.span = max(self.step, int(span))
        self.k = self.span // self.step + 1  #: kept values a history holds at most
        self.reset()

    def reset(self) -> None:
        """Forget the history."""
        c = self.columns
        self._idx = np.zeros(0, dtype=np.int64)
        self._val = np.zeros((0, 2 * c))  # each kept value and its negative
        self._start = np.zeros(0, dtype=np.int64)
        self._max = np.zeros((0, c))
        self._min = np.zeros((0, c))

    def _extremes(
        self, d_idx: np.ndarray, d_val: np.ndarray, d_start: np.ndarray, old: int
    ) -> np.ndarray:
        """The maxima (new, 2C) over each kept value's history of the kept values and their
        negatives ``d_val`` (total, 2C), for the values kept from position ``old`` on; a
        history holds the value's k last kept values from its first row ``d_start`` on
        (-inf where it holds none). Few new values (a daemon's read): one reduction each;
        many: a sparse table of maxima (max is exact, so both give the same figures)."""
        k = self.k
        total = d_idx.shape[0]
        new = total - old
        firsts = np.searchsorted(d_idx, d_start[old:])
        if new < 8:
            ext = np.empty((new, d_val.shape[1]))
            for i, first in enumerate(firsts.tolist()):
                at = old + i
                lo = max(at - k + 1, first)  # among its k last kept values, those from its start
                ext[i] = d_val[lo : at + 1].max(axis=0) if lo <= at else -np.inf
            return ext
        j = np.arange(old, total)
        los = np.maximum(j - k + 1, firsts)
        # a sparse table: level q holds the maxima of 2^q consecutive kept values, so a
        # history of L values is the maximum of two overlapping runs of 2^floor(log2 L)
        none = los > j  # no kept value in the history (-inf)
        los[none] = j[none]
        length = j - los + 1
        q = np.frexp(length.astype(float))[1] - 1  # floor(log2 L), exactly
        table = np.full((int(q.max()) + 1, total, d_val.shape[1]), -np.inf)
        table[0] = d_val
        for level in range(1, table.shape[0]):
            h = 1 << (level - 1)
            np.maximum(table[level - 1, :-h], table[level - 1, h:], out=table[level, :-h])
        ext = np.maximum(table[q, los], table[q, j + 1 - (1 << q)])
        ext[none] = -np.inf
        return ext

    def update(self, first: int, values: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Spreads (M, C) for the M consecutive stream rows from row ``first``, with
        ``values`` (M, C) and the first row of each row's history ``start`` (M,)."""
        m = values.shape[0]
        step, k, c = self.step, self.k, self.columns
        old = self._idx.shape[0]
        k0 = -first % step  # block row of the first kept value
        compiled = kernel("trailing_spread")
        if compiled is not None:
            return self._update_compiled(compiled, first, values, start)
        if k0 < m:
            kept = values[k0::step]
            d_idx = np.concatenate([self._idx, np.arange(first + k0, first + m, step)])
            d_val = np.concatenate([self._val, np.concatenate([kept, -kept], axis=1)])
            d_start = np.concatenate([self._start, start[k0::step]])
            total = d_idx.shape[0]
            # the extremes of each new kept value's history: the maxima of the values and of
            # their negatives (minus the minima) in one reduction
            ext = self._extremes(d_idx, d_val, d_start, old)
            d_max = np.concatenate([self._max, ext[:, :c]])
            d_min = np.concatenate([self._min, -ext[:, c:]])
            # each row's last kept value (at or before it)
            if m < _REPEAT_ROWS:
                p = old + (np.arange(m) - k0) // step
                pc = np.maximum(p, 0)
                have = (p >= 0) & (d_idx[pc] >= start)
                last_max, last_min = d_max[pc], d_min[pc]
            else:  # a big block: runs of ``step`` rows, repeated rather than gathered
                new = total - old
                counts = np.full(new + 1, step)
                counts[0] = k0  # the rows before the first new kept value: the last one kept
                counts[-1] = m - k0 - step * (new - 1)
                at = max(old - 1, 0)  # (none before: any row, ``have`` is False there)
                have = np.repeat(np.concatenate([d_idx[at : at + 1], d_idx[old:]]), counts)
                have = have >= start
                if not old:
                    have[:k0] = False
                last_max = np.repeat(np.concatenate([d_max[at : at + 1], d_max[old:]]), counts, 0)
                last_min = np.repeat(np.concatenate([d_min[at : at + 1], d_min[old:]]), counts, 0)
            hi = np.maximum(last_max, values)
            lo_ = np.minimum(last_min, values)
            keep = slice(max(0, total - k), None)
            self._idx, self._val, self._start = d_idx[keep], d_val[keep], d_start[keep]
            self._max, self._min = d_max[keep], d_min[keep]
        elif old:
            have = self._idx[-1] >= start
            hi = np.maximum(self._max[-1], values)
            lo_ = np.minimum(self._min[-1], values)
        else:
            return np.zeros(values.shape)
        spread = hi - lo_
        finite = np.isfinite(spread)
        if m >= _REPEAT_ROWS and have.all() and finite.all():
            return spread
        return np.where(have[:, None] & finite, spread, 0.0)

    def _update_compiled(
        self, compiled: Any, first: int, values: np.ndarray, start: np.ndarray
    ) -> np.ndarray:
        """:meth:`update` by the compiled kernel: the same kept values and state."""
        m = values.shape[0]
        step, k, c = self.step, self.k, self.columns
        old = self._idx.shape[0]
        k0 = -first % step
        values = np.asarray(values, dtype=float)  # (a strided view is read in place)
        if k0 < m:
            kept = values[k0::step]
            d_idx = np.concatenate([self._idx, np.arange(first + k0, first + m, step)])
            d_val = np.concatenate([self._val, np.concatenate([kept, -kept], axis=1)])
            d_start = np.concatenate([self._start, start[k0::step]])
            new = d_idx.shape[0] - old
            d_max = np.concatenate([self._max, np.empty((new, c))])
            d_min = np.concatenate([self._min, np.empty((new, c))])
        else:
            d_idx, d_val, d_start, d_max, d_min = (
                self._idx, self._val, self._start, self._max, self._min
            )  # fmt: skip
        out: np.ndarray = compiled(
            d_idx.astype(np.int64, copy=False),
            d_val,
            d_start.astype(np.int64, copy=False),
            d_max,
            d_min,
            old,
            k0,
            values,
            np.ascontiguousarray(start, dtype=np.int64),
            step,
            k,
        )
        keep = slice(max(0, d_idx.shape[0] - k), None)
        self._idx, self._val, self._start = d_idx[keep], d_val[keep], d_start[keep]
        self._max, self._min = d_max[keep], d_min[keep]
        return out


def plain_spread(
    rows: np.ndarray, values: np.ndarray, start: np.ndarray, step: int, span: int
) -> np.ndarray:
    """What :class:`TrailingSpread` computes, by its definition, row by row (slow: for
    tests). A whole stream: ``rows`` (M,) its stream rows from 0, ``values`` (M, C),
    ``start`` (M,) each row's history start. A value is kept at each row that is a multiple
    of ``step``; a kept value's history is the ``span // step + 1`` latest kept values up
    to it whose rows are at or after its own start. Row i's spread (per column, max - min)
    covers its last kept value's history and its own value, if that kept value is at or
    after row i's start; else (or where not finite) 0."""
    step = max(1, int(step))
    k = max(step, int(span)) // step + 1
    out = np.zeros(values.shape)
    kept = np.flatnonzero(rows % step == 0)
    for i in range(rows.shape[0]):
        before = kept[kept <= i]
        if before.size == 0 or rows[before[-1]] < start[i]:
            continue
        j = before[-1]
        history = before[-k:]
        history = history[rows[history] >= start[j]]
        group = np.vstack([values[history], values[i : i + 1]])
        spread = group.max(axis=0) - group.min(axis=0)
        out[i] = np.where(np.isfinite(spread), spread, 0.0)
    return out
